//! `lightfold soak --coordinator-kills N`: the coordinator as a process of its own over the
//! soak's daemons. A camera path of `--frames` frames is rendered by `lightfold coordinator
//! --frame-dir OUT/frames --resume --take-over`; the soak SIGKILLs the coordinator at N random
//! points (after some frames were written) and starts it again at once with `--resume`. Every
//! frame must end on disk exactly once — no frame file rewritten after it first appeared — and
//! equal the single-device render of its camera. Reports the restarts, what each resumed from,
//! and the largest gap between frames written, apart and across restarts.

use super::{Args, Checker, spawn_checker};
use crate::check::Check;
use crate::launcher::{Launcher, send_signal};
use anyhow::{Context, bail};
use lightfold_coordinator::frames_out::FramePattern;
use lightfold_coordinator::run::FramePath;
use lightfold_telemetry::outln;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rustix::process::Signal;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;
use std::process::{Child, Stdio};
use std::time::{Duration, Instant, SystemTime};

/// How often the frame folder is looked at.
const POLL: Duration = Duration::from_millis(50);
/// The whole run may take this long (a coordinator that never finishes is a failure).
const RUN_LIMIT: Duration = Duration::from_secs(3600);

/// A frame file as first seen: when, its modification time and size.
#[derive(Debug, Clone, Copy)]
struct Seen {
    at: Instant,
    modified: SystemTime,
    len: u64,
}

/// One coordinator process.
#[derive(Debug)]
struct Start {
    /// Frames complete on disk when it started, and when it was killed (`None`: it finished).
    resumed_from: usize,
    killed_at: Option<usize>,
    started: Instant,
    ended: Option<Instant>,
}

/// Runs the coordinator soak: starts the daemons the scene's plan needs, renders the camera
/// path with the coordinator killed and resumed at random points, then checks every frame
/// was written once and matches the single-device render, and writes the report.
pub(super) fn run(args: &Args, launcher: Launcher) -> anyhow::Result<()> {
    let frames = args.frames;
    if frames < 2 {
        bail!("--coordinator-kills needs --frames of at least 2");
    }
    // The coordinator loads the scene itself: its own samples per area light (not `--samples`).
    let mut scene = lightfold_scene::load(&args.scene)
        .with_context(|| format!("cannot load scene {:?}", args.scene))?;
    let (w, h) = super::parse_size(&args.size)?;
    (scene.camera.width, scene.camera.height) = (w, h);
    let scene = &scene;
    let plan_opts = lightfold_coordinator::plan::PlanOptions {
        lights_per_node: args.lights_per_node,
        ..Default::default()
    };
    let probe = lightfold_coordinator::plan::plan(
        scene,
        &lightfold_coordinator::plan::ClusterSpec::local(256, 256),
        &plan_opts,
    )?;
    let (nodes, compositors) = (probe.nodes.len(), probe.stages.len());
    let (children, daemons) = launcher.start_cluster(nodes, compositors)?;
    let addrs = |role: &str| -> Vec<String> {
        daemons
            .iter()
            .filter(|d| d.role == role)
            .map(|d| d.addr.clone())
            .collect()
    };
    let (node_addrs, comp_addrs) = (addrs("node"), addrs("compositor"));
    let dir = args.out.join("frames");
    if dir.exists() {
        std::fs::remove_dir_all(&dir)
            .with_context(|| format!("cannot empty the frame folder {}", dir.display()))?;
    }
    let pattern = FramePattern::parse(&dir.join("frame-%04d").to_string_lossy())?;
    let points = kill_points(args.seed, args.coordinator_kills, frames);
    outln!(
        "soak: {nodes} render node(s), {compositors} compositor(s); the coordinator is killed \
         when {points:?} of {frames} frames are on disk, and resumed"
    );
    let Outcome {
        seen,
        starts,
        mut failures,
    } = run_starts(
        args,
        scene,
        &launcher,
        (&node_addrs, &comp_addrs),
        &dir,
        &pattern,
        &points,
    )?;
    drop(children);
    let (checks, adapter) = check_frames(args, scene, &pattern, &seen, &mut failures)?;
    let md = report(
        args, frames, &points, &starts, &seen, &checks, &failures, &adapter,
    );
    print!("{md}");
    let file = args.out.join("coordinator-soak.md");
    std::fs::write(&file, &md).with_context(|| format!("cannot write {}", file.display()))?;
    outln!("soak: report written to {}", file.display());
    if !failures.is_empty() {
        bail!("coordinator soak failed: {}", failures.join("; "));
    }
    Ok(())
}

/// The points at which the coordinator is killed: numbers of frames complete on disk, drawn
/// from `seed` between 1 and `frames - 1`, distinct, ascending.
fn kill_points(seed: u64, kills: u32, frames: u32) -> Vec<usize> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut points: Vec<usize> = (0..kills)
        .map(|_| rng.random_range(1..frames as usize))
        .collect();
    points.sort_unstable();
    points.dedup();
    points
}

/// What the coordinator's starts left ([`run_starts`]).
#[derive(Debug)]
struct Outcome {
    /// The frames seen complete on disk, by number.
    seen: BTreeMap<u64, Seen>,
    starts: Vec<Start>,
    failures: Vec<String>,
}

/// Starts the coordinator over the daemons at `addrs` (render nodes, compositors) and watches
/// the frame folder, killing it when the next of `points` frames are on disk and starting it
/// again, until one start exits or the run's time is up.
fn run_starts(
    args: &Args,
    scene: &lightfold_scene::Scene,
    launcher: &Launcher,
    (node_addrs, comp_addrs): (&[String], &[String]),
    dir: &Path,
    pattern: &FramePattern,
    points: &[usize],
) -> anyhow::Result<Outcome> {
    let frames = args.frames;
    let mut seen: BTreeMap<u64, Seen> = BTreeMap::new();
    let mut starts: Vec<Start> = Vec::new();
    let mut failures: Vec<String> = Vec::new();
    let begun = Instant::now();
    let mut next_kill = points.iter().copied().peekable();
    'starts: loop {
        let mut child = coordinator(
            args,
            scene,
            launcher,
            node_addrs,
            comp_addrs,
            dir,
            starts.len(),
        )?;
        starts.push(Start {
            resumed_from: seen.len(),
            killed_at: None,
            started: Instant::now(),
            ended: None,
        });
        loop {
            std::thread::sleep(POLL);
            look(pattern, frames, &mut seen, &mut failures);
            let start = starts.last_mut().expect("a start");
            if let Some(status) = child.try_wait()? {
                start.ended = Some(Instant::now());
                look(pattern, frames, &mut seen, &mut failures);
                if !status.success() {
                    failures.push(format!(
                        "coordinator start {} exited with {status} (log: coordinator-{}.log)",
                        starts.len(),
                        starts.len() - 1
                    ));
                }
                break 'starts;
            }
            if next_kill.peek().is_some_and(|&k| seen.len() >= k) {
                next_kill.next();
                send_signal(child.id(), Signal::KILL);
                let _ = child.wait();
                start.killed_at = Some(seen.len());
                start.ended = Some(Instant::now());
                break;
            }
            if begun.elapsed() > RUN_LIMIT {
                let _ = child.kill();
                let _ = child.wait();
                failures.push(format!("not done after {} s", RUN_LIMIT.as_secs()));
                break 'starts;
            }
        }
    }
    Ok(Outcome {
        seen,
        starts,
        failures,
    })
}

/// Checks every frame is on disk as first seen (none missing, none written again), then each
/// against the single-device render of its camera, adding what fails to `failures`. Returns
/// the checks and the adapter that rendered the comparisons.
fn check_frames(
    args: &Args,
    scene: &lightfold_scene::Scene,
    pattern: &FramePattern,
    seen: &BTreeMap<u64, Seen>,
    failures: &mut Vec<String>,
) -> anyhow::Result<(Vec<Check>, String)> {
    // Every frame once: all there, and none written again after it first appeared.
    for n in 1..=u64::from(args.frames) {
        let Some(first) = seen.get(&n) else {
            failures.push(format!("frame {n} is not on disk"));
            continue;
        };
        match std::fs::metadata(pattern.path(n, "exr")) {
            Ok(m) if m.modified().ok() == Some(first.modified) && m.len() == first.len => {}
            Ok(_) => failures.push(format!("frame {n} was written again after it appeared")),
            Err(e) => failures.push(format!("frame {n}: {e}")),
        }
    }
    // And right: each against the single-device render of its camera.
    let path = FramePath::Orbit {
        degrees: args.orbit,
    };
    let Checker {
        queue,
        thread,
        adapter,
    } = spawn_checker(scene.clone(), path, 0)?;
    for &n in seen.keys() {
        match lightfold_scene::Image::read_exr(&pattern.path(n, "exr")) {
            Ok(img) => {
                let _ = queue.send((n, img));
            }
            Err(e) => failures.push(format!("frame {n} cannot be read: {e}")),
        }
    }
    drop(queue);
    let checks: Vec<Check> = thread
        .join()
        .map_err(|_| anyhow::anyhow!("the frame checker panicked"))??;
    for c in checks.iter().filter(|c| !c.ok) {
        failures.push(format!(
            "frame {} differs from the single-device render ({} of {} channels outside the \
             bound{})",
            c.frame,
            c.outside,
            c.channels,
            c.error
                .as_deref()
                .map(|e| format!("; {e}"))
                .unwrap_or_default()
        ));
    }
    Ok((checks, adapter))
}

/// Starts coordinator number `n` (from 0) over the soak's daemons; its output goes to
/// OUT/logs/coordinator-N.log.
fn coordinator(
    args: &Args,
    scene: &lightfold_scene::Scene,
    launcher: &Launcher,
    nodes: &[String],
    compositors: &[String],
    dir: &Path,
    n: usize,
) -> anyhow::Result<Child> {
    let mut cmd = std::process::Command::new(&launcher.exe);
    cmd.arg("coordinator")
        .arg("--token-file")
        .arg(&launcher.token)
        .args(["--scene", &args.scene, "--size", &args.size])
        .args(["-K", &args.lights_per_node.to_string()])
        .args(["--frames", &args.frames.to_string()])
        .args(["--orbit", &args.orbit.to_string()])
        .args([
            "--shadow-map-size",
            &scene.quality.shadow_map_size.to_string(),
        ])
        .args(["--heartbeat-timeout", &args.heartbeat_timeout.to_string()])
        .arg("--frame-dir")
        .arg(dir)
        .args(["--resume", "--take-over", "--wait-for-daemons", "60"])
        .args(["--out", &dir.join("latest.png").to_string_lossy()])
        .args(["--exr", &dir.join("latest.exr").to_string_lossy()]);
    for a in nodes {
        cmd.args(["--node", a]);
    }
    for a in compositors {
        cmd.args(["--compositor", a]);
    }
    let log = launcher
        .logs
        .as_deref()
        .context("the soak logs to a folder")?
        .join(format!("coordinator-{n}.log"));
    let file =
        std::fs::File::create(&log).with_context(|| format!("cannot create {}", log.display()))?;
    cmd.stdout(Stdio::from(file.try_clone()?))
        .stderr(Stdio::from(file));
    cmd.spawn().context("cannot start the coordinator")
}

/// Records the frames complete on disk that were not seen before.
fn look(
    pattern: &FramePattern,
    frames: u32,
    seen: &mut BTreeMap<u64, Seen>,
    failures: &mut Vec<String>,
) {
    let now = Instant::now();
    for n in pattern.complete(frames) {
        if seen.contains_key(&n) {
            continue;
        }
        match std::fs::metadata(pattern.path(n, "exr")) {
            Ok(m) => {
                let modified = m.modified().unwrap_or(SystemTime::UNIX_EPOCH);
                seen.insert(
                    n,
                    Seen {
                        at: now,
                        modified,
                        len: m.len(),
                    },
                );
            }
            Err(e) => failures.push(format!("frame {n}: {e}")),
        }
    }
}

/// The report (Markdown): the restarts, and the gaps between frames written, apart from and
/// across a coordinator restart.
#[allow(clippy::too_many_arguments)]
fn report(
    args: &Args,
    frames: u32,
    points: &[usize],
    starts: &[Start],
    seen: &BTreeMap<u64, Seen>,
    checks: &[Check],
    failures: &[String],
    adapter: &str,
) -> String {
    let mut times: Vec<Instant> = seen.values().map(|s| s.at).collect();
    times.sort_unstable();
    let restarts: Vec<(Instant, Instant)> = starts
        .windows(2)
        .filter_map(|w| Some((w[0].ended?, w[1].started)))
        .collect();
    let (mut apart, mut across) = (Duration::ZERO, Duration::ZERO);
    for w in times.windows(2) {
        let gap = w[1] - w[0];
        if restarts.iter().any(|&(k, _)| w[0] <= k && k <= w[1]) {
            across = across.max(gap);
        } else {
            apart = apart.max(gap);
        }
    }
    let mut md = String::new();
    let _ = writeln!(
        md,
        "`lightfold soak --coordinator-kills {} --frames {frames} --seed {}`: scene {} {}, \
         K = {}; frames checked on {adapter}\n",
        args.coordinator_kills, args.seed, args.scene, args.size, args.lights_per_node
    );
    let _ = writeln!(md, "| start | resumed from | killed at | ran |");
    let _ = writeln!(md, "|---|---|---|---|");
    for (i, s) in starts.iter().enumerate() {
        let ran = s.ended.map_or(0.0, |e| (e - s.started).as_secs_f64());
        let killed = s
            .killed_at
            .map_or("finished".to_string(), |k| format!("{k} frames on disk"));
        let _ = writeln!(
            md,
            "| {} | {} frames | {killed} | {ran:.1} s |",
            i + 1,
            s.resumed_from
        );
    }
    let ok = checks.iter().filter(|c| c.ok).count();
    let _ = writeln!(md);
    let _ = writeln!(md, "| | |\n|---|---|");
    let _ = writeln!(md, "| kill points (frames on disk) | {points:?} |");
    let _ = writeln!(
        md,
        "| coordinator starts | {} ({} killed, the last finished{}) |",
        starts.len(),
        starts.iter().filter(|s| s.killed_at.is_some()).count(),
        if starts.last().is_some_and(|s| s.killed_at.is_none()) {
            ""
        } else {
            ": no"
        }
    );
    let _ = writeln!(md, "| frames on disk | {} of {frames} |", seen.len());
    let _ = writeln!(
        md,
        "| frames equal to the single-device render | {ok} of {} |",
        checks.len()
    );
    let _ = writeln!(
        md,
        "| largest gap between frames written, no restart between | {:.2} s |",
        apart.as_secs_f64()
    );
    let _ = writeln!(
        md,
        "| largest gap across a coordinator restart | {:.2} s |",
        across.as_secs_f64()
    );
    if failures.is_empty() {
        let _ = writeln!(
            md,
            "\nEvery frame on disk once, none rewritten, every one right."
        );
    } else {
        for f in failures {
            let _ = writeln!(md, "\n**FAILED:** {f}");
        }
    }
    md
}
