//! `lightfold demo` as a user runs it (issue 10): a real multi-process cluster on loopback renders
//! a small frame whose PNG has real variance and matches its EXR, the image equals the
//! single-device `lightfold render` of all 32 lights within the link formats' bound, and every
//! process the demo started has exited afterwards.

use std::path::Path;
use std::process::Command;

fn lightfold() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_lightfold"));
    c.env("NODEVICE_SELECT", "1");
    c
}

fn read_png(path: &Path) -> (u32, u32, Vec<u8>) {
    let img = image::open(path).unwrap().to_rgb8();
    (img.width(), img.height(), img.into_raw())
}

#[test]
fn demo_renders_and_leaves_no_process_behind() {
    let dir = std::env::temp_dir().join(format!("lightfold-demo-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (png, exr) = (dir.join("out.png"), dir.join("out.exr"));
    let out = lightfold()
        .args([
            "demo",
            "--size",
            "96x72",
            "--shadow-map-size",
            "512",
            "--no-compare",
            "--work-dir",
        ])
        .arg(&dir)
        .arg("--out")
        .arg(&png)
        .arg("--exr")
        .arg(&exr)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "demo failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("node-seconds per frame"),
        "no timing summary:\n{stdout}"
    );

    // Every spawned process has exited.
    let pids = std::fs::read_to_string(dir.join("pids")).unwrap();
    let lines: Vec<&str> = pids.lines().collect();
    assert!(lines.len() >= 3, "{pids}");
    for line in lines {
        let pid = line.split_whitespace().last().unwrap();
        assert!(
            !Path::new(&format!("/proc/{pid}")).exists(),
            "{line} is still running"
        );
    }

    // The PNG is not blank and is the EXR at the scene's exposure.
    let (w, h, px) = read_png(&png);
    assert_eq!((w, h), (96, 72));
    let mean = px.iter().map(|&v| v as f64).sum::<f64>() / px.len() as f64;
    let var = px.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / px.len() as f64;
    assert!(
        var.sqrt() > 10.0,
        "PNG is nearly flat (std {:.1})",
        var.sqrt()
    );
    let lin = lightfold_scene::Image::read_exr(&exr).unwrap();
    let exposure = lightfold_scene::builtin(lightfold_scene::defaults::DEFAULT_SCENE)
        .unwrap()
        .exposure;
    let srgb = lin.to_srgb8(exposure).unwrap();
    let off = srgb
        .iter()
        .zip(&px)
        .filter(|(a, b)| (**a as i32 - **b as i32).abs() > 1)
        .count();
    assert_eq!(
        off, 0,
        "PNG differs from the EXR's sRGB encoding in {off} channels"
    );

    // The same image as one device rendering all 32 lights.
    let single = dir.join("single.exr");
    let r = lightfold()
        .args(["render", "--size", "96x72", "--out"])
        .arg(&single)
        .output()
        .unwrap();
    assert!(
        r.status.success(),
        "render failed: {}",
        String::from_utf8_lossy(&r.stderr)
    );
    let want = lightfold_scene::Image::read_exr(&single).unwrap();
    let mut bad = 0;
    for (a, b) in lin.data.iter().zip(&want.data) {
        if (a - b).abs() > 0.025 * b.abs() + 1e-3 {
            bad += 1;
        }
    }
    assert!(
        bad * 1000 <= lin.data.len(),
        "{bad} of {} channels outside the link bound",
        lin.data.len()
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// On a camera path the image written is the last frame's, and the demo's error report compares
/// it with the reference seen from that frame's camera (it once used the first camera, and a
/// correct image scored 9 dB).
#[test]
fn the_error_report_follows_the_camera_path() {
    let dir = std::env::temp_dir().join(format!("lightfold-orbit-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out = lightfold()
        .args(["demo", "--size", "96x72", "--frames", "2", "--orbit", "25"])
        .arg("--no-frame-files")
        .arg("--work-dir")
        .arg(&dir)
        .arg("--out")
        .arg(dir.join("out.png"))
        .arg("--exr")
        .arg(dir.join("out.exr"))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "demo failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let psnr: f64 = stdout
        .lines()
        .find(|l| l.starts_with("whole"))
        .and_then(|l| l.split("psnr").nth(1))
        .and_then(|r| r.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| panic!("no whole-image psnr in:\n{stdout}"));
    assert!(
        psnr > 35.0,
        "whole-image PSNR {psnr} dB on an orbit:\n{stdout}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
