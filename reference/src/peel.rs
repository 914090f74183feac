//! Peeled translucency, "glass as the eye sees it" (`docs/translucency.md`): the image as an
//! opaque layer plus `D` translucent layers composited back to front, the CPU truth of a node
//! that peels and of the compositor's `blend` operator over its layers.
//!
//! Per pixel-centre eye ray ([`Tracer::eye_layers`]):
//! - layer 0 is the nearest surface that is not translucent, its material layers untinted;
//! - layers `1..=D` are the translucent surfaces in front of it, nearest first, each shaded like
//!   any surface (the same illumination sum, shadow rays through translucent casters) with its
//!   material layers times its eye coverage `a` and an eye transmittance `T`
//!   ([`lightfold_scene::shading::eye_cover`]); a pixel without layer `d` has zeros there and
//!   `T = 1`;
//! - the pixel is `L_1 + T_1 ⊙ (L_2 + T_2 ⊙ (… (L_D + T_D ⊙ L_0)))`, each `L` that layer's
//!   paper eq. 2 radiance ([`Layers::radiance`]).

use crate::point_sum::{Layers, PixelLayers, accumulate_samples, per_pixel, sample_weights};
use lightfold_scene::shading::V3;
use lightfold_scene::trace::{SurfaceHit, Tracer};
use lightfold_scene::{Image, LightSample, Scene};

/// What a peeled render of a set of samples produces.
#[derive(Debug, Clone, PartialEq)]
pub struct PeeledLayers {
    /// Layer 0: the nearest surface that is not translucent, untinted.
    pub opaque: Layers,
    /// The translucent layers, nearest first (`layers[0]` is layer 1), their material layers
    /// premultiplied by the eye coverage; always as many as the peels asked for.
    pub layers: Vec<Layers>,
    /// Per translucent layer, 3 channels: its eye transmittance `T` (1 where it is absent).
    pub transmittance: Vec<Image>,
}

impl PeeledLayers {
    /// The composite, back to front: `out = L_0`, then `out = L_d + T_d ⊙ out` for
    /// `d = D, D − 1, …, 1`, each `L` its layer's [`Layers::radiance`] under `c_n` and the
    /// global ambient `ambient`. 3 channels.
    pub fn radiance(&self, c_n: [f32; 3], ambient: [f32; 3]) -> Image {
        let mut out = self.opaque.radiance(c_n, ambient);
        for (layer, t) in self.layers.iter().zip(&self.transmittance).rev() {
            let l = layer.radiance(c_n, ambient);
            for ((o, l), t) in out.data.iter_mut().zip(&l.data).zip(&t.data) {
                *o = l + t * *o;
            }
        }
        out
    }
}

/// One pixel's peeled layers before they are split into images.
#[derive(Debug, Clone)]
struct PeeledPixel {
    opaque: PixelLayers,
    layers: Vec<PixelLayers>,
    transmittance: Vec<V3>,
}

/// Renders the exact sum over `samples` (shadows on) for a node colour `c_n`, peeled into the
/// opaque layer and `peels` translucent layers (`peels` = 0: the opaque layer alone, glass not
/// drawn at all).
pub fn render_peeled(
    scene: &Scene,
    samples: &[LightSample],
    c_n: [f32; 3],
    peels: u32,
) -> PeeledLayers {
    let tracer = Tracer::new(scene);
    let weights = sample_weights(samples, c_n);
    let d = peels as usize;
    let lit = |hit: &SurfaceHit, factor: V3| {
        let mut px = PixelLayers::surface(&tracer, hit, factor);
        accumulate_samples(&tracer, hit, samples, &weights, true, &mut px.illum);
        px
    };
    let pixels = per_pixel(&tracer, |x, y| {
        let eye = tracer.eye_layers(x as f32 + 0.5, y as f32 + 0.5, d);
        let mut px = PeeledPixel {
            opaque: eye
                .opaque
                .map_or_else(PixelLayers::default, |hit| lit(&hit, [1.0; 3])),
            layers: vec![PixelLayers::default(); d],
            transmittance: vec![[1.0; 3]; d],
        };
        for (k, layer) in eye.translucent.iter().enumerate() {
            px.layers[k] = lit(&layer.surface, [layer.cover.coverage; 3]);
            px.transmittance[k] = layer.cover.transmittance;
        }
        px
    });
    let cam = &scene.camera;
    let (w, h) = (cam.width, cam.height);
    let opaque: Vec<PixelLayers> = pixels.iter().map(|p| p.opaque).collect();
    let layers = (0..d)
        .map(|k| {
            let layer: Vec<PixelLayers> = pixels.iter().map(|p| p.layers[k]).collect();
            Layers::from_pixels(w, h, &layer)
        })
        .collect();
    let transmittance = (0..d)
        .map(|k| {
            let mut t = Image::new(w, h, 3);
            for (px, p) in t.data.chunks_exact_mut(3).zip(&pixels) {
                px.copy_from_slice(&p.transmittance[k]);
            }
            t
        })
        .collect();
    PeeledLayers {
        opaque: Layers::from_pixels(w, h, &opaque),
        layers,
        transmittance,
    }
}

/// Final linear radiance of the peeled render of `samples` (`c_n` white, the scene's ambient).
pub fn radiance_peeled(scene: &Scene, samples: &[LightSample], peels: u32) -> Image {
    render_peeled(scene, samples, [1.0; 3], peels).radiance([1.0; 3], scene.ambient)
}
