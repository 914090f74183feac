//! `lightfold demo` (alias `cluster up`): a local multi-process cluster in one command. Plans the
//! scene to learn how many nodes and compositors it needs, spawns them as separate processes on
//! loopback, runs the coordinator as another process, then compares the image with the CPU
//! reference and shuts every process down — also on Ctrl-C; children also exit on their own if
//! this process dies (`--parent-pid`). The token, cluster file and pid list live in a temporary
//! directory removed on the way out (kept with `--work-dir`).
//!
//! The daemons run in a process group of their own, so a Ctrl-C at the terminal reaches this
//! process and the coordinator only: the coordinator finishes the frames in flight with every
//! daemon still up and prints its summary, then this process stops the daemons.

use crate::coordinator_cmd::JobArgs;
use anyhow::{Context, bail};
use lightfold_coordinator::plan::{ClusterSpec, Plan, plan};
use lightfold_harness::launcher::{
    ANY_PORT, Launcher, cluster_file, cpu_seconds, send_signal, write_token,
};
use lightfold_harness::local_cluster::{check_processes, on_this_machine, with_memory};
use lightfold_scene::Image;
use lightfold_telemetry::outln;
use rustix::process::Signal;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::Instant;

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    #[command(flatten)]
    pub job: JobArgs,
    /// Lavapipe threads per render node (LP_NUM_THREADS); 0 leaves Mesa's default.
    #[arg(long, default_value_t = 1)]
    pub gpu_threads: u32,
    /// Skip the comparison with the CPU reference.
    #[arg(long)]
    pub no_compare: bool,
    /// Log filter for the spawned daemons and coordinator (their logs go to stderr).
    #[arg(long, default_value = "warn")]
    pub daemon_log: String,
    /// Directory for the token, cluster file and pid list, kept afterwards (default: a fresh
    /// temporary directory, removed when the demo ends).
    #[arg(long)]
    pub work_dir: Option<PathBuf>,
    /// Most processes the demo may start: render nodes, compositors and the coordinator. A
    /// scene that needs more is refused before anything starts, with the -K that would fit.
    /// Default: 4 per CPU core, at least 32 (the default scene needs 17: 8 nodes, 8
    /// compositors and the coordinator).
    #[arg(long, value_name = "N")]
    pub max_processes: Option<usize>,
    /// Serve the live view on ADDR (default 127.0.0.1:8080) and run until stopped (Ctrl-C):
    /// open the printed address in a browser to watch and steer the cluster.
    #[arg(long, value_name = "ADDR", num_args = 0..=1,
          default_missing_value = lightfold_view::DEFAULT_LISTEN)]
    pub serve: Option<String>,
    /// With `--serve`: render frame after frame even when nothing changed.
    #[arg(long, requires = "serve")]
    pub continuous: bool,
    /// With `--serve`: who may see the view, and over what (as `coordinator --http`).
    #[command(flatten)]
    pub view_access: crate::coordinator_cmd::ViewAccessArgs,
    /// With `--serve`: refinement while the view is idle (as `coordinator --http`).
    #[command(flatten)]
    pub refine: crate::coordinator_cmd::RefineArgs,
    /// With `--serve`: a folder whose scene files and models viewers may open from the page,
    /// beside the built-ins (as `coordinator --scene-dir`). The cluster is the one started for
    /// `--scene`: a scene it cannot plan is refused, and the view stays on the scene it had.
    #[arg(long, value_name = "DIR", requires = "serve")]
    pub scene_dir: Option<PathBuf>,
    /// Every daemon and the coordinator serve `/metrics`, `/healthz` and `/readyz` on a loopback
    /// port of its own (`--metrics-listen`; the addresses are printed).
    #[arg(long)]
    pub metrics: bool,
}

/// What the Ctrl-C handler needs: the coordinator once it runs (SIGINT is passed on to it), and
/// before that the temporary directory to remove on the way out.
#[derive(Debug, Default)]
struct Interrupt {
    coordinator: Option<u32>,
    temp: Option<PathBuf>,
}

/// Watches for Ctrl-C for the whole demo. Once the coordinator runs, SIGINT is passed on to it
/// (it finishes its frames and this process cleans up as it returns); before that, the temporary
/// directory is removed and the demo exits (the daemons follow by `--parent-pid`).
fn watch_interrupt(state: Arc<Mutex<Interrupt>>) {
    std::thread::spawn(move || {
        let Ok(rt) = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
        else {
            return;
        };
        rt.block_on(async {
            // SIGTERM (a service manager, `kill`) stops the run as Ctrl-C does: the frames done
            // are kept and nothing is left in the temporary folder.
            let mut term =
                tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()).ok();
            let terminated = async |t: &mut Option<tokio::signal::unix::Signal>| match t {
                Some(t) => t.recv().await,
                None => std::future::pending().await,
            };
            loop {
                let got = tokio::select! {
                    r = tokio::signal::ctrl_c() => r.is_ok(),
                    r = terminated(&mut term) => r.is_some(),
                };
                if !got {
                    break;
                }
                let s = state.lock().unwrap_or_else(|e| e.into_inner());
                match s.coordinator {
                    Some(pid) => {
                        send_signal(pid, Signal::INT);
                    }
                    None => {
                        if let Some(dir) = &s.temp {
                            let _ = std::fs::remove_dir_all(dir);
                        }
                        eprintln!("demo: interrupted");
                        std::process::exit(crate::lifecycle::INTERRUPTED_EXIT);
                    }
                }
            }
        });
    });
}

pub(crate) fn run(args: Args) -> anyhow::Result<()> {
    let started = Instant::now();
    // A certificate or key the view cannot use fails here, before any daemon starts.
    if args.serve.is_some()
        && let Some(tls) = args.view_access.tls()?
    {
        lightfold_view::check_tls(&tls)?;
    }
    let interrupt = Arc::new(Mutex::new(Interrupt::default()));
    watch_interrupt(Arc::clone(&interrupt));
    let (scene, nodes, compositors) = size_cluster(&args)?;
    // Removed when dropped: on every way out of this function, errors and panics included.
    let (temp, dir) = work_dir(&args)?;
    interrupt.lock().unwrap_or_else(|e| e.into_inner()).temp = temp.as_ref().map(|_| dir.clone());
    let token_path = dir.join("token");
    write_token(&token_path)?;
    let launcher = Launcher {
        gpu_threads: args.gpu_threads,
        metrics: args.metrics,
        ..Launcher::this_exe(token_path.clone(), &args.daemon_log)?
    };
    let (children, daemons) = launcher.start_cluster(nodes, compositors)?;
    let cluster = dir.join("cluster.toml");
    std::fs::write(&cluster, cluster_file(&daemons))?;
    let (mut coord, plan_json) =
        coordinator_command(&launcher.exe, &args, &cluster, &token_path, &dir)?;
    let mut child = coord
        .stdout(Stdio::inherit())
        .stderr(Stdio::inherit())
        .spawn()
        .context("cannot start the coordinator")?;
    // Every process this demo started, so tests (and people) can check none is left behind.
    let pids: String = children
        .0
        .iter()
        .map(|(name, c)| format!("{name} {}\n", c.id()))
        .chain(std::iter::once(format!("coordinator {}\n", child.id())))
        .collect();
    std::fs::write(dir.join("pids"), pids)?;
    // Ctrl-C at the terminal reaches the coordinator too (this process's group, not the
    // daemons'); this process waits for it to finish its frames and print its summary, then
    // stops the daemons. A SIGINT sent to this process alone is passed on.
    interrupt
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .coordinator = Some(child.id());
    let status = child.wait()?;
    // From here a Ctrl-C ends the demo (the daemons follow by `--parent-pid`).
    interrupt
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .coordinator = None;
    // Daemons are still up (the coordinator detached): read what CPU time they used.
    let cpu: Vec<(String, f64)> = children
        .0
        .iter()
        .map(|(n, c)| (n.clone(), cpu_seconds(c.id())))
        .collect();
    drop(children);
    let rendered = read_plan(&plan_json);
    if let Some(t) = temp {
        let path = t.path().display().to_string();
        t.close().with_context(|| format!("cannot remove {path}"))?;
    }
    if status.code() == Some(crate::lifecycle::INTERRUPTED_EXIT) {
        // The coordinator said how far it got, in the one line an interrupted run ends with.
        return Err(crate::lifecycle::Interrupted(String::new()).into());
    }
    if !status.success() {
        bail!("the coordinator failed ({status})");
    }
    outln!(
        "demo: cluster finished in {:.2} s (all daemons stopped)",
        started.elapsed().as_secs_f64()
    );
    print_cpu(&cpu, args.job.frames);
    if args.serve.is_some() {
        return Ok(());
    }
    if !args.no_compare {
        compare_last_frame(&args, &scene, rendered.as_ref())?;
    }
    Ok(())
}

/// Loads the job's scene and plans it against a large synthetic cluster, returning the scene
/// with the number of render nodes and compositors the plan uses; says so, and fails when
/// that is more processes than the demo may start.
fn size_cluster(args: &Args) -> anyhow::Result<(lightfold_scene::Scene, usize, usize)> {
    // The coordinator loads the scene again and says what it makes of it (a glTF's ignored
    // features, geometry sanitised): loaded quietly here, so it is said once.
    let scene =
        tracing::subscriber::with_default(tracing::subscriber::NoSubscriber::default(), || {
            args.job.load_scene()
        })?;
    // Plan against a large synthetic cluster to learn what this scene needs: partitioned as the
    // coordinator will partition it (its nodes, all on this machine, report this machine's
    // memory), large meshes in chunks.
    let mut options = args.job.plan_options_for(&scene)?;
    options.partitions = lightfold_coordinator::plan::partitions_for(
        &scene,
        &with_memory(ClusterSpec::local(256, 256)),
        &options,
    );
    let probe_cluster = on_this_machine(ClusterSpec::local(256, 256));
    let probe = plan(
        &lightfold_coordinator::plan::scene_for(&scene, &probe_cluster, &options),
        &probe_cluster,
        &options,
    )?;
    let nodes = probe.nodes.len();
    let compositors = probe.stages.len();
    check_processes(&scene, &options, &probe, args.max_processes)
        .map_err(|e| anyhow::anyhow!("demo: {e}"))?;
    outln!(
        "demo: scene {:?} needs {} render node(s) and {} compositor(s); starting them on loopback",
        scene.name,
        nodes,
        compositors
    );
    Ok((scene, nodes, compositors))
}

/// The directory for the token, cluster file and pid list: `--work-dir`, created if missing,
/// or a fresh temporary directory returned with the guard that removes it.
fn work_dir(args: &Args) -> anyhow::Result<(Option<tempfile::TempDir>, PathBuf)> {
    Ok(match &args.work_dir {
        Some(d) => {
            std::fs::create_dir_all(d).with_context(|| format!("cannot create {}", d.display()))?;
            (None, d.clone())
        }
        None => {
            let t = tempfile::Builder::new()
                .prefix("lightfold-demo-")
                .tempdir()
                .context("cannot create a temporary directory")?;
            let path = t.path().to_path_buf();
            (Some(t), path)
        }
    })
}

/// The coordinator's command line for the job (written to `dir/job.json`) over the cluster file, and the path its last
/// plan is written to (`--plan-json`, in `dir` unless the job names one).
fn coordinator_command(
    exe: &Path,
    args: &Args,
    cluster: &Path,
    token_path: &Path,
    dir: &Path,
) -> anyhow::Result<(Command, PathBuf)> {
    let mut coord = Command::new(exe);
    coord
        .arg("--log")
        .arg(&args.daemon_log)
        .arg("coordinator")
        .arg("--cluster")
        .arg(cluster)
        .arg("--token-file")
        .arg(token_path)
        // Many daemons opening devices at once on few cores answer slowly at first.
        .arg("--connect-timeout")
        .arg("180");
    // The last plan, for what the comparison below says it compares.
    let mut job = args.job.clone();
    let plan_json = job
        .plan_json
        .get_or_insert_with(|| dir.join("plan.json"))
        .clone();
    // The job travels as a file, not as its flags spelt out again.
    let job_file = dir.join("job.json");
    job.write(&job_file)?;
    coord.arg("--job-file").arg(&job_file);
    if let Some(addr) = &args.serve {
        coord.arg("--http").arg(addr);
        if args.continuous {
            coord.arg("--continuous");
        }
        coord.args(args.view_access.to_args());
        coord.args(args.refine.to_args());
        if let Some(dir) = &args.scene_dir {
            coord.arg("--scene-dir").arg(dir);
        }
    }
    if args.metrics {
        coord.args(["--metrics-listen", ANY_PORT]);
    }
    coord
        .arg("--parent-pid")
        .arg(std::process::id().to_string());
    Ok((coord, plan_json))
}

/// Compares the image the cluster wrote (the last frame's) with the CPU reference for that
/// frame, summing the samples the last plan says the cluster rendered where they can stand in
/// for the scene's.
fn compare_last_frame(
    args: &Args,
    scene: &lightfold_scene::Scene,
    rendered: Option<&Plan>,
) -> anyhow::Result<()> {
    // The image written is the last frame's: on a camera path, compare it with the
    // reference seen from that frame's camera.
    // On an animation, the scene posed at that frame's time.
    let frames = args.job.frames.max(1);
    let clock = lightfold_coordinator::run::RunOptions {
        time: args.job.time,
        fps: args.job.fps,
        ..Default::default()
    };
    let (mut last, samples) = match clock.time_of(frames - 1) {
        // (A scene with indirect light is still: its samples include its VPLs.)
        Some(t) if scene.animation.is_some() => (scene.still_at(t), scene.samples_at(t)),
        _ => (scene.clone(), lightfold_scene::vpl::frame_samples(scene)),
    };
    last.camera = lightfold_coordinator::run::camera_at(&scene.camera, args.job.path(), frames - 1);
    // The samples the cluster rendered: a frame budget or an error target may have lowered
    // the scene's (the last plan says); the reference sums the same ones on a still scene.
    let n = samples.len();
    let (samples, which) = match rendered {
        Some(p) if p.samples.len() == n => (samples, format!("the same {n} point samples")),
        Some(p) if scene.animation.is_none() => (
            p.samples.clone(),
            format!(
                "the same {} point samples the cluster rendered ({} lowered the scene's {n})",
                p.samples.len(),
                lowered_by(&args.job)
            ),
        ),
        Some(p) => (
            samples,
            format!(
                "the scene's {n} point samples (the cluster rendered {}: {} lowered them; \
                 the error includes that difference)",
                p.samples.len(),
                lowered_by(&args.job)
            ),
        ),
        None => (samples, format!("the scene's {n} point samples")),
    };
    let filtered = rendered.and_then(|p| {
        if p.target.as_ref().is_some_and(|t| t.cell_filter) {
            Some((
                p,
                "each sample's shadow over its cell of the light (the cell filter)".to_string(),
            ))
        } else if p.penumbra_radius > 0 {
            Some((p, format!("the penumbra (radius {})", p.penumbra_radius)))
        } else {
            None
        }
    });
    if let Some((p, what)) = filtered {
        outln!(
            "the plan filters {what}: the difference to the point sum below includes the \
             filter's change, made to bring the image nearer the area lights the samples \
             stand for{}",
            p.target.as_ref().map_or_else(String::new, |t| format!(
                " ({:.1} dB penumbra PSNR against their truth expected by {})",
                t.expected_db,
                if t.calibrated {
                    "this scene's calibration"
                } else {
                    "the default scene's error model"
                }
            ))
        );
    }
    // A peeled plan is measured against every translucent layer in view (up to 16), so the
    // error includes what a capped peel count leaves out.
    let in_view = lightfold_coordinator::plan::depth_complexity(&last, 16);
    let peels = match rendered.and_then(|p| p.peels.as_ref()) {
        Some(c) if c.layers > 0 => {
            let all = in_view.max(c.layers);
            outln!(
                "the plan peels {} translucent layer(s); the reference peels {all} (every \
                 translucent surface in view: {in_view})",
                c.layers
            );
            all
        }
        _ => 0,
    };
    let exr = &args.job.exr;
    let test = Image::read_exr(exr).with_context(|| format!("cannot read {}", exr.display()))?;
    let aa = args.job.plan.aa;
    // A classic image of a scene with glass in view is also measured against the peeled truth
    // (glass as the eye sees it), the figure `--peels` improves; the classic renders are shared.
    let against_peeled = peels == 0 && in_view > 0;
    let wanted: &[u32] = if against_peeled {
        &[0, in_view]
    } else {
        &[peels]
    };
    let (metrics, seconds) =
        lightfold_quality::against_point_sum::measure_each(&last, &samples, &test, aa, wanted)?;
    outln!(
        "error against the CPU reference (exact sum over {which}, ray-traced shadows, {aa}×{aa} \
         rays per pixel; {seconds:.1} s on the CPU):"
    );
    outln!("{}", metrics[0]);
    if let Some(p) = metrics.get(1) {
        outln!(
            "against the reference with all {in_view} translucent layer(s) in view peeled \
             (glass as the eye sees it; `--peels auto` renders it): whole PSNR {:.2} dB, max \
             {:.3e}",
            p.whole.psnr,
            p.whole.max_abs
        );
    }
    Ok(())
}

/// The plan a coordinator wrote with `--plan-json`, `None` (said at debug level) when it cannot
/// be read: the comparison then names the scene's samples.
fn read_plan(path: &Path) -> Option<Plan> {
    /// Far above any plan's JSON (a plan of 4 096 samples and 256 nodes is about 2 MB).
    const MAX: u64 = 256 << 20;
    let read = || -> anyhow::Result<Plan> {
        let file = std::fs::File::open(path)?;
        let len = file.metadata()?.len();
        anyhow::ensure!(len <= MAX, "{len} bytes, over {MAX}");
        Ok(serde_json::from_reader(std::io::BufReader::new(file))?)
    };
    read()
        .inspect_err(|e| tracing::debug!("cannot read the plan {}: {e:#}", path.display()))
        .ok()
}

/// What lowers a plan's samples below the scene's, as the job asked for it.
fn lowered_by(job: &JobArgs) -> &'static str {
    match (
        job.plan.frame_budget.is_some(),
        job.plan.target_psnr.is_some(),
    ) {
        (true, true) => "the frame budget and the error target",
        (true, false) => "the frame budget",
        (false, true) => "the error target",
        (false, false) => "the plan",
    }
}

/// Daemon CPU per frame and the frame interval it implies on this machine's cores (start-up and
/// calibration included, so an upper estimate of the steady state).
fn print_cpu(cpu: &[(String, f64)], frames: u32) {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get()) as f64;
    let frames = frames.max(1) as f64;
    let total: f64 = cpu.iter().map(|(_, s)| s).sum();
    let nodes: f64 = cpu
        .iter()
        .filter(|(n, _)| n.starts_with("node"))
        .map(|(_, s)| s)
        .sum();
    outln!(
        "demo: daemon CPU {total:.2} s ({nodes:.2} s render nodes, {:.2} s compositors) over \
         {frames} frame(s): {:.3} CPU-s per frame, at least {:.3} s per frame on this machine's \
         {cores} core(s) (start-up included)",
        total - nodes,
        total / frames,
        total / frames / cores,
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        job: JobArgs,
    }

    #[test]
    fn the_coordinator_gets_the_job_it_was_given() {
        let given = [
            "demo",
            "--scene",
            "cornell",
            "--size",
            "64x48",
            "-K",
            "8",
            "--aa",
            "3",
            "--indirect",
            "96",
            "--indirect-clamp",
            "0.125",
            "--still",
            "--topology",
            "tree",
            "--frames",
            "3",
            "--walkthrough",
            "--force-all",
            "--shadow-map-size",
            "256",
            "--link-format",
            "chain=f32x6,material=rgba8srgb",
            "--frame-budget",
            "250",
            "--target-psnr",
            "42.5",
            "--plan-json",
            "plan.json",
            "--animation",
            "Run",
        ];
        let job = Cli::parse_from(given).job;
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("job.json");
        job.write(&file).unwrap();
        let none = Cli::parse_from(["coordinator"]).job;
        let back = JobArgs::from_file(&file, &none).unwrap();
        assert_eq!(format!("{back:?}"), format!("{job:?}"));
        // Control: a flag beside the job file would be ignored, so it is refused.
        let e = JobArgs::from_file(&file, &Cli::parse_from(["coordinator", "-K", "3"]).job)
            .unwrap_err()
            .to_string();
        assert!(e.contains("give one or the other"), "{e}");
    }

    #[test]
    fn a_bad_job_file_is_refused_with_what_is_wrong() {
        let dir = tempfile::tempdir().unwrap();
        let none = Cli::parse_from(["coordinator"]).job;
        let good = serde_json::to_value(&none).unwrap();
        let refused = |name: &str, text: &[u8]| -> String {
            let file = dir.path().join(name);
            std::fs::write(&file, text).unwrap();
            format!("{:#}", JobArgs::from_file(&file, &none).unwrap_err())
        };
        let with = |key: &str, v: serde_json::Value| {
            let mut j = good.clone();
            j[key] = v;
            serde_json::to_vec(&j).unwrap()
        };
        // What the flags' parsers refuse, a job file may not carry either.
        for (key, v, says) in [
            ("frames", serde_json::json!(0), "--frames 0"),
            (
                "frames_in_flight",
                serde_json::json!(99),
                "--frames-in-flight 99",
            ),
            ("partitions", serde_json::json!(100000), "expected auto"),
            ("target_psnr", serde_json::json!(-3.0), "not a PSNR"),
            ("frame_budget", serde_json::json!(0.0), "milliseconds"),
            (
                "penumbra_filter",
                serde_json::json!({"radius": 40}),
                "radius from 1 to 8",
            ),
            (
                "link_format",
                serde_json::json!([["Sink", "F16x6"]]),
                "not a format for sink",
            ),
        ] {
            let e = refused(key, &with(key, v));
            assert!(e.contains(says), "{key}: {e}");
        }
        assert!(refused("garbage", b"{not json").contains("is not a job file"));
        assert!(
            refused("huge", &vec![b' '; (1 << 20) + 10]).contains("more than the 1048576 bytes")
        );
        let e = format!(
            "{:#}",
            JobArgs::from_file(&dir.path().join("absent"), &none).unwrap_err()
        );
        assert!(e.contains("cannot read the job file"), "{e}");
        // Control: the defaults themselves pass.
        let file = dir.path().join("defaults.json");
        std::fs::write(&file, serde_json::to_vec(&good).unwrap()).unwrap();
        JobArgs::from_file(&file, &none).unwrap();
    }
}
