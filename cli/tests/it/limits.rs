//! Sizes and scenes beyond `lightfold_scene::limits` are refused by the commands with a clear
//! error before anything is allocated or started: `render --size` (100000x100000 used to abort
//! on a 240 GB allocation, 16384x16384 to panic in wgpu), `render --samples`, a glTF reaching
//! outside its folder, and `demo` on a scene that needs more processes than allowed (1000
//! samples used to start 250 nodes and 250 compositors). `defaults` prints the limits.

use std::process::{Command, Output};
use std::time::{Duration, Instant};

fn lightfold(args: &[&str]) -> (Output, Duration) {
    let t = Instant::now();
    let out = Command::new(env!("CARGO_BIN_EXE_lightfold"))
        .args(args)
        .env("NODEVICE_SELECT", "1")
        .output()
        .expect("runs");
    (out, t.elapsed())
}

/// Runs a command that must fail quickly; returns its stderr.
fn refused(args: &[&str]) -> String {
    let (out, took) = lightfold(args);
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!out.status.success(), "{args:?} succeeded:\n{err}");
    assert!(!err.contains("panicked"), "{args:?} panicked:\n{err}");
    assert!(took < Duration::from_secs(60), "{args:?} took {took:?}");
    err
}

fn has(text: &str, words: &[&str]) {
    for w in words {
        assert!(text.contains(w), "{w:?} missing from:\n{text}");
    }
}

#[test]
fn render_refuses_sizes_and_samples_beyond_the_limits() {
    let dir = std::env::temp_dir().join(format!("lightfold-limits-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("x.exr").display().to_string();
    let e = refused(&["render", "--size", "100000x100000", "--out", &out]);
    has(
        &e,
        &[
            "bad --size",
            "100000x100000 is too large",
            "at most 8192 per side",
        ],
    );
    let e = refused(&["render", "--size", "16384x16384", "--out", &out]);
    has(&e, &["16384x16384 is too large", "lightfold defaults"]);
    let e = refused(&["render", "--samples", "100000000", "--out", &out]);
    has(
        &e,
        &[
            "--samples asks for 100000000 samples per area light",
            "the limit is 4096",
        ],
    );
    // `--out` names the EXR; a .png there would have the PNG written over it.
    let png = dir.join("x.png").display().to_string();
    let e = refused(&["render", "--out", &png]);
    has(&e, &["--out names the EXR", "x.exr instead of"]);
    assert!(!dir.join("x.png").exists());
    let e = refused(&["render", "--shadow-map-size", "65536", "--out", &out]);
    has(&e, &["shadow-map size 65536 is outside 1..=4096"]);
    let e = refused(&["plan", "balls", "--size", "0x10"]);
    has(&e, &["must be at least 1"]);
    // A glTF whose buffer is /dev/zero: refused at once, not read until the kernel steps in.
    let model = dir.join("zero.gltf");
    std::fs::write(
        &model,
        r#"{"asset":{"version":"2.0"},"buffers":[{"uri":"/dev/zero","byteLength":44}]}"#,
    )
    .unwrap();
    let e = refused(&[
        "render",
        "--scene",
        &model.display().to_string(),
        "--out",
        &out,
    ]);
    has(&e, &["buffer 0", "absolute path"]);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn aa_beyond_the_image_limits_is_refused() {
    let dir = std::env::temp_dir().join(format!("lightfold-limits-aa-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("x.exr").display().to_string();
    // 800x600 at 8×8 samples per pixel is 6400x4800: over 4096x4096 pixels in all.
    for extra in [&[][..], &["--reference"][..]] {
        let mut args = vec!["render", "--aa", "8", "--out", &out];
        args.extend_from_slice(extra);
        let e = refused(&args);
        has(
            &e,
            &[
                "--aa 8 renders 800x600 as 6400x4800 internally",
                "4096x4096",
                "lightfold defaults",
            ],
        );
    }
    let e = refused(&["render", "--size", "5000x10", "--aa", "2", "--out", &out]);
    has(&e, &["as 10000x20 internally", "at most 8192 per side"]);
    let e = refused(&["render", "--aa", "0", "--out", &out]);
    has(&e, &["--aa must be at least 1"]);
    // `demo` refuses before it starts a daemon.
    let work = dir.join("work");
    let e = refused(&[
        "demo",
        "--aa",
        "8",
        "--no-compare",
        "--work-dir",
        work.to_str().unwrap(),
    ]);
    has(&e, &["--aa 8 renders 800x600 as 6400x4800 internally"]);
    assert!(!std::path::Path::new(&out).exists(), "nothing is written");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn demo_refuses_more_processes_than_allowed_and_says_what_fits() {
    let dir = std::env::temp_dir().join(format!("lightfold-limits-demo-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let scene = dir.join("many.toml");
    std::fs::write(
        &scene,
        "version = 1\n[quality]\nsamples_per_area_light = 500\n\
         [[object]]\ntype = \"plane\"\ncenter = [0.0, 0.0, 0.0]\nsize = [10.0, 10.0]\n\
         [[object]]\ntype = \"box\"\ncenter = [0.0, 0.5, 0.0]\nsize = [1.0, 1.0, 1.0]\n\
         [[light]]\ntype = \"rect\"\ncenter = [0.0, 3.0, 0.0]\nsize = [1.0, 1.0]\n\
         normal = [0.0, -1.0, 0.0]\nu_axis = [1.0, 0.0, 0.0]\nradiance = 5.0\n\
         [[light]]\ntype = \"rect\"\ncenter = [2.0, 3.0, 0.0]\nsize = [1.0, 1.0]\n\
         normal = [0.0, -1.0, 0.0]\nu_axis = [1.0, 0.0, 0.0]\nradiance = 5.0\n",
    )
    .unwrap();
    let work = dir.join("work");
    let args = [
        "demo",
        "--scene",
        scene.to_str().unwrap(),
        "--no-compare",
        "--work-dir",
        work.to_str().unwrap(),
    ];
    let e = refused(&args);
    has(
        &e,
        &[
            "at K = 4 needs",
            "this machine holds",
            "per core, at least 32; --max-processes N to change",
            "-K ",
            "fits",
            "--frame-budget loose enough",
        ],
    );
    assert!(!work.join("pids").exists(), "processes were started");
    let mut limited = args.to_vec();
    limited.extend(["--max-processes", "8"]);
    let e = refused(&limited);
    has(&e, &["--max-processes allows 8"]);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn defaults_prints_the_limits() {
    let (out, _) = lightfold(&["defaults"]);
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    has(
        &text,
        &[
            "limits:",
            "at most 8192 per side and 16777216 pixels",
            "at most 4096²",
            "at most 16384 per scene",
            "at most 10000000 per scene",
        ],
    );
}
