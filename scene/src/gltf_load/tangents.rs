//! MikkTSpace tangents for a normal-mapped primitive that ships none: the glTF specification asks
//! clients to compute them with the default MikkTSpace algorithm from the positions, normals and
//! the normal texture's coordinates (`bevy_mikktspace`, a Rust port of Mikkelsen's reference).
//! MikkTSpace gives a tangent per triangle corner; a vertex whose corners got different ones
//! (a seam of the tangent space) is split, as the reference implementation's users do.

use crate::model::Mesh;
use bevy_mikktspace::{Geometry, TangentSpace, generate_tangents};
use std::collections::HashMap;

/// The mesh as MikkTSpace reads it, and the tangent it writes per corner.
struct Corners<'a> {
    mesh: &'a Mesh,
    tangents: Vec<[f32; 4]>,
}

impl Corners<'_> {
    fn vertex(&self, face: usize, vert: usize) -> usize {
        self.mesh.indices[face * 3 + vert] as usize
    }
}

impl Geometry for Corners<'_> {
    fn num_faces(&self) -> usize {
        self.mesh.indices.len() / 3
    }

    fn num_vertices_of_face(&self, _face: usize) -> usize {
        3
    }

    fn position(&self, face: usize, vert: usize) -> [f32; 3] {
        self.mesh.positions[self.vertex(face, vert)]
    }

    fn normal(&self, face: usize, vert: usize) -> [f32; 3] {
        self.mesh.normals[self.vertex(face, vert)]
    }

    fn tex_coord(&self, face: usize, vert: usize) -> [f32; 2] {
        self.mesh.uvs[self.vertex(face, vert)]
    }

    fn set_tangent(&mut self, tangent_space: Option<TangentSpace>, face: usize, vert: usize) {
        // MikkTSpace's bitangent runs along +V; glTF's V runs down the image while a normal
        // map's +Y points up, so glTF's handedness is the opposite sign (three.js negates it
        // for glTF the same way). A corner MikkTSpace leaves without one gets none (w = 0).
        self.tangents[face * 3 + vert] = tangent_space.map_or([0.0; 4], |t| {
            let [x, y, z, w] = t.tangent_encoded();
            [x, y, z, -w]
        });
    }
}

/// Fills `mesh.tangents` by MikkTSpace, splitting vertices where corners disagree. The mesh
/// needs normals and UVs for every position and in-range indices; returns whether it had them.
pub(super) fn generate(mesh: &mut Mesh) -> bool {
    let n = mesh.positions.len();
    if mesh.normals.len() != n
        || mesh.uvs.len() != n
        || mesh.indices.iter().any(|&i| i as usize >= n)
        || mesh.indices.len() < 3
    {
        return false;
    }
    let mut corners = Corners {
        mesh,
        tangents: vec![[0.0; 4]; mesh.indices.len()],
    };
    if generate_tangents(&mut corners).is_err() {
        return false;
    }
    let per_corner = corners.tangents;
    let bits = |t: [f32; 4]| t.map(f32::to_bits);
    let mut tangents: Vec<Option<[f32; 4]>> = vec![None; n];
    let mut split: HashMap<(u32, [u32; 4]), u32> = HashMap::new();
    for (c, t) in per_corner.into_iter().enumerate() {
        let v = mesh.indices[c];
        match tangents[v as usize] {
            None => tangents[v as usize] = Some(t),
            Some(a) if bits(a) == bits(t) => {}
            Some(_) => {
                let copy = *split.entry((v, bits(t))).or_insert_with(|| {
                    let i = v as usize;
                    mesh.positions.push(mesh.positions[i]);
                    mesh.normals.push(mesh.normals[i]);
                    mesh.uvs.push(mesh.uvs[i]);
                    tangents.push(Some(t));
                    (mesh.positions.len() - 1) as u32
                });
                mesh.indices[c] = copy;
            }
        }
    }
    mesh.tangents = tangents
        .into_iter()
        .map(|t| t.unwrap_or([0.0; 4]))
        .collect();
    true
}
