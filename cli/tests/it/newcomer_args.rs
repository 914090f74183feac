//! The commands as a newcomer meets them (issue 28): `plan` and `bench node` take the same
//! `--scene` (built-in, `.toml`, glTF) and `--size` as the others, `-K` is lights per node
//! everywhere, `plan --nodes 2` raises K as the coordinator does instead of failing, a reader
//! that goes away (`lightfold plan | head`) ends a command quietly, `compare` gates on
//! `--min-psnr`/`--max-flip` and says what it reads when given a PNG, and `render --timings`
//! prints a clean table and counts its median honestly.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

fn lightfold() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_lightfold"));
    c.env("NODEVICE_SELECT", "1").env("RUST_BACKTRACE", "0");
    c
}

fn run(args: &[&str]) -> Output {
    lightfold().args(args).output().expect("runs")
}

fn text(out: &Output) -> (String, String) {
    (
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Runs a command that must succeed; returns its stdout.
fn ok(args: &[&str]) -> String {
    let out = run(args);
    let (stdout, stderr) = text(&out);
    assert!(out.status.success(), "{args:?} failed:\n{stdout}\n{stderr}");
    assert!(!stderr.contains("panicked"), "{args:?} panicked:\n{stderr}");
    stdout
}

/// Runs a command that must fail without a panic; returns its stderr.
fn fails(args: &[&str]) -> String {
    let out = run(args);
    let (stdout, stderr) = text(&out);
    assert!(
        !out.status.success(),
        "{args:?} succeeded:\n{stdout}\n{stderr}"
    );
    assert!(!stderr.contains("panicked"), "{args:?} panicked:\n{stderr}");
    stderr
}

fn repo(path: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(path)
        .display()
        .to_string()
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lightfold-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn plan_and_bench_take_the_scene_and_size_every_command_takes() {
    let gltf = repo("assets/BoxTextured/BoxTextured.gltf");
    let toml = repo("scenes/simple.toml");
    let p = ok(&["plan", "--scene", &gltf, "--size", "64x48"]);
    assert!(
        p.contains("scene BoxTextured") && p.contains("64×48"),
        "{p}"
    );
    let p = ok(&["plan", "--scene", &toml]);
    assert!(p.contains("scene simple"), "{p}");
    // The positional still works.
    let p = ok(&["plan", &toml]);
    assert!(p.contains("scene simple"), "{p}");

    let b = ok(&[
        "bench", "node", "--scene", &toml, "--size", "64x48", "--ks", "1", "--modes", "moving",
        "--frames", "1", "--warmup", "0", "--rounds", "1",
    ]);
    assert!(b.contains("### Frame time per node (64x48,"), "{b}");
    let e = fails(&["bench", "node", "--size", "64"]);
    assert!(e.contains("WIDTHxHEIGHT"), "{e}");

    // -K is lights per node in every command, and the help says so.
    for cmd in ["render", "plan", "coordinator", "demo"] {
        let help = ok(&[cmd, "--help"]);
        assert!(
            help.contains("-K, --lights-per-node"),
            "{cmd} --help:\n{help}"
        );
    }
    let help = ok(&["plan", "--help"]);
    assert!(
        help.contains("--topology <TOPOLOGY>\n          Compositor topology"),
        "{help}"
    );
}

#[test]
fn plan_on_a_short_cluster_raises_k_like_the_coordinator() {
    let p = ok(&["plan", "--nodes", "2"]);
    assert!(p.contains("K raised from 4 to "), "{p}");
    assert!(p.contains("nodes: 2 used"), "{p}");
    // Only when a device cannot take that many: the error says what was assumed.
    let e = fails(&["plan", "--nodes", "1", "--max-lights", "8"]);
    assert!(
        e.contains("the cluster has 1") && e.contains("--max-lights"),
        "{e}"
    );
}

/// Runs `args` with a standard output whose reader has already gone; it must end quietly.
fn into_closed_pipe(args: &[&str]) {
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let out = lightfold()
        .args(args)
        .stdout(writer)
        .stderr(Stdio::piped())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !stderr.contains("panicked") && !stderr.contains("Broken pipe"),
        "{args:?}:\n{stderr}"
    );
    assert!(out.status.success(), "{args:?}: {:?}\n{stderr}", out.status);
}

#[test]
fn a_reader_that_goes_away_ends_the_command_quietly() {
    // `lightfold plan | head -1`.
    let mut child = lightfold()
        .args(["plan", "--topology", "tree"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut first = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut first)
        .unwrap();
    assert!(first.starts_with("plan "), "{first}");
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(out.status.success(), "{:?}\n{stderr}", out.status);

    // The same with nothing read at all, so every write meets the closed pipe.
    into_closed_pipe(&["plan"]);
    into_closed_pipe(&["plan", "--json"]);
    into_closed_pipe(&["plan", "--nodes", "2"]);
    let dir = scratch("closed-pipe");
    let exr = dir.join("a.exr").display().to_string();
    ok(&["render", "--reference", "--size", "32x24", "--out", &exr]);
    into_closed_pipe(&["compare", &exr, &exr]);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn compare_is_a_gate_and_reads_exr() {
    let dir = scratch("compare-gate");
    let balls = dir.join("balls.exr").display().to_string();
    let boxes = dir.join("box.exr").display().to_string();
    for (scene, out) in [("balls", &balls), ("box", &boxes)] {
        ok(&[
            "render",
            "--reference",
            "--scene",
            scene,
            "--size",
            "64x48",
            "--out",
            out,
        ]);
    }
    // Unrelated images fail the gate, identical ones pass it.
    let e = fails(&["compare", &balls, &boxes, "--min-psnr", "40"]);
    assert!(e.contains("below --min-psnr 40"), "{e}");
    let e = fails(&["compare", &balls, &boxes, "--max-flip", "0.05"]);
    assert!(e.contains("above --max-flip 0.05"), "{e}");
    let m = ok(&[
        "compare",
        &balls,
        &balls,
        "--min-psnr",
        "40",
        "--max-flip",
        "0.01",
    ]);
    assert!(m.contains("psnr    inf dB"), "{m}");
    // Without thresholds the figures are printed and the command succeeds.
    ok(&["compare", &balls, &boxes]);

    // A PNG: the error says what compare reads, and where the EXR is.
    let png = dir.join("balls.png").display().to_string();
    let e = fails(&["compare", &png, &balls]);
    assert!(
        e.contains("compare reads EXR; got a PNG") && e.contains(&balls),
        "{e}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn render_timings_print_a_clean_table_and_an_honest_median() {
    let dir = scratch("render-timings");
    let exr = dir.join("t.exr").display().to_string();
    let frames = 3;
    let t = ok(&[
        "render",
        "--size",
        "64x48",
        "--frames",
        &frames.to_string(),
        "--timings",
        "--out",
        &exr,
    ]);
    let lines: Vec<&str> = t.lines().collect();
    let header = lines
        .iter()
        .position(|l| l.starts_with("frame  shadow_passes"))
        .unwrap_or_else(|| panic!("no table:\n{t}"));
    // Right under the header, one row per frame and nothing else.
    for (f, row) in lines[header + 1..header + 1 + frames].iter().enumerate() {
        let first = row.split_whitespace().next().unwrap_or_default();
        assert_eq!(
            first,
            f.to_string(),
            "row {f} of the table is {row:?}:\n{t}"
        );
    }
    let batches: usize = lines[header - 1]
        .split(", ")
        .find_map(|p| p.strip_suffix(" batch(es)"))
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no batch count:\n{t}"));
    let median = format!(
        "median of {} batches, {} in each of frames 1–{}",
        (frames - 1) * (batches - 1),
        batches - 1,
        frames - 1
    );
    assert!(t.contains(&median), "{median:?} missing:\n{t}");
    std::fs::remove_dir_all(&dir).ok();
}

/// Scene time on the command line: `render --time` poses an animated scene (two times give two
/// images, and the CPU reference of a pose is what the GPU renders of it); bad times and rates
/// are refused before anything runs.
#[test]
fn render_poses_an_animated_scene_at_its_time() {
    let dir = scratch("time");
    let out = |name: &str| dir.join(name).display().to_string();
    for (t, name) in [("0.5", "a.exr"), ("2.5", "b.exr")] {
        ok(&[
            "render",
            "--scene",
            "carousel",
            "--size",
            "64x48",
            "--samples",
            "4",
            "--time",
            t,
            "--out",
            &out(name),
        ]);
    }
    ok(&[
        "render",
        "--scene",
        "carousel",
        "--size",
        "64x48",
        "--samples",
        "4",
        "--time",
        "2.5",
        "--reference",
        "--out",
        &out("ref.exr"),
    ]);
    let read = |n: &str| lightfold_scene::Image::read_exr(&dir.join(n)).unwrap();
    let (a, b, r) = (read("a.exr"), read("b.exr"), read("ref.exr"));
    let moved = a
        .data
        .iter()
        .zip(&b.data)
        .filter(|(x, y)| (*x - *y).abs() > 0.02)
        .count();
    assert!(
        moved * 50 > a.data.len(),
        "two times, nearly the same image ({moved} channels)"
    );
    let m = lightfold_reference::metrics::compare(&b, &r, 1.0, None).unwrap();
    println!("GPU against the CPU reference at t = 2.5: {m}");
    assert!(m.whole.psnr > 30.0, "{m}");
    for bad in [
        vec!["render", "--scene", "carousel", "--time", "nan"],
        vec!["demo", "--fps", "0"],
        vec!["coordinator", "--fps=-3"],
    ] {
        let e = fails(&bad);
        assert!(e.contains("not a"), "{bad:?}: {e}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn indirect_light_on_an_animated_scene_is_planned_and_posed() {
    let dir = scratch("indirect");
    let out = dir.join("still.exr").display().to_string();
    let base = ["--scene", "carousel", "--size", "32x24"];
    // Its VPLs are traced again at every frame's time, one slot a light path.
    let plan = ok(&[&["plan"][..], &base, &["--indirect", "16"]].concat());
    assert!(plan.contains("virtual point lights"), "{plan}");
    let plan = ok(&[&["plan"][..], &base, &["--indirect", "16", "--still"]].concat());
    assert!(plan.contains("virtual point lights"), "{plan}");
    // `render --time` poses it, and traces the VPLs for that pose.
    ok(&[
        &["render"][..],
        &base,
        &["--indirect", "16", "--time", "1.0", "--out", &out],
    ]
    .concat());
    assert!(Path::new(&out).exists());
    assert!(
        fails(&[&["render"][..], &base, &["--indirect-clamp=-1"]].concat())
            .contains("--indirect-clamp")
    );
}
