//! The one-command cluster as users run it (issue 20): `demo --frames 5` keeps five distinct
//! frames under the frame pattern, and `demo --serve` serves the live view until Ctrl-C — a
//! WebSocket viewer gets frames and steers the camera, and Ctrl-C ends every process cleanly.

use futures::{SinkExt, StreamExt};
use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Duration;
use tokio_tungstenite::tungstenite::Message;

fn lightfold() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_lightfold"));
    c.env("NODEVICE_SELECT", "1");
    c
}

fn work_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lightfold-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// `lightfold demo` on a small image whose work dir, `--out` and `--exr` live in `dir`.
fn demo_in(dir: &std::path::Path) -> Command {
    let mut c = lightfold();
    c.args(["demo", "--size", "64x48"])
        .arg("--work-dir")
        .arg(dir)
        .arg("--out")
        .arg(dir.join("out.png"))
        .arg("--exr")
        .arg(dir.join("out.exr"));
    c
}

#[test]
fn five_frames_of_a_camera_path_are_five_distinct_files() {
    let dir = work_dir("frames5");
    let out = demo_in(&dir)
        .args(["--no-compare", "--orbit", "20", "--frames", "5"])
        .arg("--frame-pattern")
        .arg(dir.join("shots/shot-%03d"))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut seen = Vec::new();
    for i in 1..=5 {
        for ext in ["png", "exr"] {
            let p = dir.join(format!("shots/shot-{i:03}.{ext}"));
            assert!(p.is_file(), "{} missing:\n{stdout}", p.display());
        }
        let png = std::fs::read(dir.join(format!("shots/shot-{i:03}.png"))).unwrap();
        assert!(!seen.contains(&png), "frame {i} repeats an earlier frame");
        seen.push(png);
    }
    assert!(!dir.join("shots/shot-006.png").exists());
    assert!(stdout.contains("wrote 5 frame(s)"), "{stdout}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn demo_serve_streams_steers_and_stops_on_ctrl_c() {
    let dir = work_dir("serve");
    let mut demo = demo_in(&dir)
        .args(["--serve", "127.0.0.1:0"])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    // The coordinator prints where the view is.
    let (tx, rx) = std::sync::mpsc::channel::<String>();
    let stdout = demo.stdout.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut all = String::new();
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if let Some(url) = line.strip_prefix("view: http://") {
                let _ = tx.send(url.split('/').next().unwrap_or_default().to_string());
            }
            all.push_str(&line);
            all.push('\n');
        }
        all
    });
    let addr = rx
        .recv_timeout(Duration::from_secs(300))
        .expect("the demo printed no view address");
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        let (mut ws, _) = tokio_tungstenite::connect_async(format!("ws://{addr}/ws"))
            .await
            .expect("the view accepts a WebSocket");
        let mut steered = false;
        loop {
            let m = tokio::time::timeout(Duration::from_secs(300), ws.next())
                .await
                .expect("a message in time")
                .expect("the socket is open")
                .expect("no WebSocket error");
            match m {
                Message::Binary(b) => {
                    let n = u32::from_be_bytes([b[0], b[1], b[2], b[3]]) as usize;
                    let header: serde_json::Value = serde_json::from_slice(&b[4..4 + n]).unwrap();
                    if header["revision"].as_u64().unwrap() >= 1 {
                        break;
                    }
                    if !steered {
                        steered = true;
                        let orbit = r#"{"type":"orbit","yaw_deg":30,"pitch_deg":0,"id":1}"#;
                        ws.send(Message::Text(orbit.into())).await.unwrap();
                    }
                }
                Message::Text(_) => {}
                other => panic!("unexpected {other:?}"),
            }
        }
    });
    let ok = Command::new("kill")
        .arg("-INT")
        .arg(demo.id().to_string())
        .status()
        .unwrap();
    assert!(ok.success());
    let status = demo.wait().unwrap();
    let stdout = reader.join().unwrap();
    assert!(
        status.success(),
        "Ctrl-C is how a served view ends:\n{stdout}"
    );
    assert!(stdout.contains("the view stopped"), "{stdout}");
    // No process of the demo is left.
    let pids = std::fs::read_to_string(dir.join("pids")).unwrap();
    for line in pids.lines() {
        let pid = line.split_whitespace().nth(1).unwrap();
        let alive = std::path::Path::new(&format!("/proc/{pid}")).exists()
            && !std::fs::read_to_string(format!("/proc/{pid}/stat"))
                .unwrap_or_default()
                .contains(") Z ");
        assert!(!alive, "{line} is still running");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn video_without_ffmpeg_says_what_it_needs_and_keeps_the_frames() {
    let dir = work_dir("video");
    let empty = dir.join("empty-path");
    std::fs::create_dir_all(&empty).unwrap();
    let out = demo_in(&dir)
        .env("PATH", &empty)
        .args(["--no-compare", "--orbit", "20", "--frames", "3"])
        .arg("--frame-pattern")
        .arg(dir.join("f-%02d"))
        .arg("--video")
        .arg(dir.join("out.mp4"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "a video was asked for and not made");
    assert!(stderr.contains("needs ffmpeg on the PATH"), "{stderr}");
    for i in 1..=3 {
        assert!(dir.join(format!("f-{i:02}.png")).is_file(), "frame {i}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
