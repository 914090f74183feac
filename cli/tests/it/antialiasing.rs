//! `lightfold render --aa N` end to end, on the GPU and the CPU reference: `--aa 1` writes the
//! same bytes as no `--aa` (the default path is untouched), and `--aa 2` writes an image of the
//! size asked for that differs from it. How close `--aa N` comes to the area-averaged truth is
//! `harness/tests/it/antialiasing.rs`.

use std::path::{Path, PathBuf};
use std::process::Command;

const SCENE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/silhouettes.toml");

/// Runs `lightfold render` on the silhouette scene at 48x36 into `out` with `extra` arguments.
fn render(out: &Path, extra: &[&str]) {
    let o = Command::new(env!("CARGO_BIN_EXE_lightfold"))
        .args(["render", "--scene", SCENE, "--size", "48x36", "--out"])
        .arg(out)
        .args(extra)
        .env("NODEVICE_SELECT", "1")
        .output()
        .expect("runs");
    assert!(
        o.status.success(),
        "render {extra:?} failed:\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

fn bytes(p: &Path) -> Vec<u8> {
    std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

#[test]
fn aa_1_is_the_default_image_bit_for_bit_and_aa_2_is_not() {
    let dir = tempdir();
    for mode in [&[][..], &["--reference"][..]] {
        let path = |name: &str| dir.join(format!("{name}.exr"));
        let with = |aa: Option<&'static str>| -> Vec<&'static str> {
            let mut a = mode.to_vec();
            a.extend(aa.map(|n| ["--aa", n]).into_iter().flatten());
            a
        };
        render(&path("default"), &with(None));
        render(&path("aa1"), &with(Some("1")));
        render(&path("aa2"), &with(Some("2")));
        assert!(
            bytes(&path("default")) == bytes(&path("aa1")),
            "{mode:?}: --aa 1 changed the EXR"
        );
        assert!(
            bytes(&path("default").with_extension("png"))
                == bytes(&path("aa1").with_extension("png")),
            "{mode:?}: --aa 1 changed the PNG"
        );
        assert!(
            bytes(&path("default")) != bytes(&path("aa2")),
            "{mode:?}: --aa 2 wrote the one-sample image"
        );
        let png = image::open(path("aa2").with_extension("png")).unwrap();
        assert_eq!(
            (png.width(), png.height()),
            (48, 36),
            "{mode:?}: --aa 2 writes the size asked for"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

fn tempdir() -> PathBuf {
    let d = std::env::temp_dir().join(format!("lightfold-aa-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}
