//! The render thread: the only owner of the wgpu device. GPU work never runs on the async runtime
//! (`device.poll` blocks); the tokio side sends commands over a bounded channel and awaits each
//! answer on a oneshot. The renderer is rebuilt only when the scene or a build-time option changes;
//! a new light set, colour or camera reuses it (and, in walkthrough mode, its shadow maps).
//! A caller may stop waiting (a frame abandoned for a new configuration drops its future): the
//! thread finishes the command it has, its answer goes nowhere (`reply.send` fails and is
//! ignored), and it serves the next command as usual.

use super::calibrate::{self, Calibration};
use super::configure::Checked;
use crate::gpu::pack::PackedFrame;
use crate::gpu::{
    DeviceError, Gpu, GpuOptions, LayerSet, NodeFrame, RenderError, RenderOptions, RenderStats,
    Renderer,
};
use lightfold_protocol::{Hash, Layer, WireMove};
use lightfold_scene::{Camera, Image, Scene, ShadowFilter};
use std::panic::AssertUnwindSafe;
use std::sync::Arc;
use std::time::Instant;
use tokio::sync::{mpsc, oneshot};

/// Commands waiting for the render thread.
const QUEUE: usize = 4;

/// What the device is and what it costs, reported once at start-up.
#[derive(Debug, Clone)]
pub struct DeviceReport {
    pub adapter: String,
    pub backend: String,
    /// The hardware device, as `Capabilities::device` gives it (empty for a software one).
    pub device: String,
    /// The adapter renders in software (lavapipe, llvmpipe, `DeviceType::Cpu`).
    pub software: bool,
    pub limits: wgpu::Limits,
    pub calibration: Calibration,
}

/// A configuration the render thread applies.
#[derive(Debug, Clone)]
pub struct RenderSetup {
    pub scene_hash: Hash,
    pub scene: Arc<Scene>,
    pub checked: Checked,
}

/// Where a node packs its frames into link formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PackOn {
    /// The device on a hardware GPU, the CPU on a software rasteriser: lavapipe runs the pack
    /// pass on the same CPU cores, about 15× slower than the CPU pack (`docs/gpu.md`).
    #[default]
    Auto,
    /// A compute pass packs on the device and only the packed bytes are read back (`gpu::pack`);
    /// frames the device cannot pack exactly are packed on the CPU.
    Device,
    /// Every frame is read back as f32 images and packed on the CPU (the reference path).
    Cpu,
}

/// What a rendered frame holds.
#[derive(Debug)]
pub enum Output {
    /// An image per configured layer (configuration order), to be packed on the CPU.
    Images(Vec<(Layer, Arc<Image>)>),
    /// The configured layers packed on the device, in configuration order.
    Packed(PackedFrame),
}

/// One rendered frame and what it cost.
#[derive(Debug)]
pub struct Rendered {
    pub output: Output,
    pub stats: RenderStats,
    /// Wall time of the whole render call on the render thread, microseconds.
    pub total_us: u64,
    /// The image rows it rendered (a sort-first tile; `None`: every row): every other row is
    /// zero, and the bands wholly outside them travel empty.
    pub rows: Option<[u32; 2]>,
}

#[derive(Debug, Clone, thiserror::Error)]
pub enum RenderFailure {
    #[error("the render thread has stopped")]
    Stopped,
    #[error("no configuration has been applied")]
    NotConfigured,
    #[error("cannot build the renderer: {0}")]
    Build(String),
    #[error("render failed: {0}")]
    Render(String),
    #[error("the renderer panicked: {0}")]
    Panic(String),
}

enum Command {
    Configure(Box<RenderSetup>, oneshot::Sender<Result<(), RenderFailure>>),
    Render(
        Camera,
        Option<f32>,
        f32,
        FrameLights,
        Option<[u32; 2]>,
        oneshot::Sender<Result<Rendered, RenderFailure>>,
    ),
}

/// A frame's lights in place of configured ones (an animated scene's virtual point lights at
/// its time, or lights a viewer moved): each replaces the configured light at its index
/// (`FrameParams::lights`, checked by the engine).
pub type FrameLights = Arc<Vec<(usize, lightfold_scene::LightSample)>>;

/// A render queued with [`RenderHandle::submit`].
#[derive(Debug)]
pub struct Pending(oneshot::Receiver<Result<Rendered, RenderFailure>>);

impl Pending {
    pub async fn wait(self) -> Result<Rendered, RenderFailure> {
        self.0.await.map_err(|_| RenderFailure::Stopped)?
    }
}

/// The async side's handle on the render thread.
#[derive(Debug)]
pub struct RenderHandle {
    tx: mpsc::Sender<Command>,
    thread: std::thread::JoinHandle<()>,
}

impl std::fmt::Debug for Command {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Command::Configure(..) => "Configure",
            Command::Render(..) => "Render",
        })
    }
}

impl RenderHandle {
    /// Starts the render thread: it opens the device, calibrates, reports, then serves commands.
    pub async fn start(
        opts: GpuOptions,
        pack: PackOn,
    ) -> Result<(RenderHandle, DeviceReport), DeviceError> {
        let (tx, rx) = mpsc::channel(QUEUE);
        let (ready_tx, ready_rx) = oneshot::channel();
        let thread = std::thread::Builder::new()
            .name("render".into())
            .spawn(move || thread_main(opts, pack, rx, ready_tx))
            .map_err(|e| DeviceError::RequestDevice(format!("cannot start render thread: {e}")))?;
        let report = match ready_rx.await {
            Ok(r) => r?,
            Err(_) => {
                return Err(DeviceError::RequestDevice(
                    "render thread ended during start-up".into(),
                ));
            }
        };
        Ok((RenderHandle { tx, thread }, report))
    }

    pub async fn configure(&self, setup: RenderSetup) -> Result<(), RenderFailure> {
        let (reply, answer) = oneshot::channel();
        self.tx
            .send(Command::Configure(Box::new(setup), reply))
            .await
            .map_err(|_| RenderFailure::Stopped)?;
        answer.await.map_err(|_| RenderFailure::Stopped)?
    }

    /// Renders at `camera`, an animated scene posed at `time` (`None`: its rest pose) with its
    /// lights as `lights` replaces them, only the image rows `rows` (a sort-first tile, checked
    /// by the caller; `None`: every row), packing `seed64` layers against `scale`.
    pub async fn render(
        &self,
        camera: Camera,
        time: Option<f32>,
        scale: f32,
        lights: FrameLights,
        rows: Option<[u32; 2]>,
    ) -> Result<Rendered, RenderFailure> {
        self.submit(camera, time, scale, lights, rows)
            .await?
            .wait()
            .await
    }

    /// Queues a render and returns at once: the thread renders while the caller does something
    /// else (sends the previous frame), and [`Pending::wait`] collects it. Dropping the
    /// `Pending` discards the answer (the thread still renders it).
    pub async fn submit(
        &self,
        camera: Camera,
        time: Option<f32>,
        scale: f32,
        lights: FrameLights,
        rows: Option<[u32; 2]>,
    ) -> Result<Pending, RenderFailure> {
        let (reply, answer) = oneshot::channel();
        self.tx
            .send(Command::Render(camera, time, scale, lights, rows, reply))
            .await
            .map_err(|_| RenderFailure::Stopped)?;
        Ok(Pending(answer))
    }

    /// Closes the queue and waits for the thread to release the device.
    pub async fn stop(self) {
        drop(self.tx);
        let thread = self.thread;
        let _ = tokio::task::spawn_blocking(move || thread.join()).await;
    }
}

struct Current {
    hash: Hash,
    options: RenderOptions,
    renderer: Renderer,
    setup: RenderSetup,
    camera: Option<Camera>,
    /// The scene time the renderer's geometry is posed at (`None`: rest).
    time: Option<f32>,
    /// The configured light samples posed at `time`.
    lights: Vec<lightfold_scene::LightSample>,
    /// The moves the renderer's geometry was made with (`NodeConfig::moves`).
    moves: Vec<WireMove>,
}

fn thread_main(
    opts: GpuOptions,
    pack: PackOn,
    mut rx: mpsc::Receiver<Command>,
    ready: oneshot::Sender<Result<DeviceReport, DeviceError>>,
) {
    let gpu = match Gpu::new(&opts) {
        Ok(g) => g,
        Err(e) => {
            let _ = ready.send(Err(e));
            return;
        }
    };
    let software = crate::gpu::device::is_software(&gpu.info);
    let calibration = match calibrate::run(&gpu, software) {
        Ok(c) => c,
        Err(e) => {
            let _ = ready.send(Err(DeviceError::RequestDevice(format!(
                "calibration render failed: {e}"
            ))));
            return;
        }
    };
    let report = DeviceReport {
        adapter: gpu.info.name.clone(),
        backend: format!("{:?}", gpu.info.backend).to_lowercase(),
        device: crate::gpu::device::device_identity(&super::sys::hostname(), &gpu.info)
            .unwrap_or_default(),
        software,
        limits: gpu.limits.clone(),
        calibration,
    };
    let mut pack = match pack {
        PackOn::Auto if report.software => PackOn::Cpu,
        PackOn::Auto => PackOn::Device,
        chosen => chosen,
    };
    // A node never sends other bits than the CPU pack would: a driver whose pack differs on
    // hostile values is caught here, and the node packs on the CPU instead.
    if pack == PackOn::Device
        && let Err(e) = crate::gpu::pack::DevicePacker::self_check(&gpu)
    {
        tracing::warn!(error = %e, "packing on the CPU: the device's pack failed its check");
        pack = PackOn::Cpu;
    }
    tracing::info!(
        ?pack,
        "frames are packed on the {}",
        if pack == PackOn::Cpu { "CPU" } else { "device" }
    );
    if ready.send(Ok(report)).is_err() {
        return;
    }
    let mut current: Option<Current> = None;
    while let Some(cmd) = rx.blocking_recv() {
        match cmd {
            Command::Configure(setup, reply) => {
                let r = guarded(|| configure(&gpu, &mut current, *setup));
                if r.is_err() {
                    current = None;
                }
                let _ = reply.send(r);
            }
            Command::Render(camera, time, scale, lights, rows, reply) => {
                let frame = FrameAsk {
                    camera,
                    time,
                    scale,
                    lights: &lights,
                    rows,
                };
                let r = guarded(|| render(&gpu, &mut current, frame, pack));
                if matches!(r, Err(RenderFailure::Panic(_))) {
                    current = None;
                }
                let _ = reply.send(r);
            }
        }
    }
    tracing::debug!("render thread stopping");
}

/// Runs `f`, turning a panic inside the renderer or wgpu into an error so the daemon survives.
fn guarded<T>(f: impl FnOnce() -> Result<T, RenderFailure>) -> Result<T, RenderFailure> {
    match std::panic::catch_unwind(AssertUnwindSafe(f)) {
        Ok(r) => r,
        Err(p) => {
            let msg = p
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "unknown panic".into());
            tracing::error!(panic = %msg, "renderer panicked");
            Err(RenderFailure::Panic(msg))
        }
    }
}

/// The renderer's build-time options for a configuration.
fn options_for(setup: &RenderSetup) -> RenderOptions {
    let c = &setup.checked.config;
    RenderOptions {
        // Maps above the scene's base size share its budget: the light limit counts them there.
        shadow_map_size: setup.checked.budget_size,
        // The plan's per-light sides where it gives them (`Renderer::set_map_sides`), else the
        // scene's own rule, as `lightfold render` sizes them.
        map_sizing: setup.scene.quality.map_sizing,
        filter: shadow_filter(c.filter),
        depth_bias: c.depth_bias,
        slope_bias: c.slope_bias,
        walkthrough: c.walkthrough,
        chunk_triangles: crate::gpu::scene_data::CHUNK_TRIANGLES,
        shadow_lod: true,
        eye_lod: true,
        fault: None,
    }
}

/// The wire's filter code (`NodeConfig::filter`, checked by `configure::check`).
pub fn shadow_filter(code: u32) -> ShadowFilter {
    lightfold_scene::wire::filter_from_wire(code).unwrap_or(ShadowFilter::Pcf2x2)
}

fn configure(
    gpu: &Gpu,
    current: &mut Option<Current>,
    setup: RenderSetup,
) -> Result<(), RenderFailure> {
    let options = options_for(&setup);
    let reuse = matches!(&*current, Some(c) if c.hash == setup.scene_hash && c.options == options);
    if reuse {
        if let Some(c) = current.as_mut() {
            c.lights = match c.time {
                Some(t) => setup.scene.pose_samples(&setup.checked.lights, t),
                None => setup.checked.lights.clone(),
            };
            c.renderer.set_map_sides(setup.checked.map_sides.clone());
            c.renderer
                .set_eye_meshes(setup.checked.config.eye_meshes.clone());
            c.renderer
                .set_fit_to_eye_meshes(setup.checked.config.eye_meshes.is_some());
            c.renderer.set_peel(setup.checked.config.peel);
            c.setup = setup;
        }
        return Ok(());
    }
    *current = None;
    let start = Instant::now();
    let mut renderer = Renderer::new(gpu, &setup.scene, options)
        .map_err(|e: RenderError| RenderFailure::Build(e.to_string()))?;
    if setup.scene.is_animated() {
        // Views fitted to where meshes go over the motion (as the planner fits them), so a
        // moving mesh re-renders only the maps it may cast into.
        renderer.set_fit_bounds(setup.scene.swept_bounds());
    }
    renderer.set_map_sides(setup.checked.map_sides.clone());
    // A sort-last node fits its maps to its part, as the planner does.
    renderer.set_eye_meshes(setup.checked.config.eye_meshes.clone());
    renderer.set_fit_to_eye_meshes(setup.checked.config.eye_meshes.is_some());
    // The eye layer this node renders (checked: at most `configure::MAX_PEEL`).
    renderer.set_peel(setup.checked.config.peel);
    tracing::info!(ms = start.elapsed().as_millis() as u64, "renderer built");
    *current = Some(Current {
        hash: setup.scene_hash,
        options,
        renderer,
        lights: setup.checked.lights.clone(),
        setup,
        camera: None,
        time: None,
        moves: Vec::new(),
    });
    Ok(())
}

/// What one `Command::Render` asks for.
struct FrameAsk<'a> {
    camera: Camera,
    time: Option<f32>,
    scale: f32,
    lights: &'a [(usize, lightfold_scene::LightSample)],
    rows: Option<[u32; 2]>,
}

fn render(
    gpu: &Gpu,
    current: &mut Option<Current>,
    frame: FrameAsk<'_>,
    pack: PackOn,
) -> Result<Rendered, RenderFailure> {
    let FrameAsk {
        camera,
        time,
        scale,
        lights,
        rows,
    } = frame;
    let c = current.as_mut().ok_or(RenderFailure::NotConfigured)?;
    let start = Instant::now();
    if c.camera != Some(camera) {
        c.renderer.set_camera(&camera);
        c.camera = Some(camera);
    }
    c.renderer.set_rows(rows);
    let mut pose_us = 0;
    // A still scene ignores the time; an animated one is posed here, from the node's own copy.
    let time = time.filter(|_| c.setup.scene.animation.is_some());
    let moves = &c.setup.checked.config.moves;
    if c.time != time || c.moves != *moves {
        let t = Instant::now();
        let scene = &c.setup.scene;
        let mut meshes = match time {
            Some(t) => scene.pose_meshes(t),
            None => scene.meshes.clone(),
        };
        // Checked (`configure::check`): each names a mesh of the scene once.
        for m in moves {
            if let Some(mesh) = meshes.get_mut(m.mesh as usize) {
                lightfold_scene::moves::apply_columns(mesh, &m.matrix);
            }
        }
        let posed = if c.time == time {
            // Only moves changed: the meshes whose move is new, changed or undone.
            let mut changed = vec![false; meshes.len()];
            for m in moves.iter().chain(&c.moves) {
                let now = moves.iter().find(|x| x.mesh == m.mesh);
                let before = c.moves.iter().find(|x| x.mesh == m.mesh);
                if now != before
                    && let Some(k) = changed.get_mut(m.mesh as usize)
                {
                    *k = true;
                }
            }
            c.renderer.set_moved_meshes(gpu, &meshes, &changed)
        } else {
            c.renderer.set_meshes(gpu, &meshes)
        };
        posed.map_err(|e| RenderFailure::Render(e.to_string()))?;
        c.moves = moves.clone();
        c.lights = match time {
            Some(t) => scene.pose_samples(&c.setup.checked.lights, t),
            None => c.setup.checked.lights.clone(),
        };
        c.time = time;
        pose_us = t.elapsed().as_micros() as u64;
    }
    // The frame's lights in place of configured ones (indices checked by the engine).
    for (i, s) in lights {
        if let Some(l) = c.lights.get_mut(*i) {
            *l = *s;
        }
    }
    let prepared_us = start.elapsed().as_micros() as u64;
    let checked = &c.setup.checked;
    let casters = checked.casters.as_deref();
    let color = checked.config.color;
    let configured = &checked.config.layers;
    let failed = |e: RenderError| RenderFailure::Render(e.to_string());
    let packed = match pack {
        PackOn::Device => c
            .renderer
            .render_packed(
                gpu,
                &c.lights,
                casters,
                color,
                configured,
                checked.config.band_height,
                scale,
            )
            .map_err(failed)?,
        PackOn::Cpu | PackOn::Auto => None,
    };
    let (output, mut stats) = match packed {
        Some((frame, stats)) => (Output::Packed(frame), stats),
        None => {
            let layers: Vec<Layer> = configured.iter().map(|(l, _)| *l).collect();
            let frame = c
                .renderer
                .render(
                    gpu,
                    &c.lights,
                    casters,
                    color,
                    LayerSet::of(layers.iter().copied()),
                )
                .map_err(failed)?;
            let stats = frame.stats.clone();
            (Output::Images(take_layers(frame, &layers)?), stats)
        }
    };
    stats.pose_us = pose_us;
    // Camera and pose updates count as the frame's set-up, beside the renderer's own.
    stats.setup_us += prepared_us - pose_us;
    Ok(Rendered {
        output,
        stats,
        total_us: start.elapsed().as_micros() as u64,
        rows,
    })
}

/// Takes one layer's image out of a rendered frame (radiance is never a node's).
pub fn take_layer(frame: &mut NodeFrame, layer: Layer) -> Option<Image> {
    match layer {
        Layer::Illumination => frame.illumination.take(),
        Layer::Diffuse => frame.diffuse.take(),
        Layer::Specular => frame.specular.take(),
        Layer::Ambient => frame.ambient.take(),
        Layer::Emissive => frame.emissive.take(),
        Layer::Depth => frame.depth.take(),
        Layer::AmbientMask => frame.ambient_mask.take(),
        Layer::Transmittance => frame.transmittance.take(),
        Layer::Radiance => None,
    }
}

/// The configured layers' images out of a rendered frame, in configuration order.
fn take_layers(
    mut frame: NodeFrame,
    layers: &[Layer],
) -> Result<Vec<(Layer, Arc<Image>)>, RenderFailure> {
    layers
        .iter()
        .map(|&layer| {
            take_layer(&mut frame, layer)
                .map(|img| (layer, Arc::new(img)))
                .ok_or_else(|| {
                    RenderFailure::Render(format!("the renderer produced no {layer:?} image"))
                })
        })
        .collect()
}
