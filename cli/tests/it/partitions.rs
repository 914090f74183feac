//! `lightfold render --partitions P` end to end (issue 24's sort-last partitions on one device):
//! the parts' eye passes drawn alone, each with maps fitted to its part, and selected per pixel
//! by the nearest surface give the unpartitioned image; combinations that cannot hold are
//! refused.

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

/// Each part's maps are fitted to that part's receivers (as a sort-last node of the cluster
/// fits them), so shadow edges fall on other texel grids than the whole scene's maps: the image
/// agrees with the unpartitioned one within what texel placement moves (the CPU reference is
/// as close to either: `docs/scaling.md`), with no bias.
#[test]
fn partitions_render_the_unpartitioned_image() {
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
    let exr = |n: &str| lightfold_scene::Image::read_exr(&path(n)).unwrap();
    let (one, three) = (exr("one"), exr("three"));
    let (mut sum1, mut sum3, mut err, mut peak) = (0.0f64, 0.0f64, 0.0f64, 0.0f32);
    for (&a, &b) in three.data.iter().zip(&one.data) {
        sum3 += f64::from(a);
        sum1 += f64::from(b);
        err += f64::from(a - b).powi(2);
        peak = peak.max(b);
    }
    let rmse = (err / one.data.len() as f64).sqrt();
    let psnr = 20.0 * (f64::from(peak) / rmse).log10();
    assert!(
        psnr > 50.0,
        "PSNR {psnr:.1} dB against the unpartitioned image"
    );
    assert!(
        (sum3 / sum1 - 1.0).abs() < 5e-4,
        "bias {}",
        sum3 / sum1 - 1.0
    );
    // The PNGs differ only at a few shadow-edge pixels.
    let png = |n: &str| pixels(&path(n).with_extension("png"));
    let differ = png("one")
        .iter()
        .zip(&png("three"))
        .filter(|(a, b)| a.abs_diff(**b) > 2)
        .count();
    assert!(
        differ * 100 < one.data.len(),
        "{differ} PNG values differ by more than 2"
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
/// depth compose along the chain; more parts than meshes split the large meshes; more than the
/// limit is refused. `--tiles T` prints the tiles' grid and rows, beside `--partitions P` the
/// grid of both; the automatic plan its decomposition line.
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
    // Untiled: on these synthetic nodes the automatic choice would add tiles (below).
    let out = plan(&["--partitions", "2", "--tiles", "1"]);
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
    // More parts than meshes: the large meshes are split into chunks (`plan::scene_for`).
    let out = plan(&["--partitions", "16"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("partitions: 16 parts × "), "{text}");
    assert!(text.contains("part 15 · "), "{text}");
    let out = plan(&["--partitions", "65"]);
    assert!(!out.status.success(), "65 partitions were accepted");
    // Sort-first tiles: rows per tile on each node's line; a grid beside partitions.
    let out = plan(&["--tiles", "3", "--size", "320x240"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("tiles: 3 sort-first tiles × "), "{text}");
    assert!(text.contains("tile 2 (rows "), "{text}");
    let out = plan(&["--tiles", "2", "--partitions", "2", "--size", "320x240"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains("tiles: 2 sort-first tiles × 2 sort-last parts × "),
        "{text}"
    );
    assert!(text.contains("part 1 · tile 1 (rows "), "{text}");
    // The automatic choice says why.
    let out = plan(&["--size", "320x240"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("decomposition: "), "{text}");
}

/// `--peels`: `auto` peels the glass stack's three translucent layers and says why; an asked
/// count beside tiles is refused with the reason; a bad count is refused by the parser.
#[test]
fn plan_peels_glass_as_asked_and_refuses_what_peeling_does_not_take() {
    const STACK: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/glass-stack.toml");
    let plan = |extra: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_lightfold"))
            .args(["plan", "--scene", STACK, "--nodes", "8", "-K", "16"])
            .args(extra)
            .output()
            .expect("runs")
    };
    let out = plan(&["--peels", "auto"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains("peels: 3 translucent layer(s): the scene's depth complexity in view is 3"),
        "{text}"
    );
    assert!(
        text.contains("4 eye layers × 1 light group(s) = 4 nodes"),
        "{text}"
    );
    assert!(
        text.contains("opaque layer · ") && text.contains("translucent layer 3 · "),
        "{text}"
    );
    // Off by default: the classic plan.
    let out = plan(&[]);
    assert!(out.status.success());
    assert!(!String::from_utf8_lossy(&out.stdout).contains("peels:"));
    let out = plan(&["--peels", "2", "--tiles", "2"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("peeled translucency takes no sort-first tiles"),
        "{err}"
    );
    let out = plan(&["--peels", "5"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("expected off, auto or 1 to 4"), "{err}");
}
