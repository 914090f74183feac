//! Deterministic sampling of source lights into point samples (ARCHITECTURE §2).
//!
//! An area-light sample is a cosine lobe `I(θ) = L·A/N·max(0, cos θ)` about the emitter normal, so
//! the N samples together emit the area light's power `π·L·A`.

use crate::model::{LightSample, LightShape, Quality, SampleKind, SamplePattern, Scene};
use crate::shading::{V3, add, cross, normalize, scale};

pub use crate::sampling_shapes::sample_power;
pub use crate::scene_ops::mesh_area;

/// All point samples of a scene, in light order, with the scene's quality options.
pub fn scene_samples(scene: &Scene) -> Vec<LightSample> {
    let mut out = Vec::new();
    for (i, _) in scene.lights.iter().enumerate() {
        out.extend(light_samples(scene, i, &scene.quality));
    }
    out
}

/// The point samples of light `index`.
pub fn light_samples(scene: &Scene, index: usize, q: &Quality) -> Vec<LightSample> {
    let light = &scene.lights[index];
    let n = q.samples_per_area_light.unwrap_or(light.samples).max(1);
    let base = LightSample {
        position: [0.0; 3],
        direction: [0.0, -1.0, 0.0],
        kind: SampleKind::Isotropic,
        intensity: light.power,
        color: light.color,
        range: light.range,
        light: index as u32,
    };
    match &light.shape {
        LightShape::Point { position } => vec![LightSample {
            position: *position,
            ..base
        }],
        LightShape::Spot {
            position,
            direction,
            inner_angle,
            outer_angle,
        } => vec![LightSample {
            position: *position,
            direction: normalize(*direction),
            kind: SampleKind::Spot {
                cos_outer: outer_angle.cos(),
                cos_inner: inner_angle.cos(),
            },
            ..base
        }],
        LightShape::Directional { direction } => vec![LightSample {
            direction: normalize(*direction),
            kind: SampleKind::Directional,
            ..base
        }],
        LightShape::Rect {
            center,
            normal,
            u_axis,
            size,
        } => {
            let nrm = normalize(*normal);
            let u = normalize(*u_axis);
            let v = cross(nrm, u);
            let area = size[0] * size[1];
            unit_square_points(n, q.pattern, q.seed ^ index as u64)
                .into_iter()
                .map(|(a, b)| {
                    let p = add(
                        *center,
                        add(scale(u, (a - 0.5) * size[0]), scale(v, (b - 0.5) * size[1])),
                    );
                    lobe(base, p, nrm, light.power * area / n as f32)
                })
                .collect()
        }
        other => crate::sampling_shapes::samples(scene, light, other, n, q, base),
    }
}

pub(crate) fn lobe(base: LightSample, position: V3, normal: V3, intensity: f32) -> LightSample {
    LightSample {
        position,
        direction: normal,
        kind: SampleKind::CosineLobe,
        intensity,
        ..base
    }
}

/// `n` points in the unit square: a stratified `a×b` grid (`a·b = n`, as square as possible) at
/// cell centres, jittered within cells, or the Halton (2, 3) sequence.
pub fn unit_square_points(n: u32, pattern: SamplePattern, seed: u64) -> Vec<(f32, f32)> {
    let (nx, ny) = grid_shape(n);
    match pattern {
        SamplePattern::Grid | SamplePattern::Jittered => {
            let mut rng = SplitMix64(seed.wrapping_add(0x9E37_79B9_7F4A_7C15));
            let mut pts = Vec::with_capacity(n as usize);
            for j in 0..ny {
                for i in 0..nx {
                    let (ja, jb) = if pattern == SamplePattern::Jittered {
                        (rng.next_f32(), rng.next_f32())
                    } else {
                        (0.5, 0.5)
                    };
                    pts.push(((i as f32 + ja) / nx as f32, (j as f32 + jb) / ny as f32));
                }
            }
            pts
        }
        SamplePattern::Halton => (1..=n)
            .map(|i| (radical_inverse(i, 2), radical_inverse(i, 3)))
            .collect(),
    }
}

/// The most square factorisation `nx·ny = n` with `nx ≥ ny`.
pub fn grid_shape(n: u32) -> (u32, u32) {
    let n = n.max(1);
    let mut ny = (n as f64).sqrt() as u32;
    while ny > 1 && !n.is_multiple_of(ny) {
        ny -= 1;
    }
    (n / ny.max(1), ny.max(1))
}

fn radical_inverse(mut i: u32, base: u32) -> f32 {
    let inv = 1.0 / base as f64;
    let mut f = inv;
    let mut r = 0.0;
    while i > 0 {
        r += (i % base) as f64 * f;
        i /= base;
        f *= inv;
    }
    r as f32
}

/// A small deterministic generator (SplitMix64) so sampling needs no RNG crate.
#[derive(Debug, Clone)]
pub struct SplitMix64(pub u64);

impl SplitMix64 {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }
}
