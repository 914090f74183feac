//! Several hosts on one machine: daemons in separate network namespaces joined by a bridge and
//! veth pairs (`scripts/netns-cluster.sh`), the coordinator in the root namespace. Traffic crosses
//! real interfaces with non-loopback addresses. Needs root (CAP_NET_ADMIN) and iproute2; fails
//! loudly without them.

use std::process::Command;

#[test]
fn cluster_across_network_namespaces() {
    let is_root = Command::new("id")
        .arg("-u")
        .output()
        .map(|o| o.stdout == b"0\n")
        .unwrap_or(false);
    assert!(
        is_root,
        "the multi-host test needs root for `ip netns` (run the tests as root)"
    );
    let dir = std::env::temp_dir().join(format!("lightfold-netns-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let png = dir.join("out.png");
    let out = Command::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../scripts/netns-cluster.sh"
    ))
    .args([
        "2",
        "2",
        "--scene",
        "box",
        "--size",
        "96x72",
        "-K",
        "16",
        "--verbose",
        "--out",
    ])
    .arg(&png)
    .arg("--exr")
    .arg(dir.join("out.exr"))
    .env("LIGHTFOLD_BIN", env!("CARGO_BIN_EXE_lightfold"))
    .env("RUST_BACKTRACE", "0")
    .output()
    .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "netns cluster failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // The full plan's links (`--verbose`) name the namespace addresses, not loopback.
    assert!(stdout.contains("10.77.0."), "{stdout}");
    assert!(png.exists());
    let _ = std::fs::remove_dir_all(&dir);
}
