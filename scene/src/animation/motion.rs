//! Scene-file motions (`[[motion]]`): an object or a light that spins about an axis through a
//! pivot and/or follows a path of offsets, each repeating on its own period. A motion becomes
//! three nodes of the common model — path (translation keys) → pivot (fixed translation) →
//! spin (rotation keys, four 90° slerp segments per turn, which turn at exactly constant rate) —
//! and a rig of the object's mesh (vertices relative to the pivot) or of the light.

use super::{AnimNode, Animation, Channel, IDENTITY, Interpolation, LightRig, MeshRig, Target};
use crate::model::{LightShape, Scene};
use glam::{Mat4, Quat, Vec3};
use serde::{Deserialize, Serialize};

/// One `[[motion]]` table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MotionSpec {
    /// The `[[object]]` (by name) that moves; exactly one of `object` and `light`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub object: Option<String>,
    /// The `[[light]]` (by name) that moves.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub light: Option<String>,
    /// The point it turns about (default: the object's bounding-box centre, the light's centre
    /// or position).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pivot: Option<[f32; 3]>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub spin: Option<SpinSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub path: Option<PathSpec>,
}

/// A full turn about `axis` every `period` seconds (negative: the other way).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpinSpec {
    pub axis: [f32; 3],
    pub period: f32,
}

/// Offsets from the authored position at key times (seconds, from 0, increasing); the path
/// repeats after its last key.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PathSpec {
    pub times: Vec<f32>,
    pub offsets: Vec<[f32; 3]>,
    /// `linear` (default) or `step`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub interpolation: Option<String>,
}

/// Most `[[motion]]` tables and path keys a scene file may hold.
const MAX_MOTIONS: usize = 4096;
const MAX_PATH_KEYS: usize = 1 << 16;

/// Adds `motions` to `scene` (objects by `objects[name] = mesh index`, lights by name).
pub fn apply_motions(
    scene: &mut Scene,
    motions: &[MotionSpec],
    objects: &std::collections::HashMap<String, usize>,
) -> Result<(), String> {
    if motions.is_empty() {
        return Ok(());
    }
    if motions.len() > MAX_MOTIONS {
        return Err(format!("{} motions (at most {MAX_MOTIONS})", motions.len()));
    }
    if scene.animation.is_some() {
        return Err("motions cannot be added to an animated glTF".into());
    }
    let mut anim = Animation {
        name: "motion".into(),
        root: IDENTITY,
        nodes: Vec::new(),
        channels: Vec::new(),
        meshes: Vec::new(),
        lights: Vec::new(),
        looping: true,
    };
    for (i, m) in motions.iter().enumerate() {
        add(&mut anim, scene, m, objects).map_err(|e| format!("motion {}: {e}", i + 1))?;
    }
    scene.animation = Some(anim);
    Ok(())
}

fn add(
    anim: &mut Animation,
    scene: &Scene,
    m: &MotionSpec,
    objects: &std::collections::HashMap<String, usize>,
) -> Result<(), String> {
    enum Subject {
        Mesh(usize),
        Light(usize),
    }
    let subject = match (&m.object, &m.light) {
        (Some(o), None) => Subject::Mesh(
            *objects
                .get(o)
                .ok_or_else(|| format!("names unknown object {o:?}"))?,
        ),
        (None, Some(l)) => Subject::Light(
            scene
                .lights
                .iter()
                .position(|x| &x.name == l)
                .ok_or_else(|| format!("names unknown light {l:?}"))?,
        ),
        _ => return Err("give exactly one of `object` and `light`".into()),
    };
    if m.spin.is_none() && m.path.is_none() {
        return Err("neither `spin` nor `path` is given".into());
    }
    let pivot = match (m.pivot, &subject) {
        (Some(p), _) => p,
        (None, Subject::Mesh(i)) => crate::moves::pivot(&scene.meshes[*i]),
        (None, Subject::Light(i)) => light_centre(&scene.lights[*i].shape, scene),
    };
    if !pivot.iter().all(|v| v.is_finite()) {
        return Err("the pivot is not finite".into());
    }
    let base = anim.nodes.len() as u32;
    let path_node = base;
    let pivot_node = base + 1;
    let spin_node = base + 2;
    anim.nodes.push(AnimNode::identity("path", None));
    let mut p = AnimNode::identity("pivot", Some(path_node));
    p.translation = pivot;
    anim.nodes.push(p);
    anim.nodes
        .push(AnimNode::identity("spin", Some(pivot_node)));
    if let Some(path) = &m.path {
        anim.channels.push(path_channel(path, path_node)?);
    }
    if let Some(spin) = &m.spin {
        anim.channels.push(spin_channel(spin, spin_node)?);
    }
    match subject {
        Subject::Mesh(i) => {
            let mesh = &scene.meshes[i];
            anim.meshes.push(MeshRig {
                mesh: i as u32,
                node: spin_node,
                positions: mesh
                    .positions
                    .iter()
                    .map(|q| std::array::from_fn(|k| q[k] - pivot[k]))
                    .collect(),
                normals: mesh.normals.clone(),
                vertex_map: Vec::new(),
                skin: None,
                targets: Vec::new(),
            });
            // An emissive-mesh light on the object moves with it.
            for (l, light) in scene.lights.iter().enumerate() {
                if light.shape == (LightShape::EmissiveMesh { mesh: i }) {
                    anim.lights.push(LightRig {
                        light: l as u32,
                        node: spin_node,
                        rest: Mat4::from_translation(Vec3::from(pivot)).to_cols_array(),
                    });
                }
            }
        }
        Subject::Light(l) => {
            if anim.lights.iter().any(|r| r.light == l as u32) {
                return Err("the light already has a motion".into());
            }
            anim.lights.push(LightRig {
                light: l as u32,
                node: spin_node,
                rest: Mat4::from_translation(Vec3::from(pivot)).to_cols_array(),
            });
        }
    }
    Ok(())
}

/// Where a light is, for its default pivot.
fn light_centre(shape: &LightShape, scene: &Scene) -> [f32; 3] {
    match *shape {
        LightShape::Point { position } | LightShape::Spot { position, .. } => position,
        LightShape::Rect { center, .. }
        | LightShape::Disk { center, .. }
        | LightShape::Sphere { center, .. }
        | LightShape::Cylinder { center, .. } => center,
        LightShape::Directional { .. } => [0.0; 3],
        LightShape::EmissiveMesh { mesh } => scene
            .meshes
            .get(mesh)
            .and_then(|m| m.positions.first().copied())
            .unwrap_or([0.0; 3]),
    }
}

fn spin_channel(s: &SpinSpec, node: u32) -> Result<Channel, String> {
    let axis = Vec3::from(s.axis);
    if !(s.period.is_finite() && s.period != 0.0) {
        return Err("spin period must be a finite non-zero number of seconds".into());
    }
    if !axis.is_finite() || axis.length() < 1e-6 {
        return Err("spin axis must be a non-zero vector".into());
    }
    let axis = axis.normalize();
    let period = s.period.abs();
    let sign = s.period.signum();
    let mut times = Vec::new();
    let mut values = Vec::new();
    for k in 0..=4 {
        times.push(period * k as f32 / 4.0);
        let q = Quat::from_axis_angle(axis, sign * std::f32::consts::FRAC_PI_2 * k as f32);
        values.extend_from_slice(&[q.x, q.y, q.z, q.w]);
    }
    Ok(Channel {
        node,
        target: Target::Rotation,
        interpolation: Interpolation::Linear,
        times,
        values,
        width: 4,
        repeat: true,
    })
}

fn path_channel(p: &PathSpec, node: u32) -> Result<Channel, String> {
    if p.times.is_empty() || p.times.len() != p.offsets.len() || p.times.len() > MAX_PATH_KEYS {
        return Err(format!(
            "path has {} times and {} offsets (1 to {MAX_PATH_KEYS} of each, as many)",
            p.times.len(),
            p.offsets.len()
        ));
    }
    if !p.times.iter().all(|t| t.is_finite() && *t >= 0.0)
        || p.times.windows(2).any(|w| w[1] <= w[0])
    {
        return Err("path times must be finite, from 0 and increasing".into());
    }
    if !p.offsets.iter().flatten().all(|v| v.is_finite()) {
        return Err("a path offset is not finite".into());
    }
    let interpolation = match p.interpolation.as_deref() {
        None | Some("linear") => Interpolation::Linear,
        Some("step") => Interpolation::Step,
        Some(other) => {
            return Err(format!(
                "path interpolation {other:?} (expected \"linear\" or \"step\")"
            ));
        }
    };
    Ok(Channel {
        node,
        target: Target::Translation,
        interpolation,
        times: p.times.clone(),
        values: p.offsets.iter().flatten().copied().collect(),
        width: 3,
        repeat: true,
    })
}
