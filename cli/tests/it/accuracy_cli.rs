//! `lightfold accuracy` as a newcomer runs it (issue 28, item 8): its results go to a folder of
//! their own in the current directory (never over the committed `docs/accuracy/`), a knob the
//! chosen sweep does not vary is an error, and the report reads cleanly.

use std::process::Command;

fn lightfold() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_lightfold"));
    c.env("NODEVICE_SELECT", "1");
    c
}

fn fresh_dir(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("lightfold-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn a_knob_the_sweep_does_not_vary_is_an_error() {
    let out = lightfold()
        .args(["accuracy", "--sweep", "tiny", "--knobs", "map"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("does not vary map"), "{stderr}");
}

#[test]
fn a_sweep_writes_into_its_own_folder_with_clean_figures() {
    let cwd = fresh_dir("accuracy-cwd");
    let out = lightfold()
        .current_dir(&cwd)
        .env_remove("LP_NUM_THREADS")
        .args([
            "accuracy",
            "--sweep",
            "tiny",
            "--size",
            "48x36",
            "--truth-samples",
            "4",
            "--repeats",
            "1",
            "--cache-dir",
        ])
        .arg(cwd.join("cache"))
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let results = cwd.join("lightfold-accuracy/balls");
    for f in ["sweep.csv", "README.md", "frontier.svg"] {
        assert!(
            results.join(f).is_file(),
            "{f} not in {}",
            results.display()
        );
    }
    assert!(!cwd.join("docs").exists(), "wrote into ./docs");
    assert!(!cwd.join("target").exists(), "wrote into ./target");
    let readme = std::fs::read_to_string(results.join("README.md")).unwrap();
    assert!(
        !readme.contains("unset"),
        "the reproduce line names an unset variable"
    );
    let svg = std::fs::read_to_string(results.join("frontier.svg")).unwrap();
    assert!(
        !svg.contains("00000000") && !svg.contains("99999999"),
        "axis ticks with float noise"
    );
    let _ = std::fs::remove_dir_all(&cwd);
}
