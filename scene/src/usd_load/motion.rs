//! Time-sampled transforms as animation: a mesh or light whose world transform has time samples
//! (on its own `xformOp`s or an ancestor's, up to a `resetXformStack`) gets a node of the scene's
//! [`Animation`] keyed at every time code any of them is sampled at, with the world transform at
//! that time code decomposed into translation, rotation and scale (linear keys, rotations by
//! slerp, between the samples as USD interpolates them; a sheared transform is approximated and
//! said so). Time codes become seconds from the stage's start at its `timeCodesPerSecond`; the
//! clip holds its ends (USD holds the first and last samples). The rest pose is the stage's start
//! time, at which meshes and lights are read.

use super::walk::{At, Error, Reader};
use crate::animation::{
    AnimNode, Animation, Channel, IDENTITY, Interpolation, LightRig, MeshRig, Target,
};
use glam::{DMat4, DQuat, DVec3};
use openusd::schemas::geom::Xformable;
use openusd::sdf;
use openusd::usd::TimeCode;

/// Most time codes one animated transform is keyed at (more are left out, and said so).
pub(super) const MAX_TIMES: usize = 4096;
/// Most local transforms evaluated for animation in one stage (time codes × depth).
const MAX_EVALUATIONS: u64 = 1 << 22;

/// The prim at `path`'s world transform at `t`: its local transforms up to the root, or to the
/// first that resets the stack, under the stage's `root` frame (as the walk composes them).
fn world_at(r: &mut Reader, path: &sdf::Path, t: TimeCode, root: DMat4) -> Result<DMat4, Error> {
    let mut m = DMat4::IDENTITY;
    let mut p = path.clone();
    while !p.is_abs_root() {
        r.evaluations += 1;
        super::count(
            "animated transform evaluations",
            r.evaluations,
            MAX_EVALUATIONS,
        )?;
        let x = super::walk::AnyPrim(r.stage.prim(p.clone()));
        let local = x.local_to_parent_transform(t).at(&p)?;
        m = DMat4::from_cols_array(&local.0) * m;
        if x.resets_xform_stack().at(&p)? {
            break;
        }
        match p.parent() {
            Some(q) => p = q,
            None => break,
        }
    }
    Ok(root * m)
}

/// Keys the meshes `meshes` and lights `lights` (indices into the scene being built, all read
/// under `rest`, the prim's world transform at the start) to the prim at `path`'s world
/// transform at each of `times` (time codes, ascending, at least two).
pub(super) fn animate(
    r: &mut Reader,
    path: &sdf::Path,
    times: &[f64],
    rest: DMat4,
    root: DMat4,
    meshes: std::ops::Range<usize>,
    lights: std::ops::Range<usize>,
) -> Result<(), Error> {
    let mut keys = Vec::with_capacity(times.len());
    let mut sheared = false;
    let mut last: Option<DQuat> = None;
    for &t in times {
        let w = world_at(r, path, TimeCode::new(t), root)?;
        let (s, q, tr) = w.to_scale_rotation_translation();
        let back = DMat4::from_scale_rotation_translation(s, q, tr);
        let size = w.to_cols_array().iter().fold(1.0f64, |a, b| a.max(b.abs()));
        sheared |= !w.abs_diff_eq(back, 1e-6 * size);
        // Successive rotations in one hemisphere, so slerp takes the short way.
        let q = match last {
            Some(p) if p.dot(q) < 0.0 => -q,
            _ => q,
        };
        last = Some(q);
        keys.push(((t - r.clock.start) / r.clock.per_second, s, q, tr));
    }
    if sheared {
        r.ignored
            .insert("shear in time-sampled transforms (approximated by scale and rotation)".into());
    }
    let finite = keys
        .iter()
        .all(|(t, s, q, tr)| t.is_finite() && s.is_finite() && q.is_finite() && tr.is_finite());
    if !finite {
        return Err(Error::Usd(format!(
            "{}: a time-sampled transform is not finite",
            super::walk::truncate(path.as_str(), 200)
        )));
    }
    let anim = r.motion.get_or_insert_with(|| Animation {
        name: "usd".into(),
        root: IDENTITY,
        nodes: Vec::new(),
        channels: Vec::new(),
        meshes: Vec::new(),
        lights: Vec::new(),
        looping: false,
    });
    let node = anim.nodes.len() as u32;
    let (s0, q0, t0) = (keys[0].1, keys[0].2, keys[0].3);
    anim.nodes.push(AnimNode {
        translation: t0.as_vec3().to_array(),
        rotation: q0.as_quat().to_array(),
        scale: s0.as_vec3().to_array(),
        ..AnimNode::identity(path.as_str(), None)
    });
    let times: Vec<f32> = keys.iter().map(|k| k.0 as f32).collect();
    let channel = |target, width, values: Vec<f32>| Channel {
        node,
        target,
        interpolation: Interpolation::Linear,
        times: times.clone(),
        values,
        width,
        repeat: false,
    };
    let v3 = |f: fn(&(f64, DVec3, DQuat, DVec3)) -> DVec3| -> Vec<f32> {
        keys.iter()
            .flat_map(|k| f(k).as_vec3().to_array())
            .collect()
    };
    anim.channels
        .push(channel(Target::Translation, 3, v3(|k| k.3)));
    anim.channels.push(channel(Target::Scale, 3, v3(|k| k.1)));
    anim.channels.push(channel(
        Target::Rotation,
        4,
        keys.iter().flat_map(|k| k.2.as_quat().to_array()).collect(),
    ));
    // Rigs: vertices and normals in the node's space at rest.
    let inverse = rest.inverse();
    let normal = glam::DMat3::from_mat4(rest).transpose();
    for m in meshes {
        let mesh = &r.scene.meshes[m];
        let positions = mesh
            .positions
            .iter()
            .map(|p| {
                inverse
                    .transform_point3(DVec3::from(p.map(f64::from)))
                    .as_vec3()
                    .to_array()
            })
            .collect();
        let normals = mesh
            .normals
            .iter()
            .map(|n| {
                (normal * DVec3::from(n.map(f64::from)))
                    .normalize_or_zero()
                    .as_vec3()
                    .to_array()
            })
            .collect();
        anim.meshes.push(MeshRig {
            mesh: m as u32,
            node,
            positions,
            normals,
            vertex_map: Vec::new(),
            skin: None,
            targets: Vec::new(),
        });
    }
    for l in lights {
        anim.lights.push(LightRig {
            light: l as u32,
            node,
            rest: rest.as_mat4().to_cols_array(),
        });
    }
    Ok(())
}

/// Ascending, distinct time codes of `a` and `b`, at most [`MAX_TIMES`] (the rest left out, and
/// said so in `ignored`).
pub(super) fn merge(
    a: &[f64],
    b: &[f64],
    ignored: &mut std::collections::BTreeSet<String>,
) -> Vec<f64> {
    let mut all: Vec<f64> = a
        .iter()
        .chain(b)
        .copied()
        .filter(|t| t.is_finite())
        .collect();
    all.sort_by(f64::total_cmp);
    all.dedup();
    if all.len() > MAX_TIMES {
        ignored.insert(format!(
            "time samples of a transform past the first {MAX_TIMES}"
        ));
        all.truncate(MAX_TIMES);
    }
    all
}
