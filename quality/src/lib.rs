//! lightfold's quality measurements: the hard cases of numerical stability (each a scene, a metric
//! against ground truth, an asserted bound and a negative control) and the speed-against-error
//! sweep behind `lightfold accuracy`.
//!
//! Uses the GPU renderer and the CPU reference side by side; nothing here runs in a daemon.

pub mod accuracy;
pub mod calibrate;
pub mod hard;

use anyhow::Context;
use lightfold_node::gpu::{Gpu, LayerSet, RenderOptions, Renderer};
use lightfold_scene::{Image, LightSample, Scene};
use std::time::Instant;

/// Lights per GPU batch of [`gpu_radiance`]: the K the node-seconds are measured at.
pub const BATCH_LIGHTS: usize = 16;

/// The final radiance of `scene` under `samples` on one device, in batches of
/// [`BATCH_LIGHTS`] (each batch's `m^d⊙I^d + m^s⊙I^s`, the ambient and emissive terms once),
/// and the seconds the batches took after a warm-up frame (pipelines compile on first use): the
/// node-seconds of the frame.
pub fn gpu_radiance(
    gpu: &Gpu,
    scene: &Scene,
    samples: &[LightSample],
) -> anyhow::Result<(Image, f64)> {
    let mut r = Renderer::new(gpu, scene, RenderOptions::from_quality(&scene.quality))?;
    r.set_camera(&scene.camera);
    r.render(
        gpu,
        &samples[..samples.len().min(BATCH_LIGHTS)],
        None,
        [1.0; 3],
        LayerSet::all(),
    )?;
    let mut total: Option<Image> = None;
    let mut seconds = 0.0;
    for chunk in samples.chunks(BATCH_LIGHTS) {
        let t = Instant::now();
        let f = r.render(gpu, chunk, None, [1.0; 3], LayerSet::all())?;
        seconds += t.elapsed().as_secs_f64();
        let illum = f.illumination.clone().context("illumination")?;
        // The ambient and emissive terms once, with the first batch.
        let ambient = if total.is_none() {
            scene.ambient
        } else {
            [0.0; 3]
        };
        let mut img = f.radiance(&illum, ambient)?;
        if let Some(t) = &total {
            let e = f.emissive.as_ref().context("emissive")?;
            for ((o, v), s) in img.data.iter_mut().zip(&e.data).zip(&t.data) {
                *o += s - v;
            }
        }
        total = Some(img);
    }
    Ok((total.context("no samples")?, seconds))
}
