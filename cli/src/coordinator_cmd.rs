//! `lightfold coordinator`: connect a cluster (from a cluster file or addresses on the command
//! line), plan the scene, drive frames, write the final image (EXR linear, PNG sRGB) and print the
//! plan (in a few lines; in full with `--verbose`) and timing tables. While frames run, a
//! terminal shows a progress bar; a log (stderr not a terminal) gets a line per frame.

use anyhow::{Context, bail};
use lightfold_coordinator::cluster::ClusterFile;
use lightfold_coordinator::console::{Console, JobOutput};
use lightfold_coordinator::control::Session;
use lightfold_coordinator::control::{ControlOptions, DaemonAddr};
use lightfold_coordinator::frames_out::FramePattern;
use lightfold_coordinator::plan::PlanOptions;
use lightfold_coordinator::run::{FramePath, RunOptions, render_until};
use lightfold_net::{Identity, Timeouts};
use lightfold_protocol::Role;
use lightfold_telemetry::outln;
use std::path::{Path, PathBuf};
use std::time::Duration;

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
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
    /// Address the sink compositor dials to reach this coordinator (default: the bound sink
    /// address), e.g. a routable address when the coordinator listens on `0.0.0.0`.
    #[arg(long)]
    pub sink_advertise: Option<String>,
    /// File holding the cluster token (else LIGHTFOLD_TOKEN).
    #[arg(long)]
    pub token_file: Option<PathBuf>,
    #[command(flatten)]
    pub job: JobArgs,
    /// The job (what to render and how) from a JSON file, as `demo` writes it for its
    /// coordinator, instead of the job's flags (`--scene`, `-K`, `--frames`, …).
    #[arg(long, value_name = "FILE")]
    pub job_file: Option<PathBuf>,
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
    #[command(flatten)]
    pub view: ViewArgs,
    #[command(flatten)]
    pub metrics: crate::lifecycle::MetricsArgs,
}

/// The live view (`docs/live-view.md`).
#[derive(Debug, Clone, clap::Args)]
pub(crate) struct ViewArgs {
    /// Serve the live view on ADDR and run until stopped (Ctrl-C) instead of rendering
    /// `--frames`: a web page that shows frames as they complete and steers camera and lights.
    /// Viewers beyond loopback see nothing but the page until they present the token (see
    /// `--public-watch`).
    #[arg(long, value_name = "ADDR")]
    pub http: Option<String>,
    /// With `--http`: render frame after frame even when nothing changed.
    #[arg(long)]
    pub continuous: bool,
    /// With `--http`: the token viewers beyond loopback present to watch and steer (default:
    /// the cluster's token).
    #[arg(long, value_name = "FILE")]
    pub view_token_file: Option<PathBuf>,
    /// With `--http`: JPEG quality of the frames pushed to viewers.
    #[arg(long, default_value_t = 85, value_parser = clap::value_parser!(u8).range(1..=100))]
    pub jpeg_quality: u8,
    #[command(flatten)]
    pub refine: RefineArgs,
    #[command(flatten)]
    pub access: ViewAccessArgs,
    /// With `--http`: the folder whose scene files and models (.toml, .gltf/.glb, .obj, .ply,
    /// .usda/.usdc/.usdz, directly in it) viewers may open from the page, beside the built-ins;
    /// each is loaded as `--scene` would be (same size and plan options).
    #[arg(long, value_name = "DIR")]
    pub scene_dir: Option<PathBuf>,
}

/// Refinement while the live view is idle (`docs/live-view.md` § Refinement when idle): shared
/// by `coordinator --http` and `demo --serve`.
#[derive(Debug, Clone, clap::Args)]
pub(crate) struct RefineArgs {
    /// Live view: once no viewer has changed anything for MS milliseconds, render the frame
    /// again at a higher quality, one step a frame (the samples per area light doubled, then the
    /// antialiasing factor doubled, up to their caps); any input drops back to the session's
    /// quality (its frame budget's) in the next frame.
    #[arg(long, value_name = "MS", default_value_t = 500)]
    pub refine_after: u64,
    /// Live view: no refinement while idle.
    #[arg(long)]
    pub no_refine: bool,
    /// Live view: the samples per area light refinement doubles up to (default: 4 × the
    /// scene's largest count, at most 256).
    #[arg(long, value_name = "N",
          value_parser = clap::value_parser!(u32).range(1..=i64::from(lightfold_scene::limits::MAX_SAMPLES_PER_AREA_LIGHT)))]
    pub refine_max_samples: Option<u32>,
    /// Live view: the antialiasing factor refinement doubles up to once the samples are at
    /// their cap (1: no antialiasing step).
    #[arg(long, value_name = "N", default_value_t = 2,
          value_parser = clap::value_parser!(u32).range(1..=16))]
    pub refine_max_aa: u32,
}

impl RefineArgs {
    /// The view's refinement (`None`: `--no-refine`).
    pub(crate) fn options(&self) -> Option<lightfold_view::RefineOptions> {
        (!self.no_refine).then(|| lightfold_view::RefineOptions {
            after: std::time::Duration::from_millis(self.refine_after),
            max_samples: self.refine_max_samples.unwrap_or(0),
            max_supersample: self.refine_max_aa,
        })
    }

    /// The same flags for a coordinator started by `demo`.
    pub(crate) fn to_args(&self) -> Vec<std::ffi::OsString> {
        let mut a: Vec<std::ffi::OsString> = Vec::new();
        if self.no_refine {
            a.push("--no-refine".into());
        }
        a.push("--refine-after".into());
        a.push(self.refine_after.to_string().into());
        if let Some(n) = self.refine_max_samples {
            a.push("--refine-max-samples".into());
            a.push(n.to_string().into());
        }
        a.push("--refine-max-aa".into());
        a.push(self.refine_max_aa.to_string().into());
        a
    }
}

/// Who may see the live view, and over what (`docs/live-view.md` § Access): shared by
/// `coordinator --http` and `demo --serve`.
#[derive(Debug, Clone, Default, clap::Args)]
pub(crate) struct ViewAccessArgs {
    /// Live view (`--http`, `demo --serve`): let viewers beyond loopback watch without the
    /// token: frames and the cluster's status, with daemon addresses removed (steering still
    /// needs the token). Default: they get the page and nothing more until they present it.
    #[arg(long)]
    pub public_watch: bool,
    /// Live view: serve it over HTTPS and WSS with this certificate chain (PEM); needs
    /// `--tls-key`.
    #[arg(long, value_name = "PEM", requires = "tls_key")]
    pub tls_cert: Option<PathBuf>,
    /// Live view: the private key of `--tls-cert` (PEM: PKCS#8, PKCS#1 or SEC1); needs
    /// `--tls-cert`.
    #[arg(long, value_name = "PEM", requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
    /// Live view without TLS: accept the token from viewers beyond loopback anyway (it then
    /// crosses the network readable). Default: refused there, so the token is only sent over
    /// TLS or on loopback.
    #[arg(long)]
    pub allow_plain_token: bool,
}

impl ViewAccessArgs {
    /// The certificate and key, both or neither.
    pub(crate) fn tls(&self) -> anyhow::Result<Option<lightfold_view::TlsFiles>> {
        match (&self.tls_cert, &self.tls_key) {
            (Some(cert), Some(key)) => Ok(Some(lightfold_view::TlsFiles {
                cert: cert.clone(),
                key: key.clone(),
            })),
            (None, None) => Ok(None),
            _ => bail!("--tls-cert and --tls-key go together: give both, or neither"),
        }
    }

    /// The same flags for a coordinator started by `demo` (paths made absolute).
    pub(crate) fn to_args(&self) -> Vec<std::ffi::OsString> {
        let abs = |p: &PathBuf| std::path::absolute(p).unwrap_or_else(|_| p.clone());
        let mut a: Vec<std::ffi::OsString> = Vec::new();
        if self.public_watch {
            a.push("--public-watch".into());
        }
        if let (Some(cert), Some(key)) = (&self.tls_cert, &self.tls_key) {
            a.push("--tls-cert".into());
            a.push(abs(cert).into());
            a.push("--tls-key".into());
            a.push(abs(key).into());
        }
        if self.allow_plain_token {
            a.push("--allow-plain-token".into());
        }
        a
    }
}

impl ViewArgs {
    /// Binds the view's listener, if asked for, and says where it is. `scene` is how the
    /// session's scene was named (`--scene`), what a saved session names as its base.
    pub(crate) async fn bind(
        &self,
        cluster_token: &[u8],
        job: &JobArgs,
    ) -> anyhow::Result<Option<lightfold_view::View>> {
        let Some(listen) = &self.http else {
            return Ok(None);
        };
        if let Some(dir) = &self.scene_dir
            && !dir.is_dir()
        {
            bail!("--scene-dir {}: not a folder", dir.display());
        }
        let scene = job.scene.as_str();
        // A scene a viewer picks is loaded as `--scene` is, with its own error model.
        let picked = job.clone();
        let scenes = lightfold_view::SceneCatalog {
            dir: self.scene_dir.clone(),
            open: Box::new(move |source: &str| {
                let job = JobArgs {
                    scene: source.to_string(),
                    animation: None,
                    ..picked.clone()
                };
                let scene = job.load_scene()?;
                let options = job.plan_options_for(&scene)?;
                Ok(lightfold_view::Opened { scene, options })
            }),
        };
        let token = match &self.view_token_file {
            Some(f) => lightfold_net::load_token(Some(f))?,
            None => cluster_token.to_vec(),
        };
        let view = lightfold_view::View::bind(lightfold_view::ViewOptions {
            listen: listen.clone(),
            token: Some(token),
            continuous: self.continuous,
            refine: self.refine.options(),
            jpeg_quality: self.jpeg_quality,
            public_watch: self.access.public_watch,
            tls: self.access.tls()?,
            allow_plain_token: self.access.allow_plain_token,
            scene_source: Some(scene.to_string()),
            scenes: Some(std::sync::Arc::new(scenes)),
            ..lightfold_view::ViewOptions::default()
        })
        .await?;
        outln!("{}", view.address_line());
        Ok(Some(view))
    }
}

/// What to render and how: shared by `coordinator` and `demo`, which hands it to its
/// coordinator as a job file (`--job-file`, JSON).
#[derive(Debug, Clone, clap::Args, serde::Serialize, serde::Deserialize)]
pub(crate) struct JobArgs {
    /// Built-in scene name, scene file (.toml) or model (.gltf/.glb, .obj, .ply,
    /// .usda/.usdc/.usdz).
    #[arg(long, default_value = lightfold_scene::defaults::DEFAULT_SCENE)]
    pub scene: String,
    /// The glTF animation to play, by name or index (a `--scene` .gltf/.glb with several
    /// clips; the first when not given). A scene file names it in its `[gltf]` table.
    #[arg(long, value_name = "NAME")]
    pub animation: Option<String>,
    #[command(flatten)]
    #[serde(flatten)]
    pub(crate) plan: crate::plan_args::PlanArgs,
    /// Frames to render (at least 1).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    pub frames: u32,
    /// Orbit the camera by this many degrees per frame (a camera path).
    #[arg(long)]
    pub orbit: Option<f32>,
    /// Scene time of the first frame in seconds: an animated scene (glTF clip, scene-file
    /// motions) is posed at it (default: its rest pose; 0 with `--fps`).
    #[arg(long, value_parser = crate::coordinator_cmd::finite_seconds)]
    pub time: Option<f32>,
    /// Animation frames per second: frame i is at `--time` + i / fps, so the scene moves with
    /// the frames.
    #[arg(long, value_parser = crate::coordinator_cmd::positive_fps)]
    pub fps: Option<f32>,
    /// Keep shadow maps between frames (static lights and geometry).
    #[arg(long)]
    pub walkthrough: bool,
    /// Frames requested ahead of the one being finished: 2 keeps every stage busy (the
    /// pipelined rate of the slowest stage), 1 shortens the live view's latency at lower rate.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=8))]
    pub frames_in_flight: u32,
    /// PNG output (sRGB at the scene's exposure).
    #[arg(long, default_value = "out.png")]
    pub out: PathBuf,
    /// EXR output (linear radiance).
    #[arg(long, default_value = "out.exr")]
    pub exr: PathBuf,
    /// Where every frame of a camera path (`--frames` > 1) is written as it completes, PNG and
    /// EXR: a path with `%d` or `%0Nd` for the frame number, without extension (`--out` and
    /// `--exr` always hold the newest complete frame). Given explicitly, also for one frame and
    /// for the live view.
    #[arg(long, value_name = "PATTERN", conflicts_with = "frame_dir")]
    pub frame_pattern: Option<String>,
    /// Shorthand for `--frame-pattern DIR/frame-%04d`.
    #[arg(long, value_name = "DIR")]
    pub frame_dir: Option<PathBuf>,
    /// Keep only `--out`/`--exr`, not every frame.
    #[arg(long, conflicts_with_all = ["frame_pattern", "frame_dir"])]
    pub no_frame_files: bool,
    /// After the run, assemble the frames' PNGs into this video with `ffmpeg` (on the PATH).
    #[arg(long, value_name = "FILE", conflicts_with = "no_frame_files")]
    pub video: Option<PathBuf>,
    /// Frames per second of `--video` (default: `--fps`, so an animation plays at its own speed;
    /// 24 without it).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=240))]
    pub video_fps: Option<u32>,
    /// Print the full plan (every node, light, stage and link) and one line per frame after the
    /// run, instead of the plan in a few lines.
    #[arg(long, short = 'v')]
    pub verbose: bool,
    /// Write one JSON line per frame here as frames arrive: latency, interval and each daemon's
    /// phase times (ms), bytes and memory (`docs/operations.md`).
    #[arg(long, value_name = "FILE")]
    pub stats: Option<PathBuf>,
    /// Write the last plan the run rendered with here, as JSON (the samples it rendered, K, the
    /// nodes and stages, what a frame budget gave up).
    #[arg(long, value_name = "FILE")]
    pub plan_json: Option<PathBuf>,
    /// Go on with a camera path or animation a coordinator did not finish: the frames whose PNG
    /// and EXR are already under the frame pattern are skipped (frames are renamed into place
    /// complete), the others rendered with their own numbers, cameras and times; nothing written
    /// is overwritten.
    #[arg(long, conflicts_with = "no_frame_files")]
    pub resume: bool,
}

/// The largest job file read (a job is a few kilobytes).
const MAX_JOB_FILE: u64 = 1 << 20;

impl JobArgs {
    /// The job with every flag at its default, as `lightfold coordinator` alone parses it.
    pub(crate) fn defaults() -> JobArgs {
        use clap::{Args as _, FromArgMatches as _};
        let cmd = JobArgs::augment_args(clap::Command::new("job"));
        JobArgs::from_arg_matches(&cmd.get_matches_from(["job"]))
            .expect("every job flag has a default")
    }

    /// Writes the job as a job file (JSON) for `--job-file`.
    pub(crate) fn write(&self, path: &Path) -> anyhow::Result<()> {
        let text = serde_json::to_string_pretty(self)?;
        std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
    }

    /// The job of a job file; `flags` (the job's flags as parsed) must all be at their defaults:
    /// a job file replaces them, so a flag given beside it would be ignored silently.
    pub(crate) fn from_file(path: &Path, flags: &JobArgs) -> anyhow::Result<JobArgs> {
        let defaults = serde_json::to_value(JobArgs::defaults())?;
        if serde_json::to_value(flags)? != defaults {
            bail!(
                "--job-file replaces the job's flags (--scene, -K, --frames, …): give one or the other"
            );
        }
        let bytes = lightfold_scene::read_bounded(path, MAX_JOB_FILE)
            .map_err(|e| anyhow::anyhow!("cannot read the job file {}: {e}", path.display()))?;
        let job: JobArgs = serde_json::from_slice(&bytes)
            .with_context(|| format!("{} is not a job file", path.display()))?;
        job.check()
            .map_err(|e| anyhow::anyhow!("the job file {}: {e}", path.display()))?;
        Ok(job)
    }

    /// What the flags' parsers and conflicts check, for a job that did not come through them
    /// (a job file).
    fn check(&self) -> Result<(), String> {
        let within = |v: u32, lo: u32, hi: u32, flag: &str| {
            if (lo..=hi).contains(&v) {
                Ok(())
            } else {
                Err(format!("{flag} {v} is not in {lo}..={hi}"))
            }
        };
        within(self.frames, 1, u32::MAX, "--frames")?;
        within(self.frames_in_flight, 1, 8, "--frames-in-flight")?;
        if let Some(v) = self.video_fps {
            within(v, 1, 240, "--video-fps")?;
        }
        if let Some(t) = self.time {
            finite_seconds(&t.to_string())?;
        }
        if let Some(f) = self.fps {
            positive_fps(&f.to_string())?;
        }
        self.plan.check()?;
        let patterned = self.frame_pattern.is_some() || self.frame_dir.is_some();
        if self.frame_pattern.is_some() && self.frame_dir.is_some() {
            return Err("--frame-pattern and --frame-dir together".into());
        }
        if self.no_frame_files && (patterned || self.video.is_some() || self.resume) {
            return Err("--no-frame-files with frame files asked for".into());
        }
        Ok(())
    }

    /// The frames `--resume` skips: those already complete under the frame pattern.
    pub(crate) fn resumed(&self, serving: bool) -> anyhow::Result<Vec<u64>> {
        if !self.resume {
            return Ok(Vec::new());
        }
        if serving {
            bail!("--resume goes on with a camera path; the live view has none");
        }
        let Some(pattern) = self.frame_files(serving)? else {
            bail!("--resume needs the frames' files (--frame-dir or --frame-pattern)");
        };
        Ok(pattern.complete(self.frames))
    }

    pub(crate) fn load_scene(&self) -> anyhow::Result<lightfold_scene::Scene> {
        let mut scene = lightfold_scene::load_with_clip(&self.scene, self.animation.as_deref())
            .with_context(|| format!("cannot load scene {:?}", self.scene))?;
        self.plan.apply(&mut scene)?;
        Ok(scene)
    }

    /// The plan options of the job: the planning flags' (`PlanArgs::plan_options`) with the
    /// job's walkthrough and frames in flight.
    pub(crate) fn plan_options(&self) -> PlanOptions {
        PlanOptions {
            walkthrough: self.walkthrough,
            frames_in_flight: self.frames_in_flight,
            ..self.plan.plan_options()
        }
    }

    /// [`JobArgs::plan_options`] with the error model for `scene` (`--error-model`: a
    /// calibration of it sets the default error target).
    pub(crate) fn plan_options_for(
        &self,
        scene: &lightfold_scene::Scene,
    ) -> anyhow::Result<PlanOptions> {
        let mut o = self.plan_options();
        self.plan.model.apply(scene, &mut o)?;
        Ok(o)
    }

    /// Frames per second of `--video`: `--video-fps`, else the animation's `--fps`, else 24.
    pub(crate) fn video_rate(&self) -> f32 {
        match (self.video_fps, self.fps) {
            (Some(v), _) => v as f32,
            (None, Some(fps)) => fps,
            (None, None) => 24.0,
        }
    }

    /// Where every frame goes, if anywhere: the pattern given, or the default for a camera path
    /// (`serving`: the live view keeps every frame only when asked to).
    pub(crate) fn frame_files(&self, serving: bool) -> anyhow::Result<Option<FramePattern>> {
        if self.no_frame_files {
            return Ok(None);
        }
        let given = match (&self.frame_pattern, &self.frame_dir) {
            (Some(p), _) => Some(p.clone()),
            (None, Some(d)) => Some(d.join("frame-%04d").to_string_lossy().into_owned()),
            (None, None) => None,
        };
        let pattern = match given {
            Some(p) => p,
            None if (self.frames > 1 && !serving) || self.video.is_some() => {
                lightfold_coordinator::frames_out::DEFAULT_PATTERN.to_string()
            }
            None => return Ok(None),
        };
        FramePattern::parse(&pattern).map(Some)
    }

    /// Where the job's results go (`serving`: the live view drives the frames).
    pub(crate) fn output(&self, serving: bool, shutdown: bool) -> anyhow::Result<JobOutput> {
        Ok(JobOutput {
            out: self.out.clone(),
            exr: self.exr.clone(),
            every: self.frame_files(serving)?,
            plan_json: self.plan_json.clone(),
            stats: self.stats.clone(),
            verbose: self.verbose,
            video: self.video.clone().map(|v| (v, self.video_rate())),
            shutdown,
        })
    }

    pub(crate) fn path(&self) -> FramePath {
        match self.orbit {
            Some(d) => FramePath::Orbit { degrees: d },
            None => FramePath::Still,
        }
    }
}

/// A scene time in seconds: any finite number (`--time`).
pub(crate) fn finite_seconds(s: &str) -> Result<f32, String> {
    match s.parse::<f32>() {
        Ok(t) if t.is_finite() => Ok(t),
        _ => Err(format!("{s:?} is not a finite number of seconds")),
    }
}

/// Frames per second: finite and positive (`--fps`).
pub(crate) fn positive_fps(s: &str) -> Result<f32, String> {
    match s.parse::<f32>() {
        Ok(f) if f.is_finite() && f > 0.0 => Ok(f),
        _ => Err(format!(
            "{s:?} is not a positive number of frames per second"
        )),
    }
}

pub(crate) fn run_cmd(mut args: Args) -> anyhow::Result<()> {
    if let Some(path) = &args.job_file {
        args.job = JobArgs::from_file(path, &args.job)?;
    }
    let token = lightfold_net::load_token(args.token_file.as_deref())?;
    let (daemons, sink_listen, sink_advertise) = match &args.cluster {
        Some(path) => {
            let f = ClusterFile::load(path)?;
            let d = f.daemons();
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
            frames_in_flight: args.job.frames_in_flight as usize,
            ..ControlOptions::default()
        };
        let opts = RunOptions {
            plan: args.job.plan_options_for(&scene)?,
            frames: args.job.frames,
            path: args.job.path(),
            color_changes: Vec::new(),
            control,
            time: args.job.time,
            fps: args.job.fps,
            skip: args.job.resumed(args.view.http.is_some())?,
        };
        if args.job.resume {
            outln!(
                "resuming: {} of {} frame(s) already written; rendering the other {}",
                opts.skip.len(),
                opts.frames,
                opts.frames as usize - opts.skip.len()
            );
            if opts.skip.len() == opts.frames as usize {
                return Ok(());
            }
        }
        let view = args.view.bind(&token, &args.job).await?;
        let me = Identity::new(&token, Role::Coordinator, "coordinator");
        let cancel = crate::lifecycle::shutdown_token(args.parent_pid);
        lightfold_view::metrics::start(
            args.metrics.metrics_listen.as_deref(),
            "coordinator",
            "coordinator",
            cancel.clone(),
        )
        .await?;
        lightfold_telemetry::health::set_live(true);
        let connect = Session::connect(&daemons, listener, sink_advertise, me, control);
        let session = tokio::select! {
            r = connect => r?,
            _ = cancel.cancelled() => {
                return Err(crate::lifecycle::Interrupted(
                    "interrupted before the cluster was reached".into(),
                )
                .into());
            }
        };
        // Ctrl-C from here on: no new frame is requested, the frames in flight are finished and
        // written, and the summary is printed.
        let mut session = session;
        let output = args.job.output(view.is_some(), args.shutdown)?;
        let mut console = Console::start(&session, &scene, &opts, output, view.is_some())?;
        let on_frame = |f| console.frame(f);
        let outcome = match view {
            None => render_until(&mut session, &scene, &opts, cancel.clone(), on_frame).await,
            Some(v) => {
                v.run_with(&mut session, &scene, &opts.plan, cancel.clone(), on_frame)
                    .await
            }
        };
        console.finish(session, outcome, &cancel).await
    })
}

fn seconds(v: f64, what: &str) -> anyhow::Result<Duration> {
    if !(v.is_finite() && (0.0..1e7).contains(&v)) {
        bail!("{what} {v} is not a number of seconds");
    }
    Ok(Duration::from_secs_f64(v))
}

#[cfg(test)]
mod tests {
    use super::JobArgs;
    use crate::plan_args::{LinkClass, parse_link_format};
    use clap::Parser;
    use lightfold_protocol::PixelFormat;

    #[derive(Debug, clap::Parser)]
    struct Job {
        #[command(flatten)]
        job: JobArgs,
    }

    #[test]
    fn animation_picks_a_glb_clip_and_is_refused_elsewhere() {
        let fox = concat!(env!("CARGO_MANIFEST_DIR"), "/../assets/Fox/Fox.glb");
        let load = |args: &[&str]| {
            let mut all = vec!["job"];
            all.extend_from_slice(args);
            Job::try_parse_from(all).unwrap().job.load_scene()
        };
        let clip = |args: &[&str]| load(args).unwrap().animation.map(|a| a.name);
        // The first clip by default; others by name or index.
        assert_eq!(clip(&["--scene", fox]).as_deref(), Some("Survey"));
        assert_eq!(
            clip(&["--scene", fox, "--animation", "Run"]).as_deref(),
            Some("Run")
        );
        assert_eq!(
            clip(&["--scene", fox, "--animation", "1"]).as_deref(),
            Some("Walk")
        );
        let err = format!(
            "{:#}",
            load(&["--scene", fox, "--animation", "Fly"]).unwrap_err()
        );
        assert!(
            err.contains("no animation \"Fly\"") && err.contains("\"Run\""),
            "{err}"
        );
        let err = format!(
            "{:#}",
            load(&["--scene", "carousel", "--animation", "Run"]).unwrap_err()
        );
        assert!(err.contains("[gltf] table"), "{err}");
    }

    #[test]
    fn a_video_plays_at_the_animation_rate_unless_told_otherwise() {
        let rate = |args: &[&str]| {
            let mut all = vec!["job"];
            all.extend_from_slice(args);
            Job::try_parse_from(all).unwrap().job.video_rate()
        };
        assert_eq!(rate(&[]), 24.0);
        assert_eq!(rate(&["--fps", "8"]), 8.0);
        assert_eq!(rate(&["--fps", "8", "--video-fps", "30"]), 30.0);
        assert_eq!(rate(&["--video-fps", "12"]), 12.0);
    }

    #[test]
    fn link_formats_parse_per_class() {
        assert_eq!(
            parse_link_format("chain=f32x6"),
            Ok((LinkClass::Chain, PixelFormat::F32x6))
        );
        assert_eq!(
            parse_link_format("node=seed64"),
            Ok((LinkClass::Node, PixelFormat::Seed64))
        );
        assert_eq!(
            parse_link_format("material=rgba8srgb"),
            Ok((LinkClass::Material, PixelFormat::Rgba8Srgb))
        );
        assert_eq!(
            parse_link_format("sink=f16x4"),
            Ok((LinkClass::Sink, PixelFormat::F16x4))
        );
        // A format that cannot carry the class's channels, an unknown class or format.
        for bad in [
            "node=f16x4",
            "material=f32x6",
            "sink=depth32",
            "edge=f16x6",
            "chain=f8",
            "f16x6",
        ] {
            let e = parse_link_format(bad).unwrap_err();
            assert!(!e.is_empty(), "{bad}");
        }
        assert!(
            parse_link_format("node=f16x4")
                .unwrap_err()
                .contains("rgb9e5x2")
        );
    }
}
