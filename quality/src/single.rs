//! A whole frame on one device: every sample in batches of K (one shadow-map set and one eye pass
//! per batch, as one render node of K lights), illumination summed over the batches with `c_n` =
//! white, material layers from the first batch, the screen-space penumbra filter where asked, then
//! paper eq. 2 — the image a cluster of nodes of K lights must deliver. `lightfold render`, the
//! harness's frame check and the quality measurements all render through it; sort-last parts are
//! depth-composed as the compositor's `depth` operator does.

use anyhow::Context;
use lightfold_node::gpu::{Gpu, LayerSet, NodeFrame, Renderer};
use lightfold_scene::{Image, LightSample, Scene};
use std::time::Instant;

/// Sums of one frame over its batches, and each batch's own cost (one node frame of K lights).
#[derive(Debug, Default, Clone)]
pub struct FrameTimes {
    pub shadow_passes: u32,
    pub shadow_us: u64,
    pub eye_us: u64,
    pub readback_us: u64,
    pub total_us: u64,
    /// Each batch's shadow, eye and readback microseconds.
    pub batches: Vec<[u64; 3]>,
    /// Shadow views per light of the first batch (cube faces, cascades).
    pub passes_per_light: Vec<u32>,
}

impl FrameTimes {
    /// Adds another pass over the same lights (a partition's): its phases and batches; the views
    /// per light are the same, kept once.
    pub fn add(&mut self, other: &FrameTimes) {
        self.shadow_passes += other.shadow_passes;
        self.shadow_us += other.shadow_us;
        self.eye_us += other.eye_us;
        self.readback_us += other.readback_us;
        self.batches.extend_from_slice(&other.batches);
        if self.passes_per_light.is_empty() {
            self.passes_per_light = other.passes_per_light.clone();
        }
    }
}

/// One image over sort-last partitions: each part's image alone ([`Renderer::set_eye_meshes`],
/// its shadow maps fitted to the part: [`Renderer::set_fit_to_eye_meshes`]),
/// then per pixel the part whose surface is nearest (eye depth > 0; ties to the lower part, as
/// the compositor's `depth` operator breaks them). Times add up over the parts.
pub fn render_partitioned(
    gpu: &Gpu,
    renderer: &mut Renderer,
    scene: &Scene,
    samples: &[LightSample],
    k: usize,
    parts: &[Vec<u32>],
    casters: Option<&[Vec<Vec<u32>>]>,
) -> anyhow::Result<((Image, Image), FrameTimes)> {
    let t = Instant::now();
    let mut best: Option<(Image, Image)> = None;
    let mut times = FrameTimes::default();
    // As a sort-last node of the cluster: its part's eye pass, maps fitted to its part, with the
    // casters `casters[part]` that can shadow it (`None`: every mesh casts).
    renderer.set_fit_to_eye_meshes(true);
    for (p, part) in parts.iter().enumerate() {
        renderer.set_eye_meshes(Some(part.clone()));
        let part_casters = casters.map(|c| c[p].as_slice());
        let ((radiance, depth), part_times) =
            render_frame(gpu, renderer, scene, samples, k, part_casters, 0)?;
        times.add(&part_times);
        best = Some(match best {
            None => (radiance, depth),
            Some((mut r, mut d)) => {
                let c = r.channels;
                for (i, &z) in depth.data.iter().enumerate() {
                    if z > 0.0 && (d.data[i] == 0.0 || z < d.data[i]) {
                        d.data[i] = z;
                        r.data[i * c..i * c + c].copy_from_slice(&radiance.data[i * c..i * c + c]);
                    }
                }
                (r, d)
            }
        });
    }
    renderer.set_eye_meshes(None);
    renderer.set_fit_to_eye_meshes(false);
    times.total_us = t.elapsed().as_micros() as u64;
    Ok((best.context("no partition rendered")?, times))
}

/// One image: every batch of `k` samples (`casters[i]`: the meshes that shadow sample `i`;
/// `None`: every mesh), summed, filtered by the penumbra filter of radius `penumbra` (0: none),
/// composed with the material layers. Returns the radiance and the eye depth, and the frame's
/// costs.
pub fn render_frame(
    gpu: &Gpu,
    renderer: &mut Renderer,
    scene: &Scene,
    samples: &[LightSample],
    k: usize,
    casters: Option<&[Vec<u32>]>,
    penumbra: u32,
) -> anyhow::Result<((Image, Image), FrameTimes)> {
    let t = Instant::now();
    let (w, h) = (scene.camera.width, scene.camera.height);
    let mut illumination = Image::new(w, h, 6);
    let mut materials: Option<NodeFrame> = None;
    let mut times = FrameTimes::default();
    let batches: Vec<&[LightSample]> = if samples.is_empty() {
        vec![&[]]
    } else {
        samples.chunks(k).collect()
    };
    let mut start = 0;
    for (i, batch) in batches.into_iter().enumerate() {
        let layers = if i == 0 {
            LayerSet::all()
        } else {
            LayerSet::illumination()
        };
        let batch_casters = casters.map(|c| &c[start..start + batch.len()]);
        start += batch.len();
        let frame = renderer.render(gpu, batch, batch_casters, [1.0; 3], layers)?;
        times.shadow_passes += frame.stats.shadow_passes;
        times
            .passes_per_light
            .extend_from_slice(&frame.stats.passes_per_light);
        times.shadow_us += frame.stats.shadow_us;
        times.eye_us += frame.stats.eye_us;
        times.readback_us += frame.stats.readback_us;
        times.batches.push([
            frame.stats.shadow_us,
            frame.stats.eye_us,
            frame.stats.readback_us,
        ]);
        if let Some(il) = &frame.illumination {
            for (a, b) in illumination.data.iter_mut().zip(&il.data) {
                *a += b;
            }
        }
        if i == 0 {
            materials = Some(frame);
        }
    }
    let m = materials.context("no frame rendered")?;
    let layer = |img: &Option<Image>, name: &str| {
        img.clone().with_context(|| format!("{name} layer missing"))
    };
    let depth = layer(&m.depth, "depth")?;
    if penumbra > 0 {
        // The last stage's filter, as a cluster planned with the same radius applies it.
        illumination.data = lightfold_compositor::ops::penumbra::filter_frame(
            w,
            penumbra,
            scene.camera.fov_y_deg,
            &illumination.data,
            &depth.data,
        )?;
    }
    let radiance = m.radiance(&illumination, scene.ambient)?;
    times.total_us = t.elapsed().as_micros() as u64;
    Ok(((radiance, depth), times))
}

/// Sort-last parts of a scene for one device: the meshes of each part, and each part's casters
/// per sample where the scene is still (an animated one casts every mesh).
#[derive(Debug, Clone)]
pub struct Parts {
    pub parts: Vec<Vec<u32>>,
    pub casters: Option<Vec<Vec<Vec<u32>>>>,
}

impl Parts {
    /// `n` parts of `scene` (already chunked for them, `partition::chunk_for_parts`), as the
    /// cluster's planner partitions it.
    pub fn new(scene: &Scene, samples: &[LightSample], n: usize) -> Parts {
        let parts = lightfold_scene::partition::partition_meshes(scene, n);
        let casters = scene
            .animation
            .is_none()
            .then(|| lightfold_coordinator::plan::part_casters(scene, samples, &parts));
        Parts { parts, casters }
    }
}

/// Frames of one scene rendered one after another ([`render_repeated`]): the last image and
/// what its batches cost once warm.
#[derive(Debug)]
pub struct Repeated {
    /// The last frame's radiance and eye depth.
    pub image: (Image, Image),
    /// Shadow views per light of the first frame.
    pub views_per_light: Vec<u32>,
    /// Each steady batch's shadow, eye and readback microseconds: every frame after the first
    /// (which also compiles shaders and allocates; the only one when there is one), without each
    /// frame's first batch (which also renders the material layers).
    pub steady: Vec<[u64; 3]>,
    /// Frames the steady batches come from.
    pub steady_frames: usize,
}

impl Repeated {
    /// Median shadow, eye and readback microseconds of the steady batches (0 without any).
    pub fn steady_medians(&self) -> [u64; 3] {
        std::array::from_fn(|c| {
            let v: Vec<u64> = self.steady.iter().map(|r| r[c]).collect();
            lightfold_protocol::stats::median(&v).unwrap_or(0)
        })
    }
}

/// Renders `frames` (at least one) frames of the scene on one device, whole
/// ([`render_frame`], with the penumbra filter's `penumbra` radius) or as sort-last `parts`
/// ([`render_partitioned`]), handing each frame's costs to `each` as it completes.
#[allow(clippy::too_many_arguments)]
pub fn render_repeated(
    gpu: &Gpu,
    renderer: &mut Renderer,
    scene: &Scene,
    samples: &[LightSample],
    k: usize,
    frames: u32,
    parts: Option<&Parts>,
    penumbra: u32,
    mut each: impl FnMut(u32, &FrameTimes),
) -> anyhow::Result<Repeated> {
    let frames = frames.max(1);
    let mut run = Repeated {
        image: (Image::new(0, 0, 3), Image::new(0, 0, 1)),
        views_per_light: Vec::new(),
        steady: Vec::new(),
        steady_frames: 0,
    };
    for f in 0..frames {
        let (image, times) = match parts {
            None => render_frame(gpu, renderer, scene, samples, k, None, penumbra)?,
            Some(p) => render_partitioned(
                gpu,
                renderer,
                scene,
                samples,
                k,
                &p.parts,
                p.casters.as_deref(),
            )?,
        };
        each(f, &times);
        if f > 0 || frames == 1 {
            run.steady.extend(times.batches.iter().skip(1));
            run.steady_frames += 1;
        }
        if f == 0 {
            run.views_per_light = times.passes_per_light;
        }
        run.image = image;
    }
    Ok(run)
}
