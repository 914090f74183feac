//! glTF mesh primitives → world-space lightfold meshes: node transforms (normals by the inverse
//! transpose, winding flipped under mirroring), skinned meshes in their rest pose (joint nodes at
//! their authored transforms), triangle strips and fans, and flat normals where none are given.

use super::accessor::{Buffers, ReadResult};
use crate::animation::{MeshRig, MorphTarget, SkinRig};
use crate::model::Mesh;
use crate::shading::{cross, normalize, sub};
use glam::{Mat3, Mat4, Vec3};
use gltf::Semantic;
use gltf::accessor::Dimensions;
use gltf::mesh::Mode;
use std::collections::BTreeSet;

/// What a node's meshes need from the rest of the document.
pub(super) struct NodeContext<'a> {
    pub bufs: &'a Buffers,
    /// World matrix of every node.
    pub world: &'a [Mat4],
    pub ignored: &'a mut BTreeSet<String>,
    /// Triangles of the model so far (instances counted each time), for the scene limit.
    pub triangles: u64,
    /// Keep what posing needs (the document is animated): each mesh comes with its rig.
    pub rig: bool,
}

/// The meshes of one node's primitives; `material` maps a glTF material index (None = default).
/// With `ctx.rig`, each comes with its rig (`mesh` 0 and `node` the glTF node index, for the
/// caller to renumber).
pub(super) fn node_meshes(
    node: &gltf::Node,
    mesh: &gltf::Mesh,
    ctx: &mut NodeContext,
    material: &mut dyn FnMut(Option<usize>) -> usize,
) -> ReadResult<Vec<(Mesh, Option<MeshRig>)>> {
    let mut out = Vec::new();
    let name = node.name().or(mesh.name()).unwrap_or("mesh");
    for prim in mesh.primitives() {
        if let Some(made) = primitive_mesh(node, mesh, &prim, name, ctx, material)? {
            out.push(made);
        }
    }
    Ok(out)
}

/// The world-space mesh of one primitive of `node`'s mesh (named `{name}#{index}`), with its rig
/// when `ctx.rig`; `None` for a point or line primitive, which is noted as ignored.
fn primitive_mesh(
    node: &gltf::Node,
    mesh: &gltf::Mesh,
    prim: &gltf::Primitive,
    name: &str,
    ctx: &mut NodeContext,
    material: &mut dyn FnMut(Option<usize>) -> usize,
) -> ReadResult<Option<(Mesh, Option<MeshRig>)>> {
    let at = format!("mesh {} primitive {}", mesh.index(), prim.index());
    let mode = prim.mode();
    if !matches!(
        mode,
        Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan
    ) {
        ctx.ignored.insert("point and line primitives".into());
        return Ok(None);
    }
    if prim.morph_targets().len() > 0 && !ctx.rig {
        ctx.ignored.insert("morph targets (base shape used)".into());
    }
    let v = read_vertices(prim, mode, ctx, &at)?;
    let n = v.n;
    let tris = triangulate(mode, &v.indices);

    let skinning = match node.skin() {
        Some(skin) => skin_matrices(&skin, prim, n, ctx, &at)?,
        None => None,
    };
    let mut rig = if ctx.rig {
        Some(MeshRig {
            mesh: 0,
            node: node.index() as u32,
            positions: v.pos.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
            normals: v
                .normals
                .as_ref()
                .map(|v| v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
                .unwrap_or_default(),
            vertex_map: Vec::new(),
            skin: match node.skin() {
                Some(skin) => skin_rig(&skin, prim, n, ctx, &at)?,
                None => None,
            },
            targets: morph_targets(prim, n, v.normals.is_some(), ctx, &at)?,
        })
    } else {
        None
    };
    let mut m = Mesh {
        name: format!("{name}#{}", prim.index()),
        positions: Vec::with_capacity(n),
        normals: Vec::new(),
        uvs: v
            .uvs
            .as_ref()
            .map(|u| u.chunks_exact(2).map(|c| [c[0], c[1]]).collect())
            .unwrap_or_default(),
        tangents: Vec::new(),
        indices: tris,
        material: material(prim.material().index()),
    };
    place_vertices(&mut m, &v, ctx.world[node.index()], skinning.as_deref());
    if v.normals.is_none() {
        let (flat, map) = flat_shaded(m);
        m = flat;
        if let Some(r) = rig.as_mut() {
            r.vertex_map = map;
        }
    }
    // A normal map without the model's tangents: MikkTSpace's, as the specification asks.
    // (A posed mesh uses its triangles' own: rigs carry no tangents.)
    if m.tangents.is_empty()
        && v.normals.is_some()
        && rig.is_none()
        && prim.material().normal_texture().is_some()
    {
        super::tangents::generate(&mut m);
    }
    Ok(Some((m, rig)))
}

/// A primitive's vertex attributes as read (flat arrays of components) and its indices.
struct Vertices {
    /// Number of vertices.
    n: usize,
    pos: Vec<f32>,
    normals: Option<Vec<f32>>,
    uvs: Option<Vec<f32>>,
    tangents: Option<Vec<f32>>,
    indices: Vec<u32>,
}

/// Counts the primitive's declared triangles towards the scene limit, then reads its positions,
/// normals, first texture coordinates, tangents (only with both of those) and indices, checking
/// every count and index against the positions.
fn read_vertices(
    prim: &gltf::Primitive,
    mode: Mode,
    ctx: &mut NodeContext,
    at: &str,
) -> ReadResult<Vertices> {
    let pos_acc = prim
        .get(&Semantic::Positions)
        .ok_or_else(|| format!("{at} has no POSITION attribute"))?;
    // The triangles this primitive declares, counted before anything is read (instances
    // count each time: one mesh placed by many nodes is many meshes).
    let declared = prim.indices().map_or(pos_acc.count(), |a| a.count()) as u64;
    ctx.triangles += match mode {
        Mode::Triangles => declared / 3,
        _ => declared.saturating_sub(2),
    };
    crate::limits::check_triangles(ctx.triangles).map_err(|e| format!("{at}: {e}"))?;
    let (pos, _) = ctx
        .bufs
        .read_f32(&pos_acc, &[Dimensions::Vec3], "POSITION")?;
    let n = pos.len() / 3;
    let attr = |sem: Semantic, dims: Dimensions, what: &str| -> ReadResult<Option<Vec<f32>>> {
        match prim.get(&sem) {
            None => Ok(None),
            Some(acc) => {
                let (v, c) = ctx.bufs.read_f32(&acc, &[dims], what)?;
                if v.len() / c != n {
                    return Err(format!(
                        "{at}: {what} has {} elements but POSITION has {n}",
                        v.len() / c
                    ));
                }
                Ok(Some(v))
            }
        }
    };
    let normals = attr(Semantic::Normals, Dimensions::Vec3, "NORMAL")?;
    let uvs = attr(Semantic::TexCoords(0), Dimensions::Vec2, "TEXCOORD_0")?;
    // Provided tangents go with provided normals (without, the specification has flat
    // normals computed and tangents ignored); a normal map needs UVs too.
    let tangents = match (&normals, &uvs) {
        (Some(_), Some(_)) => attr(Semantic::Tangents, Dimensions::Vec4, "TANGENT")?,
        _ => None,
    };
    if prim.get(&Semantic::Colors(0)).is_some() {
        ctx.ignored.insert("vertex colours".into());
    }
    let indices: Vec<u32> = match prim.indices() {
        Some(acc) => ctx.bufs.read_u32(&acc, &[Dimensions::Scalar], "indices")?.0,
        None => (0..n as u32).collect(),
    };
    if let Some(&bad) = indices.iter().find(|&&i| i as usize >= n) {
        return Err(format!("{at}: index {bad} is out of range ({n} vertices)"));
    }
    Ok(Vertices {
        n,
        pos,
        normals,
        uvs,
        tangents,
        indices,
    })
}

/// Fills the mesh's world-space positions, normals and tangents, each vertex by its skinning
/// matrix (else the node's `rigid` world matrix), and keeps triangles counter-clockwise where a
/// vertex's transform mirrors.
fn place_vertices(m: &mut Mesh, attrs: &Vertices, rigid: Mat4, skinning: Option<&[Mat4]>) {
    let (n, pos) = (attrs.n, &attrs.pos);
    let rigid_normal = normal_matrix(&rigid);
    let mut mirrored = vec![false; n];
    let mut world_normals = Vec::with_capacity(if attrs.normals.is_some() { n } else { 0 });
    let mut world_tangents = Vec::with_capacity(if attrs.tangents.is_some() { n } else { 0 });
    for v in 0..n {
        let p = Vec3::new(pos[3 * v], pos[3 * v + 1], pos[3 * v + 2]);
        let mat = skinning.map_or(rigid, |s| s[v]);
        m.positions.push(mat.transform_point3(p).to_array());
        mirrored[v] = Mat3::from_mat4(mat).determinant() < 0.0;
        if let Some(nrm) = &attrs.normals {
            let nm = if skinning.is_some() {
                normal_matrix(&mat)
            } else {
                rigid_normal
            };
            let nv = Vec3::new(nrm[3 * v], nrm[3 * v + 1], nrm[3 * v + 2]);
            world_normals.push(normalize((nm * nv).to_array()));
        }
        if let Some(t) = &attrs.tangents {
            // A direction in the surface: transformed as positions are; a mirroring
            // transform turns the bitangent w·(n × t) over, so w changes sign with it.
            let tv = Vec3::new(t[4 * v], t[4 * v + 1], t[4 * v + 2]);
            let [x, y, z] = normalize((Mat3::from_mat4(mat) * tv).to_array());
            let w = if t[4 * v + 3] < 0.0 { -1.0 } else { 1.0 };
            let w = if mirrored[v] { -w } else { w };
            world_tangents.push([x, y, z, w]);
        }
    }
    m.normals = world_normals;
    m.tangents = world_tangents;
    // Mirroring transforms turn counter-clockwise into clockwise: swap to keep CCW front.
    for t in m.indices.chunks_exact_mut(3) {
        if mirrored[t[0] as usize] {
            t.swap(1, 2);
        }
    }
}

fn normal_matrix(m: &Mat4) -> Mat3 {
    let m3 = Mat3::from_mat4(*m);
    if m3.determinant().abs() > 1e-30 {
        m3.inverse().transpose()
    } else {
        m3
    }
}

/// Triangle list from a list, strip or fan (strips alternate winding so every triangle keeps the
/// orientation of the first).
fn triangulate(mode: Mode, idx: &[u32]) -> Vec<u32> {
    match mode {
        Mode::TriangleStrip => (0..idx.len().saturating_sub(2))
            .flat_map(|i| {
                if i % 2 == 0 {
                    [idx[i], idx[i + 1], idx[i + 2]]
                } else {
                    [idx[i + 1], idx[i], idx[i + 2]]
                }
            })
            .collect(),
        Mode::TriangleFan => (1..idx.len().saturating_sub(1))
            .flat_map(|i| [idx[0], idx[i], idx[i + 1]])
            .collect(),
        _ => idx[..idx.len() - idx.len() % 3].to_vec(),
    }
}

/// Per-vertex skinning matrices `Σ w_k · world(joint_k) · inverseBind_k` in the rest pose, or
/// `None` when the primitive carries no joints/weights.
fn skin_matrices(
    skin: &gltf::Skin,
    prim: &gltf::Primitive,
    n: usize,
    ctx: &NodeContext,
    at: &str,
) -> ReadResult<Option<Vec<Mat4>>> {
    let Some(rig) = skin_rig(skin, prim, n, ctx, at)? else {
        return Ok(None);
    };
    let joint_mats: Vec<Mat4> = rig
        .joints
        .iter()
        .zip(&rig.inverse_bind)
        .map(|(&j, ib)| ctx.world[j as usize] * Mat4::from_cols_array(ib))
        .collect();
    let mut out = Vec::with_capacity(n);
    for (joints, weights) in rig.vertex_joints.iter().zip(&rig.vertex_weights) {
        let mut m = Mat4::ZERO;
        let mut total = 0.0;
        for k in 0..4 {
            if weights[k] != 0.0 {
                m += joint_mats[joints[k] as usize] * weights[k];
                total += weights[k];
            }
        }
        // Weights should sum to one; renormalise small drift, fall back to the first joint.
        out.push(if total > 1e-6 {
            m * (1.0 / total)
        } else {
            joint_mats.first().copied().unwrap_or(Mat4::IDENTITY)
        });
    }
    Ok(Some(out))
}

/// A skin's joints (glTF node indices), inverse bind matrices and per-vertex influences, or `None`
/// when the primitive carries no joints/weights.
fn skin_rig(
    skin: &gltf::Skin,
    prim: &gltf::Primitive,
    n: usize,
    ctx: &NodeContext,
    at: &str,
) -> ReadResult<Option<SkinRig>> {
    let (Some(ja), Some(wa)) = (
        prim.get(&Semantic::Joints(0)),
        prim.get(&Semantic::Weights(0)),
    ) else {
        return Ok(None);
    };
    let (joints, _) = ctx.bufs.read_u32(&ja, &[Dimensions::Vec4], "JOINTS_0")?;
    let (weights, _) = ctx.bufs.read_f32(&wa, &[Dimensions::Vec4], "WEIGHTS_0")?;
    if joints.len() != 4 * n || weights.len() != 4 * n {
        return Err(format!(
            "{at}: JOINTS_0/WEIGHTS_0 counts differ from POSITION ({n})"
        ));
    }
    let joint_nodes: Vec<u32> = skin.joints().map(|j| j.index() as u32).collect();
    let inverse_bind: Vec<[f32; 16]> = match skin.inverse_bind_matrices() {
        Some(acc) => {
            let (v, _) = ctx
                .bufs
                .read_f32(&acc, &[Dimensions::Mat4], "inverseBindMatrices")?;
            v.chunks_exact(16)
                .take(joint_nodes.len())
                .map(|c| std::array::from_fn(|i| c[i]))
                .collect()
        }
        None => vec![Mat4::IDENTITY.to_cols_array(); joint_nodes.len()],
    };
    if inverse_bind.len() < joint_nodes.len() {
        return Err(format!(
            "skin {}: {} inverse bind matrices for {} joints",
            skin.index(),
            inverse_bind.len(),
            joint_nodes.len()
        ));
    }
    let mut vertex_joints = Vec::with_capacity(n);
    for (v, j) in joints.chunks_exact(4).enumerate() {
        let mut out = [0u16; 4];
        for k in 0..4 {
            // A zero weight may name any joint; keep it in range.
            let jk = if weights[4 * v + k] == 0.0 { 0 } else { j[k] };
            if jk as usize >= joint_nodes.len() {
                return Err(format!(
                    "{at}: joint {jk} is out of range (skin has {})",
                    joint_nodes.len()
                ));
            }
            out[k] = jk as u16;
        }
        vertex_joints.push(out);
    }
    Ok(Some(SkinRig {
        joints: joint_nodes,
        inverse_bind,
        vertex_joints,
        vertex_weights: weights
            .chunks_exact(4)
            .map(|w| [w[0], w[1], w[2], w[3]])
            .collect(),
    }))
}

/// The primitive's morph targets (position and, where the mesh has normals, normal deltas).
fn morph_targets(
    prim: &gltf::Primitive,
    n: usize,
    with_normals: bool,
    ctx: &NodeContext,
    at: &str,
) -> ReadResult<Vec<MorphTarget>> {
    let mut out = Vec::new();
    for (k, t) in prim.morph_targets().enumerate() {
        if k >= crate::animation::MAX_TARGETS {
            return Err(format!(
                "{at}: more than {} morph targets",
                crate::animation::MAX_TARGETS
            ));
        }
        let read = |acc: Option<gltf::Accessor>, what: &str| -> ReadResult<Vec<[f32; 3]>> {
            match acc {
                None => Ok(Vec::new()),
                Some(acc) => {
                    let (v, _) = ctx.bufs.read_f32(&acc, &[Dimensions::Vec3], what)?;
                    if v.len() != 3 * n {
                        return Err(format!(
                            "{at}: morph target {k} {what} has {} of {n} vertices",
                            v.len() / 3
                        ));
                    }
                    Ok(v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
                }
            }
        };
        let mut positions = read(t.positions(), "POSITION")?;
        if positions.is_empty() {
            positions = vec![[0.0; 3]; n];
        }
        let normals = if with_normals {
            let nrm = read(t.normals(), "NORMAL")?;
            if nrm.is_empty() {
                vec![[0.0; 3]; n]
            } else {
                nrm
            }
        } else {
            Vec::new()
        };
        out.push(MorphTarget { positions, normals });
    }
    Ok(out)
}

/// Unwelds the mesh so every triangle gets its own vertices with the face normal; also returns
/// each new vertex's old index.
pub(crate) fn flat_shaded(m: Mesh) -> (Mesh, Vec<u32>) {
    let Mesh {
        name,
        positions,
        uvs,
        indices,
        material,
        ..
    } = m;
    let mut out = Mesh {
        name,
        positions: Vec::with_capacity(indices.len()),
        normals: Vec::with_capacity(indices.len()),
        uvs: Vec::new(),
        tangents: Vec::new(),
        indices: Vec::with_capacity(indices.len()),
        material,
    };
    let mut map = Vec::with_capacity(indices.len());
    for t in indices.chunks_exact(3) {
        map.extend_from_slice(t);
        let p = [0, 1, 2].map(|k| positions[t[k] as usize]);
        let nrm = normalize(cross(sub(p[1], p[0]), sub(p[2], p[0])));
        for (k, &i) in t.iter().enumerate() {
            out.indices.push(out.positions.len() as u32);
            out.positions.push(p[k]);
            out.normals.push(nrm);
            if !uvs.is_empty() {
                out.uvs.push(uvs[i as usize]);
            }
        }
    }
    (out, map)
}
