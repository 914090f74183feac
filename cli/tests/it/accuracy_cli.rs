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

/// A calibration as `lightfold calibrate` caches it, for `balls` at 400×300: the scene's own
/// floor stops gaining, 2048² maps reach 45 dB at 64 samples.
const MAP_BOUND: &str = r#"{
  "source": "test calibration",
  "calibrated": true,
  "truth_floor_db": 56.0,
  "curves": [
    {"map_floor": 512, "unfiltered": [[4, 29.0], [16, 35.5], [64, 37.5]], "filtered": [],
     "seconds_per_sample": 0.01},
    {"map_floor": 2048, "unfiltered": [[4, 30.0], [16, 40.0], [64, 46.0]], "filtered": [],
     "seconds_per_sample": 0.03}
  ]
}"#;

#[test]
fn a_calibration_sets_the_plans_default_target_and_a_bad_model_file_is_an_error() {
    let dir = fresh_dir("error-model");
    let model = dir.join("model.json");
    std::fs::write(&model, MAP_BOUND).unwrap();
    let plan = |extra: &[&str]| {
        lightfold()
            .args(["plan", "--scene", "balls", "--size", "400x300"])
            .args(extra)
            .output()
            .unwrap()
    };
    let out = plan(&["--error-model", &model.display().to_string()]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains("error target 45.0 dB")
            && text.contains("16 → 64, shadow maps from 2048²")
            && text.contains("this scene's calibration"),
        "{text}"
    );
    assert!(!String::from_utf8_lossy(&out.stderr).contains("another scene"));
    // A model made for another scene or size is used, with a warning.
    let other = dir.join("other.json");
    std::fs::write(
        &other,
        MAP_BOUND.replace(
            "\"source\"",
            "\"key\": \"0123456789abcdef01234567\", \"source\"",
        ),
    )
    .unwrap();
    let out = plan(&["--error-model", &other.display().to_string()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success() && err.contains("calibrated for another scene"),
        "{err}"
    );
    // Control: the default scene's model, no target asked for: the scene as it asks.
    let out = plan(&["--error-model", "default"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success() && !text.contains("error target"),
        "{text}"
    );
    // An empty cache: nothing calibrated, the same as the default.
    let cache = dir.join("cache").display().to_string();
    let out = plan(&["--model-cache", &cache]);
    assert!(!String::from_utf8_lossy(&out.stdout).contains("error target"));
    // Broken or missing model files are refused with their path.
    std::fs::write(&model, &MAP_BOUND[..MAP_BOUND.len() / 2]).unwrap();
    for path in [model.clone(), dir.join("missing.json")] {
        let out = plan(&["--error-model", &path.display().to_string()]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{path:?}");
        assert!(err.contains("cannot read the error model"), "{err}");
    }
}
