//! Renders one setting as a cluster would: the frame's samples split into batches of K, each batch
//! one node's frame (the first also draws the material layers), its illumination sent through the
//! link format (pack, unpack) and summed, then paper eq. 2 into linear radiance. Every batch is
//! timed wall-clock, pack included (the fastest of a few frames); a warm-up batch first keeps
//! shader compilation out of it.

use super::{AccuracyError, Setting};
use lightfold_node::gpu::{Gpu, LayerSet, NodeFrame, RenderOptions, Renderer};
use lightfold_protocol::format::{self, PixelFormat};
use lightfold_scene::sampling::direct_samples;
use lightfold_scene::{Image, LightSample, Scene};
use std::time::Instant;

/// One setting's image and cost.
#[derive(Debug, Clone)]
pub struct Measured {
    pub image: Image,
    /// Frame time of each node (batch), seconds.
    pub node_seconds: Vec<f64>,
    /// The part of each node's time that scales with the image's pixels (eye pass, readback,
    /// the link's pack; the screen-space filter's node), seconds: a cost model at another image
    /// size scales these by the pixel ratio and keeps the rest (shadow passes, set-up).
    pub pixel_seconds: Vec<f64>,
    pub k_run: u32,
    pub lights: usize,
}

/// Renders the settings of one group (they differ in link format only) from one set of batches.
pub fn measure_group(
    gpu: &Gpu,
    scene: &Scene,
    settings: &[Setting],
    repeats: u32,
) -> Result<Vec<Measured>, AccuracyError> {
    let Some(first) = settings.first() else {
        return Ok(Vec::new());
    };
    let mut scene = scene.clone();
    first.apply(&mut scene);
    measure_prepared(gpu, &scene, settings, repeats)
}

/// [`measure_group`] of a scene whose quality is already set as the settings render (samples,
/// pattern, map sizing, filter): the settings give K, the largest map (for the devices' K
/// limit), the link format and the penumbra filter.
pub fn measure_prepared(
    gpu: &Gpu,
    scene: &Scene,
    settings: &[Setting],
    repeats: u32,
) -> Result<Vec<Measured>, AccuracyError> {
    let Some(first) = settings.first() else {
        return Ok(Vec::new());
    };
    let err = |message: String| AccuracyError::Render {
        setting: first.to_string(),
        message,
    };
    let scene = scene.clone();
    let samples = direct_samples(&scene);
    let opts = RenderOptions::from_quality(&scene.quality);
    let k_run = first.k.clamp(1, gpu.max_lights(first.map_size).max(1));
    let mut renderer = Renderer::new(gpu, &scene, opts).map_err(|e| err(e.to_string()))?;
    let batches: Vec<&[LightSample]> = if samples.is_empty() {
        vec![&[]]
    } else {
        samples.chunks(k_run as usize).collect()
    };
    // Warm-up: pipelines compile and textures are created on the first draw.
    renderer
        .render(gpu, batches[0], None, [1.0; 3], LayerSet::all())
        .map_err(|e| err(e.to_string()))?;
    let mut frames: Vec<(NodeFrame, f64)> = Vec::with_capacity(batches.len());
    // The machine is shared: each node's time is its fastest of `repeats` frames.
    for pass in 0..repeats.max(1) {
        for (i, batch) in batches.iter().enumerate() {
            let layers = if i == 0 {
                LayerSet::all()
            } else {
                LayerSet::illumination()
            };
            let t = Instant::now();
            let frame = renderer
                .render(gpu, batch, None, [1.0; 3], layers)
                .map_err(|e| err(e.to_string()))?;
            let secs = t.elapsed().as_secs_f64();
            if pass == 0 {
                frames.push((frame, secs));
            } else {
                frames[i].1 = frames[i].1.min(secs);
            }
        }
    }
    let mut out = Vec::with_capacity(settings.len());
    for s in settings {
        let (w, h) = (scene.camera.width, scene.camera.height);
        let mut illumination = Image::new(w, h, 6);
        let mut node_seconds = Vec::with_capacity(frames.len());
        let mut pixel_seconds = Vec::with_capacity(frames.len());
        let mut bytes = Vec::new();
        for (frame, secs) in &frames {
            let il = frame
                .illumination
                .as_ref()
                .ok_or_else(|| err("illumination layer missing".into()))?;
            let t = Instant::now();
            let linked = through_link(s.format, &il.data, &mut bytes)?;
            let pack = t.elapsed().as_secs_f64();
            node_seconds.push(secs + pack);
            // The frame's own phases say which share of its time the pixels took.
            let st = &frame.stats;
            let phases = (st.setup_us + st.shadow_us + st.eye_us + st.readback_us).max(1) as f64;
            let pixel_share = (st.eye_us + st.readback_us) as f64 / phases;
            pixel_seconds.push(secs * pixel_share + pack);
            for (a, b) in illumination.data.iter_mut().zip(&linked) {
                *a += b;
            }
        }
        if s.penumbra > 0 {
            // The compositor's filter, timed as one more node's work.
            let t = Instant::now();
            illumination =
                penumbra_filter(&scene, &frames[0].0, &illumination, s.penumbra).map_err(err)?;
            node_seconds.push(t.elapsed().as_secs_f64());
            pixel_seconds.push(t.elapsed().as_secs_f64());
        }
        let image = radiance(&scene, &frames[0].0, &illumination).map_err(err)?;
        out.push(Measured {
            image,
            node_seconds,
            pixel_seconds,
            k_run,
            lights: samples.len(),
        });
    }
    Ok(out)
}

/// `unpack(pack(v))` through `format`. `seed64` is fixed point against a per-frame scale: the
/// node's own maximum, the best a coordinator could choose for this frame.
fn through_link(
    format: PixelFormat,
    v: &[f32],
    bytes: &mut Vec<u8>,
) -> Result<Vec<f32>, AccuracyError> {
    let map = |source| AccuracyError::Format { format, source };
    let max = v
        .iter()
        .copied()
        .filter(|x| x.is_finite())
        .fold(0.0f32, f32::max);
    let scale = if max > 0.0 { max } else { 1.0 };
    bytes.resize(v.len() / 6 * format.bytes_per_pixel(), 0);
    format::pack(format, v, scale, bytes).map_err(map)?;
    let mut back = vec![0.0; v.len()];
    format::unpack(format, bytes, scale, &mut back).map_err(map)?;
    Ok(back)
}

/// The compositor's `penumbra` operator of `radius` over a whole frame of illumination, with the
/// first node's depth layer and the crease test the planner gives it for the scene's camera.
fn penumbra_filter(scene: &Scene, m: &NodeFrame, il: &Image, radius: u32) -> Result<Image, String> {
    let depth = m.depth.as_ref().ok_or("depth layer missing")?;
    let data = lightfold_compositor::ops::penumbra::filter_frame(
        il.width,
        radius,
        scene.camera.fov_y_deg,
        &il.data,
        &depth.data,
    )
    .map_err(|e| e.to_string())?;
    Ok(Image {
        data,
        ..Image::new(il.width, il.height, 6)
    })
}

/// Paper eq. 2 from the first node's material layers and the summed illumination (`c_n` white).
fn radiance(scene: &Scene, m: &NodeFrame, il: &Image) -> Result<Image, String> {
    m.radiance(il, scene.ambient).map_err(|e| e.to_string())
}
