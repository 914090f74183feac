//! One-bounce indirect light's truth (`docs/indirect.md`), the quantity the VPLs of
//! `lightfold_scene::vpl` approximate, without them.
//!
//! **Truth.** [`render_one_bounce`] path-traces the same quantity without VPLs: per pixel, `P`
//! cosine-weighted directions from the visible point, each to the first surface `y` it meets,
//! whose diffuse radiance from the direct samples is summed exactly with ray-traced visibility
//! (next-event estimation, no clamp). So the VPL error (sampling and clamp) is measured against it
//! and the shadow-map error against the exact VPL sum ([`crate::render_point_sum`] over the
//! direct samples and the VPLs), separately.

use crate::point_sum::{Layers, render_pixels};
use lightfold_scene::shading::{self, Lobe, V3, blinn_phong, dot, ggx_terms};
use lightfold_scene::trace::{SurfaceHit, Tracer};
use lightfold_scene::vpl::cosine_hemisphere;
use lightfold_scene::{LightSample, SampleKind, Scene, sampling};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f32::consts::PI;

/// How [`render_one_bounce`] estimates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OneBounceOptions {
    /// Cosine-weighted paths per pixel.
    pub paths: u32,
    pub seed: u64,
}

/// The one-bounce indirect illumination of `direct` as layers (`illumination` holds the
/// indirect `(I^d, I^s)` for `c_n` = white; the diffuse and specular layers are the visible
/// surfaces', as [`crate::render_point_sum`] gives them, the emissive and ambient layers zero, so
/// that [`Layers::radiance`] is the bounce alone), path-traced with exact next-event estimation.
pub fn render_one_bounce(
    scene: &Scene,
    direct: &[LightSample],
    options: &OneBounceOptions,
) -> Layers {
    let tracer = Tracer::new(scene);
    let paths = options.paths.max(1);
    let width = scene.camera.width;
    let pixels = render_pixels(&tracer, |x, y, hit, px| {
        let pixel = u64::from(y) * u64::from(width) + u64::from(x);
        let mut rng = ChaCha8Rng::seed_from_u64(
            options.seed ^ 0x4F4E_455F_424F_554E ^ pixel.wrapping_mul(0xD1B5_4A32_D192_ED03),
        );
        let lobe = tracer.surface(hit).lobe;
        let (nx, ny) = sampling::grid_shape(paths);
        let mut sum = [0.0f64; 6];
        for j in 0..ny {
            for i in 0..nx {
                let a = (i as f32 + rng.random::<f32>()) / nx as f32;
                let b = (j as f32 + rng.random::<f32>()) / ny as f32;
                let d = cosine_hemisphere(hit.normal, a, b);
                if dot(d, hit.geometric_normal) <= 0.0 {
                    continue;
                }
                let l = bounce_radiance(&tracer, hit, d, direct);
                // Per unit of L·cos/π (the cosine-weighted estimate): the lobe's diffuse and
                // specular weights, as `shading::lobe_coefficients` weighs irradiance.
                let (kd, ks) = match lobe {
                    Lobe::BlinnPhong {
                        shininess,
                        specular,
                    } => {
                        let bp = if specular {
                            PI * blinn_phong(hit.normal, d, hit.to_viewer, shininess)
                        } else {
                            0.0
                        };
                        (1.0, [bp; 3])
                    }
                    Lobe::Ggx { alpha, f0 } => {
                        let (id, dv, w) = ggx_terms(hit.normal, d, hit.to_viewer, alpha);
                        (PI * id, f0.map(|f| PI * dv * (f + (1.0 - f) * w)))
                    }
                };
                for k in 0..3 {
                    sum[k] += f64::from(l[k] * kd);
                    sum[3 + k] += f64::from(l[k] * ks[k]);
                }
            }
        }
        let n = f64::from(nx * ny);
        for (out, v) in px.illum.iter_mut().zip(sum) {
            *out += v / n;
        }
    });
    let cam = &scene.camera;
    let mut layers = Layers::from_pixels(cam.width, cam.height, &pixels);
    // Only the bounce: what the visible surfaces emit or take from ambient light is direct.
    layers.emissive.data.fill(0.0);
    layers.ambient.data.fill(0.0);
    layers
}

/// Diffuse radiance towards the visible point of the surface a ray from it along `d` meets, lit
/// by `direct` with ray-traced visibility (the irradiance taken on the geometric normal, as a
/// VPL's power is).
fn bounce_radiance(tracer: &Tracer<'_>, from: &SurfaceHit, d: V3, direct: &[LightSample]) -> V3 {
    let side = from.geometric_normal.map(f64::from);
    let o = [0, 1, 2].map(|k| from.position[k] + tracer.epsilon() * side[k]);
    let Some((y, unseen_back, tint)) = tracer.light_ray_tinted(o, d) else {
        return [0.0; 3];
    };
    if unseen_back {
        return [0.0; 3];
    }
    let albedo = tracer.diffuse(&y);
    if albedo == [0.0; 3] {
        return [0.0; 3];
    }
    let p = y.position_f32();
    let mut e = [0.0f32; 3];
    for s in direct {
        if matches!(s.kind, SampleKind::Bounce { .. }) {
            continue;
        }
        let irr = shading::irradiance(s, p, y.geometric_normal);
        if irr == 0.0 {
            continue;
        }
        let t = tracer.transmittance(&y, s);
        for k in 0..3 {
            e[k] += irr * s.color[k] * t[k];
        }
    }
    [0, 1, 2].map(|k| albedo[k] * e[k] * tint[k] / PI)
}
