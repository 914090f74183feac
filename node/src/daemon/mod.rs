//! The render-node daemon: a render thread owns the device; the tokio side accepts authenticated
//! control links from coordinators on one listener, receives scenes by content hash and
//! configurations, and streams each frame's packed bands to the compositor it dials. See
//! `docs/cluster-protocol.md` for the sequence and `docs/node.md` for operation and measurements.

pub mod bands;
pub mod calibrate;
pub mod configure;
mod control_link;
mod engine;
pub mod render_thread;
pub mod scene_cache;
pub mod sys;

use crate::gpu::GpuOptions;
use crate::gpu::device::max_lights_for;
use control_link::Ended;
use engine::Engine;
use lightfold_net::claim::Claims;
use lightfold_net::{Identity, Timeouts};
use lightfold_protocol::{Capabilities, Role};
pub use render_thread::PackOn;
use render_thread::{DeviceReport, RenderHandle};
use scene_cache::SceneCache;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;
use tokio::net::TcpListener;
use tokio::sync::Mutex;
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

/// How a node runs.
#[derive(Clone)]
pub struct NodeOptions {
    /// This daemon's id (authenticated in every handshake; compositors match inputs by it).
    pub daemon_id: String,
    /// Address other daemons should dial; `None` advertises the listener's local address.
    pub advertise: Option<String>,
    /// The cluster token (never logged).
    pub token: Arc<[u8]>,
    pub gpu: GpuOptions,
    pub timeouts: Timeouts,
    /// Scene bytes are also kept here, by hash, across restarts.
    pub cache_dir: Option<PathBuf>,
    /// Largest scene accepted, bytes.
    pub max_scene_bytes: u64,
    /// How long the data link keeps dialling a compositor that is not up yet.
    pub dial_deadline: Duration,
    /// Refuse to start on a software rasteriser (lavapipe, llvmpipe): a GPU node whose driver
    /// is missing fails instead of rendering on the CPU.
    pub require_gpu: bool,
    /// Where frames are packed into link formats (by default the device, unless it is a
    /// software rasteriser).
    pub pack: PackOn,
    /// Render a frame whose request has arrived while the previous frame's bands stream (on by
    /// default; off gives one frame at a time, for comparison).
    pub render_ahead: bool,
    /// The memory registration reports (`Capabilities::memory_bytes`); `None`: what the machine
    /// or its control group has.
    pub memory_bytes: Option<u64>,
    /// A claimed control link that brings nothing (not even a keepalive) for this long is
    /// released: the coordinator stopped, hung or was cut off, and the node is free for the next
    /// one. Zero: never.
    pub coordinator_silence: Duration,
}

impl std::fmt::Debug for NodeOptions {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NodeOptions")
            .field("daemon_id", &self.daemon_id)
            .field("advertise", &self.advertise)
            .field("gpu", &self.gpu)
            .field("timeouts", &self.timeouts)
            .field("cache_dir", &self.cache_dir)
            .field("max_scene_bytes", &self.max_scene_bytes)
            .field("dial_deadline", &self.dial_deadline)
            .field("require_gpu", &self.require_gpu)
            .field("pack", &self.pack)
            .field("render_ahead", &self.render_ahead)
            .field("memory_bytes", &self.memory_bytes)
            .field("coordinator_silence", &self.coordinator_silence)
            .finish_non_exhaustive()
    }
}

impl NodeOptions {
    /// Defaults for everything but identity and token.
    pub fn new(daemon_id: impl Into<String>, token: &[u8]) -> NodeOptions {
        NodeOptions {
            daemon_id: daemon_id.into(),
            advertise: None,
            token: Arc::from(token),
            gpu: GpuOptions::default(),
            timeouts: Timeouts::default(),
            cache_dir: None,
            max_scene_bytes: lightfold_scene::MAX_SCENE_BYTES as u64,
            dial_deadline: Duration::from_secs(30),
            require_gpu: false,
            pack: PackOn::Auto,
            render_ahead: true,
            memory_bytes: None,
            coordinator_silence: lightfold_net::claim::COORDINATOR_SILENCE,
        }
    }
}

/// What registration reports for this device.
fn capabilities(opts: &NodeOptions, advertise: String, report: &DeviceReport) -> Capabilities {
    let map = lightfold_scene::defaults::SHADOW_MAP_SIZE;
    Capabilities {
        role: Role::Node,
        daemon_id: opts.daemon_id.clone(),
        advertise,
        adapter: report.adapter.clone(),
        backend: report.backend.clone(),
        device: report.device.clone(),
        cpu_host: if report.software {
            sys::machine()
        } else {
            String::new()
        },
        max_lights: max_lights_for(&report.limits, map),
        max_texture_size: report.limits.max_texture_dimension_2d,
        formats: configure::supported_formats(),
        cost_per_light_us: report.calibration.cost_per_light_us,
        fixed_cost_us: report.calibration.fixed_cost_us,
        threads: sys::threads(),
        version: env!("CARGO_PKG_VERSION").to_string(),
        memory_bytes: opts.memory_bytes.unwrap_or_else(sys::memory_bytes),
        eye_ns_per_triangle: report.calibration.eye_ns_per_triangle,
    }
}

/// Why `--require-gpu` refuses to start on `adapter`, a software rasteriser.
pub fn no_hardware_gpu(adapter: &str, backend: &str) -> String {
    format!(
        "--require-gpu: the only usable adapter is {adapter:?} ({backend}), a software rasteriser; \
         no hardware GPU was found (is its Vulkan driver installed and the device visible to this \
         process? `vulkaninfo --summary` lists what the loader sees)"
    )
}

/// The device, once opened and calibrated: what registration reports and the engine links use.
type Ready = Option<(Capabilities, Arc<Mutex<Engine>>)>;

/// Opens the device, calibrates it and builds the engine (what [`run`] waits for before it
/// serves a link).
async fn start_device(
    opts: &NodeOptions,
    advertise: String,
    local: std::net::SocketAddr,
    me: &Identity,
) -> anyhow::Result<(Capabilities, Arc<Mutex<Engine>>)> {
    let (render, report) = RenderHandle::start(opts.gpu.clone(), opts.pack).await?;
    if report.software && opts.require_gpu {
        render.stop().await;
        anyhow::bail!(no_hardware_gpu(&report.adapter, &report.backend));
    }
    if report.software {
        // Info, not a warning: the coordinator says it once for the whole cluster, and on a
        // machine without a GPU every node would say it.
        tracing::info!(
            adapter = %report.adapter, backend = %report.backend,
            "rendering on a software rasteriser (the CPU), not a GPU"
        );
    }
    lightfold_telemetry::record::adapter(&report.adapter, &report.backend, report.software);
    let caps = capabilities(opts, advertise, &report);
    tracing::info!(
        id = %opts.daemon_id, %local, adapter = %caps.adapter, backend = %caps.backend,
        software = report.software, max_lights = caps.max_lights, "render node ready"
    );
    let engine = Arc::new(Mutex::new(
        Engine::new(
            opts.daemon_id.clone(),
            render,
            report,
            SceneCache::new(opts.cache_dir.clone(), opts.max_scene_bytes),
            lightfold_net::Downstream::new(me.clone(), opts.timeouts, opts.dial_deadline),
            opts.timeouts.max_frame,
        )
        .render_ahead(opts.render_ahead),
    ));
    Ok((caps, engine))
}

/// Runs a render node on `listener` until `shutdown` is cancelled or a coordinator sends
/// `Shutdown`. Fails only when the device cannot be opened or calibrated; every later error is
/// reported to the peer that caused it and the node keeps serving. Peers are accepted and
/// authenticated while the device opens and calibrates (which may wait for the machine's other
/// nodes to calibrate: `calibrate.rs`); each link is served once the device is ready, so a
/// coordinator waits for the registration under its register deadline, not its handshake one.
pub async fn run(
    listener: TcpListener,
    opts: NodeOptions,
    shutdown: CancellationToken,
) -> anyhow::Result<()> {
    let local = listener.local_addr()?;
    let advertise = opts.advertise.clone().unwrap_or_else(|| local.to_string());
    let me = Identity {
        token: opts.token.clone(),
        role: Role::Node,
        daemon_id: opts.daemon_id.clone(),
    };
    let (ready_tx, ready_rx) = tokio::sync::watch::channel::<Ready>(None);
    let startup = start_device(&opts, advertise, local, &me);
    tokio::pin!(startup);
    let mut engine: Option<Arc<Mutex<Engine>>> = None;
    // Unclaimed links (test drivers, `lightfold bench`) may run side by side, sharing the engine.
    let claims = Claims::new(&opts.daemon_id, false);
    let stop = shutdown.child_token();
    let tracker = TaskTracker::new();
    // Each link is served once the device is ready (at once, after start-up); links are
    // accepted and authenticated while the device opens.
    let serve_link = {
        let (ready, claims, stop, silence) = (
            ready_rx.clone(),
            claims.clone(),
            stop.clone(),
            opts.coordinator_silence,
        );
        move |link| {
            let (mut ready, claims, stop) = (ready.clone(), claims.clone(), stop.clone());
            async move {
                let (caps, engine) = tokio::select! {
                    _ = stop.cancelled() => return,
                    r = ready.wait_for(Option::is_some) => match r.ok().and_then(|r| r.clone()) {
                        Some(x) => x,
                        None => return,
                    },
                };
                drop(ready);
                let ended =
                    control_link::serve(link, caps, engine, claims, silence, stop.clone()).await;
                if ended == Ended::Shutdown {
                    stop.cancel();
                }
            }
        }
    };
    let failed = {
        let serving = lightfold_net::serve(
            &listener,
            &me,
            opts.timeouts,
            &stop,
            &tracker,
            "handshakes",
            serve_link,
        );
        tokio::pin!(serving);
        loop {
            tokio::select! {
                () = &mut serving => break None,
                started = &mut startup, if engine.is_none() => match started {
                    Ok((caps, e)) => {
                        engine = Some(Arc::clone(&e));
                        lightfold_telemetry::health::set_live(true);
                        let _ = ready_tx.send(Some((caps, e)));
                    }
                    Err(e) => {
                        stop.cancel();
                        (&mut serving).await;
                        break Some(e);
                    }
                },
            }
        }
    };
    if let Some(e) = failed {
        tracker.close();
        tracker.wait().await;
        return Err(e);
    }
    lightfold_telemetry::health::set_live(false);
    tracker.close();
    tracker.wait().await;
    drop(listener);
    // The links are done: the watch's copy is the engine's last one besides ours.
    drop(ready_rx);
    drop(ready_tx);
    match engine.map(Arc::try_unwrap) {
        Some(Ok(engine)) => engine.into_inner().stop().await,
        Some(Err(_)) => tracing::warn!("engine still shared at shutdown"),
        // Stopped before the device was ready: the start-up is dropped with it.
        None => {}
    }
    tracing::info!("render node stopped");
    Ok(())
}
