//! `lightfold render --partitions P` end to end (issue 24's sort-last partitions on one device):
//! the parts' eye passes drawn alone and selected per pixel by the nearest surface give the
//! unpartitioned image bit for bit; combinations that cannot hold are refused.

use std::path::Path;
use std::process::{Command, Output};

const SCENE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/glass.toml");

fn render(out: &Path, extra: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_lightfold"))
        .args([
            "render",
            "--scene",
            SCENE,
            "--size",
            "64x48",
            "--samples",
            "4",
            "--out",
        ])
        .arg(out)
        .args(extra)
        .env("NODEVICE_SELECT", "1")
        .output()
        .expect("runs")
}

fn pixels(p: &Path) -> Vec<u8> {
    image::open(p)
        .unwrap_or_else(|e| panic!("{}: {e}", p.display()))
        .to_rgb8()
        .into_raw()
}

#[test]
fn partitions_render_the_unpartitioned_image_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let path = |n: &str| dir.path().join(format!("{n}.exr"));
    for (name, extra) in [("one", &[][..]), ("three", &["--partitions", "3"][..])] {
        let o = render(&path(name), extra);
        assert!(
            o.status.success(),
            "{extra:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    }
    let png = |n: &str| pixels(&path(n).with_extension("png"));
    let (one, three) = (png("one"), png("three"));
    let differ = one.iter().zip(&three).filter(|(a, b)| a != b).count();
    assert_eq!(differ, 0, "{differ} PNG values differ");
    assert!(
        std::fs::read(path("one")).unwrap() == std::fs::read(path("three")).unwrap(),
        "EXR differs"
    );
    let mut o = render(&path("timed"), &["--partitions", "3", "--timings"]);
    assert!(o.status.success());
    let text = String::from_utf8_lossy(&std::mem::take(&mut o.stdout)).to_string();
    assert_eq!(text.matches("partition ").count(), 3, "{text}");
}

#[test]
fn partitions_refuse_the_reference_and_the_penumbra_filter() {
    let dir = tempfile::tempdir().unwrap();
    for extra in [
        &["--partitions", "2", "--reference"][..],
        &["--partitions", "2", "--penumbra-filter", "2"][..],
    ] {
        let o = render(&dir.path().join("x.exr"), extra);
        assert!(!o.status.success(), "{extra:?} was accepted");
        assert!(
            String::from_utf8_lossy(&o.stderr).contains("--partitions"),
            "{extra:?}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
    }
}

/// `lightfold plan --partitions P` prints the grid: parts × light groups, each node's part, the
/// depth compose along the chain; an impossible count is refused with the largest that works.
#[test]
fn plan_prints_the_partition_grid() {
    let plan = |extra: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_lightfold"))
            .args([
                "plan",
                "--scene",
                SCENE,
                "--nodes",
                "16",
                "--compositors",
                "4",
                "-K",
                "4",
            ])
            .args(extra)
            .output()
            .expect("runs")
    };
    let out = plan(&["--partitions", "2"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("partitions: 2 parts × "), "{text}");
    assert!(
        text.contains("part 0 · ") && text.contains("part 1 · "),
        "{text}"
    );
    assert!(text.contains("merge") && text.contains("depth"), "{text}");
    let out = plan(&["--partitions", "64"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(err.contains("leave a part empty"), "{err}");
}
