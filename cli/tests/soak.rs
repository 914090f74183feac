//! `lightfold soak` in small: a few random faults (seeded) over a 64×48 orbit on a real
//! multi-process cluster. It exits 0 (no frame lost, duplicated, out of order or wrong), writes
//! its report files with one row per fault, and leaves no daemon process behind.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const FAULTS: usize = 4;

#[test]
fn a_short_soak_passes_and_leaves_no_process_behind() {
    let dir = std::env::temp_dir().join(format!("lightfold-soak-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("report");
    let mut child = Command::new(env!("CARGO_BIN_EXE_lightfold"))
        .env("NODEVICE_SELECT", "1")
        .args(["--log", "warn", "soak", "--size", "64x48", "--seed", "3"])
        .args(["--faults", &FAULTS.to_string(), "--settle-frames", "3"])
        .args(["--max-seconds", "120", "--daemon-log", "warn", "--out"])
        .arg(&out)
        .stdout(std::fs::File::create(dir.join("stdout")).unwrap())
        .stderr(std::fs::File::create(dir.join("stderr")).unwrap())
        .stdin(Stdio::null())
        .spawn()
        .unwrap();
    let pid = child.id();
    let deadline = Instant::now() + Duration::from_secs(400);
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("the soak did not finish within 400 s");
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let stdout = std::fs::read_to_string(dir.join("stdout")).unwrap();
    let stderr = std::fs::read_to_string(dir.join("stderr")).unwrap();
    assert!(status.success(), "{status}\n{stdout}\n{stderr}");
    let csv = std::fs::read_to_string(out.join("soak.csv")).unwrap();
    for zero in [
        "frames lost,0",
        "frames duplicated,0",
        "frames out of order,0",
    ] {
        assert!(csv.lines().any(|l| l == zero), "{zero:?} in\n{csv}");
    }
    assert!(
        csv.contains(&format!("faults injected,\"{FAULTS} (")),
        "{csv}"
    );
    let faults = std::fs::read_to_string(out.join("faults.csv")).unwrap();
    assert_eq!(faults.lines().count(), FAULTS + 1, "{faults}");
    let md = std::fs::read_to_string(out.join("soak.md")).unwrap();
    assert!(md.contains("| frames wrong | 0 of "), "{md}");
    for f in ["daemons.csv", "epochs.csv"] {
        assert!(out.join(f).is_file(), "{f}");
    }
    // Every daemon (its command line names the soak's token directory) has exited.
    let marker = format!("lightfold-soak-{pid}");
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let left: Vec<String> = std::fs::read_dir("/proc")
            .unwrap()
            .flatten()
            .filter_map(|e| std::fs::read(e.path().join("cmdline")).ok())
            .map(|c| String::from_utf8_lossy(&c).replace('\0', " "))
            .filter(|c| c.contains(&marker))
            .collect();
        if left.is_empty() {
            break;
        }
        assert!(Instant::now() < deadline, "left behind: {left:?}");
        std::thread::sleep(Duration::from_millis(100));
    }
    let _ = std::fs::remove_dir_all(&dir);
}
