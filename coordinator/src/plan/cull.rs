//! Which light samples are active: a sample is dropped only when it provably adds nothing to the
//! view (no emission, no visible receiver in reach) or when the conservative bound of what it adds
//! fits in the ε budget the plan prints (ARCHITECTURE §9).

use super::geom::{Aabb, Miss, reach};
use super::types::DropReason;
use lightfold_scene::{LightSample, SampleKind, Scene};
use std::f32::consts::PI;

/// A visible mesh: index, bounds, and the largest radiance per unit irradiance its material can
/// send to the eye (`max m^d/π + max m^s·(s+8)/(8π)`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Receiver {
    pub mesh: usize,
    pub bounds: Aabb,
    pub brdf_max: f32,
}

/// Visible receivers: meshes whose bounds may intersect the view frustum.
pub(crate) fn receivers(scene: &Scene, bounds: &[Option<Aabb>]) -> Vec<Receiver> {
    let frustum = super::geom::Frustum::new(&scene.camera);
    bounds
        .iter()
        .enumerate()
        .filter_map(|(mesh, b)| {
            let b = (*b)?;
            if scene.meshes[mesh].indices.len() < 3 || !frustum.may_contain(&b) {
                return None;
            }
            Some(Receiver {
                mesh,
                bounds: b,
                brdf_max: brdf_max(scene, scene.meshes[mesh].material),
            })
        })
        .collect()
}

fn brdf_max(scene: &Scene, material: usize) -> f32 {
    let Some(m) = scene.materials.get(material) else {
        // The renderers treat a missing material as a default one; stay unbounded.
        return f32::INFINITY;
    };
    let cmax = |c: [f32; 3]| c.iter().fold(0.0f32, |a, &v| a.max(v.abs()));
    if let Some(p) = &m.pbr {
        return metallic_roughness_max(p);
    }
    // A diffuse texture multiplies `diffuse` by at most 1.
    let d = cmax(m.diffuse) / PI;
    let s = if m.has_specular() || m.specular.iter().any(|&v| v != 0.0) {
        if m.shininess.is_nan() || m.shininess < 0.0 || !m.shininess.is_finite() {
            return f32::INFINITY;
        }
        cmax(m.specular) * (m.shininess + 8.0) / (8.0 * PI)
    } else {
        0.0
    };
    let v = d + s;
    if v.is_finite() { v } else { f32::INFINITY }
}

/// A bound of a metallic-roughness material's `f·(n·l)` per unit of `E/(n·l)` (the irradiance
/// a surface facing the light gets): diffuse `c_diff·(1 − F0)/π ≤ base/π`; specular
/// `F·D·V·(n·l) ≤ 1/(πα²) · 0.5/α` (`D ≤ 1/(πα²)`, and `V·(n·l) ≤ 0.5/α`), at the smallest `α`
/// its roughness texture allows.
fn metallic_roughness_max(p: &lightfold_scene::MetallicRoughness) -> f32 {
    let base = p.base_color.iter().fold(0.0f32, |a, &v| a.max(v.abs()));
    let roughness = if p.metallic_roughness_texture.is_some() {
        0.0
    } else {
        p.roughness
    };
    let alpha = lightfold_scene::shading::ggx_alpha(roughness);
    let v = base / PI + 0.5 / (PI * alpha * alpha * alpha);
    if v.is_finite() { v } else { f32::INFINITY }
}

/// The outcome for every sample: `Ok(lit receivers)` or why it is dropped.
pub(crate) struct Culling {
    pub active: Vec<usize>,
    pub dropped: Vec<(usize, DropReason)>,
    /// Per sample index: indices into the receiver list that the sample reaches.
    pub lit: Vec<Vec<usize>>,
    pub epsilon_used: f32,
}

/// Decide the active samples. `exposure` scales radiance to display units for the ε test.
pub(crate) fn cull(
    samples: &[LightSample],
    receivers: &[Receiver],
    exposure: f32,
    epsilon: f32,
    force_all: bool,
) -> Culling {
    let mut lit = vec![Vec::new(); samples.len()];
    if force_all {
        for l in lit.iter_mut() {
            *l = (0..receivers.len()).collect();
        }
        return Culling {
            active: (0..samples.len()).collect(),
            dropped: Vec::new(),
            lit,
            epsilon_used: 0.0,
        };
    }
    let exposure = if exposure.is_finite() && exposure > 0.0 {
        exposure
    } else {
        1.0
    };
    let mut dropped = Vec::new();
    let mut bounds = Vec::new();
    for (i, s) in samples.iter().enumerate() {
        if let Some(reason) = emits_nothing(s) {
            dropped.push((i, reason));
            continue;
        }
        if receivers.is_empty() {
            dropped.push((i, DropReason::NoVisibleReceiver));
            continue;
        }
        let (mut range, mut cone, mut behind) = (0u32, 0u32, 0u32);
        let mut bound = 0.0f32;
        for (r, rec) in receivers.iter().enumerate() {
            match reach(s, &rec.bounds) {
                Ok(e) => {
                    lit[i].push(r);
                    bound = bound.max(e * rec.brdf_max);
                }
                Err(Miss::Range) => range += 1,
                Err(Miss::Cone) => cone += 1,
                Err(Miss::Behind) => behind += 1,
            }
        }
        if lit[i].is_empty() {
            dropped.push((
                i,
                DropReason::Unreached {
                    out_of_range: range,
                    outside_cone: cone,
                    behind,
                },
            ));
            continue;
        }
        let cmax = s.color.iter().fold(0.0f32, |a, &v| a.max(v.abs()));
        let b = bound * cmax * exposure;
        bounds.push((i, if b.is_finite() { b } else { f32::INFINITY }));
    }
    // Spend the ε budget on the smallest contributions first (ties by index: deterministic).
    bounds.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
    let mut used = 0.0f32;
    let mut active = Vec::new();
    for (i, b) in bounds {
        if epsilon > 0.0 && used + b <= epsilon {
            used += b;
            dropped.push((i, DropReason::BelowEpsilon { bound: b }));
            lit[i].clear();
        } else {
            active.push(i);
        }
    }
    active.sort_unstable();
    dropped.sort_by_key(|d| d.0);
    Culling {
        active,
        dropped,
        lit,
        epsilon_used: used,
    }
}

/// Re-activates the samples `moving[i]` dropped for what they miss (not for emitting nothing):
/// they move, so what they reach at rest says nothing of other times. Active or not, each then
/// lights every one of the `receivers`.
pub(crate) fn keep_moving(
    c: &mut Culling,
    moving: &[bool],
    samples: &[LightSample],
    receivers: usize,
) {
    let mut kept = Vec::new();
    c.dropped.retain(|(i, reason)| {
        // A moving virtual point light dark at rest (its path left nothing there) may light
        // up at another time: its slot stays.
        let revives = matches!(samples[*i].kind, lightfold_scene::SampleKind::Bounce { .. });
        let drop = !moving[*i]
            || matches!(reason, DropReason::NonFinite)
            || (matches!(reason, DropReason::ZeroEmission) && !revives);
        if !drop {
            if let DropReason::BelowEpsilon { bound } = reason {
                c.epsilon_used -= bound;
            }
            kept.push(*i);
        }
        drop
    });
    c.active.extend(kept);
    c.active.sort_unstable();
    c.epsilon_used = c.epsilon_used.max(0.0);
    for (i, lit) in c.lit.iter_mut().enumerate() {
        if moving[i] && c.active.binary_search(&i).is_ok() {
            *lit = (0..receivers).collect();
        }
    }
}

/// A sample that emits nothing whatever the receivers: zero or non-finite parameters.
fn emits_nothing(s: &LightSample) -> Option<DropReason> {
    let finite3 = |v: [f32; 3]| v.iter().all(|c| c.is_finite());
    let needs_position = !matches!(s.kind, SampleKind::Directional);
    let needs_direction = !matches!(s.kind, SampleKind::Isotropic);
    if !s.intensity.is_finite()
        || !finite3(s.color)
        || (needs_position && !finite3(s.position))
        || (needs_direction && !finite3(s.direction))
    {
        return Some(DropReason::NonFinite);
    }
    let zero_dir = needs_direction && s.direction == [0.0; 3];
    let spot_reaches_sideways =
        matches!(s.kind, SampleKind::Spot { cos_outer, .. } if cos_outer < 0.0);
    if s.intensity == 0.0 || s.color == [0.0; 3] || (zero_dir && !spot_reaches_sideways) {
        return Some(DropReason::ZeroEmission);
    }
    None
}
