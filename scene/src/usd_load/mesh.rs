//! `UsdGeomMesh` into a world-space [`Mesh`]: faces fan-triangulated (`(0, i, i+1)`), `normals`
//! (or `primvars:normals`) and `primvars:st` at vertex, face-varying or uniform interpolation
//! (indexed primvars expanded), `orientation = "leftHanded"` and mirroring transforms keeping
//! counter-clockwise front faces. A mesh whose attributes vary per face corner is unwelded.

use super::walk::{self, Error, Reader, add_triangles, int_array, interpolation, token};
use crate::gltf_load::flat_shaded;
use crate::limits;
use crate::model::Mesh;
use crate::shading::normalize;
use glam::{DMat3, DMat4, DVec3};
use openusd::usd::Prim;

/// How a per-mesh attribute is laid out over the mesh.
#[derive(Clone, Copy, PartialEq)]
enum Per {
    Point,
    Corner,
    Face,
}

/// An attribute's values and their layout (`None`: not used).
fn layout<T: Copy>(
    r: &mut Reader,
    what: &str,
    values: Option<Vec<T>>,
    interp: Option<String>,
    default: &str,
    sizes: [usize; 3],
) -> Option<(Vec<T>, Per)> {
    let values = values?;
    let per = match interp.as_deref().unwrap_or(default) {
        "vertex" | "varying" => Per::Point,
        "faceVarying" => Per::Corner,
        "uniform" => Per::Face,
        _ => {
            r.ignored
                .insert(format!("{what} of constant interpolation"));
            return None;
        }
    };
    let need = sizes[per as usize];
    if values.len() != need {
        r.ignored
            .insert(format!("{what} whose count does not match the mesh"));
        return None;
    }
    Some((values, per))
}

/// An indexed primvar's values expanded through its `:indices`.
fn expand<T: Copy>(prim: &Prim, name: &str, values: Vec<T>, r: &Reader) -> Result<Vec<T>, Error> {
    let Some(indices) = int_array(prim, &format!("{name}:indices"), r.time)? else {
        return Ok(values);
    };
    indices
        .iter()
        .map(|&i| {
            usize::try_from(i)
                .ok()
                .and_then(|i| values.get(i).copied())
                .ok_or_else(|| {
                    Error::Usd(format!(
                        "{}.{name}:indices holds {i}, outside its {} values",
                        prim.path().as_str(),
                        values.len()
                    ))
                })
        })
        .collect()
}

/// Reads the `UsdGeomMesh` `prim` into a world-space mesh of the scene, placed by `world`; a mesh
/// without points or triangles adds nothing, and an emissive or light mesh is noted as a light.
pub(super) fn read(r: &mut Reader, prim: &Prim, world: DMat4) -> Result<(), Error> {
    let t = r.time;
    let path = prim.path().as_str().to_string();
    let Some(points) = walk::vec3_array(prim, "points", t)? else {
        return Ok(());
    };
    r.points += points.len() as u64;
    super::count("points", r.points, limits::MAX_VERTICES)?;
    let Some(Faces {
        counts,
        indices,
        triangles,
    }) = faces(r, prim, &path, points.len())?
    else {
        return Ok(());
    };
    let is_light = check_prim(r, prim, &path)?;
    let sizes = [points.len(), indices.len(), counts.len()];
    let (normals, st) = primvars(r, prim, sizes)?;
    let left = token(prim, "orientation", t)?.as_deref() == Some("leftHanded");
    let double_sided = walk::boolean(prim, "doubleSided", t)?.unwrap_or(false);
    let material = super::light::material(r, prim, double_sided)?;
    let name = prim
        .path()
        .name()
        .map(str::to_string)
        .unwrap_or_else(|| path.clone());
    let mut mesh = Mesh {
        name,
        positions: Vec::new(),
        normals: Vec::new(),
        uvs: Vec::new(),
        tangents: Vec::new(),
        indices: Vec::with_capacity(triangles as usize * 3),
        material,
    };
    let welded = fill_attributes(&mut mesh, points, normals, st, &counts, &indices);
    let mirrored = world.determinant() < 0.0;
    add_faces(&mut mesh, &counts, &indices, welded, left != mirrored);
    to_world(&mut mesh, world);
    let mesh = if mesh.normals.is_empty() {
        flat_shaded(mesh).0
    } else {
        mesh
    };
    let k = r.scene.meshes.len();
    r.scene.meshes.push(mesh);
    if is_light {
        super::light::mesh_light(r, prim, k)?;
    } else if r.scene.materials[material]
        .emissive
        .iter()
        .any(|&c| c > 0.0)
    {
        r.emissive_meshes.push(k);
    }
    Ok(())
}

/// An error about the prim at `path` (shortened to 200 characters).
fn prim_error(path: &str, message: String) -> Error {
    Error::Usd(format!("{}: {message}", walk::truncate(path, 200)))
}

/// A mesh's faces: vertex counts per face, the point index of each corner, and the number of
/// triangles they fan into.
struct Faces {
    counts: Vec<i64>,
    indices: Vec<i64>,
    triangles: u64,
}

/// Reads and checks the mesh's faces against its `points` points and counts their triangles
/// towards the model's limit; `None` when the mesh has no triangles.
fn faces(r: &mut Reader, prim: &Prim, path: &str, points: usize) -> Result<Option<Faces>, Error> {
    let t = r.time;
    let bad = |m: String| prim_error(path, m);
    let counts = int_array(prim, "faceVertexCounts", t)?.unwrap_or_default();
    let indices = int_array(prim, "faceVertexIndices", t)?.unwrap_or_default();
    super::count(
        "face-vertex indices",
        indices.len() as u64,
        limits::MAX_VERTICES,
    )?;
    let mut triangles = 0u64;
    let mut corners = 0u64;
    for (f, &c) in counts.iter().enumerate() {
        if c < 3 {
            return Err(bad(format!(
                "faceVertexCounts[{f}] is {c}; a face has at least 3 vertices"
            )));
        }
        triangles += c as u64 - 2;
        corners += c as u64;
    }
    if corners != indices.len() as u64 {
        return Err(bad(format!(
            "faceVertexCounts add up to {corners} but faceVertexIndices has {}",
            indices.len()
        )));
    }
    add_triangles(r, triangles)?;
    if let Some((k, &i)) = indices
        .iter()
        .enumerate()
        .find(|&(_, &i)| i < 0 || i as u64 >= points as u64)
    {
        return Err(bad(format!(
            "faceVertexIndices[{k}] is {i}, outside its {points} points"
        )));
    }
    if triangles == 0 {
        return Ok(None);
    }
    Ok(Some(Faces {
        counts,
        indices,
        triangles,
    }))
}

/// Counts the mesh towards the model's limit, notes what of the prim is not rendered
/// (subdivision, time-sampled points) and returns whether the prim is a mesh light.
fn check_prim(r: &mut Reader, prim: &Prim, path: &str) -> Result<bool, Error> {
    let bad = |m: String| prim_error(path, m);
    super::count(
        "meshes",
        r.scene.meshes.len() as u64 + 1,
        limits::MAX_MODEL_MESHES,
    )?;
    let scheme = token(prim, "subdivisionScheme", r.time)?;
    if scheme.as_deref() != Some("none") {
        r.ignored
            .insert("subdivision surfaces (their control meshes are rendered)".into());
    }
    let is_light = prim
        .api_schemas()
        .map_err(|e| bad(e.to_string()))?
        .iter()
        .any(|s| matches!(s.as_str(), "MeshLightAPI" | "LightAPI"));
    if prim
        .attribute("points")
        .num_time_samples()
        .map_err(|e| bad(e.to_string()))?
        > 1
    {
        r.ignored
            .insert("time-sampled points (read at the start time)".into());
    }
    Ok(is_light)
}

/// A mesh's normals and their layout, if used.
type Normals = Option<(Vec<[f32; 3]>, Per)>;
/// A mesh's texture coordinates and their layout, if used.
type Uvs = Option<(Vec<[f32; 2]>, Per)>;

/// Reads the mesh's normals (`primvars:normals`, else `normals`) and `primvars:st`, expanded
/// through their indices, with their layouts over `sizes` (points, corners, faces).
fn primvars(r: &mut Reader, prim: &Prim, sizes: [usize; 3]) -> Result<(Normals, Uvs), Error> {
    let t = r.time;
    let normals_name = if walk::value(prim, "primvars:normals", t)?.is_some() {
        "primvars:normals"
    } else {
        "normals"
    };
    let normals = match walk::vec3_array(prim, normals_name, t)? {
        Some(n) => Some(expand(prim, normals_name, n, r)?),
        None => None,
    };
    let normals = layout(
        r,
        "normals",
        normals,
        interpolation(prim, normals_name)?,
        "vertex",
        sizes,
    );
    let st = match walk::vec2_array(prim, "primvars:st", t)? {
        Some(v) => Some(expand(prim, "primvars:st", v, r)?),
        None => None,
    };
    let st = layout(
        r,
        "primvars:st",
        st,
        interpolation(prim, "primvars:st")?,
        "vertex",
        sizes,
    );
    Ok((normals, st))
}

/// Fills the mesh's positions, normals and texture coordinates: shared per point when every
/// attribute is per point (welded, the returned flag), else one vertex per face corner.
fn fill_attributes(
    mesh: &mut Mesh,
    points: Vec<[f32; 3]>,
    normals: Normals,
    st: Uvs,
    counts: &[i64],
    indices: &[i64],
) -> bool {
    let welded = normals.as_ref().is_none_or(|n| n.1 == Per::Point)
        && st.as_ref().is_none_or(|s| s.1 == Per::Point);
    // Each corner's point, and each corner's (or point's) attribute row.
    let corner_face: Vec<usize> = counts
        .iter()
        .enumerate()
        .flat_map(|(f, &c)| std::iter::repeat_n(f, c as usize))
        .collect();
    let pick = |per: Per, k: usize| match per {
        Per::Point => indices[k] as usize,
        Per::Corner => k,
        Per::Face => corner_face[k],
    };
    if welded {
        mesh.positions = points;
        mesh.normals = normals.map(|n| n.0).unwrap_or_default();
        mesh.uvs = st.map(|s| s.0).unwrap_or_default();
    } else {
        mesh.positions = indices.iter().map(|&i| points[i as usize]).collect();
        if let Some((n, per)) = &normals {
            mesh.normals = (0..indices.len()).map(|k| n[pick(*per, k)]).collect();
        }
        if let Some((s, per)) = &st {
            mesh.uvs = (0..indices.len()).map(|k| s[pick(*per, k)]).collect();
        }
    }
    // USD's st has v up; lightfold's textures have row 0 at the top.
    for uv in &mut mesh.uvs {
        uv[1] = 1.0 - uv[1];
    }
    welded
}

/// Fan-triangulates the faces into the mesh's indices, reversing each triangle's winding when
/// `flip` (a left-handed mesh or a mirroring transform, not both).
fn add_faces(mesh: &mut Mesh, counts: &[i64], indices: &[i64], welded: bool, flip: bool) {
    let corner = |k: usize| if welded { indices[k] as u32 } else { k as u32 };
    let mut start = 0usize;
    for &c in counts {
        for i in 1..c as usize - 1 {
            let (a, b, d) = (corner(start), corner(start + i), corner(start + i + 1));
            if flip {
                mesh.indices.extend_from_slice(&[a, d, b]);
            } else {
                mesh.indices.extend_from_slice(&[a, b, d]);
            }
        }
        start += c as usize;
    }
}

/// Moves the mesh's positions and normals into world space by `world`.
fn to_world(mesh: &mut Mesh, world: DMat4) {
    let normal_matrix = DMat3::from_mat4(world).inverse().transpose();
    for p in &mut mesh.positions {
        *p = world
            .transform_point3(DVec3::from(p.map(f64::from)))
            .as_vec3()
            .to_array();
    }
    for n in &mut mesh.normals {
        let v = (normal_matrix * DVec3::from(n.map(f64::from))).as_vec3();
        *n = normalize(v.to_array());
    }
}
