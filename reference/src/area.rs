//! The true direct illumination of area lights: per pixel centre, a fresh stratified-jittered set
//! of points on every area light (solid-angle sampling for spheres), each shaded through
//! `scene::shading` with an exact ray-traced visibility test; a soft sun, a fresh set of
//! directions over its disk on the sky, equal in solid angle. Point, spot and parallel
//! directional lights are exact (their one sample). Deliberately independent of `scene::sampling`'s area maps, so a
//! mistake there shows up as a difference rather than being reproduced.

use crate::point_sum::{Layers, PixelLayers, Shade, render_pixels};
use lightfold_scene::sampling::{SplitMix64, grid_shape, light_samples};
use lightfold_scene::shading::{V3, cross, dot, length, normalize, scale, sub};
use lightfold_scene::trace::{SurfaceHit, Tracer};
use lightfold_scene::{Image, LightSample, LightShape, SampleKind, Scene};
use std::f64::consts::{PI, TAU};

/// How the area-light truth is computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AreaOptions {
    /// Points per area light per pixel (a stratified `a×b` grid, jittered in each cell).
    pub samples_per_light: u32,
    /// Seeds the per-pixel jitter; two seeds give two independent estimates (the noise floor).
    pub seed: u64,
    /// Trace visibility; `false` gives the unoccluded image.
    pub shadows: bool,
}

impl Default for AreaOptions {
    fn default() -> Self {
        AreaOptions {
            samples_per_light: 256,
            seed: 1,
            shadows: true,
        }
    }
}

/// One light as the truth evaluates it.
#[derive(Debug, Clone)]
enum Emitter {
    /// Point, spot, directional: exact.
    Exact(LightSample),
    /// A flat emitter: `p(a, b)` over the unit square, area-preserving, with its radiance.
    Rect {
        center: V3,
        normal: V3,
        u: V3,
        v: V3,
        area: f32,
        base: LightSample,
    },
    Disk {
        center: V3,
        normal: V3,
        u: V3,
        v: V3,
        radius: f32,
        base: LightSample,
    },
    Sphere {
        center: V3,
        radius: f32,
        base: LightSample,
    },
    /// The curved side of a cylinder: `p(a, b)` along the axis and around it.
    Cylinder {
        center: [f64; 3],
        axis: [f64; 3],
        u: [f64; 3],
        v: [f64; 3],
        length: f64,
        radius: f64,
        base: LightSample,
    },
    /// A soft sun: directions about `w` (the direction of travel) within the cap
    /// `1 − cos θ ≤ one_minus_cos`, each parallel light carrying `E/n / (1 − one_minus_cos/2)`
    /// (the cap's radiance `E / (π sin²α)` times its solid angle over `n`).
    Sun {
        w: [f64; 3],
        /// A frame perpendicular to `w`.
        u: [f64; 3],
        v: [f64; 3],
        one_minus_cos: f64,
        base: LightSample,
    },
    Mesh {
        /// `(p0, e1, e2, unit normal)` of each non-degenerate triangle.
        tris: Vec<(V3, V3, V3, V3)>,
        /// Cumulative areas.
        cdf: Vec<f64>,
        two_sided: bool,
        base: LightSample,
    },
}

/// Renders the truth's layers (illumination with `c_n` = white: `Σ c_λ·i_λ·s_λ`).
pub fn render_area(scene: &Scene, options: &AreaOptions) -> Layers {
    let tracer = Tracer::new(scene);
    let emitters = emitters(scene);
    let n = options.samples_per_light.max(1);
    let cam = &scene.camera;
    let pixels = render_pixels(&tracer, |x, y, hit, px: &mut PixelLayers| {
        // Jitter depends on the seed and the pixel only, never on thread scheduling.
        let mut rng = SplitMix64(hash3(options.seed, (u64::from(y) << 32) | u64::from(x), 0));
        direct(
            &tracer,
            hit,
            &emitters,
            n,
            options.shadows,
            &mut rng,
            &mut px.illum,
        );
    });
    Layers::from_pixels(cam.width, cam.height, &pixels)
}

/// Final linear radiance of the truth (3 channels).
pub fn radiance_area(scene: &Scene, options: &AreaOptions) -> Image {
    render_area(scene, options).radiance([1.0; 3], scene.ambient)
}

/// `(Σ c·i^d, Σ c·i^s)` of every light at one surface point, for tests at arbitrary points.
pub fn direct_at(
    tracer: &Tracer<'_>,
    hit: &SurfaceHit,
    options: &AreaOptions,
    stream: u64,
) -> [f64; 6] {
    let emitters = emitters(tracer.scene());
    let mut rng = SplitMix64(hash3(options.seed, stream, 1));
    let mut illum = [0.0; 6];
    let n = options.samples_per_light.max(1);
    direct(
        tracer,
        hit,
        &emitters,
        n,
        options.shadows,
        &mut rng,
        &mut illum,
    );
    illum
}

fn emitters(scene: &Scene) -> Vec<Emitter> {
    let mut out = Vec::new();
    for (i, light) in scene.lights.iter().enumerate() {
        let base = LightSample {
            position: [0.0; 3],
            direction: [0.0, -1.0, 0.0],
            kind: SampleKind::CosineLobe,
            intensity: light.power,
            color: light.color,
            range: light.range,
            light: i as u32,
            area: None,
            cell: 0.0,
        };
        let e = match &light.shape {
            LightShape::Directional { direction, angle } if *angle > 0.0 => {
                let d = direction.map(f64::from);
                let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                let half = f64::from(*angle) / 2.0;
                let w = d.map(|c| c / l);
                let (u, v) = frame64(w);
                Some(Emitter::Sun {
                    w,
                    u,
                    v,
                    one_minus_cos: 2.0 * (half / 2.0).sin().powi(2),
                    base: LightSample {
                        kind: SampleKind::Directional,
                        ..base
                    },
                })
            }
            LightShape::Point { .. } | LightShape::Spot { .. } | LightShape::Directional { .. } => {
                light_samples(scene, i, &scene.quality)
                    .into_iter()
                    .next()
                    .map(Emitter::Exact)
            }
            LightShape::Cylinder {
                center,
                axis,
                length,
                radius,
            } => {
                let a = axis.map(f64::from);
                let l = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
                let a = a.map(|c| c / l);
                let (u, v) = frame64(a);
                Some(Emitter::Cylinder {
                    center: center.map(f64::from),
                    axis: a,
                    u,
                    v,
                    length: f64::from(*length),
                    radius: f64::from(*radius),
                    base,
                })
            }
            LightShape::Rect {
                center,
                normal,
                u_axis,
                size,
            } => {
                let n = normalize(*normal);
                // Project the u axis into the emitter plane (a no-op for valid input).
                let u = normalize(sub(*u_axis, scale(n, dot(*u_axis, n))));
                let v = cross(n, u);
                Some(Emitter::Rect {
                    center: *center,
                    normal: n,
                    u: scale(u, size[0]),
                    v: scale(v, size[1]),
                    area: size[0] * size[1],
                    base,
                })
            }
            LightShape::Disk {
                center,
                normal,
                radius,
            } => {
                let n = normalize(*normal);
                let helper = if n[1].abs() < 0.9 {
                    [0.0, 1.0, 0.0]
                } else {
                    [0.0, 0.0, 1.0]
                };
                let u = normalize(cross(n, helper));
                Some(Emitter::Disk {
                    center: *center,
                    normal: n,
                    u,
                    v: cross(n, u),
                    radius: *radius,
                    base,
                })
            }
            LightShape::Sphere { center, radius } => Some(Emitter::Sphere {
                center: *center,
                radius: *radius,
                base,
            }),
            LightShape::EmissiveMesh { mesh } => scene.meshes.get(*mesh).map(|m| {
                let mut tris = Vec::new();
                let mut cdf = Vec::new();
                let mut total = 0.0;
                for t in m.indices.chunks_exact(3) {
                    let get = |i: u32| m.positions.get(i as usize).copied();
                    let (Some(a), Some(b), Some(c)) = (get(t[0]), get(t[1]), get(t[2])) else {
                        continue;
                    };
                    let (e1, e2) = (sub(b, a), sub(c, a));
                    let cr = cross(e1, e2);
                    let area = 0.5 * f64::from(length(cr));
                    if area > 0.0 && area.is_finite() {
                        total += area;
                        cdf.push(total);
                        tris.push((a, e1, e2, normalize(cr)));
                    }
                }
                let two_sided = scene
                    .materials
                    .get(m.material)
                    .is_some_and(|mat| mat.double_sided);
                Emitter::Mesh {
                    tris,
                    cdf,
                    two_sided,
                    base,
                }
            }),
        };
        out.extend(e);
    }
    out
}

/// Adds every emitter's `c·(i^d, i^s)·V` at `hit` into `illum`.
fn direct(
    tracer: &Tracer<'_>,
    hit: &SurfaceHit,
    emitters: &[Emitter],
    n: u32,
    shadows: bool,
    rng: &mut SplitMix64,
    illum: &mut [f64; 6],
) {
    let shade = Shade::new(tracer, hit);
    let p = hit.position_f32();
    let (nx, ny) = grid_shape(n);
    for e in emitters {
        let colour = |s: &LightSample| s.color.map(f64::from);
        if let Emitter::Exact(s) = e {
            shade.add(tracer, hit, s, colour(s), shadows, illum);
            continue;
        }
        for j in 0..ny {
            for i in 0..nx {
                let a = (f64::from(i) + f64::from(rng.next_f32())) / f64::from(nx);
                let b = (f64::from(j) + f64::from(rng.next_f32())) / f64::from(ny);
                if let Some(s) = point_on(e, p, a, b, nx * ny) {
                    shade.add(tracer, hit, &s, colour(&s), shadows, illum);
                }
            }
        }
    }
}

/// The sample for unit-square point `(a, b)` of an `n`-point estimate of emitter `e` seen from
/// `p`; `None` when the emitter cannot contribute (inside a sphere light, empty mesh).
fn point_on(e: &Emitter, p: V3, a: f64, b: f64, n: u32) -> Option<LightSample> {
    let n = f64::from(n);
    let (a32, b32) = (a as f32, b as f32);
    match e {
        Emitter::Exact(s) => Some(*s),
        Emitter::Rect {
            center,
            normal,
            u,
            v,
            area,
            base,
        } => {
            let q = [0, 1, 2].map(|k| center[k] + (a32 - 0.5) * u[k] + (b32 - 0.5) * v[k]);
            Some(lobe(
                base,
                q,
                *normal,
                f64::from(base.intensity) * f64::from(*area) / n,
            ))
        }
        Emitter::Disk {
            center,
            normal,
            u,
            v,
            radius,
            base,
        } => {
            // Polar map r = R·√a (area-preserving).
            let r = radius * a32.sqrt();
            let phi = (TAU * b) as f32;
            let (s, c) = phi.sin_cos();
            let q = [0, 1, 2].map(|k| center[k] + r * (c * u[k] + s * v[k]));
            let area = PI * f64::from(*radius) * f64::from(*radius);
            Some(lobe(base, q, *normal, f64::from(base.intensity) * area / n))
        }
        Emitter::Sphere {
            center,
            radius,
            base,
        } => sphere_point(*center, *radius, base, p, a, b, n),
        Emitter::Cylinder {
            center,
            axis,
            u,
            v,
            length,
            radius,
            base,
        } => {
            let (s, c) = (TAU * b).sin_cos();
            let nrm = [0, 1, 2].map(|k| c * u[k] + s * v[k]);
            let q = [0, 1, 2]
                .map(|k| (center[k] + (a - 0.5) * length * axis[k] + radius * nrm[k]) as f32);
            let area = TAU * radius * length;
            Some(lobe(
                base,
                q,
                nrm.map(|x| x as f32),
                f64::from(base.intensity) * area / n,
            ))
        }
        Emitter::Sun {
            w,
            u,
            v,
            one_minus_cos,
            base,
        } => {
            // Uniform in solid angle over the cap: cos θ = 1 − a·(1 − cos α).
            let cos_t = 1.0 - a * one_minus_cos;
            let sin_t = (a * one_minus_cos * (2.0 - a * one_minus_cos))
                .max(0.0)
                .sqrt();
            let (s, c) = (TAU * b).sin_cos();
            let dir = [0, 1, 2].map(|k| (cos_t * w[k] + sin_t * (c * u[k] + s * v[k])) as f32);
            Some(LightSample {
                direction: dir,
                intensity: (f64::from(base.intensity) / n / (1.0 - one_minus_cos / 2.0)) as f32,
                ..*base
            })
        }
        Emitter::Mesh {
            tris,
            cdf,
            two_sided,
            base,
        } => {
            let total = *cdf.last()?;
            let target = a * total;
            let k = cdf.partition_point(|&c| c <= target).min(tris.len() - 1);
            let lo = if k == 0 { 0.0 } else { cdf[k - 1] };
            // Reuse the stratum inside the chosen triangle; uniform triangle map (√ trick).
            let a2 = ((target - lo) / (cdf[k] - lo)).clamp(0.0, 1.0);
            let su = a2.sqrt();
            let (w1, w2) = ((su * (1.0 - b)) as f32, (su * b) as f32);
            let (p0, e1, e2, nrm) = tris[k];
            let q = [0, 1, 2].map(|c| p0[c] + w1 * e1[c] + w2 * e2[c]);
            let mut s = lobe(base, q, nrm, f64::from(base.intensity) * total / n);
            if *two_sided {
                s.kind = SampleKind::TwoSidedLobe;
            }
            Some(s)
        }
    }
}

/// Uniform sampling of the cone the sphere subtends at `p`: an isotropic sample on the visible
/// surface with `I = L·Ω·t²/n`, so its irradiance is `L·Ω/n·cos θ`.
fn sphere_point(
    center: V3,
    radius: f32,
    base: &LightSample,
    p: V3,
    a: f64,
    b: f64,
    n: f64,
) -> Option<LightSample> {
    let d = sub(center, p).map(f64::from);
    let dist = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    let r = f64::from(radius);
    if dist.is_nan() || dist <= r {
        // On or inside an outward-emitting sphere: nothing reaches the point.
        return None;
    }
    let sin2 = (r / dist) * (r / dist);
    let cos_max = (1.0 - sin2).sqrt();
    // 1 − cos θmax without cancellation for distant spheres.
    let one_minus = sin2 / (1.0 + cos_max);
    let omega = TAU * one_minus;
    let cos_t = 1.0 - a * one_minus;
    let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
    let phi = TAU * b;
    let w = d.map(|c| c / dist);
    let (u, v) = frame64(w);
    let dir = [0, 1, 2].map(|k| sin_t * (phi.cos() * u[k] + phi.sin() * v[k]) + cos_t * w[k]);
    // Nearest intersection with the sphere along `dir`.
    let t = dist * cos_t - (r * r - dist * dist * sin_t * sin_t).max(0.0).sqrt();
    let pf = p.map(f64::from);
    let q = [0, 1, 2].map(|k| (pf[k] + t * dir[k]) as f32);
    let t32 = f64::from(length(sub(q, p)));
    Some(LightSample {
        position: q,
        kind: SampleKind::Isotropic,
        intensity: (f64::from(base.intensity) * omega * t32 * t32 / n) as f32,
        ..*base
    })
}

fn lobe(base: &LightSample, position: V3, normal: V3, intensity: f64) -> LightSample {
    LightSample {
        position,
        direction: normal,
        kind: SampleKind::CosineLobe,
        intensity: intensity as f32,
        ..*base
    }
}

fn frame64(w: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let h = if w[0].abs() < 0.9 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let c = |a: [f64; 3], b: [f64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    let u = c(h, w);
    let l = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt();
    let u = u.map(|x| x / l);
    (u, c(w, u))
}

/// Mixes three words into one seed by chaining SplitMix64 steps.
fn hash3(a: u64, b: u64, c: u64) -> u64 {
    let x = SplitMix64(a).next_u64();
    let y = SplitMix64(x ^ b).next_u64();
    SplitMix64(y ^ c).next_u64()
}
