//! lightfold's quality measurements: the hard cases of numerical stability (each a scene, a metric
//! against ground truth, an asserted bound and a negative control) and the speed-against-error
//! sweep behind `lightfold accuracy`.
//!
//! Uses the GPU renderer and the CPU reference side by side; nothing here runs in a daemon.

pub mod accuracy;
pub mod against_point_sum;
pub mod calibrate;
pub mod hard;
pub mod single;

use lightfold_node::gpu::{Gpu, LayerSet, RenderOptions, Renderer};
use lightfold_scene::{Image, LightSample, Scene};
use std::time::Instant;

/// Lights per GPU batch of [`gpu_radiance`]: the K the node-seconds are measured at.
pub const BATCH_LIGHTS: usize = 16;

/// The final radiance of `scene` under `samples` on one device, in batches of
/// [`BATCH_LIGHTS`] ([`single::render_frame`]), and the seconds the frame took after a warm-up
/// frame (pipelines compile on first use): the node-seconds of the frame.
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
    let t = Instant::now();
    let ((image, _), _) = single::render_frame(gpu, &mut r, scene, samples, BATCH_LIGHTS, None, 0)?;
    Ok((image, t.elapsed().as_secs_f64()))
}
