//! `lightfold soak`: the failover soak measurement. Starts a local cluster of daemon processes as
//! `demo` does, each on a fixed loopback port (so that a restarted daemon comes back on its
//! address with its id, as under a supervisor), runs the coordinator's event loop in this process
//! over an endless camera orbit, and injects random faults into the daemons: SIGKILL and a
//! restart after a short delay, SIGSTOP for 0.2–3 s then SIGCONT, SIGTERM and a restart — at
//! most two daemons at once, each fault after a frame requested since the last one came back.
//! Every delivered frame is checked, in another thread, against the single-device GPU render of
//! its camera. Reports frames requested / delivered / lost / duplicated / wrong, detection and
//! recovery times, re-plans and each daemon's peak RSS, on stdout and as CSV and Markdown under
//! `--out`; fails if a frame was lost, duplicated, delivered out of order or wrong.

mod coordinator;
mod report;

use crate::check::{Check, compare, radiance};
use crate::launcher::{
    Children, Launcher, Started, cpu_seconds, peak_rss_kib, run_token, send_signal,
};
use anyhow::{Context, bail};
use lightfold_coordinator::control::{
    ControlOptions, DaemonAddr, FrameResult, FrameSpec, Live, LiveSummary, Session,
};
use lightfold_coordinator::plan::{ClusterSpec, MapSizing, PlanOptions, plan};
use lightfold_coordinator::run::{FramePath, camera_at};
use lightfold_net::{Identity, Timeouts};
use lightfold_node::gpu::{Gpu, GpuOptions, RenderOptions, Renderer};
use lightfold_protocol::Role;
use lightfold_scene::{Image, Scene};
use lightfold_telemetry::outln;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use report::{Report, ReportInput};
use rustix::process::Signal;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio_util::sync::CancellationToken;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Built-in scene name, scene file (.toml) or model (.gltf/.glb, .obj, .ply,
    /// .usda/.usdc/.usdz).
    #[arg(long, default_value = "balls")]
    pub scene: String,
    /// Image size as WIDTHxHEIGHT.
    #[arg(long, default_value = "160x120")]
    pub size: String,
    /// Samples per area light (0: the scene's own).
    #[arg(long, default_value_t = 4)]
    pub samples: u32,
    /// Lights per node (K).
    #[arg(short = 'K', long, default_value_t = 2)]
    pub lights_per_node: u32,
    /// Faults to inject.
    #[arg(long, default_value_t = 100)]
    pub faults: u32,
    /// Seed of the fault schedule (victims, kinds, durations, delays).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Directory for the report (soak.md, soak.csv, daemons.csv, faults.csv, epochs.csv) and the
    /// daemons' logs (logs/ID.log).
    #[arg(long, default_value = "soak-out")]
    pub out: PathBuf,
    /// Degrees the camera orbits per frame.
    #[arg(long, default_value_t = 2.0)]
    pub orbit: f32,
    /// Seconds a daemon may leave heartbeats unanswered before it is lost.
    #[arg(long, default_value_t = 1.0)]
    pub heartbeat_timeout: f64,
    /// Frames delivered before the first fault, and with every daemon back after the last one.
    #[arg(long, default_value_t = 10)]
    pub settle_frames: usize,
    /// Stop injecting after this many seconds (the report covers what happened until then).
    #[arg(long, default_value_t = 3600.0)]
    pub max_seconds: f64,
    /// Lavapipe threads per render node (LP_NUM_THREADS); 0 leaves Mesa's default.
    #[arg(long, default_value_t = 1)]
    pub gpu_threads: u32,
    /// Log filter of the daemons (their logs go to OUT/logs/ID.log).
    #[arg(long, default_value = "info")]
    pub daemon_log: String,
    /// Steer the first light's colour every this many frames, mixed with the faults: the scene's
    /// colour, pure red, pure green, white, in turn (each change from a colour with a zero
    /// channel re-plans over the recoloured scene); every frame is checked against the
    /// single-device render under its colours. 0: never.
    #[arg(long, default_value_t = 0)]
    pub steer_every: u64,
    /// Run the coordinator as a process of its own and SIGKILL it this many times at random
    /// frames of a `--frames` camera path, resuming it each time (`--resume`) over the same
    /// frame folder; no daemon faults. Every frame must be on disk once and right
    /// (`OUT/coordinator-soak.md`).
    #[arg(long, default_value_t = 0)]
    pub coordinator_kills: u32,
    /// Frames of the camera path under `--coordinator-kills`.
    #[arg(long, default_value_t = 60)]
    pub frames: u32,
}

/// The colours the soak steers the first light through (`--steer-every`); `None`: the scene's.
const STEER_COLOURS: [Option<[f32; 3]>; 4] = [
    None,
    Some([1.0, 0.0, 0.0]),
    Some([0.0, 1.0, 0.0]),
    Some([1.0, 1.0, 1.0]),
];

/// The light colours of frame `frame` (from 1) when steering every `every` frames.
fn steered_colours(frame: u64, every: u64) -> Vec<(u32, [f32; 3])> {
    if every == 0 {
        return Vec::new();
    }
    let step = (frame.saturating_sub(1) / every) as usize % STEER_COLOURS.len();
    STEER_COLOURS[step].map(|c| (0, c)).into_iter().collect()
}

/// `scene` with the light colours of `colours` (source light → colour).
fn recoloured(scene: &Scene, colours: &[(u32, [f32; 3])]) -> Scene {
    let mut s = scene.clone();
    for &(l, c) in colours {
        if let Some(light) = s.lights.get_mut(l as usize) {
            light.color = c;
        }
    }
    s
}

/// A SIGSTOP lasts this long at least and at most.
const STALL: (f64, f64) = (0.2, 3.0);
/// A killed or terminated daemon is restarted after a delay in this range (seconds).
const RESTART_DELAY: (f64, f64) = (0.1, 1.0);
/// Faults are this far apart at least (seconds, drawn), besides waiting for progress.
const GAP: (f64, f64) = (0.3, 2.5);
/// At most this many daemons are faulted at once.
const MAX_CONCURRENT: usize = 2;
/// A daemon running again that is not back in a delivered frame after this long is given up on.
const BACK_TIMEOUT: Duration = Duration::from_secs(60);
/// A daemon told SIGTERM that has not exited after this long is killed (and that is noted).
const TERM_TIMEOUT: Duration = Duration::from_secs(10);
/// A restart whose bind fails is tried again this often, this many times.
const RESTART_RETRY: Duration = Duration::from_millis(250);
const RESTART_TRIES: u32 = 40;

/// One daemon of the cluster (its process is `children.0[i]` at the same index).
#[derive(Debug, Clone)]
pub(crate) struct DaemonInfo {
    pub id: String,
    pub role: &'static str,
    pub addr: String,
    /// Processes started for it.
    pub starts: u32,
    /// Largest VmHWM (KiB) of its processes so far.
    pub hwm_kib: u64,
    /// CPU seconds of its processes that ended.
    pub cpu_done: f64,
}

impl DaemonInfo {
    /// A daemon's record after its first start.
    fn first(d: Started) -> DaemonInfo {
        DaemonInfo {
            id: d.id,
            role: d.role,
            addr: d.addr,
            starts: 1,
            hwm_kib: 0,
            cpu_done: 0.0,
        }
    }
}

/// `--size` as WIDTHxHEIGHT.
pub(crate) fn parse_size(s: &str) -> anyhow::Result<(u32, u32)> {
    lightfold_scene::limits::parse_image_size(s)
        .map_err(|e| anyhow::anyhow!("bad --size: {e} (see `lightfold defaults`)"))
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Kind {
    Kill,
    Stop(Duration),
    Term,
}

impl Kind {
    pub(crate) fn name(&self) -> &'static str {
        match self {
            Kind::Kill => "SIGKILL",
            Kind::Stop(_) => "SIGSTOP",
            Kind::Term => "SIGTERM",
        }
    }
}

/// One injected fault and what the injector saw of it.
#[derive(Debug, Clone)]
pub(crate) struct Fault {
    pub daemon: usize,
    pub kind: Kind,
    /// When the signal was sent.
    pub at: Instant,
    /// SIGKILL / SIGTERM: when the process had exited.
    pub exited: Option<Instant>,
    /// When it runs again: restarted and listening, or continued.
    pub resumed: Option<Instant>,
    /// The next action (restart or SIGCONT) is due then.
    due: Option<Instant>,
    /// When a frame requested after `resumed` came back with this daemon's report.
    pub back: Option<Instant>,
    pub restart_tries: u32,
    gave_up: bool,
    pub notes: Vec<String>,
}

impl Fault {
    fn active(&self) -> bool {
        self.back.is_none() && !self.gave_up
    }
}

/// A frame handed over by the event loop.
#[derive(Debug, Clone)]
pub(crate) struct Delivery {
    pub frame: u64,
    pub at: Instant,
    pub requested_at: Instant,
    daemons: Vec<String>,
}

/// What the event loop's callback shares with the injector.
#[derive(Debug, Default)]
struct Progress {
    deliveries: Vec<Delivery>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let started = Instant::now();
    let (setup, launcher) = setup(&args)?;
    if args.coordinator_kills > 0 {
        return coordinator::run(&args, launcher);
    }
    let (scene, nodes, compositors) = (&setup.scene, setup.nodes, setup.compositors);
    let (w, h) = (scene.camera.width, scene.camera.height);
    outln!(
        "soak: scene {:?} {w}x{h}, {} light samples, K = {}: {nodes} render node(s) and \
         {compositors} compositor(s) on loopback; {} faults, seed {}",
        scene.name,
        setup.active,
        setup.k,
        args.faults,
        args.seed
    );

    let Checker {
        queue: check_tx,
        thread: checker,
        adapter,
    } = spawn_checker(scene.clone(), setup.path, args.steer_every)?;
    let mut machine = Machine::probe(adapter);

    let (children, first) = launcher.start_cluster(nodes, compositors)?;
    let daemons: Vec<DaemonInfo> = first.into_iter().map(DaemonInfo::first).collect();
    let addrs: Vec<DaemonAddr> = daemons
        .iter()
        .map(|d| DaemonAddr {
            address: d.addr.clone(),
            role: if d.role == "node" {
                Role::Node
            } else {
                Role::Compositor
            },
            id: Some(d.id.clone()),
        })
        .collect();
    let control = control_options(&args)?;

    let shared = Shared {
        progress: Arc::default(),
        run_over: Arc::new(AtomicBool::new(false)),
        interrupted: Arc::new(AtomicBool::new(false)),
        stop_feeding: CancellationToken::new(),
    };
    let requested = Arc::new(AtomicU64::new(0));
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;

    let me = Identity::new(&setup.token, Role::Coordinator, "coordinator");
    let mut session = rt.block_on(async {
        let sink = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
        anyhow::Ok(Session::connect(&addrs, sink, None, me, control).await?)
    })?;
    outln!(
        "soak: cluster connected after {:.1} s; injecting faults",
        started.elapsed().as_secs_f64()
    );

    let injector = spawn_injector(&args, shared.clone(), launcher, children, daemons)?;

    let run_started = Instant::now();
    let (run_error, summary) = rt.block_on(drive(
        &mut session,
        &setup,
        args.steer_every,
        &shared,
        &requested,
        check_tx,
    ));
    let run_time = run_started.elapsed();
    shared.run_over.store(true, Ordering::SeqCst);
    shared.stop_feeding.cancel();
    let inj = match injector.join() {
        Ok(inj) => inj,
        Err(_) => bail!("the fault injector panicked"),
    };
    let Injector {
        mut children,
        mut daemons,
        faults,
        notes,
        loads,
        ..
    } = inj;
    machine.load = loads;
    // Every daemon runs (none is stopped): read what each used before shutting them down.
    for (d, (_, c)) in daemons.iter_mut().zip(children.0.iter_mut()) {
        if matches!(c.try_wait(), Ok(None)) {
            d.hwm_kib = d.hwm_kib.max(peak_rss_kib(c.id()));
            d.cpu_done += cpu_seconds(c.id());
        }
    }
    rt.block_on(session.shutdown());
    drop(children);
    drop(rt);
    let _ = setup.work.close();
    eprintln!("soak: cluster stopped; waiting for the frame checks");
    let checks = checker
        .join()
        .map_err(|_| anyhow::anyhow!("the frame checker panicked"))??;

    let deliveries = std::mem::take(
        &mut shared
            .progress
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .deliveries,
    );
    let report = Report::build(&ReportInput {
        args: &args,
        scene: &setup.scene,
        nodes,
        compositors,
        control,
        machine: &machine,
        requested: requested.load(Ordering::SeqCst),
        deliveries: &deliveries,
        checks: &checks,
        summary: &summary,
        faults: &faults,
        daemons: &daemons,
        run_error: run_error.as_deref(),
        run_time,
        notes: &notes,
        interrupted: shared.interrupted.load(Ordering::SeqCst),
    });
    report.print();
    report.write(&args.out)?;
    outln!("soak: report written to {}", args.out.display());
    if !report.failures.is_empty() {
        bail!("soak failed: {}", report.failures.join("; "));
    }
    Ok(())
}

/// Runs the coordinator's event loop over the orbit until it ends or fails: frames are fed
/// until `shared.stop_feeding` is cancelled, and each delivered frame is recorded in
/// `shared.progress` and queued for its check. Returns the loop's error, if any, and what it
/// did.
async fn drive(
    session: &mut Session,
    setup: &Setup,
    steer_every: u64,
    shared: &Shared,
    requested: &Arc<AtomicU64>,
    check_tx: std::sync::mpsc::Sender<(u64, Image)>,
) -> (Option<String>, LiveSummary) {
    let (tx, rx) = tokio::sync::mpsc::channel::<FrameSpec>(2);
    let feeder = spawn_feeder(
        tx,
        setup.scene.camera,
        setup.path,
        steer_every,
        shared.stop_feeding.clone(),
        Arc::clone(requested),
    );
    let ctrl_c = spawn_interrupt(Arc::clone(&shared.interrupted));
    let mut live = match Live::new(session, &setup.scene, &setup.plan_opts) {
        Ok(l) => l,
        Err(e) => {
            feeder.abort();
            ctrl_c.abort();
            return (Some(e.to_string()), LiveSummary::default());
        }
    };
    let p = Arc::clone(&shared.progress);
    let on_frame = move |f: FrameResult| {
        let daemons = f.stats.iter().map(|s| s.daemon_id.clone()).collect();
        p.lock()
            .unwrap_or_else(|e| e.into_inner())
            .deliveries
            .push(Delivery {
                frame: f.frame,
                at: Instant::now(),
                requested_at: f.requested_at,
                daemons,
            });
        let _ = check_tx.send((f.frame, f.image));
    };
    let result = live.run(rx, on_frame).await;
    feeder.abort();
    ctrl_c.abort();
    let summary = std::mem::take(&mut live.summary);
    (result.err().map(|e| e.to_string()), summary)
}

/// What the soak runs: the scene at its size, the camera path, the plan options, the cluster
/// the plan asks for, and the token the daemons share.
struct Setup {
    scene: Scene,
    path: FramePath,
    plan_opts: PlanOptions,
    /// Render nodes and compositors the scene's plan uses, with its active samples and K.
    nodes: usize,
    compositors: usize,
    active: usize,
    k: u32,
    /// Holds the token file; removed when dropped, also when the soak fails on the way.
    work: tempfile::TempDir,
    token: Vec<u8>,
}

/// Loads the scene as `args` ask, plans it over a cluster large enough for any plan to learn
/// the cluster to start, and writes the token and the log folder the daemons use; the launcher
/// starts them.
fn setup(args: &Args) -> anyhow::Result<(Setup, Launcher)> {
    let mut scene = lightfold_scene::load(&args.scene)
        .with_context(|| format!("cannot load scene {:?}", args.scene))?;
    let (w, h) = parse_size(&args.size)?;
    scene.camera.width = w;
    scene.camera.height = h;
    if args.samples > 0 {
        scene.quality.samples_per_area_light = Some(args.samples);
    }
    if args.faults > 0 && args.settle_frames == 0 {
        bail!("--settle-frames must be at least 1");
    }
    let path = FramePath::Orbit {
        degrees: args.orbit,
    };
    // Fixed map sizes, so nodes render the maps the single-device check renders.
    let plan_opts = PlanOptions {
        lights_per_node: args.lights_per_node,
        map_sizing: MapSizing::Fixed(scene.quality.shadow_map_size),
        ..PlanOptions::default()
    };
    let probe = plan(&scene, &ClusterSpec::local(256, 256), &plan_opts)?;
    let (nodes, compositors) = (probe.nodes.len(), probe.stages.len());
    let logs = args.out.join("logs");
    std::fs::create_dir_all(&logs).with_context(|| format!("cannot create {}", logs.display()))?;
    let (work, token_path, token) = run_token("lightfold-soak-")?;
    let exe = std::env::current_exe().context("cannot find the lightfold executable")?;
    let launcher = Launcher {
        exe,
        token: token_path.clone(),
        log: args.daemon_log.clone(),
        logs: Some(logs.clone()),
        gpu_threads: args.gpu_threads,
        metrics: false,
        node_args: Vec::new(),
    };
    let setup = Setup {
        scene,
        path,
        plan_opts,
        nodes,
        compositors,
        active: probe.active.len(),
        k: probe.k,
        work,
        token,
    };
    Ok((setup, launcher))
}

/// The coordinator's deadlines for the soak: generous where daemons start at once on few
/// cores, and the heartbeat timeout `args` ask for.
fn control_options(args: &Args) -> anyhow::Result<ControlOptions> {
    let heartbeat_timeout = Duration::try_from_secs_f64(args.heartbeat_timeout)
        .ok()
        .filter(|d| !d.is_zero())
        .context("--heartbeat-timeout is not a positive number of seconds")?;
    Ok(ControlOptions {
        link: Timeouts {
            connect: Duration::from_secs(5),
            handshake: Duration::from_secs(10),
            send: Duration::from_secs(30),
            ..Timeouts::default()
        },
        // Daemons opening their devices at once on few cores register slowly.
        register: Duration::from_secs(120),
        configure: Duration::from_secs(60),
        frame: Duration::from_secs(60),
        heartbeat_timeout,
        // Two daemons may be down at once; wait for one to come back rather than fail.
        wait_for_daemons: Duration::from_secs(60),
        ..ControlOptions::default()
    })
}

/// Starts the fault injector's thread over the cluster; it hands its record back when joined.
fn spawn_injector(
    args: &Args,
    shared: Shared,
    launcher: Launcher,
    children: Children,
    daemons: Vec<DaemonInfo>,
) -> std::io::Result<std::thread::JoinHandle<Injector>> {
    let cfg = InjectorConfig {
        faults: args.faults as usize,
        settle_frames: args.settle_frames,
        deadline: Instant::now() + Duration::from_secs_f64(args.max_seconds.max(0.0)),
        seed: args.seed,
    };
    let seed = args.seed;
    std::thread::Builder::new()
        .name("soak-faults".into())
        .spawn(move || {
            let mut inj = Injector {
                cfg,
                shared,
                launcher,
                children,
                daemons,
                faults: Vec::new(),
                rng: ChaCha8Rng::seed_from_u64(seed),
                seen: 0,
                notes: Vec::new(),
                loads: Vec::new(),
            };
            inj.run();
            inj
        })
}

/// Feeds the event loop the frames of the orbit from `base`, with the steered light colours,
/// counting each in `requested`, until `stop` is cancelled or the loop stops taking them.
fn spawn_feeder(
    tx: tokio::sync::mpsc::Sender<FrameSpec>,
    base: lightfold_scene::Camera,
    path: FramePath,
    steer_every: u64,
    stop: CancellationToken,
    req: Arc<AtomicU64>,
) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        for i in 0u32.. {
            let camera = lightfold_scene::wire::camera_to_wire(&camera_at(&base, path, i));
            let spec = FrameSpec {
                camera: Some(camera),
                light_colors: steered_colours(u64::from(i) + 1, steer_every),
                time: None,
                frame_budget_us: None,
                refine: None,
                lights: None,
                scene: None,
                moves: None,
            };
            tokio::select! {
                biased;
                _ = stop.cancelled() => break,
                r = tx.send(spec) => if r.is_err() { break },
            }
            req.fetch_add(1, Ordering::SeqCst);
        }
    })
}

/// On Ctrl-C, marks the soak `interrupted`: no more faults, and the frames in flight finish.
fn spawn_interrupt(interrupted: Arc<AtomicBool>) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        if tokio::signal::ctrl_c().await.is_ok() {
            eprintln!("soak: interrupted: no more faults; finishing the frames in flight");
            interrupted.store(true, Ordering::SeqCst);
        }
    })
}

#[derive(Debug)]
struct InjectorConfig {
    faults: usize,
    settle_frames: usize,
    deadline: Instant,
    seed: u64,
}

#[derive(Debug, Clone)]
struct Shared {
    progress: Arc<Mutex<Progress>>,
    run_over: Arc<AtomicBool>,
    interrupted: Arc<AtomicBool>,
    stop_feeding: CancellationToken,
}

/// The fault injector: a thread that polls every 10 ms, signals and restarts processes, and
/// follows the frames delivered to know when a faulted daemon is back.
struct Injector {
    cfg: InjectorConfig,
    shared: Shared,
    launcher: Launcher,
    children: Children,
    daemons: Vec<DaemonInfo>,
    faults: Vec<Fault>,
    rng: ChaCha8Rng,
    /// Deliveries looked at so far.
    seen: usize,
    notes: Vec<String>,
    /// The machine's 1-minute load average, every second.
    loads: Vec<f64>,
}

impl std::fmt::Debug for Injector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Injector")
            .field("faults", &self.faults.len())
            .field("seed", &self.cfg.seed)
            .finish_non_exhaustive()
    }
}

impl Injector {
    fn run(&mut self) {
        let poll = Duration::from_millis(10);
        let all: Vec<String> = self.daemons.iter().map(|d| d.id.clone()).collect();
        let mut next_fault_at = Instant::now();
        // A frame requested after the last fault has come back (faults wait for progress).
        let mut progressed = true;
        let mut delivered = 0usize;
        let mut last_sample = Instant::now();
        let mut stopping = false;
        // After the last fault: since when, how many frames with every daemon, until when.
        let mut settle: Option<(Instant, usize, Instant)> = None;
        while !self.shared.run_over.load(Ordering::SeqCst) {
            let now = Instant::now();
            let interrupted = self.shared.interrupted.load(Ordering::SeqCst);
            if (interrupted || now >= self.cfg.deadline) && !stopping {
                stopping = true;
                if !interrupted {
                    self.notes.push(format!(
                        "--max-seconds reached after {} fault(s)",
                        self.faults.len()
                    ));
                }
                self.end_faults_now();
            }
            if interrupted {
                self.shared.stop_feeding.cancel();
            }
            if now.duration_since(last_sample) >= Duration::from_secs(1) {
                last_sample = now;
                self.sample();
                self.loads.extend(load_average());
            }
            self.advance(now);
            let new: Vec<Delivery> = {
                let p = self
                    .shared
                    .progress
                    .lock()
                    .unwrap_or_else(|e| e.into_inner());
                p.deliveries[self.seen..].to_vec()
            };
            self.seen += new.len();
            let last_fault = self.faults.last().map(|f| f.at);
            for d in &new {
                delivered += 1;
                for f in self.faults.iter_mut().filter(|f| f.active()) {
                    let id = &self.daemons[f.daemon].id;
                    if f.resumed.is_some_and(|r| d.requested_at > r) && d.daemons.contains(id) {
                        f.back = Some(d.at);
                    }
                }
                if last_fault.is_none_or(|t| d.requested_at > t) {
                    progressed = true;
                }
                if let Some((since, n, _)) = &mut settle
                    && d.requested_at > *since
                    && all.iter().all(|id| d.daemons.contains(id))
                {
                    *n += 1;
                }
            }
            let active = self.faults.iter().filter(|f| f.active()).count();
            let injected = self.faults.len();
            if !stopping
                && injected < self.cfg.faults
                && delivered >= self.cfg.settle_frames
                && active < MAX_CONCURRENT
                && now >= next_fault_at
                && progressed
            {
                self.inject();
                progressed = false;
                let gap = self.rng.random_range(GAP.0..GAP.1);
                next_fault_at = Instant::now() + Duration::from_secs_f64(gap);
                continue;
            }
            if (stopping || injected >= self.cfg.faults) && active == 0 && settle.is_none() {
                settle = Some((now, 0, now + BACK_TIMEOUT));
            }
            if let Some((_, n, until)) = settle {
                if n >= self.cfg.settle_frames.max(1) {
                    self.shared.stop_feeding.cancel();
                } else if now >= until && !self.shared.stop_feeding.is_cancelled() {
                    self.notes.push(format!(
                        "the cluster did not settle (every daemon in {} frames) within {} s of the last fault",
                        self.cfg.settle_frames,
                        BACK_TIMEOUT.as_secs()
                    ));
                    self.shared.stop_feeding.cancel();
                }
            }
            std::thread::sleep(poll);
        }
        self.end_faults_now();
        self.sample();
    }

    /// Reads the peak RSS of every running daemon.
    fn sample(&mut self) {
        for (d, (_, c)) in self.daemons.iter_mut().zip(self.children.0.iter_mut()) {
            // A reaped child's pid may belong to another process by now.
            if matches!(c.try_wait(), Ok(None)) {
                d.hwm_kib = d.hwm_kib.max(peak_rss_kib(c.id()));
            }
        }
    }

    fn inject(&mut self) {
        let busy: Vec<usize> = self
            .faults
            .iter()
            .filter(|f| f.active())
            .map(|f| f.daemon)
            .collect();
        let free: Vec<usize> = (0..self.daemons.len())
            .filter(|i| !busy.contains(i))
            .collect();
        let daemon = free[self.rng.random_range(0..free.len())];
        let kind = match self.rng.random_range(0..3u32) {
            0 => Kind::Kill,
            1 => Kind::Stop(Duration::from_secs_f64(
                self.rng.random_range(STALL.0..STALL.1),
            )),
            _ => Kind::Term,
        };
        let pid = self.children.0[daemon].1.id();
        let d = &mut self.daemons[daemon];
        // What this process used, before it goes.
        d.hwm_kib = d.hwm_kib.max(peak_rss_kib(pid));
        if !matches!(kind, Kind::Stop(_)) {
            d.cpu_done += cpu_seconds(pid);
        }
        let (sig, name) = match kind {
            Kind::Kill => (Signal::KILL, "KILL"),
            Kind::Stop(_) => (Signal::STOP, "STOP"),
            Kind::Term => (Signal::TERM, "TERM"),
        };
        let at = Instant::now();
        let mut f = Fault {
            daemon,
            kind,
            at,
            exited: None,
            resumed: None,
            due: None,
            back: None,
            restart_tries: 0,
            gave_up: false,
            notes: Vec::new(),
        };
        if !send_signal(pid, sig) {
            f.notes.push(format!("SIG{name} to {pid} failed"));
        }
        match kind {
            Kind::Kill => {
                let _ = self.children.0[daemon].1.wait();
                f.exited = Some(Instant::now());
                f.due = Some(at + self.restart_delay());
            }
            Kind::Stop(d) => f.due = Some(at + d),
            Kind::Term => {}
        }
        let n = self.faults.len() + 1;
        let extra = match kind {
            Kind::Stop(d) => format!(" for {:.2} s", d.as_secs_f64()),
            _ => String::new(),
        };
        tracing::info!(
            "soak: fault {n}/{}: {} {}{extra}",
            self.cfg.faults,
            kind.name(),
            self.daemons[daemon].id
        );
        if n.is_multiple_of(10) || n == self.cfg.faults {
            eprintln!(
                "soak: {n}/{} faults injected, {} frames delivered so far",
                self.cfg.faults, self.seen
            );
        }
        self.faults.push(f);
    }

    fn restart_delay(&mut self) -> Duration {
        Duration::from_secs_f64(self.rng.random_range(RESTART_DELAY.0..RESTART_DELAY.1))
    }

    /// Moves every active fault on: SIGTERM exits, restarts and SIGCONTs due, give-ups.
    fn advance(&mut self, now: Instant) {
        for i in 0..self.faults.len() {
            if !self.faults[i].active() {
                continue;
            }
            let daemon = self.faults[i].daemon;
            let f = &self.faults[i];
            match (f.kind, f.exited, f.resumed, f.due) {
                (Kind::Term, None, _, _) => {
                    let child = &mut self.children.0[daemon].1;
                    match child.try_wait() {
                        Ok(Some(_)) => {
                            let delay = self.restart_delay();
                            let f = &mut self.faults[i];
                            f.exited = Some(now);
                            f.due = Some(now + delay);
                        }
                        Ok(None) if now.duration_since(f.at) > TERM_TIMEOUT => {
                            let _ = child.kill();
                            let _ = child.wait();
                            let delay = self.restart_delay();
                            let f = &mut self.faults[i];
                            f.notes.push(format!(
                                "did not exit within {} s of SIGTERM; killed",
                                TERM_TIMEOUT.as_secs()
                            ));
                            f.exited = Some(Instant::now());
                            f.due = Some(now + delay);
                        }
                        _ => {}
                    }
                }
                (Kind::Stop(_), _, None, Some(due)) if now >= due => {
                    let pid = self.children.0[daemon].1.id();
                    let f = &mut self.faults[i];
                    if !send_signal(pid, Signal::CONT) {
                        f.notes.push("SIGCONT failed".into());
                    }
                    f.resumed = Some(Instant::now());
                }
                (Kind::Kill | Kind::Term, Some(_), None, Some(due)) if now >= due => {
                    self.restart(i);
                }
                (_, _, Some(r), _) if now.duration_since(r) > BACK_TIMEOUT => {
                    let f = &mut self.faults[i];
                    f.gave_up = true;
                    f.notes.push(format!(
                        "not back in a delivered frame {} s after it ran again",
                        BACK_TIMEOUT.as_secs()
                    ));
                }
                _ => {}
            }
        }
    }

    /// Starts fault `i`'s daemon again on its address (retrying while the port is busy).
    fn restart(&mut self, i: usize) {
        let daemon = self.faults[i].daemon;
        let (id, role, addr) = {
            let d = &self.daemons[daemon];
            (d.id.clone(), d.role, d.addr.clone())
        };
        match self
            .launcher
            .start(&id, role, &addr, Duration::from_secs(10))
        {
            Ok((child, got)) => {
                if got != addr {
                    self.faults[i]
                        .notes
                        .push(format!("restarted on {got}, not {addr}"));
                }
                self.children.0[daemon].1 = child;
                self.daemons[daemon].starts += 1;
                self.faults[i].resumed = Some(Instant::now());
            }
            Err(e) => {
                let f = &mut self.faults[i];
                f.restart_tries += 1;
                f.notes.push(format!("restart {}: {e:#}", f.restart_tries));
                if f.restart_tries >= RESTART_TRIES {
                    f.gave_up = true;
                } else {
                    f.due = Some(Instant::now() + RESTART_RETRY);
                }
            }
        }
    }

    /// Ends every fault at once: stopped daemons continue, killed ones restart now.
    fn end_faults_now(&mut self) {
        for i in 0..self.faults.len() {
            let f = &self.faults[i];
            if f.resumed.is_some() || f.gave_up {
                continue;
            }
            let daemon = f.daemon;
            match f.kind {
                Kind::Stop(_) => {
                    let pid = self.children.0[daemon].1.id();
                    send_signal(pid, Signal::CONT);
                    self.faults[i].resumed = Some(Instant::now());
                }
                Kind::Term if f.exited.is_none() => {
                    let child = &mut self.children.0[daemon].1;
                    let deadline = Instant::now() + TERM_TIMEOUT;
                    while matches!(child.try_wait(), Ok(None)) && Instant::now() < deadline {
                        std::thread::sleep(Duration::from_millis(20));
                    }
                    if matches!(child.try_wait(), Ok(None)) {
                        let _ = child.kill();
                    }
                    let _ = child.wait();
                    self.faults[i].exited = Some(Instant::now());
                    self.restart(i);
                }
                _ => self.restart(i),
            }
        }
    }
}

/// The thread that checks every delivered frame against the single-device render of its camera:
/// its queue, the thread, and its adapter (name and backend).
pub(crate) struct Checker {
    pub queue: std::sync::mpsc::Sender<(u64, Image)>,
    pub thread: std::thread::JoinHandle<anyhow::Result<Vec<Check>>>,
    pub adapter: String,
}

pub(crate) fn spawn_checker(
    scene: Scene,
    path: FramePath,
    steer_every: u64,
) -> anyhow::Result<Checker> {
    let (tx, rx) = std::sync::mpsc::channel::<(u64, Image)>();
    let (ready_tx, ready_rx) = std::sync::mpsc::channel::<anyhow::Result<String>>();
    let handle = std::thread::Builder::new()
        .name("soak-check".into())
        .spawn(move || {
            let setup = (|| {
                let gpu = Gpu::new(&GpuOptions::default())
                    .context("the frame check needs a GPU adapter (install mesa-vulkan-drivers)")?;
                let mut r =
                    Renderer::new(&gpu, &scene, RenderOptions::from_quality(&scene.quality))?;
                // Cluster nodes fit their maps to what the camera sees (not walkthrough).
                r.set_fit_to_camera(true);
                anyhow::Ok((gpu, r))
            })();
            let (gpu, mut renderer) = match setup {
                Ok(x) => {
                    let _ =
                        ready_tx.send(Ok(format!("{} ({:?})", x.0.info.name, x.0.info.backend)));
                    x
                }
                Err(e) => {
                    let msg = format!("{e:#}");
                    let _ = ready_tx.send(Err(e));
                    bail!("{msg}");
                }
            };
            let mut checks = Vec::new();
            for (frame, image) in rx {
                let mut s = recoloured(&scene, &steered_colours(frame, steer_every));
                let samples = lightfold_scene::vpl::frame_samples(&s);
                s.camera = camera_at(&scene.camera, path, (frame - 1) as u32);
                let check = match radiance(&gpu, &mut renderer, &s, &samples, 0) {
                    Ok(truth) => compare(frame, &image, &truth, 1000),
                    Err(e) => Check::failed(
                        frame,
                        image.data.len(),
                        format!("the reference render failed: {e:#}"),
                    ),
                };
                checks.push(check);
            }
            Ok(checks)
        })?;
    match ready_rx.recv() {
        Ok(Ok(adapter)) => Ok(Checker {
            queue: tx,
            thread: handle,
            adapter,
        }),
        Ok(Err(e)) => Err(e),
        Err(_) => match handle.join() {
            Ok(Err(e)) => Err(e),
            _ => bail!("the frame checker stopped before it was ready"),
        },
    }
}

/// Where the soak ran.
#[derive(Debug, Clone, Default)]
pub(crate) struct Machine {
    pub cpu: String,
    pub cores: usize,
    pub memory_gib: f64,
    /// The frame checker's adapter and backend.
    pub checker: String,
    /// 1-minute load averages sampled every second during the run.
    pub load: Vec<f64>,
}

impl Machine {
    fn probe(checker: String) -> Machine {
        let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
        let cpu = cpuinfo
            .lines()
            .find_map(|l| l.strip_prefix("model name"))
            .map(|v| v.trim_start_matches([' ', '\t', ':']).trim().to_string())
            .unwrap_or_else(|| "unknown CPU".into());
        let memory_kib: f64 = std::fs::read_to_string("/proc/meminfo")
            .ok()
            .and_then(|m| {
                m.lines()
                    .find_map(|l| l.strip_prefix("MemTotal:"))
                    .and_then(|v| v.split_whitespace().next()?.parse().ok())
            })
            .unwrap_or(0.0);
        Machine {
            cpu,
            cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
            memory_gib: memory_kib / (1024.0 * 1024.0),
            checker,
            load: Vec::new(),
        }
    }
}

/// The 1-minute load average.
fn load_average() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_comparison_follows_the_link_bound() {
        let mut want = Image::new(10, 10, 3);
        want.data.iter_mut().for_each(|v| *v = 1.0);
        let mut test = want.clone();
        assert!(compare(1, &test, &want, 1000).ok);
        // 2 % off everywhere: inside the per-channel bound, but the energy is off by 2 %.
        test.data.iter_mut().for_each(|v| *v = 1.02);
        let c = compare(1, &test, &want, 1000);
        assert_eq!(c.outside, 0);
        assert!(!c.ok, "energy");
        // One channel in 300 far off: too many outside.
        let mut test = want.clone();
        test.data[0] = 2.0;
        let c = compare(1, &test, &want, 1000);
        assert_eq!(c.outside, 1);
        assert!(!c.ok);
        test.data[0] = f32::NAN;
        assert!(!compare(1, &test, &want, 1000).ok);
    }
}
