//! `lightfold coordinator`: connect a cluster (from a cluster file or addresses on the command
//! line), plan the scene, drive frames, write the final image (EXR linear, PNG sRGB) and print the
//! plan and timing tables.

use anyhow::{Context, bail};
use lightfold_coordinator::cluster::ClusterFile;
use lightfold_coordinator::control::Session;
use lightfold_coordinator::control::{ControlOptions, DaemonAddr};
use lightfold_coordinator::control::{FrameResult, IncidentKind, LiveSummary};
use lightfold_coordinator::plan::{PlanOptions, Topology};
use lightfold_coordinator::report::Report;
use lightfold_coordinator::run::{FramePath, RunOptions};
use lightfold_net::{Identity, Timeouts};
use lightfold_protocol::Role;
use std::path::PathBuf;
use std::time::Duration;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Cluster file (TOML) listing daemons by address or DNS name.
    #[arg(long, conflicts_with_all = ["node", "compositor"])]
    pub cluster: Option<PathBuf>,
    /// A render node's address (repeatable), instead of a cluster file.
    #[arg(long)]
    pub node: Vec<String>,
    /// A compositor's address (repeatable), instead of a cluster file.
    #[arg(long)]
    pub compositor: Vec<String>,
    /// Where the sink compositor sends final bands (overrides the cluster file).
    #[arg(long)]
    pub sink_listen: Option<String>,
    #[arg(long)]
    pub sink_advertise: Option<String>,
    /// File holding the cluster token (else LIGHTFOLD_TOKEN).
    #[arg(long)]
    pub token_file: Option<PathBuf>,
    #[command(flatten)]
    pub job: JobArgs,
    /// Stop every daemon when done.
    #[arg(long)]
    pub shutdown: bool,
    /// Seconds to wait for a daemon to accept, authenticate and register (daemons still opening
    /// their devices answer late).
    #[arg(long, default_value_t = 10.0)]
    pub connect_timeout: f64,
    /// Seconds a frame may take end to end; a daemon that answers its heartbeats but has not
    /// finished a frame by then is treated as lost.
    #[arg(long, default_value_t = 120.0)]
    pub frame_timeout: f64,
    /// Seconds a daemon may leave heartbeats unanswered before it is treated as lost (stopped,
    /// hung or cut off) and the cluster is re-planned without it.
    #[arg(long, default_value_t = 1.0)]
    pub heartbeat_timeout: f64,
    /// Claim daemons that another coordinator is running a job on (that coordinator is told it
    /// was taken over and stops).
    #[arg(long)]
    pub take_over: bool,
    /// When too few daemons are left for any plan, wait this many seconds for lost ones to come
    /// back (they are redialled all along) instead of failing.
    #[arg(long, default_value_t = 0.0)]
    pub wait_for_daemons: f64,
    /// Exit when this process is no longer our parent (set by launchers).
    #[arg(long)]
    pub parent_pid: Option<u32>,
}

/// What to render and how: shared by `coordinator` and `demo`.
#[derive(Debug, Clone, clap::Args)]
pub struct JobArgs {
    /// Built-in scene name, scene file (.toml) or glTF (.gltf/.glb).
    #[arg(long, default_value = lightfold_scene::defaults::DEFAULT_SCENE)]
    pub scene: String,
    /// Image size as WIDTHxHEIGHT (default: the scene's).
    #[arg(long)]
    pub size: Option<String>,
    /// Lights per node (K).
    #[arg(short = 'K', long, default_value_t = lightfold_scene::defaults::LIGHTS_PER_NODE)]
    pub lights_per_node: u32,
    /// Compositor topology: chain or tree.
    #[arg(long, default_value = "chain")]
    pub topology: Topology,
    /// Frames to render.
    #[arg(long, default_value_t = 1)]
    pub frames: u32,
    /// Orbit the camera by this many degrees per frame (a camera path).
    #[arg(long)]
    pub orbit: Option<f32>,
    /// Keep shadow maps between frames (static lights and geometry).
    #[arg(long)]
    pub walkthrough: bool,
    /// No culling: every light, stage and caster.
    #[arg(long)]
    pub force_all: bool,
    /// One shadow-map size for every light (default: sized per node from the eye/light
    /// resolution mismatch).
    #[arg(long)]
    pub shadow_map_size: Option<u32>,
    /// Render the material layers on a node of their own (the paper's layout) instead of as
    /// extra targets of an illumination node at the last stage.
    #[arg(long)]
    pub material_own_node: bool,
    /// Frame-time budget in milliseconds: K becomes the largest whose slowest node fits it (by
    /// the nodes' cost model), so the plan uses as few nodes as it allows; overrides -K.
    #[arg(long, value_parser = crate::coordinator_cmd::positive_ms)]
    pub frame_budget: Option<f64>,
    /// PNG output (sRGB at the scene's exposure).
    #[arg(long, default_value = "out.png")]
    pub out: PathBuf,
    /// EXR output (linear radiance).
    #[arg(long, default_value = "out.exr")]
    pub exr: PathBuf,
    /// Also keep every frame, as DIR/frame-NNNNN.exr and .png, written as it completes (`--out`
    /// and `--exr` always hold the latest complete frame).
    #[arg(long)]
    pub frame_dir: Option<PathBuf>,
}

impl JobArgs {
    pub fn load_scene(&self) -> anyhow::Result<lightfold_scene::Scene> {
        let mut scene = lightfold_scene::load(&self.scene)
            .with_context(|| format!("cannot load scene {:?}", self.scene))?;
        if let Some(size) = &self.size {
            let (w, h) = parse_size(size)?;
            scene.camera.width = w;
            scene.camera.height = h;
        }
        if let Some(n) = self.shadow_map_size {
            lightfold_scene::limits::check_shadow_map_size(n)
                .map_err(|e| anyhow::anyhow!("bad --shadow-map-size: {e}"))?;
        }
        Ok(scene)
    }

    pub fn plan_options(&self) -> PlanOptions {
        PlanOptions {
            lights_per_node: self.lights_per_node,
            topology: self.topology,
            force_all: self.force_all,
            walkthrough: self.walkthrough,
            map_sizing: match self.shadow_map_size {
                Some(n) => lightfold_coordinator::plan::MapSizing::Fixed(n),
                None => PlanOptions::default().map_sizing,
            },
            material_own_node: self.material_own_node,
            frame_budget_us: self.frame_budget.map(|b| (b * 1000.0).round() as u64),
            ..PlanOptions::default()
        }
    }

    pub fn path(&self) -> FramePath {
        match self.orbit {
            Some(d) => FramePath::Orbit { degrees: d },
            None => FramePath::Still,
        }
    }
}

/// A duration in milliseconds that must be finite and positive (`--frame-budget`).
pub fn positive_ms(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 && v < 1e9 => Ok(v),
        _ => Err(format!("{s:?} is not a positive number of milliseconds")),
    }
}

/// `--size WIDTHxHEIGHT`, within the image limits every input shares
/// (`lightfold_scene::limits`, printed by `lightfold defaults`).
pub fn parse_size(s: &str) -> anyhow::Result<(u32, u32)> {
    lightfold_scene::limits::parse_image_size(s)
        .map_err(|e| anyhow::anyhow!("bad --size: {e} (see `lightfold defaults`)"))
}

pub fn run_cmd(args: Args) -> anyhow::Result<()> {
    let token = lightfold_net::load_token(args.token_file.as_deref())?;
    let (daemons, sink_listen, sink_advertise) = match &args.cluster {
        Some(path) => {
            let f = ClusterFile::load(path)?;
            let mut d: Vec<DaemonAddr> = f
                .nodes
                .iter()
                .map(|e| DaemonAddr {
                    address: e.address.clone(),
                    role: Role::Node,
                    id: e.id.clone(),
                })
                .collect();
            d.extend(f.compositors.iter().map(|e| DaemonAddr {
                address: e.address.clone(),
                role: Role::Compositor,
                id: e.id.clone(),
            }));
            (
                d,
                args.sink_listen.clone().unwrap_or(f.sink_listen),
                args.sink_advertise.clone().or(f.sink_advertise),
            )
        }
        None => {
            if args.node.is_empty() || args.compositor.is_empty() {
                bail!("give --cluster FILE, or at least one --node ADDR and one --compositor ADDR");
            }
            let d = DaemonAddr::list(&args.node, &args.compositor);
            (
                d,
                args.sink_listen
                    .clone()
                    .unwrap_or_else(|| "127.0.0.1:0".into()),
                args.sink_advertise.clone(),
            )
        }
    };
    let scene = args.job.load_scene()?;
    let rt = tokio::runtime::Runtime::new()?;
    rt.block_on(async move {
        let listener = tokio::net::TcpListener::bind(&sink_listen)
            .await
            .with_context(|| format!("cannot bind the sink listener on {sink_listen}"))?;
        let control = ControlOptions {
            link: Timeouts {
                connect: Duration::from_secs_f64(args.connect_timeout),
                handshake: Duration::from_secs_f64(args.connect_timeout),
                ..Timeouts::default()
            },
            register: Duration::from_secs_f64(args.connect_timeout),
            frame: Duration::from_secs_f64(args.frame_timeout),
            heartbeat_timeout: seconds(args.heartbeat_timeout, "--heartbeat-timeout")?,
            wait_for_daemons: seconds(args.wait_for_daemons, "--wait-for-daemons")?,
            take_over: args.take_over,
            ..ControlOptions::default()
        };
        let opts = RunOptions {
            plan: args.job.plan_options(),
            frames: args.job.frames,
            path: args.job.path(),
            color_changes: Vec::new(),
            control,
        };
        let me = Identity::new(&token, Role::Coordinator, "coordinator");
        let cancel = crate::lifecycle::shutdown_token(args.parent_pid);
        let connect = Session::connect(&daemons, listener, sink_advertise, me, control);
        let session = tokio::select! {
            r = connect => r?,
            _ = cancel.cancelled() => bail!("interrupted"),
        };
        // Ctrl-C from here on: no new frame is requested, the frames in flight are finished and
        // written, and the summary is printed.
        execute(session, &scene, &opts, &args.job, args.shutdown, cancel).await
    })
}

fn seconds(v: f64, what: &str) -> anyhow::Result<Duration> {
    if !(v.is_finite() && (0.0..1e7).contains(&v)) {
        bail!("{what} {v} is not a number of seconds");
    }
    Ok(Duration::from_secs_f64(v))
}

/// Runs the job on a connected session through the coordinator's event loop: prints the plan,
/// writes each frame as it completes, then prints the frames, timing table, failover summary
/// and totals. A run that cannot go on keeps what it wrote and fails naming the daemon and why.
pub async fn execute(
    mut session: Session,
    scene: &lightfold_scene::Scene,
    opts: &RunOptions,
    job: &JobArgs,
    shutdown: bool,
    stop: tokio_util::sync::CancellationToken,
) -> anyhow::Result<()> {
    let start = std::time::Instant::now();
    if let Some(dir) = &job.frame_dir {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create the frame directory {}", dir.display()))?;
    }
    let mut report = Report::default();
    let progress = (opts.frames > 1).then(|| {
        let pb = indicatif::ProgressBar::new(opts.frames as u64);
        pb.set_style(
            indicatif::ProgressStyle::with_template(
                "{bar:40} {pos}/{len} frames {per_sec} eta {eta}",
            )
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        pb
    });
    let writer = FrameWriter::start(job, scene.exposure);
    let outcome = lightfold_coordinator::run::render_until(
        &mut session,
        scene,
        opts,
        stop.clone(),
        |frame| {
            report.record(&frame);
            if let Some(pb) = &progress {
                pb.inc(1);
            }
            writer.send(frame);
        },
    )
    .await;
    if let Some(pb) = progress {
        pb.finish_and_clear();
    }
    let written = writer.finish();
    if let Some(plan) = &outcome.summary.plan {
        println!("{plan}");
    }
    if !report.frames.is_empty() {
        println!("{}", report.frame_lines());
    }
    if let (Some(plan), false) = (&outcome.summary.plan, report.frames.is_empty()) {
        println!("{}", report.table(plan));
        println!("{}", report.summary(plan));
    }
    println!("{}", failover_summary(&outcome.summary, start));
    if shutdown {
        session.shutdown().await;
    } else {
        session.detach();
    }
    let (image_size, write_error) = written;
    if let Some(e) = write_error {
        return Err(e.context("writing frames"));
    }
    if let Some(e) = outcome.error {
        bail!(
            "the run stopped after {} of {} frame(s): {e}",
            outcome.summary.delivered,
            opts.frames
        );
    }
    if stop.is_cancelled() {
        bail!(
            "interrupted after {} of {} frame(s); the frames done are written",
            outcome.summary.delivered,
            opts.frames
        );
    }
    let (w, h) = image_size.context("no frame was rendered")?;
    println!(
        "wrote {} and {} ({w}x{h}) in {:.2} s",
        job.out.display(),
        job.exr.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

/// What the run survived: one line per lost, stalled, slow or rejoined daemon and per re-plan.
pub fn failover_summary(s: &LiveSummary, start: std::time::Instant) -> String {
    let mut out = String::new();
    let at = |t: std::time::Instant| t.saturating_duration_since(start).as_secs_f64();
    let lost = s
        .incidents
        .iter()
        .filter(|i| matches!(i.kind, IncidentKind::Lost { .. }))
        .count();
    out.push_str(&format!(
        "failover: {} frame(s) delivered, {} daemon(s) lost, {} re-plan(s), {} frame request(s) sent again",
        s.delivered,
        lost,
        s.epochs.len().saturating_sub(1),
        s.rerequested
    ));
    // Slow frames: one line per frame, naming every daemon it waited on.
    let mut slow: Vec<(std::time::Instant, u64, u128, Vec<&str>)> = Vec::new();
    for i in &s.incidents {
        let what = match &i.kind {
            IncidentKind::Lost { reason } => format!("lost: {reason}"),
            IncidentKind::Slow { frame, waited } => {
                match slow.iter_mut().find(|x| x.1 == *frame) {
                    Some(x) => x.3.push(&i.daemon),
                    None => slow.push((i.at, *frame, waited.as_millis(), vec![&i.daemon])),
                }
                continue;
            }
            IncidentKind::Rejoined => "rejoined".to_string(),
        };
        out.push_str(&format!("\n  {:>7.2} s  {}  {what}", at(i.at), i.daemon));
    }
    for (t, frame, ms, who) in slow {
        out.push_str(&format!(
            "\n  {:>7.2} s  slow: frame {frame} waited {ms} ms on {}",
            at(t),
            who.join(", ")
        ));
    }
    for e in s.epochs.iter().skip(1) {
        out.push_str(&format!(
            "\n  {:>7.2} s  epoch {}: {} node(s), {} stage(s), K = {}, {} light(s) moved, configured in {} ms ({})",
            at(e.at),
            e.epoch,
            e.nodes,
            e.stages,
            e.k,
            e.lights_moved,
            e.configure.as_millis(),
            e.reason
        ));
    }
    out
}

/// What the frame writer's thread ends with: the size of the frames written, and the first error.
type WriterEnd = (Option<(u32, u32)>, Option<anyhow::Error>);

/// Writes frames off the event loop as they complete: `--out`/`--exr` get the newest (replaced
/// atomically), `--frame-dir` every one.
struct FrameWriter {
    tx: Option<std::sync::mpsc::Sender<FrameResult>>,
    thread: Option<std::thread::JoinHandle<WriterEnd>>,
}

impl FrameWriter {
    fn start(job: &JobArgs, exposure: f32) -> FrameWriter {
        let (tx, rx) = std::sync::mpsc::channel::<FrameResult>();
        let (png, exr, dir) = (job.out.clone(), job.exr.clone(), job.frame_dir.clone());
        let thread = std::thread::spawn(move || {
            let mut size = None;
            let mut error = None;
            while let Ok(mut f) = rx.recv() {
                // Every frame into the frame directory; only the newest queued into --out.
                let mut newest = Vec::new();
                loop {
                    if let Some(d) = &dir {
                        let stem = d.join(format!("frame-{:05}", f.frame));
                        let r = f
                            .image
                            .write_exr(&stem.with_extension("exr"))
                            .and_then(|()| {
                                f.image.write_png(&stem.with_extension("png"), exposure)
                            });
                        if let Err(e) = r {
                            error.get_or_insert(e.into());
                        }
                    }
                    newest.push(f);
                    match rx.try_recv() {
                        Ok(next) => f = next,
                        Err(_) => break,
                    }
                }
                if let Some(last) = newest.pop() {
                    size = Some((last.image.width, last.image.height));
                    if let Err(e) = write_atomically(&last.image, &png, &exr, exposure) {
                        error.get_or_insert(e);
                    }
                }
            }
            (size, error)
        });
        FrameWriter {
            tx: Some(tx),
            thread: Some(thread),
        }
    }

    fn send(&self, f: FrameResult) {
        if let Some(tx) = &self.tx {
            let _ = tx.send(f);
        }
    }

    /// Waits for every frame to be written; the last frame's size, and the first error.
    fn finish(mut self) -> (Option<(u32, u32)>, Option<anyhow::Error>) {
        drop(self.tx.take());
        match self.thread.take().map(|t| t.join()) {
            Some(Ok(r)) => r,
            Some(Err(_)) => (None, Some(anyhow::anyhow!("the frame writer panicked"))),
            None => (None, None),
        }
    }
}

/// Writes beside the target and renames over it, so a reader (or a crash) never sees half a file.
fn write_atomically(
    image: &lightfold_scene::Image,
    png: &std::path::Path,
    exr: &std::path::Path,
    exposure: f32,
) -> anyhow::Result<()> {
    let tmp = |p: &std::path::Path| {
        let name = p
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        // Keep the extension last: the writers pick the format from it.
        p.with_file_name(format!(".partial-{name}"))
    };
    let (tp, te) = (tmp(png), tmp(exr));
    image.write_exr(&te)?;
    std::fs::rename(&te, exr).with_context(|| format!("cannot write {}", exr.display()))?;
    image.write_png(&tp, exposure)?;
    std::fs::rename(&tp, png).with_context(|| format!("cannot write {}", png.display()))?;
    Ok(())
}
