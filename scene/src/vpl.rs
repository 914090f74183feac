//! One-bounce indirect light's virtual point lights (VPLs, `docs/indirect.md`), traced from a
//! scene's direct samples: what the planner, `render` and the CPU reference all add to a frame's
//! samples ([`frame_samples`]).
//!
//! **VPLs.** `M` light paths leave the direct samples, each sample chosen with probability
//! proportional to its emitted power and each direction drawn from its emission pattern; a path
//! carries the power `Φ = c_λ·I_λ(ω)/(pdf(ω)·p_λ·M)` (times the sample's range window at the hit)
//! to the first opaque surface it meets. There it leaves a VPL: a cosine lobe about the surface's
//! geometric normal that re-emits `Φ ⊙ m^d` (the diffuse albedo there), i.e. radiant intensity
//! `I(θ) = |Φ ⊙ m^d|/π·cos θ` — a [`SampleKind::Bounce`] sample, planned, culled, grouped and
//! shadowed like any other. Its `1/r²` falloff is clamped to `1/max(r², clamp²)`, which removes
//! the spikes of VPLs next to the receiver at the cost of a bias (energy missing near corners) the
//! docs measure. The selection is stratified and seeded, so the same scene gives the same VPLs.
//! Only diffuse reflection bounces; the back of a single-sided surface (which nothing sees)
//! reflects nothing; emissive surfaces emit only through their own light samples.
//!
//! The one-bounce truth the VPLs are measured against is the reference's
//! (`lightfold_reference::render_one_bounce`).

use crate::shading::{self, V3, add, normalize, range_window, scale};
use crate::trace::Tracer;
use crate::{LightSample, SampleKind, Scene, sampling};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::f32::consts::PI;
use std::f64::consts::PI as PI_F64;

/// How the VPLs of a scene are made.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IndirectOptions {
    /// Light paths, hence at most this many VPLs (paths that leave the scene or end on a black
    /// or unseen surface leave none).
    pub count: u32,
    /// Falloff clamp distance in metres (0: none).
    pub clamp: f32,
    pub seed: u64,
}

impl IndirectOptions {
    /// The scene's own: `quality.indirect` paths, its clamp (or
    /// [`crate::defaults::INDIRECT_CLAMP_REL`] of its bounding diagonal), its seed.
    pub fn of(scene: &Scene) -> IndirectOptions {
        let q = &scene.quality;
        IndirectOptions {
            count: q.indirect,
            clamp: q.indirect_clamp.unwrap_or_else(|| default_clamp(scene)),
            seed: q.seed,
        }
    }
}

/// [`crate::defaults::INDIRECT_CLAMP_REL`] of the scene's bounding diagonal.
pub fn default_clamp(scene: &Scene) -> f32 {
    let diag = scene
        .bounds()
        .map_or(0.0, |(lo, hi)| shading::length(shading::sub(hi, lo)));
    crate::defaults::INDIRECT_CLAMP_REL * diag
}

/// Every sample a frame of `scene` renders: its direct samples, then its VPLs when
/// `quality.indirect` asks for them. What the planner, `render` and the reference all call.
/// An animated scene's VPLs are its rest pose's, one a light path whether or not the path left
/// one ([`vpl_slots`]): the frame at time `t` replaces them with [`frame_samples_at`]'s.
pub fn frame_samples(scene: &Scene) -> Vec<LightSample> {
    let mut samples = sampling::direct_samples(scene);
    let options = IndirectOptions::of(scene);
    if options.count > 0 {
        let tracer = Tracer::new(scene);
        if scene.is_animated() {
            samples.extend(vpl_slots(&tracer, &samples, &options));
        } else {
            samples.extend(vpls(&tracer, &samples, &options));
        }
    }
    samples
}

/// The samples of an animated scene's frame at time `t`, slot for slot with
/// [`frame_samples`]: the direct samples moved with their lights, and the VPLs traced again in
/// the scene posed at `t` with the same light paths (the same source and directions per path,
/// so a VPL moves with what it landed on instead of jumping to a fresh random place). A still
/// scene's are [`frame_samples`]'.
pub fn frame_samples_at(scene: &Scene, t: f32) -> Vec<LightSample> {
    if !scene.is_animated() {
        return frame_samples(scene);
    }
    let rest = sampling::direct_samples(scene);
    let mut samples = scene.pose_samples(&rest, t);
    if scene.quality.indirect > 0 {
        samples.extend(vpls_at(scene, &rest, t));
    }
    samples
}

/// The VPL slots of an animated scene at time `t` traced from `direct_rest` (its direct
/// samples at rest, as a plan holds them: moved with their lights here), in the scene posed at
/// `t` ([`frame_samples_at`]'s VPLs; what a frame at `t` sends the nodes of a plan).
pub fn vpls_at(scene: &Scene, direct_rest: &[LightSample], t: f32) -> Vec<LightSample> {
    let direct = scene.pose_samples(direct_rest, t);
    let posed = scene.still_at(t);
    vpl_slots(&Tracer::new(&posed), &direct, &IndirectOptions::of(scene))
}

/// The VPL of every light path, in path order: a path that leaves none (it left the scene or
/// ended on a black or unseen surface) gives a dark one (intensity 0, at the origin facing up),
/// so that path `j` keeps slot `j` at every pose.
pub fn vpl_slots(
    tracer: &Tracer<'_>,
    direct: &[LightSample],
    options: &IndirectOptions,
) -> Vec<LightSample> {
    let clamp = sanitized_clamp(options.clamp);
    let dark = LightSample {
        position: [0.0; 3],
        direction: [0.0, 1.0, 0.0],
        kind: SampleKind::Bounce { clamp },
        intensity: 0.0,
        color: [1.0; 3],
        range: None,
        light: 0,
        area: None,
        cell: 0.0,
    };
    let paths = vpl_paths(tracer, direct, options);
    if paths.is_empty() {
        return vec![dark; options.count as usize];
    }
    paths.into_iter().map(|p| p.unwrap_or(dark)).collect()
}

fn sanitized_clamp(clamp: f32) -> f32 {
    if clamp.is_finite() {
        clamp.max(0.0)
    } else {
        0.0
    }
}

/// The VPLs of `direct` in the traced scene (see the module documentation).
pub fn vpls(
    tracer: &Tracer<'_>,
    direct: &[LightSample],
    options: &IndirectOptions,
) -> Vec<LightSample> {
    vpl_paths(tracer, direct, options)
        .into_iter()
        .flatten()
        .collect()
}

/// Per light path, the VPL it leaves (none when there is no source or no path).
fn vpl_paths(
    tracer: &Tracer<'_>,
    direct: &[LightSample],
    options: &IndirectOptions,
) -> Vec<Option<LightSample>> {
    let m = options.count as usize;
    let sources: Vec<(usize, f64)> = direct
        .iter()
        .enumerate()
        .filter_map(|(i, s)| {
            let w = nominal_power(tracer, s) * luminance(s.color).max(0.0);
            (w > 0.0 && w.is_finite()).then_some((i, w))
        })
        .collect();
    if m == 0 || sources.is_empty() {
        return Vec::new();
    }
    let total: f64 = sources.iter().map(|s| s.1).sum();
    let mut cdf = Vec::with_capacity(sources.len());
    let mut acc = 0.0;
    for s in &sources {
        acc += s.1 / total;
        cdf.push(acc);
    }
    let clamp = sanitized_clamp(options.clamp);
    let offset = tracer.epsilon() * 10.0;
    let paths: Vec<Option<LightSample>> = (0..m)
        .into_par_iter()
        .map(|j| {
            let mut rng = ChaCha8Rng::seed_from_u64(
                options.seed
                    ^ 0x5650_4C5F_5041_5448
                    ^ (j as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
            );
            // Stratified choice of the source: one path per 1/M of the power CDF.
            let u = (j as f64 + rng.random::<f64>()) / m as f64;
            let k = cdf.partition_point(|&c| c <= u).min(sources.len() - 1);
            let (index, w) = sources[k];
            let p = w / total;
            let s = &direct[index];
            let (origin, dir, weight) = emit(tracer, s, &mut rng)?;
            // Through glass: the light that reaches the bounce is tinted by it.
            let (hit, unseen_back, tint) = tracer.light_ray_tinted(origin, dir)?;
            if unseen_back {
                return None;
            }
            let r = shading::length(shading::sub(hit.position_f32(), origin.map(|c| c as f32)));
            let window = match s.kind {
                SampleKind::Directional => 1.0,
                _ => range_window(r, s.range),
            };
            let albedo = tracer.diffuse(&hit);
            let scale_path = weight * f64::from(window) / (p * m as f64);
            let flux: V3 = [0, 1, 2]
                .map(|c| (f64::from(s.color[c] * albedo[c] * tint[c]) * scale_path) as f32);
            let peak = flux.iter().copied().fold(0.0f32, f32::max);
            if !(peak > 0.0 && peak.is_finite()) {
                return None;
            }
            let n = hit.geometric_normal;
            let at = shading::add(hit.position_f32(), scale(n, offset as f32));
            Some(LightSample {
                position: at,
                direction: n,
                kind: SampleKind::Bounce { clamp },
                intensity: peak / PI,
                color: flux.map(|c| c / peak),
                range: None,
                light: s.light,
                area: None,
                cell: 0.0,
            })
        })
        .collect();
    paths
}

/// Radiant power of a sample (W, scalar), for choosing sources; a directional light's is its
/// irradiance over the disk that covers the scene.
fn nominal_power(tracer: &Tracer<'_>, s: &LightSample) -> f64 {
    let i = f64::from(s.intensity.abs());
    match s.kind {
        SampleKind::Isotropic => 4.0 * PI_F64 * i,
        SampleKind::CosineLobe => PI_F64 * i,
        SampleKind::TwoSidedLobe => 2.0 * PI_F64 * i,
        SampleKind::Spot { cos_outer, .. } => {
            2.0 * PI_F64 * (1.0 - f64::from(cos_outer.clamp(-1.0, 1.0))) * i
        }
        SampleKind::Directional => {
            let (_, radius) = scene_sphere(tracer);
            PI_F64 * radius * radius * i
        }
        // One bounce: VPLs are not sources.
        SampleKind::Bounce { .. } => 0.0,
    }
}

/// A path leaving `s`: origin, unit direction and `I(ω)/pdf(ω)` (scalar, W), or `None` where the
/// drawn direction carries nothing.
fn emit(tracer: &Tracer<'_>, s: &LightSample, rng: &mut ChaCha8Rng) -> Option<([f64; 3], V3, f64)> {
    let (a, b) = (rng.random::<f32>(), rng.random::<f32>());
    let axis = normalize(s.direction);
    let i = f64::from(s.intensity);
    let at = s.position.map(f64::from);
    match s.kind {
        SampleKind::Isotropic => Some((at, uniform_sphere(a, b), 4.0 * PI_F64 * i)),
        SampleKind::CosineLobe => Some((at, cosine_hemisphere(axis, a, b), PI_F64 * i)),
        SampleKind::TwoSidedLobe => {
            let side = if rng.random::<bool>() {
                axis
            } else {
                scale(axis, -1.0)
            };
            Some((at, cosine_hemisphere(side, a, b), 2.0 * PI_F64 * i))
        }
        SampleKind::Spot { cos_outer, .. } => {
            let co = cos_outer.clamp(-1.0, 1.0);
            // Uniform over the cone's solid angle 2π(1 − cos_outer).
            let z = 1.0 - a * (1.0 - co);
            let d = around(axis, z, b);
            let solid = 2.0 * PI_F64 * (1.0 - f64::from(co));
            let w = f64::from(shading::sample_intensity(s, d)) * solid;
            (w > 0.0).then_some((at, d, w))
        }
        SampleKind::Directional => {
            let (centre, radius) = scene_sphere(tracer);
            let d = axis;
            let (u, v) = sampling::basis(d);
            let r = (a as f64).sqrt() * radius;
            let phi = 2.0 * PI_F64 * f64::from(b);
            let back = 2.0 * radius + 1.0;
            let o = [0, 1, 2].map(|k| {
                centre[k] - back * f64::from(d[k])
                    + r * (phi.cos() * f64::from(u[k]) + phi.sin() * f64::from(v[k]))
            });
            Some((o, d, PI_F64 * radius * radius * i))
        }
        SampleKind::Bounce { .. } => None,
    }
}

/// Centre and radius of the sphere around the traced scene.
fn scene_sphere(tracer: &Tracer<'_>) -> ([f64; 3], f64) {
    tracer.bvh().bounds().map_or(([0.0; 3], 1.0), |(lo, hi)| {
        let c = [0, 1, 2].map(|k| 0.5 * (f64::from(lo[k]) + f64::from(hi[k])));
        let h = [0, 1, 2].map(|k| 0.5 * (f64::from(hi[k]) - f64::from(lo[k])));
        (
            c,
            (h[0] * h[0] + h[1] * h[1] + h[2] * h[2]).sqrt().max(1e-3),
        )
    })
}

fn luminance(c: V3) -> f64 {
    f64::from(0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2])
}

/// The unit direction at cosine `z` from `axis`, azimuth `b` (a fraction of a turn).
fn around(axis: V3, z: f32, b: f32) -> V3 {
    let (u, v) = sampling::basis(axis);
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * b;
    normalize(add(
        scale(axis, z),
        add(scale(u, r * phi.cos()), scale(v, r * phi.sin())),
    ))
}

fn uniform_sphere(a: f32, b: f32) -> V3 {
    around([0.0, 0.0, 1.0], 1.0 - 2.0 * a, b)
}

/// Cosine-weighted direction about `axis` (pdf `cos θ/π`).
pub fn cosine_hemisphere(axis: V3, a: f32, b: f32) -> V3 {
    around(axis, (1.0 - a).sqrt(), b)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shading::dot;

    #[test]
    fn grid_shapes_cover_n() {
        for n in [1, 2, 7, 16, 64, 100, 256] {
            let (a, b) = sampling::grid_shape(n);
            assert_eq!(a * b, n);
            assert!(a >= b);
        }
    }

    #[test]
    fn cosine_directions_stay_in_their_hemisphere() {
        let axis = normalize([0.3, -0.8, 0.2]);
        for i in 0..64 {
            let d = cosine_hemisphere(axis, (i as f32 + 0.5) / 64.0, (i * 7 % 64) as f32 / 64.0);
            assert!(dot(d, axis) >= 0.0);
            assert!((shading::length(d) - 1.0).abs() < 1e-5);
        }
    }
}
