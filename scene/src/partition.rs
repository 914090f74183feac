//! Sort-last partitions of a scene's meshes (issue 24, seed 000 §6): `parts` spatially coherent
//! groups balanced by triangle count, by recursive bisection of the mesh centres. Each step sorts
//! the group's meshes along the longest axis of their centres' bounds (ties by mesh index) and
//! cuts where the triangles before the cut come nearest the share of the parts on that side, so
//! every part holds about `total / parts` triangles: off by at most about the largest mesh per
//! level of bisection, since meshes are not split. Deterministic: the same scene gives the same
//! parts. Pure CPU code.

use crate::model::{Mesh, Scene};

/// Partitions the meshes of `scene` into `parts` groups (mesh indices, ascending in each).
/// Every mesh is in exactly one group; meshes without a finite position go to the first group;
/// groups are empty only when there are fewer meshes than `parts`. `parts` 0 is taken as 1.
pub fn partition_meshes(scene: &Scene, parts: usize) -> Vec<Vec<u32>> {
    let parts = parts.max(1);
    let mut out = vec![Vec::new(); parts];
    // (index, centre, triangles) of the meshes with a position; the others join part 0.
    let mut items: Vec<(u32, [f32; 3], u64)> = Vec::with_capacity(scene.meshes.len());
    for (i, m) in scene.meshes.iter().enumerate() {
        match m.bounds() {
            Some((lo, hi)) => items.push((
                i as u32,
                [0, 1, 2].map(|k| 0.5 * lo[k] + 0.5 * hi[k]),
                m.triangle_count() as u64,
            )),
            None => out[0].push(i as u32),
        }
    }
    bisect(&mut items, 0, parts, &mut out);
    for p in &mut out {
        p.sort_unstable();
    }
    out
}

/// Splits `items` into parts `first .. first + count` of `out`.
fn bisect(items: &mut [(u32, [f32; 3], u64)], first: usize, count: usize, out: &mut [Vec<u32>]) {
    if count == 1 || items.len() <= 1 {
        out[first].extend(items.iter().map(|it| it.0));
        return;
    }
    let axis = longest_axis(items);
    items.sort_by(|a, b| a.1[axis].total_cmp(&b.1[axis]).then(a.0.cmp(&b.0)));
    let left_parts = count / 2;
    let total: u64 = items.iter().map(|it| it.2.max(1)).sum();
    // The cut whose left triangles come nearest the left parts' share; each side keeps at least
    // as many meshes as it has parts where it can.
    let want = total as f64 * left_parts as f64 / count as f64;
    let lo = left_parts.min(items.len() - 1).max(1);
    let hi = items.len().saturating_sub(count - left_parts).max(lo);
    let mut acc = 0u64;
    let mut best = (f64::INFINITY, lo);
    for (cut, it) in items.iter().enumerate().take(hi) {
        acc += it.2.max(1);
        let at = cut + 1;
        if at < lo {
            continue;
        }
        let miss = (acc as f64 - want).abs();
        if miss < best.0 {
            best = (miss, at);
        }
    }
    let (left, right) = items.split_at_mut(best.1);
    bisect(left, first, left_parts, out);
    bisect(right, first + left_parts, count - left_parts, out);
}

fn longest_axis(items: &[(u32, [f32; 3], u64)]) -> usize {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for it in items {
        for k in 0..3 {
            lo[k] = lo[k].min(it.1[k]);
            hi[k] = hi[k].max(it.1[k]);
        }
    }
    (0..3)
        .max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b])).then(b.cmp(&a)))
        .unwrap_or(0)
}

/// The scene one sort-last node needs (`docs/planner.md` § Partitions): the meshes `keep` marks
/// whole, every other mesh with triangles replaced by a stand-in, one triangle spanning the
/// bounds of the mesh's triangles with the mesh's material. A node never draws a stand-in (it is
/// in no eye part, no light's casters and no glass pass of that node). Stand-ins keep every
/// mesh's box, hence the scene's extent (which sets the shadow views' near plane) and what views
/// fitted to every mesh would cover, so the node's maps and image are those of the whole scene. Mesh indices, materials, textures, lights and camera
/// are unchanged. A mesh whose bounds no triangle can span without failing validation (flat in
/// two axes, which a clean mesh is not) is kept whole. Meshes past `keep`'s end are replaced.
pub fn keep_meshes(scene: &Scene, keep: &[bool]) -> Scene {
    let meshes = scene
        .meshes
        .iter()
        .enumerate()
        .map(|(i, m)| {
            if keep.get(i).copied().unwrap_or(false) {
                m.clone()
            } else {
                stand_in(m).unwrap_or_else(|| m.clone())
            }
        })
        .collect();
    Scene {
        name: scene.name.clone(),
        meshes,
        materials: scene.materials.clone(),
        textures: scene.textures.clone(),
        lights: scene.lights.clone(),
        camera: scene.camera,
        ambient: scene.ambient,
        exposure: scene.exposure,
        quality: scene.quality,
        animation: scene.animation.clone(),
    }
}

/// One triangle over the bounds of `m`'s triangles: its two extreme corners and the box corner
/// that makes the largest triangle with them. `None` for a mesh without triangles (kept as it is)
/// or one too flat to span.
fn stand_in(m: &Mesh) -> Option<Mesh> {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for t in m.indices.chunks_exact(3) {
        for &i in t {
            let p = m.positions.get(i as usize)?;
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
    }
    if !lo.iter().chain(&hi).all(|c| c.is_finite()) {
        return None;
    }
    let corners = [
        [lo[0], lo[1], hi[2]],
        [lo[0], hi[1], lo[2]],
        [hi[0], lo[1], lo[2]],
    ];
    let area = |c: &[f32; 3]| {
        let e1 = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
        let e2 = [c[0] - lo[0], c[1] - lo[1], c[2] - lo[2]];
        let x = [
            e1[1] * e2[2] - e1[2] * e2[1],
            e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0],
        ];
        let c2 = (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
        let scale2 = e1.iter().chain(&e2).map(|v| v * v).sum::<f32>();
        (c2, scale2)
    };
    let third = corners
        .iter()
        .max_by(|a, b| area(a).0.total_cmp(&area(b).0))?;
    // The validation's rule for a degenerate triangle (`validate`), with a margin.
    let (c, scale2) = area(third);
    if !(c.is_finite() && c > 1e-6 * scale2) {
        return None;
    }
    Some(Mesh {
        name: m.name.clone(),
        positions: vec![lo, hi, *third],
        normals: Vec::new(),
        uvs: Vec::new(),
        tangents: Vec::new(),
        indices: vec![0, 1, 2],
        material: m.material,
    })
}

/// `scene` with every mesh too large for `parts` parts split into chunks (`None` when no mesh
/// is): a mesh of more triangles than a part's share (`total / parts`) becomes chunks of at most
/// half a share, by recursive bisection of its triangles' centroids along their longest axis, so
/// [`partition_meshes`] can balance the parts. The first chunk keeps the mesh's index and the
/// others are appended, so every other mesh keeps its index. Each chunk copies the vertices its
/// triangles use and is named `name#k`. An animated scene, or a mesh an emissive-mesh light
/// samples, is left whole (tracks and lights name meshes by index). Deterministic.
pub fn chunk_for_parts(scene: &Scene, parts: usize) -> Option<Scene> {
    if parts <= 1 || scene.animation.is_some() {
        return None;
    }
    let total: usize = scene.meshes.iter().map(Mesh::triangle_count).sum();
    let share = total.div_ceil(parts);
    let emissive: Vec<usize> = scene
        .lights
        .iter()
        .filter_map(|l| match l.shape {
            crate::model::LightShape::EmissiveMesh { mesh } => Some(mesh),
            _ => None,
        })
        .collect();
    let too_large = |(i, m): &(usize, &Mesh)| m.triangle_count() > share && !emissive.contains(i);
    if !scene.meshes.iter().enumerate().any(|im| too_large(&im)) {
        return None;
    }
    let mut out = scene.clone();
    let mut appended = Vec::new();
    for (i, m) in scene.meshes.iter().enumerate() {
        if !too_large(&(i, m)) {
            continue;
        }
        let pieces = m.triangle_count().div_ceil((share / 2).max(1));
        let mut chunks = split_mesh(m, pieces).into_iter();
        if let Some(first) = chunks.next() {
            out.meshes[i] = first;
        }
        appended.extend(chunks);
    }
    out.meshes.extend(appended);
    Some(out)
}

/// `m` split into `pieces` chunks of its triangles (fewer when it has fewer triangles).
fn split_mesh(m: &Mesh, pieces: usize) -> Vec<Mesh> {
    let mut tris: Vec<(u32, [f32; 3], u64)> = m
        .indices
        .chunks_exact(3)
        .enumerate()
        .map(|(t, tri)| {
            let mut c = [0.0f32; 3];
            for &v in tri {
                let p = m.positions.get(v as usize).copied().unwrap_or([0.0; 3]);
                for k in 0..3 {
                    c[k] += p[k] / 3.0;
                }
            }
            let c = c.map(|x| if x.is_finite() { x } else { 0.0 });
            (t as u32, c, 1)
        })
        .collect();
    let pieces = pieces.clamp(1, tris.len().max(1));
    let mut groups = vec![Vec::new(); pieces];
    bisect(&mut tris, 0, pieces, &mut groups);
    groups
        .iter_mut()
        .enumerate()
        .map(|(k, g)| {
            // Triangles in their original order within a chunk.
            g.sort_unstable();
            let mut remap = vec![u32::MAX; m.positions.len()];
            let mut chunk = Mesh {
                name: format!("{}#{k}", m.name),
                positions: Vec::new(),
                normals: Vec::new(),
                uvs: Vec::new(),
                tangents: Vec::new(),
                indices: Vec::with_capacity(g.len() * 3),
                material: m.material,
            };
            let has_normals = m.normals.len() == m.positions.len();
            let has_uvs = m.uvs.len() == m.positions.len();
            let has_tangents = m.tangents.len() == m.positions.len();
            for &t in g.iter() {
                let tri = &m.indices[t as usize * 3..t as usize * 3 + 3];
                if tri.iter().any(|&v| v as usize >= m.positions.len()) {
                    continue; // out of range: no renderer draws it either
                }
                for &v in tri {
                    let v = v as usize;
                    if remap[v] == u32::MAX {
                        remap[v] = chunk.positions.len() as u32;
                        chunk.positions.push(m.positions[v]);
                        if has_normals {
                            chunk.normals.push(m.normals[v]);
                        }
                        if has_uvs {
                            chunk.uvs.push(m.uvs[v]);
                        }
                        if has_tangents {
                            chunk.tangents.push(m.tangents[v]);
                        }
                    }
                    chunk.indices.push(remap[v]);
                }
            }
            chunk
        })
        .collect()
}
