//! Failover with real processes (issue 18): during `lightfold demo --frames N --orbit …`, a render
//! node is SIGKILLed and restarted on its address the way systemd would restart it, and a
//! compositor is SIGKILLed; in another run a node is stopped (SIGSTOP) for 3 s. Every run exits 0
//! with all N frames written as they completed, and its report names the daemons it lost and the
//! one that came back.
//!
//! Its own test binary (the crate's other tests are modules of `tests/it`): the restart must be
//! folded in while the run still renders, a race the machine's load decides; sharing a process
//! with the crate's other multi-process tests, it lost that race.

use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

fn lightfold() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_lightfold"));
    c.env("NODEVICE_SELECT", "1");
    c
}

fn work_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lightfold-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("frames")).unwrap();
    dir
}

/// Starts `lightfold demo` on a small orbit, keeping every frame in `dir/frames`.
fn start_demo(dir: &Path, frames: u32) -> Child {
    start_demo_with(dir, frames, &[])
}

fn start_demo_with(dir: &Path, frames: u32, extra: &[&str]) -> Child {
    lightfold()
        .args([
            "demo",
            "--size",
            "96x72",
            "--shadow-map-size",
            "512",
            "--no-compare",
            "--orbit",
            "3",
            "--frames",
        ])
        .arg(frames.to_string())
        .arg("--work-dir")
        .arg(dir)
        .arg("--frame-dir")
        .arg(dir.join("frames"))
        .arg("--out")
        .arg(dir.join("out.png"))
        .arg("--exr")
        .arg(dir.join("out.exr"))
        .args(extra)
        // Into files, not pipes: a pipe nobody reads until the end fills (64 KiB) and then
        // blocks the coordinator's next write — a stall that looks like a hang.
        .stdout(std::fs::File::create(dir.join("demo.out")).unwrap())
        .stderr(std::fs::File::create(dir.join("demo.err")).unwrap())
        .spawn()
        .unwrap()
}

/// The demo's exit status and what it printed (stdout, stderr) once it ends.
fn output(mut demo: Child, dir: &Path) -> (std::process::ExitStatus, String, String) {
    let status = demo.wait().unwrap();
    let read = |f: &str| std::fs::read_to_string(dir.join(f)).unwrap_or_default();
    (status, read("demo.out"), read("demo.err"))
}

/// Polls until the demo in `dir` has written `n` frames; past `within`, stops it and fails
/// with the end of what it printed.
fn wait_for_frames(demo: &mut Child, dir: &Path, n: usize, within: Duration) {
    // A demo that has exited writes no more frames: stop at once rather than wait out `within`.
    let mut exited = None;
    let got = poll_until(within, || {
        if frames_written(dir) >= n {
            return true;
        }
        exited = demo.try_wait().ok().flatten();
        exited.is_some()
    });
    if got && exited.is_none() {
        return;
    }
    let _ = demo.kill();
    let _ = demo.wait();
    let tail = |f: &str| {
        let t = std::fs::read_to_string(dir.join(f)).unwrap_or_default();
        let lines: Vec<&str> = t.lines().collect();
        lines[lines.len().saturating_sub(40)..].join("\n")
    };
    panic!(
        "{} waiting for frame {n} ({} written); the demo's stdout ends:\n{}\n\
         its stderr ends:\n{}",
        exited.map_or("timed out".to_string(), |s| format!(
            "the demo exited ({s})"
        )),
        frames_written(dir),
        tail("demo.out"),
        tail("demo.err")
    );
}

/// Polls until `f` holds, giving up (false) after `within`.
fn poll_until(within: Duration, mut f: impl FnMut() -> bool) -> bool {
    let start = Instant::now();
    while !f() {
        if start.elapsed() >= within {
            return false;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    true
}

/// Polls until `f` holds, failing after `within`.
fn wait_for(what: &str, within: Duration, f: impl FnMut() -> bool) {
    assert!(poll_until(within, f), "timed out waiting for {what}");
}

fn frames_written(dir: &Path) -> usize {
    std::fs::read_dir(dir.join("frames"))
        .map(|d| {
            d.filter_map(Result::ok)
                .filter(|e| e.path().extension().is_some_and(|x| x == "exr"))
                // Not a frame being written (beside its name, renamed when complete).
                .filter(|e| e.file_name().to_string_lossy().starts_with("frame-"))
                .count()
        })
        .unwrap_or(0)
}

/// The pid of daemon `name` from the demo's `pids` file.
fn pid_of(dir: &Path, name: &str) -> String {
    let path = dir.join("pids");
    wait_for("the pids file", Duration::from_secs(120), || {
        std::fs::read_to_string(&path).is_ok_and(|p| p.contains("coordinator"))
    });
    let pids = std::fs::read_to_string(&path).unwrap();
    pids.lines()
        .find_map(|l| l.strip_prefix(&format!("{name} ")))
        .unwrap_or_else(|| panic!("{name} not in {pids}"))
        .trim()
        .to_string()
}

/// The address daemon `id` listens on, from the demo's cluster file.
fn address_of(dir: &Path, id: &str) -> String {
    let text = std::fs::read_to_string(dir.join("cluster.toml")).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    let at = lines
        .iter()
        .position(|l| l.trim() == format!("id = \"{id}\""))
        .unwrap_or_else(|| panic!("{id} not in {text}"));
    lines[at - 1]
        .trim()
        .strip_prefix("address = \"")
        .and_then(|a| a.strip_suffix('"'))
        .unwrap()
        .to_string()
}

fn signal(sig: &str, pid: &str) {
    let ok = Command::new("kill").arg(sig).arg(pid).status().unwrap();
    assert!(ok.success(), "kill {sig} {pid}");
}

fn finish(demo: Child, dir: &Path) -> (String, String) {
    let (status, stdout, stderr) = output(demo, dir);
    assert!(
        status.success(),
        "demo failed ({status}):\n{stdout}\n{stderr}"
    );
    (stdout, stderr)
}

#[test]
fn killed_daemons_cost_no_frame_and_a_restarted_one_comes_back() {
    // Enough frames that a restarted node (start-up and calibration, then the coordinator's
    // redial) is folded back in while they last, even on a loaded machine.
    const FRAMES: u32 = 80;
    let dir = work_dir("failover-kill");
    let mut demo = start_demo(&dir, FRAMES);
    wait_for_frames(&mut demo, &dir, 2, Duration::from_secs(300));
    let node = pid_of(&dir, "node-1");
    let addr = address_of(&dir, "node-1");
    signal("-KILL", &node);
    // A supervisor restarts it on the same address under the same id, and again a moment later
    // while the address is still taken (seen on a loaded machine: "Address already in use" for
    // a while after the kill), as systemd's `Restart=` with `RestartSec=` does.
    std::thread::sleep(Duration::from_millis(500));
    // Its log says when a plan configures it ("renderer built"): the coordinator took it back.
    let log = dir.join("node-1-restarted.log");
    let out = dir.join("node-1-restarted.out");
    let start = Instant::now();
    let mut restarted = loop {
        let mut child = lightfold()
            .args([
                "--log",
                "info",
                "node",
                "--listen",
                &addr,
                "--id",
                "node-1",
                "--token-file",
            ])
            .arg(dir.join("token"))
            .stdout(std::fs::File::create(&out).unwrap())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .unwrap();
        // Listening (its `listening ADDR` line), or gone because the address was still taken.
        let mut exited = false;
        wait_for(
            "the restarted node-1 to listen or exit",
            Duration::from_secs(120),
            || {
                exited = matches!(child.try_wait(), Ok(Some(_)));
                exited || std::fs::read_to_string(&out).is_ok_and(|o| o.contains("listening"))
            },
        );
        if !exited {
            break child;
        }
        let why = std::fs::read_to_string(&log).unwrap_or_default();
        assert!(
            why.contains("Address already in use"),
            "the restarted node-1 exited: {why}"
        );
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "node-1's address stayed taken for 60 s after it was killed"
        );
        std::thread::sleep(Duration::from_millis(200));
    };
    wait_for(
        "the restarted node-1 to be configured into a plan",
        Duration::from_secs(300),
        || {
            assert!(
                frames_written(&dir) < FRAMES as usize,
                "the run ended before the restarted node-1 was folded back in"
            );
            std::fs::read_to_string(&log).is_ok_and(|l| l.contains("renderer built"))
        },
    );
    let seen = frames_written(&dir);
    wait_for("two more frames", Duration::from_secs(300), || {
        frames_written(&dir) >= seen + 2
    });
    signal("-KILL", &pid_of(&dir, "comp-1"));
    let (stdout, _) = finish(demo, &dir);
    let _ = restarted.kill();
    let _ = restarted.wait();
    assert_eq!(frames_written(&dir), FRAMES as usize, "{stdout}");
    for line in ["node-1  lost", "node-1  rejoined", "comp-1  lost"] {
        assert!(
            stdout.contains(line),
            "no {line:?} in the report:\n{stdout}"
        );
    }
    assert!(
        stdout.contains(&format!("failover: {FRAMES} frame(s) delivered")),
        "{stdout}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_stopped_node_is_named_and_every_frame_arrives() {
    const FRAMES: u32 = 8;
    let dir = work_dir("failover-stop");
    let mut demo = start_demo(&dir, FRAMES);
    wait_for_frames(&mut demo, &dir, 2, Duration::from_secs(300));
    let node = pid_of(&dir, "node-2");
    signal("-STOP", &node);
    std::thread::sleep(Duration::from_secs(3));
    signal("-CONT", &node);
    let (stdout, _) = finish(demo, &dir);
    assert_eq!(frames_written(&dir), FRAMES as usize, "{stdout}");
    assert!(
        stdout.contains("node-2  lost: no answer to heartbeats"),
        "the report does not name the stalled node:\n{stdout}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_interrupted_run_keeps_every_frame_it_finished() {
    let dir = work_dir("failover-int");
    let mut demo = start_demo(&dir, 500);
    wait_for_frames(&mut demo, &dir, 3, Duration::from_secs(300));
    // Ctrl-C reaches the coordinator: it requests nothing more and finishes what is in flight.
    signal("-INT", &pid_of(&dir, "coordinator"));
    let (status, stdout, stderr) = output(demo, &dir);
    assert_eq!(status.code(), Some(130), "an interrupted run ends with 130");
    assert!(
        stderr.contains("interrupted after"),
        "no interruption message:\n{stdout}\n{stderr}"
    );
    let kept = frames_written(&dir);
    assert!((3..500).contains(&kept), "{kept} frames kept");
    // Every frame on disk is whole, in order from 1.
    for i in 1..=kept {
        let path = dir.join("frames").join(format!("frame-{i:04}.exr"));
        let img = lightfold_scene::Image::read_exr(&path)
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert_eq!((img.width, img.height), (96, 72));
    }
    assert!(
        stdout.contains(&format!("failover: {kept} frame(s) delivered")),
        "{stdout}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// The coordinator SIGKILLed at frame 3 or so of a 12-frame path, then the run started again with
/// `--resume` over the same frame folder: every frame is on disk exactly once, whole, and the
/// frames written before the kill were neither rendered again nor rewritten.
#[test]
fn a_killed_coordinator_is_resumed_without_rewriting_a_frame() {
    const FRAMES: u32 = 12;
    let dir = work_dir("failover-resume");
    let mut demo = start_demo(&dir, FRAMES);
    wait_for_frames(&mut demo, &dir, 3, Duration::from_secs(300));
    signal("-KILL", &pid_of(&dir, "coordinator"));
    let (status, _, _) = output(demo, &dir);
    assert!(
        !status.success(),
        "a run whose coordinator died is not a success"
    );
    let frame = |i: u32| dir.join("frames").join(format!("frame-{i:04}.exr"));
    let before: Vec<(u32, std::time::SystemTime)> = (1..=FRAMES)
        .filter(|&i| frame(i).is_file() && frame(i).with_extension("png").is_file())
        .map(|i| (i, std::fs::metadata(frame(i)).unwrap().modified().unwrap()))
        .collect();
    assert!(
        (1..FRAMES as usize).contains(&before.len()),
        "{} frames before the kill",
        before.len()
    );
    let _ = std::fs::remove_file(dir.join("pids"));
    let (stdout, _) = finish(start_demo_with(&dir, FRAMES, &["--resume"]), &dir);
    assert!(
        stdout.contains(&format!(
            "resuming: {} of {FRAMES} frame(s) already written",
            before.len()
        )),
        "{stdout}"
    );
    let rendered = FRAMES as usize - before.len();
    assert!(
        stdout.contains(&format!("failover: {rendered} frame(s) delivered")),
        "only the missing frames are rendered:\n{stdout}"
    );
    assert_eq!(frames_written(&dir), FRAMES as usize, "every frame once");
    for i in 1..=FRAMES {
        let img = lightfold_scene::Image::read_exr(&frame(i))
            .unwrap_or_else(|e| panic!("frame {i}: {e}"));
        assert_eq!((img.width, img.height), (96, 72));
    }
    for (i, at) in before {
        let now = std::fs::metadata(frame(i)).unwrap().modified().unwrap();
        assert_eq!(now, at, "frame {i} was written again");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
