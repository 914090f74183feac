//! What `lightfold demo` shows and leaves behind (issue 28): a short default output with units
//! (the full plan behind `--verbose`), a line per frame on a log (stderr here is a pipe, not a
//! terminal), no temporary directory left — also after a Ctrl-C —, `--frames 0` refused before
//! any process starts, a Ctrl-C that blames no daemon, and a glTF's warning said once.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

fn lightfold(tmp: &Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_lightfold"));
    c.env("NODEVICE_SELECT", "1").env("TMPDIR", tmp);
    c
}

/// A fresh test folder holding `tmp/` (the child's TMPDIR) and the outputs; the child runs in it.
fn work_dir(name: &str) -> (PathBuf, PathBuf) {
    let dir = std::env::temp_dir().join(format!("lightfold-out-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let tmp = dir.join("tmp");
    std::fs::create_dir_all(&tmp).unwrap();
    (dir, tmp)
}

fn demo(dir: &Path, tmp: &Path, args: &[&str]) -> Command {
    let mut c = lightfold(tmp);
    c.current_dir(dir)
        .arg("demo")
        .args(args)
        .arg("--out")
        .arg(dir.join("out.png"))
        .arg("--exr")
        .arg(dir.join("out.exr"));
    c
}

fn texts(out: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn assert_empty(tmp: &Path, what: &str) {
    let left: Vec<_> = std::fs::read_dir(tmp)
        .unwrap()
        .filter_map(Result::ok)
        .map(|e| e.file_name())
        .collect();
    assert!(left.is_empty(), "{what} left {left:?} in its TMPDIR");
}

#[test]
fn the_default_output_is_short_with_units_logs_every_frame_and_leaves_no_temp_dir() {
    let (dir, tmp) = work_dir("default");
    let out = demo(
        &dir,
        &tmp,
        &[
            "--size",
            "64x48",
            "--no-compare",
            "--frames",
            "3",
            "--orbit",
            "5",
            "--no-frame-files",
        ],
    )
    .output()
    .unwrap();
    let (stdout, stderr) = texts(&out);
    assert!(out.status.success(), "demo failed:\n{stdout}\n{stderr}");
    assert_empty(&tmp, "demo");

    // A few lines of plan, the table, the summary: all the default scene's 16 daemons fit.
    let lines = stdout.lines().count();
    assert!(lines < 40, "{lines} lines:\n{stdout}");
    for part in [
        "plan: scene balls at 64×48, K = 4 lights per render node",
        "--verbose",
        "shadow",
        "ms",
        "p50",
        "p95",
        "kB",
        "node-seconds per frame",
        "frames/s",
        "failover: 3 frame(s) delivered",
    ] {
        assert!(stdout.contains(part), "no {part:?} in:\n{stdout}");
    }
    // A first run warns about nothing: no slow-frame lines (the summary says it once, and the
    // estimate knows the nodes share this machine's CPU), no warning about the CPU adapter of
    // a cluster that is all on the CPU (a note).
    for text in [&stdout, &stderr] {
        assert!(
            !text.contains("WARN") && !text.contains("warning"),
            "a warning in:\n{stdout}\n{stderr}"
        );
    }
    // No full plan, no raw byte counts, no unexplained frame counts.
    for absent in [
        "stages:",
        "links (bytes per frame)",
        "bytes",
        "(0 frames)",
        "c_n",
    ] {
        assert!(!stdout.contains(absent), "{absent:?} in:\n{stdout}");
    }
    // Compositor rows in natural order, after the nodes.
    let row = |id: &str| {
        stdout
            .lines()
            .position(|l| l.starts_with(&format!("| {id} ")))
            .unwrap_or_else(|| panic!("no row for {id}:\n{stdout}"))
    };
    assert!(row("node-7") < row("comp-0"));
    assert!(row("comp-1") < row("comp-2") && row("comp-2") < row("comp-7"));

    // stderr is a pipe: frame lines instead of a progress bar, the first and the last always.
    for f in ["frame 1/3: latency", "frame 3/3: latency"] {
        assert!(stderr.contains(f), "no {f:?} on stderr:\n{stderr}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn verbose_prints_the_full_plan_and_every_frame() {
    let (dir, tmp) = work_dir("verbose");
    let out = demo(
        &dir,
        &tmp,
        &[
            "--size",
            "32x24",
            "-K",
            "32",
            "--no-compare",
            "--frames",
            "2",
            "--no-frame-files",
            "--verbose",
        ],
    )
    .output()
    .unwrap();
    let (stdout, stderr) = texts(&out);
    assert!(out.status.success(), "demo failed:\n{stdout}\n{stderr}");
    for part in [
        "plan epoch",
        "samples: 32 total, 32 active",
        "stages:",
        "links (bytes per frame):",
        "key: ",
        "+z along its axis",
        "frame 1: latency",
        "frame 2: latency",
        "node-seconds per frame",
    ] {
        assert!(stdout.contains(part), "no {part:?} in:\n{stdout}");
    }
    assert!(!stdout.contains("+axis"), "{stdout}");
    assert_empty(&tmp, "demo --verbose");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn frames_zero_is_refused_before_anything_starts() {
    let (dir, tmp) = work_dir("frames0");
    for cmd in ["demo", "coordinator"] {
        let start = Instant::now();
        let out = lightfold(&tmp)
            .current_dir(&dir)
            .args([cmd, "--frames", "0"])
            .output()
            .unwrap();
        let (stdout, stderr) = texts(&out);
        // A usage error from argument parsing: status 2, nothing started or printed.
        assert_eq!(out.status.code(), Some(2), "{cmd}:\n{stdout}\n{stderr}");
        assert!(stderr.contains("--frames"), "{cmd}: {stderr}");
        assert!(stdout.is_empty(), "{cmd} printed:\n{stdout}");
        assert!(start.elapsed() < Duration::from_secs(10), "{cmd} was slow");
        assert_empty(&tmp, cmd);
    }
    // The help text of --sink-advertise says what it is.
    let help = lightfold(&tmp)
        .args(["coordinator", "--help"])
        .output()
        .unwrap();
    let help = String::from_utf8_lossy(&help.stdout);
    let line = help
        .lines()
        .skip_while(|l| !l.contains("--sink-advertise"))
        .take(2)
        .collect::<String>();
    assert!(line.contains("sink compositor dials"), "{help}");
    let _ = std::fs::remove_dir_all(&dir);
}

fn frames_in(dir: &Path) -> usize {
    std::fs::read_dir(dir).map_or(0, |d| {
        d.filter_map(Result::ok)
            .filter(|e| e.path().extension().is_some_and(|x| x == "exr"))
            .count()
    })
}

/// Ctrl-C at a terminal signals the whole foreground process group: the demo and its
/// coordinator finish the frames in flight with every daemon up, report no daemon lost, end with
/// one line saying how far they got and the status 130, and the temporary directory goes.
#[test]
fn ctrl_c_reads_as_a_shutdown_and_cleans_up() {
    interrupted_by("ctrl-c", |child: &std::process::Child| {
        let group = rustix::process::Pid::from_raw(child.id() as i32).unwrap();
        rustix::process::kill_process_group(group, rustix::process::Signal::INT).unwrap();
    });
}

/// SIGTERM to the demo alone (a service manager, `kill`) stops the run as Ctrl-C does: the
/// frames done kept, status 130, nothing left in the temporary directory.
#[test]
fn sigterm_stops_the_demo_as_ctrl_c_does() {
    interrupted_by("sigterm", |child: &std::process::Child| {
        let pid = rustix::process::Pid::from_raw(child.id() as i32).unwrap();
        rustix::process::kill_process(pid, rustix::process::Signal::TERM).unwrap();
    });
}

fn interrupted_by(name: &str, interrupt: impl FnOnce(&std::process::Child)) {
    let (dir, tmp) = work_dir(name);
    let frames = dir.join("frames");
    let mut cmd = demo(
        &dir,
        &tmp,
        &[
            "--size",
            "64x48",
            "-K",
            "16",
            "--no-compare",
            "--frames",
            "500",
            "--orbit",
            "2",
        ],
    );
    cmd.arg("--frame-dir").arg(&frames);
    // Its own process group, as a shell gives a foreground job.
    std::os::unix::process::CommandExt::process_group(&mut cmd, 0);
    let child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while frames_in(&frames) < 3 {
        assert!(
            start.elapsed() < Duration::from_secs(300),
            "no frames in time"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    interrupt(&child);
    let out = child.wait_with_output().unwrap();
    let (stdout, stderr) = texts(&out);
    assert_eq!(
        out.status.code(),
        Some(130),
        "an interrupted run ends with 130:\n{stdout}\n{stderr}"
    );
    assert_eq!(
        stderr.matches("interrupted after").count(),
        1,
        "one line says how far it got:\n{stdout}\n{stderr}"
    );
    assert!(
        !stderr.contains("Error:"),
        "an interruption is not an error:\n{stdout}\n{stderr}"
    );
    assert!(
        stdout.contains("0 daemon(s) lost, 0 re-plan(s)"),
        "a daemon was blamed:\n{stdout}\n{stderr}"
    );
    for blame in ["lost:", "closed the connection", "Broken pipe"] {
        assert!(
            !stdout.contains(blame) && !stderr.contains(blame),
            "{blame:?}:\n{stdout}\n{stderr}"
        );
    }
    assert_empty(&tmp, "an interrupted demo");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_gltf_warning_is_said_once() {
    let (dir, tmp) = work_dir("gltf");
    // The Fox has three clips; the two not played are a glTF feature ignored.
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/Fox/Fox.glb");
    let scene = scene.to_str().unwrap();
    let out = demo(
        &dir,
        &tmp,
        &[
            "--size",
            "32x24",
            "-K",
            "32",
            "--no-compare",
            "--scene",
            scene,
        ],
    )
    .output()
    .unwrap();
    let (stdout, stderr) = texts(&out);
    assert!(out.status.success(), "demo failed:\n{stdout}\n{stderr}");
    assert_eq!(
        stderr.matches("glTF features ignored").count(),
        1,
        "{stderr}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
