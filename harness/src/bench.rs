//! `lightfold bench`: benchmarks that print figures (not timed tests). `bench node` measures what
//! K buys on one render node: for each K and each mode it starts a fresh `lightfold node` process
//! with a fixed `LP_NUM_THREADS`, plays the coordinator and the compositor over loopback, drives a
//! few frames with a slowly orbiting camera and reports the node's own per-phase timings, the
//! node-seconds a frame of L lights costs, and the nodes L lights need under a frame budget.

use crate::driver::ControlClient;
use crate::launcher::{ANY_PORT, Children, Launcher, run_token};
use anyhow::{Context, bail};
use lightfold_net::{Identity, Timeouts, accept};
use lightfold_protocol::frame::Frame;
use lightfold_protocol::{
    FrameParams, FrameStats, Layer, NodeConfig, PixelFormat, Role, WireShadow, stats,
};
use lightfold_scene::sampling::direct_samples;
use lightfold_scene::wire::{camera_to_wire, light_to_wire};
use lightfold_scene::{Camera, Scene};
use lightfold_telemetry::outln;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;
use tokio::net::TcpListener;

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(subcommand)]
    what: What,
}

#[derive(Debug, clap::Subcommand)]
enum What {
    /// Frame time of one render node against K (lights per node), moving lights and walkthrough.
    Node(NodeArgs),
}

#[derive(Debug, clap::Args)]
pub struct NodeArgs {
    /// Built-in scene name, scene file (.toml) or model (.gltf/.glb, .obj, .ply,
    /// .usda/.usdc/.usdz).
    #[arg(long, default_value = lightfold_scene::defaults::DEFAULT_SCENE)]
    scene: String,
    /// Image size as WIDTHxHEIGHT.
    #[arg(long, default_value = "800x600", value_parser = parse_size)]
    size: (u32, u32),
    /// Image width (the same as the first half of `--size`).
    #[arg(long, hide = true, conflicts_with = "size")]
    width: Option<u32>,
    /// Image height (the same as the second half of `--size`).
    #[arg(long, hide = true, conflicts_with = "size")]
    height: Option<u32>,
    /// Shadow-map size per face.
    #[arg(long, default_value_t = 512)]
    map: u32,
    /// Lights per node to measure.
    #[arg(long, value_delimiter = ',', default_value = "1,2,4,8,16,32")]
    ks: Vec<u32>,
    /// L, the lights a frame needs in all (for node-seconds and node counts).
    #[arg(long, default_value_t = 32)]
    lights: u32,
    /// Modes to measure: `moving` (shadow maps every frame), `walkthrough` (maps kept, the camera
    /// orbits), `static` (walkthrough with a still camera: cached bands are resent) and
    /// `noshadows` (every light's caster list empty: its map passes draw nothing, the paper's "no
    /// shadows" column).
    #[arg(long, value_delimiter = ',', default_value = "moving,walkthrough")]
    modes: Vec<String>,
    /// Timed frames per configuration (after the warm-up frames).
    #[arg(long, default_value_t = 4)]
    frames: u32,
    #[arg(long, default_value_t = 2)]
    warmup: u32,
    /// Rounds over all configurations (a fresh node process each time).
    #[arg(long, default_value_t = 3)]
    rounds: u32,
    /// `LP_NUM_THREADS` of every node process (lavapipe's rasteriser threads).
    #[arg(long, default_value_t = 1)]
    threads: u32,
    /// Frame budgets for the node count, milliseconds.
    #[arg(long, value_delimiter = ',', default_value = "250,500,1000")]
    budget_ms: Vec<f64>,
    /// Link format of the illumination layer.
    #[arg(long, default_value = "rgb9e5x2")]
    format: String,
    #[arg(long, default_value_t = 64)]
    band_height: u32,
    /// Graphics backend of the node processes (`vulkan`; nodes refuse OpenGL adapters).
    #[arg(long, value_parser = ["vulkan"], default_value = "vulkan")]
    backend: String,
    /// Where the nodes pack frames (`lightfold node --pack`): each is measured, interleaved in
    /// the same rounds, so `device,cpu` gives the device pack against the CPU pack in one run.
    #[arg(long, value_delimiter = ',', default_value = "device,cpu", value_parser = ["device", "cpu"])]
    pack: Vec<String>,
    /// Frame requests kept outstanding, as a coordinator's frames in flight: with 2 the node
    /// renders each frame while it sends the previous one, and `interval` (the time between its
    /// answers) falls below its frame time.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=8))]
    in_flight: u32,
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    lightfold_scene::limits::parse_image_size(s)
        .map_err(|e| format!("{e} (see `lightfold defaults`)"))
}

impl NodeArgs {
    /// The image size: `--size`, or the older `--width`/`--height` over its default.
    fn image_size(&self) -> (u32, u32) {
        (
            self.width.unwrap_or(self.size.0),
            self.height.unwrap_or(self.size.1),
        )
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    match args.what {
        What::Node(mut a) => {
            a.size = a.image_size();
            lightfold_scene::limits::check_image_size(a.size.0, a.size.1)
                .map_err(|e| anyhow::anyhow!("bad image size: {e} (see `lightfold defaults`)"))?;
            let rt = tokio::runtime::Builder::new_multi_thread()
                .worker_threads(2)
                .enable_all()
                .build()?;
            rt.block_on(bench_node(a))
        }
    }
}

/// One measured configuration.
#[derive(Debug, Clone)]
struct Row {
    /// The mode, and where the node packed when several were measured.
    mode: String,
    k: u32,
    frames: Vec<FrameStats>,
    /// Microseconds between consecutive answers over the timed frames.
    intervals: Vec<u64>,
    /// CPU time of the node process over all timed frames, ms (all its threads).
    cpu_ms_total: f64,
}

/// The median of `v` (`stats::median`), 0 when empty.
fn median(v: &[u64]) -> f64 {
    stats::median(v).unwrap_or(0) as f64
}

impl Row {
    fn ms(&self, f: impl Fn(&FrameStats) -> u64) -> f64 {
        median(&self.frames.iter().map(f).collect::<Vec<_>>()) / 1000.0
    }
    fn total_ms(&self) -> f64 {
        self.ms(|s| s.total_us)
    }
    /// Mean CPU time of the node process per timed frame, ms.
    fn cpu_ms(&self) -> f64 {
        self.cpu_ms_total / self.frames.len().max(1) as f64
    }
    /// The fastest frame: other processes on a shared machine only ever add time, so this is
    /// the best estimate of a node with the machine to itself.
    fn best_ms(&self) -> f64 {
        self.frames.iter().map(|s| s.total_us).min().unwrap_or(0) as f64 / 1000.0
    }
}

async fn bench_node(a: NodeArgs) -> anyhow::Result<()> {
    let format = PixelFormat::from_name(&a.format)
        .with_context(|| format!("unknown pixel format {:?}", a.format))?;
    let mut scene = lightfold_scene::load(&a.scene)
        .with_context(|| format!("cannot load scene {:?}", a.scene))?;
    (scene.camera.width, scene.camera.height) = a.size;
    scene.quality.shadow_map_size = a.map;
    scene.quality.map_sizing = lightfold_scene::MapSizing::Fixed;
    let samples = direct_samples(&scene);
    if samples.is_empty() {
        bail!("scene {} has no lights", a.scene);
    }
    let bytes = scene.to_bytes()?;
    let hash = scene.content_hash();
    // A token for this run only, in a file the node processes read.
    let (_work, token_path, token) = run_token("lightfold-bench-")?;
    let launcher = Launcher {
        gpu_threads: a.threads,
        ..Launcher::this_exe(token_path, "warn")?
    };

    // The compositor: accepts data links and counts what arrives.
    let data = TcpListener::bind("127.0.0.1:0").await?;
    let data_addr = data.local_addr()?.to_string();
    let received = Arc::new(AtomicU64::new(0));
    tokio::spawn(drain(data, token.clone(), received.clone()));

    eprintln!(
        "bench node: scene {} ({} triangles, {} samples), {}x{}, {}² maps, LP_NUM_THREADS={}",
        a.scene,
        scene.triangle_count(),
        samples.len(),
        a.size.0,
        a.size.1,
        a.map,
        a.threads
    );
    let mut plan = Vec::new();
    let label = |mode: &str, pack: &str| {
        if a.pack.len() > 1 {
            format!("{mode}, {pack} pack")
        } else {
            mode.to_string()
        }
    };
    for mode in &a.modes {
        let (walkthrough, shadows) = match mode.as_str() {
            "moving" => (false, true),
            "walkthrough" | "static" => (true, true),
            "noshadows" => (false, false),
            other => bail!("unknown mode {other:?} (moving, walkthrough, static, noshadows)"),
        };
        for &k in &a.ks {
            let lights: Vec<_> = (0..k as usize)
                .map(|i| {
                    let idx = (i * samples.len() / k as usize) % samples.len();
                    light_to_wire(&samples[idx], idx as u32)
                })
                .collect();
            let config = NodeConfig {
                epoch: 1,
                scene: hash,
                shadows: (0..k)
                    .map(|light| WireShadow {
                        light,
                        map_size: a.map,
                        casters: if shadows {
                            (0..scene.meshes.len() as u32).collect()
                        } else {
                            Vec::new()
                        },
                    })
                    .collect(),
                lights,
                color: [1.0; 3],
                layers: vec![(Layer::Illumination, format)],
                scale: 1.0,
                band_height: a.band_height,
                camera: camera_to_wire(&scene.camera),
                walkthrough,
                downstream: data_addr.clone(),
                input_index: 0,
                filter: 1,
                depth_bias: scene.quality.depth_bias,
                slope_bias: scene.quality.slope_bias,
                eye_meshes: None,
                rows: None,
                moves: Vec::new(),
                peel: None,
            };
            for pack in &a.pack {
                plan.push((mode.clone(), pack.clone(), k, config.clone()));
            }
        }
    }
    let mut rows: Vec<Row> = plan
        .iter()
        .map(|(mode, pack, k, _)| Row {
            mode: label(mode, pack),
            k: *k,
            frames: Vec::new(),
            intervals: Vec::new(),
            cpu_ms_total: 0.0,
        })
        .collect();
    // Rounds interleave the configurations, so a burst of load from other processes on a
    // shared machine spreads over all of them instead of skewing one.
    for round in 0..a.rounds {
        for ((mode, pack, k, config), row) in plan.iter().zip(rows.iter_mut()) {
            let still = mode == "static";
            let (frames, cpu_ms, intervals) =
                measure(&a, pack, &launcher, &scene, &bytes, config.clone(), still).await?;
            row.intervals.extend(intervals);
            row.cpu_ms_total += cpu_ms * frames.len() as f64;
            row.frames.extend(frames);
            eprintln!(
                "  round {round} {:<24} K={k:<3} {:>8.1} ms/frame fastest, {:>8.1} CPU ms/frame",
                row.mode,
                row.best_ms(),
                row.cpu_ms()
            );
        }
    }
    print_tables(&a, &rows);
    // Every frame's bands reached the stand-in compositor (a node that answered FrameDone
    // without sending would make every figure above a lie).
    let per_frame = u64::from(a.size.1.div_ceil(a.band_height.max(1)));
    let expected =
        u64::from(a.rounds) * plan.len() as u64 * u64::from(a.warmup + a.frames) * per_frame;
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    while received.load(Ordering::Relaxed) < expected && std::time::Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let got = received.load(Ordering::Relaxed);
    if got != expected {
        bail!("the nodes sent {got} bands where {expected} were due");
    }
    Ok(())
}

/// Starts a node process, sends the scene and `config`, drives warm-up and timed frames, stops it.
async fn measure(
    a: &NodeArgs,
    pack: &str,
    launcher: &Launcher,
    scene: &Scene,
    bytes: &[u8],
    config: NodeConfig,
    still: bool,
) -> anyhow::Result<(Vec<FrameStats>, f64, Vec<u64>)> {
    let node = Launcher {
        node_args: vec![
            "--backend".into(),
            a.backend.clone(),
            "--pack".into(),
            pack.into(),
        ],
        ..launcher.clone()
    };
    let (child, addr) = tokio::task::block_in_place(|| {
        node.start("bench-node", "node", ANY_PORT, Duration::from_secs(30))
    })?;
    let pid = child.id();
    // Stopped and reaped on every way out, errors included.
    let mut children = Children(vec![("bench-node".into(), child)]);
    match drive(a, launcher, scene, bytes, config, still, pid, &addr).await {
        Ok(r) => {
            // The node was told to shut down: give it time to exit before `Children` stops it.
            let deadline = std::time::Instant::now() + Duration::from_secs(30);
            while let Some((_, c)) = children.0.first_mut()
                && matches!(c.try_wait(), Ok(None))
                && std::time::Instant::now() < deadline
            {
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            Ok(r)
        }
        Err(e) => {
            // A node that died (no device, a crash) shows only as a broken link here: say so.
            match children.0.first_mut().map(|(_, c)| c.try_wait()) {
                Some(Ok(Some(status))) => Err(e.context(format!(
                    "the node process exited ({status}); its own messages are above"
                ))),
                _ => Err(e),
            }
        }
    }
}

/// One node process's run: configure it, render the frames, shut it down.
#[allow(clippy::too_many_arguments)]
async fn drive(
    a: &NodeArgs,
    launcher: &Launcher,
    scene: &Scene,
    bytes: &[u8],
    config: NodeConfig,
    still: bool,
    pid: u32,
    addr: &str,
) -> anyhow::Result<(Vec<FrameStats>, f64, Vec<u64>)> {
    let token = lightfold_net::load_token(Some(&launcher.token))?;
    let me = Identity::new(&token, Role::Coordinator, "bench");
    let wait = Duration::from_secs(600);
    let mut node = ControlClient::connect(addr, &me, Timeouts::default(), wait).await?;
    node.send_scene(config.scene, bytes, 4 << 20, wait).await?;
    let epoch = config.epoch;
    node.configure_node(config, wait).await?;
    let mut stats = Vec::new();
    let mut intervals = Vec::new();
    let mut cpu_start = None;
    let total = a.warmup + a.frames;
    let params = FrameParams {
        colors: Vec::new(),
        scale: None,
        time: None,
        lights: Vec::new(),
        rows: None,
    };
    let camera = |f: u32| {
        let c = if still {
            scene.camera
        } else {
            orbit(&scene.camera, f)
        };
        Some(camera_to_wire(&c))
    };
    // Up to `in_flight` requests outstanding; the next goes out as each answer comes back.
    let mut sent = 0;
    while sent < total.min(a.in_flight) {
        node.render_from(epoch, u64::from(sent), camera(sent), params.clone())
            .await?;
        sent += 1;
    }
    let mut last = None::<std::time::Instant>;
    for f in 0..total {
        if f == a.warmup {
            cpu_start = Some(crate::launcher::cpu_seconds(pid));
        }
        let s = node.frame_done(u64::from(f), wait).await?;
        let now = std::time::Instant::now();
        if f >= a.warmup {
            if let Some(t) = last {
                intervals.push((now - t).as_micros() as u64);
            }
            stats.push(s);
        }
        last = Some(now);
        if sent < total {
            node.render_from(epoch, u64::from(sent), camera(sent), params.clone())
                .await?;
            sent += 1;
        }
    }
    // CPU time of the node process over the timed frames (0 where /proc cannot tell).
    let cpu_ms = match cpu_start {
        Some(a0) => (crate::launcher::cpu_seconds(pid) - a0) * 1000.0 / f64::from(a.frames),
        None => f64::NAN,
    };
    node.shutdown().await?;
    Ok((stats, cpu_ms, intervals))
}

/// The scene camera turned `f` half-degrees about the vertical through its target: a walkthrough
/// that needs a new eye pass every frame.
fn orbit(c: &Camera, f: u32) -> Camera {
    c.orbited(-0.5 * f as f32)
}

/// Accepts data links and counts the bands that arrive.
async fn drain(listener: TcpListener, token: Vec<u8>, count: Arc<AtomicU64>) {
    let me = Identity::new(&token, Role::Compositor, "bench-compositor");
    while let Ok((stream, _)) = listener.accept().await {
        let (me, count) = (me.clone(), count.clone());
        tokio::spawn(async move {
            let Ok(link) = accept(stream, &me, Timeouts::default()).await else {
                return;
            };
            let (mut reader, _writer) = link.split();
            while let Some(Ok(Frame::Band(..))) = reader.next().await {
                count.fetch_add(1, Ordering::Relaxed);
            }
        });
    }
}

fn print_tables(a: &NodeArgs, rows: &[Row]) {
    let l = a.lights;
    outln!(
        "\n### Frame time per node ({}x{}, {}² maps, LP_NUM_THREADS={}, {} rounds × {} frames, phases are medians, ms)\n",
        a.size.0,
        a.size.1,
        a.map,
        a.threads,
        a.rounds,
        a.frames
    );
    outln!(
        "| mode | K | fastest | median | interval | CPU | setup | shadow | eye | readback | pack | send | untimed | ahead | interval ÷ device | read B/px | shadow passes | MB out | peak RSS MB |"
    );
    outln!(
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
    );
    let pixels = f64::from(a.size.0) * f64::from(a.size.1);
    for r in rows {
        let passes = median(
            &r.frames
                .iter()
                .map(|s| u64::from(s.shadow_passes))
                .collect::<Vec<_>>(),
        );
        let mb = median(&r.frames.iter().map(|s| s.bytes_out).collect::<Vec<_>>()) / 1e6;
        let rss = r.frames.iter().map(|s| s.peak_rss_bytes).max().unwrap_or(0) as f64 / 1e6;
        // Time no phase accounts for (packing overlaps sending, so it is not subtracted).
        let untimed = r.ms(|s| {
            s.total_us.saturating_sub(
                s.pose_us + s.setup_us + s.shadow_us + s.eye_us + s.readback_us + s.send_us,
            )
        });
        let device = r.ms(|s| s.shadow_us + s.eye_us);
        let interval = median(&r.intervals) / 1000.0;
        let ratio = if device > 0.0 && interval > 0.0 {
            format!("{:.2}", interval / device)
        } else {
            "—".into()
        };
        let read = median(&r.frames.iter().map(|s| s.read_bytes).collect::<Vec<_>>()) / pixels;
        let ahead = r.frames.iter().filter(|s| s.prefetched).count() * 100 / r.frames.len().max(1);
        outln!(
            "| {} | {} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {}% | {} | {:.1} | {} | {:.2} | {:.0} |",
            r.mode,
            r.k,
            r.best_ms(),
            r.total_ms(),
            interval,
            r.cpu_ms(),
            r.ms(|s| s.setup_us + s.pose_us),
            r.ms(|s| s.shadow_us),
            r.ms(|s| s.eye_us),
            r.ms(|s| s.readback_us),
            r.ms(|s| s.pack_us),
            r.ms(|s| s.send_us),
            untimed,
            ahead,
            ratio,
            read,
            passes,
            mb,
            rss
        );
    }
    outln!(
        "\n`interval` is the median time between the node's answers ({} request(s) in flight). Device time is the shadow and eye phases (each waits for the device); interval ÷ device is the node's rate against it (1.5 or less: the node nearly keeps up with its device). `read B/px` is what the node copied from the device a pixel: the link format's bytes when packing on the device (plus a few words a band), 32 (lit buffer) or 16 a target when packing on the CPU. `untimed` is the frame less every timed phase; `ahead` the share of frames the node rendered while it sent the one before.",
        a.in_flight
    );
    outln!("\n### L = {l}: node-seconds per frame (fastest wall time, and CPU time of the node)\n");
    outln!(
        "| mode | K | nodes ⌈L/K⌉ | node-s / frame | vs K = 1 | CPU node-s / frame | vs K = 1 |"
    );
    outln!("|---|---:|---:|---:|---:|---:|---:|");
    for r in rows {
        let nodes = f64::from(l.div_ceil(r.k));
        let base = rows.iter().find(|b| b.mode == r.mode && b.k == 1);
        let ratio = |per_frame: &dyn Fn(&Row) -> f64| {
            let (b, x) = (base.map_or(0.0, per_frame), per_frame(r));
            // A still camera costs almost nothing: no ratio of two near-zero figures.
            if b > 0.0 && x > 0.0 {
                format!("{:.2}×", f64::from(l) * b / (nodes * x))
            } else {
                "—".to_string()
            }
        };
        outln!(
            "| {} | {} | {nodes} | {:.2} | {} | {:.2} | {} |",
            r.mode,
            r.k,
            nodes * r.best_ms() / 1000.0,
            ratio(&|x: &Row| x.best_ms()),
            nodes * r.cpu_ms() / 1000.0,
            ratio(&|x: &Row| x.cpu_ms()),
        );
    }
    outln!("\n### L = {l}: illumination nodes needed within a frame budget (fastest wall time)\n");
    outln!(
        "| mode | {} |",
        a.budget_ms
            .iter()
            .map(|b| format!("{b:.0} ms"))
            .collect::<Vec<_>>()
            .join(" | ")
    );
    outln!("|---|{}", "---|".repeat(a.budget_ms.len()));
    let mut labels: Vec<&str> = Vec::new();
    for r in rows {
        if !labels.contains(&r.mode.as_str()) {
            labels.push(&r.mode);
        }
    }
    for mode in labels {
        let cells: Vec<String> = a
            .budget_ms
            .iter()
            .map(|&budget| {
                rows.iter()
                    .filter(|r| r.mode == mode && r.best_ms() <= budget)
                    .min_by_key(|r| l.div_ceil(r.k))
                    .map_or("none".to_string(), |r| {
                        format!("{} (K = {})", l.div_ceil(r.k), r.k)
                    })
            })
            .collect();
        outln!("| {mode} | {} |", cells.join(" | "));
    }
}
