//! The exact CPU evaluator of a set of point-light samples: per pixel centre, the sum of paper
//! eq. 2 over the samples with ray-traced binary visibility `s_λ ∈ {0, 1}`, through the same
//! `scene::shading` the GPU mirrors. Produces the same layers an illumination node and the
//! material pass produce, so GPU output can be compared layer by layer.

use lightfold_scene::shading::{self, MaterialLayers, V3};
use lightfold_scene::trace::{SurfaceHit, Tracer};
use lightfold_scene::{Image, LightSample, Scene};
use rayon::prelude::*;

/// What one render of a set of samples produces, per pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct Layers {
    /// 6 channels: `Σ (c_λ ⊘ c_n)·i^d_λ·s_λ` (RGB), then the same for `i^s`.
    pub illumination: Image,
    /// 3 channels each: `m^d` (texture applied), `m^s`, `m^a`, `e`.
    pub diffuse: Image,
    pub specular: Image,
    pub ambient: Image,
    pub emissive: Image,
    /// Whether the pixel's primary ray hit geometry.
    pub coverage: Vec<bool>,
    /// 1 channel: eye-space distance along the view axis, 0 for background.
    pub depth: Image,
}

/// Options of the evaluator beyond the sample set.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PointSumOptions {
    /// Trace shadow rays; `false` gives the unoccluded image (every `s_λ = 1`).
    pub shadows: bool,
}

impl Default for PointSumOptions {
    fn default() -> Self {
        PointSumOptions { shadows: true }
    }
}

/// One pixel's layers before they are split into images.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct PixelLayers {
    pub illum: [f64; 6],
    pub diffuse: V3,
    pub specular: V3,
    pub ambient: V3,
    pub emissive: V3,
    pub depth: f32,
    pub covered: bool,
}

impl Layers {
    /// Final linear radiance (paper eq. 2, [`shading::compose_frame`]) with
    /// `I^d = c_n ⊙ illumination`, `I^a = 0` and global ambient `c^a = ambient` where a surface
    /// covers the pixel: `e + m^a⊙c^a + m^d⊙I^d + m^s⊙I^s`. 3 channels.
    pub fn radiance(&self, c_n: [f32; 3], ambient: [f32; 3]) -> Image {
        let m = MaterialLayers {
            diffuse: &self.diffuse,
            specular: &self.specular,
            ambient: &self.ambient,
            emissive: &self.emissive,
        };
        shading::compose_frame(&self.illumination, c_n, m, ambient, |i| self.coverage[i])
    }

    pub(crate) fn from_pixels(width: u32, height: u32, pixels: &[PixelLayers]) -> Layers {
        let mut l = Layers {
            illumination: Image::new(width, height, 6),
            diffuse: Image::new(width, height, 3),
            specular: Image::new(width, height, 3),
            ambient: Image::new(width, height, 3),
            emissive: Image::new(width, height, 3),
            coverage: vec![false; pixels.len()],
            depth: Image::new(width, height, 1),
        };
        for (i, p) in pixels.iter().enumerate() {
            for k in 0..6 {
                l.illumination.data[i * 6 + k] = p.illum[k] as f32;
            }
            l.diffuse.data[i * 3..i * 3 + 3].copy_from_slice(&p.diffuse);
            l.specular.data[i * 3..i * 3 + 3].copy_from_slice(&p.specular);
            l.ambient.data[i * 3..i * 3 + 3].copy_from_slice(&p.ambient);
            l.emissive.data[i * 3..i * 3 + 3].copy_from_slice(&p.emissive);
            l.depth.data[i] = p.depth;
            l.coverage[i] = p.covered;
        }
        l
    }
}

/// Renders the exact sum over `samples` (shadows on) for a node colour `c_n`.
pub fn render_point_sum(scene: &Scene, samples: &[LightSample], c_n: [f32; 3]) -> Layers {
    render_point_sum_with(scene, samples, c_n, PointSumOptions::default())
}

/// [`render_point_sum`] with options (e.g. no shadows for the unoccluded image).
pub fn render_point_sum_with(
    scene: &Scene,
    samples: &[LightSample],
    c_n: [f32; 3],
    options: PointSumOptions,
) -> Layers {
    let tracer = Tracer::new(scene);
    let weights = sample_weights(samples, c_n);
    let pixels = render_pixels(&tracer, |_, _, hit, px| {
        accumulate_samples(
            &tracer,
            hit,
            samples,
            &weights,
            options.shadows,
            &mut px.illum,
        );
    });
    let cam = &scene.camera;
    Layers::from_pixels(cam.width, cam.height, &pixels)
}

/// Final linear radiance of the exact sum over `samples` (3 channels, `c_n` = white).
pub fn radiance_point_sum(scene: &Scene, samples: &[LightSample]) -> Image {
    render_point_sum(scene, samples, [1.0; 3]).radiance([1.0; 3], scene.ambient)
}

/// `c_λ ⊘ c_n` of every sample: the weights [`accumulate_samples`] takes.
pub(crate) fn sample_weights(samples: &[LightSample], c_n: [f32; 3]) -> Vec<[f64; 3]> {
    samples
        .iter()
        .map(|s| [0, 1, 2].map(|k| colour_ratio(s.color[k], c_n[k])))
        .collect()
}

/// `c_λ / c_n` per channel; a channel the node colour lacks contributes nothing.
fn colour_ratio(c: f32, c_n: f32) -> f64 {
    if c_n != 0.0 && c_n.is_finite() {
        f64::from(c) / f64::from(c_n)
    } else {
        0.0
    }
}

/// Adds `Σ w_λ·(i^d_λ, i^s_λ)·s_λ` of `samples` at `hit` into `illum`.
pub(crate) fn accumulate_samples(
    tracer: &Tracer<'_>,
    hit: &SurfaceHit,
    samples: &[LightSample],
    weights: &[[f64; 3]],
    shadows: bool,
    illum: &mut [f64; 6],
) {
    let shade = Shade::new(tracer, hit);
    for (s, w) in samples.iter().zip(weights) {
        shade.add(tracer, hit, s, *w, shadows, illum);
    }
}

/// The per-hit constants of shading one sample after another.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Shade {
    position: V3,
    lobe: shading::Lobe,
}

impl Shade {
    pub(crate) fn new(tracer: &Tracer<'_>, hit: &SurfaceHit) -> Shade {
        Shade {
            position: hit.position_f32(),
            lobe: tracer.surface(hit).lobe,
        }
    }

    /// Adds `w·(i^d, i^s)·s` of one sample, tracing its shadow ray only when it contributes.
    #[inline]
    pub(crate) fn add(
        &self,
        tracer: &Tracer<'_>,
        hit: &SurfaceHit,
        s: &LightSample,
        w: [f64; 3],
        shadows: bool,
        illum: &mut [f64; 6],
    ) {
        let (id, is) =
            shading::lobe_coefficients(s, self.position, hit.normal, hit.to_viewer, &self.lobe);
        if id == 0.0 && is == [0.0; 3] {
            return;
        }
        if shadows && tracer.has_translucent() {
            // s_λ is RGB: what translucent casters let through (`docs/translucency.md`).
            let t = tracer.transmittance(hit, s);
            for k in 0..3 {
                let t = f64::from(t[k]);
                illum[k] += w[k] * f64::from(id) * t;
                illum[3 + k] += w[k] * f64::from(is[k]) * t;
            }
            return;
        }
        if shadows && !tracer.visible(hit, s) {
            return;
        }
        for k in 0..3 {
            illum[k] += w[k] * f64::from(id);
            illum[3 + k] += w[k] * f64::from(is[k]);
        }
    }
}

/// Traces every pixel centre in parallel over rows, fills the material layers and depth, and
/// lets `light` add the illumination of covered pixels.
pub(crate) fn render_pixels(
    tracer: &Tracer<'_>,
    light: impl Fn(u32, u32, &SurfaceHit, &mut PixelLayers) + Sync,
) -> Vec<PixelLayers> {
    per_pixel(tracer, |x, y| {
        let Some(hit) = tracer.primary(x, y) else {
            return PixelLayers::default();
        };
        // Filters in front tint every material layer alike.
        let t = tracer.eye_transmittance(x, y, &hit);
        let mut px = PixelLayers::surface(tracer, &hit, t);
        light(x, y, &hit, &mut px);
        px
    })
}

/// `f` of every pixel `(x, y)`, in parallel over rows, row-major.
pub(crate) fn per_pixel<T: Send>(tracer: &Tracer<'_>, f: impl Fn(u32, u32) -> T + Sync) -> Vec<T> {
    let cam = &tracer.scene().camera;
    let (w, h) = (cam.width, cam.height);
    let rows: Vec<Vec<T>> = (0..h)
        .into_par_iter()
        .map(|y| (0..w).map(|x| f(x, y)).collect())
        .collect();
    rows.into_iter().flatten().collect()
}

impl PixelLayers {
    /// A pixel covered by `hit`: its depth and its material layers (`m^d`, `m^s`, `m^a`, `e`)
    /// each multiplied by `factor`; no illumination yet.
    pub(crate) fn surface(tracer: &Tracer<'_>, hit: &SurfaceHit, factor: V3) -> PixelLayers {
        let sp = tracer.surface(hit);
        PixelLayers {
            covered: true,
            depth: hit.depth,
            diffuse: shading::mul(sp.diffuse, factor),
            specular: shading::mul(sp.specular, factor),
            ambient: shading::mul(sp.ambient, factor),
            emissive: shading::mul(sp.emissive, factor),
            ..PixelLayers::default()
        }
    }
}
