//! A node given a scene it cannot get, an unsupported format, a frame it was not configured for or
//! a wrong token says so clearly and keeps serving: a good request succeeds after each. Scenes are
//! cached by hash in memory (a second coordinator finds them) and on disk (a restarted node finds
//! them). Needs a GPU adapter: fails, never skips, without one.

use crate::daemon_support;

use daemon_support::*;
use lightfold_net::{Identity, NetError, dial};
use lightfold_protocol::{ErrorCode, Layer, Message, PixelFormat, Role};

fn expect_error(m: Message, code: ErrorCode, needle: &str) {
    match &m {
        Message::Error {
            code: c, message, ..
        } if *c == code && message.contains(needle) => {}
        _ => panic!("expected {code:?} mentioning {needle:?}, got {m:?}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_requests_get_clear_errors_and_the_node_keeps_serving() {
    let mut node = start_node("node-e", None).await;
    let mut comp = start_compositor().await;
    let mut coord = node.coordinator().await;

    // A wrong token fails the handshake; the node goes on serving the right one.
    let intruder = Identity::new(b"not the token", Role::Coordinator, "intruder");
    match dial(&node.addr, &intruder, quick()).await {
        Err(NetError::Handshake { .. }) => {}
        other => panic!("expected a handshake failure, got {other:?}"),
    }
    assert_eq!(
        coord.request(Message::Ping { seq: 1 }).await,
        Message::Pong { seq: 1 }
    );

    // A configuration naming a scene the node never received.
    let scene = scene();
    let bytes = scene.to_bytes().unwrap();
    let hash = scene.content_hash();
    let unknown = [0xab; 32];
    let cfg = node_config(
        1,
        unknown,
        &lights(1),
        vec![(Layer::Illumination, PixelFormat::Rgb9e5x2)],
        &comp.addr,
    );
    expect_error(
        coord.request(Message::ConfigureNode(cfg)).await,
        ErrorCode::UnknownScene,
        "abab",
    );

    // Another scene's bytes under the offered hash, then bytes that are no scene at all.
    let mut other = scene.clone();
    other.exposure *= 2.0;
    let forged = other.to_bytes().unwrap();
    let offer = Message::SceneOffer {
        hash,
        size: forged.len() as u64,
    };
    assert_eq!(
        coord.request(offer).await,
        Message::SceneNeed { hash, need: true }
    );
    coord.send_chunks(hash, &forged, 4096).await;
    expect_error(coord.recv().await, ErrorCode::UnknownScene, "content hash");
    let garbage = vec![0x5a; 1000];
    let offer = Message::SceneOffer {
        hash,
        size: garbage.len() as u64,
    };
    assert_eq!(
        coord.request(offer).await,
        Message::SceneNeed { hash, need: true }
    );
    coord.send_chunks(hash, &garbage, 300).await;
    expect_error(coord.recv().await, ErrorCode::BadConfig, "does not decode");
    let offer = Message::SceneOffer {
        hash,
        size: bytes.len() as u64,
    };
    // The real scene is then accepted.
    assert_eq!(
        coord.request(offer).await,
        Message::SceneNeed { hash, need: true }
    );
    coord.send_chunks(hash, &bytes, 4096).await;
    assert!(matches!(coord.recv().await, Message::SceneReady { .. }));

    // Formats a node cannot emit.
    for (layer, format) in [
        (Layer::Illumination, PixelFormat::Rgba8Linear),
        (Layer::Radiance, PixelFormat::F32x3),
        (Layer::Depth, PixelFormat::F16x4),
    ] {
        let cfg = node_config(2, hash, &lights(1), vec![(layer, format)], &comp.addr);
        expect_error(
            coord.request(Message::ConfigureNode(cfg)).await,
            ErrorCode::UnsupportedFormat,
            &format!("{format:?}"),
        );
    }
    // Not configured (the refused configurations left the node unconfigured).
    expect_error(
        coord.frame(2, 1).await,
        ErrorCode::BadConfig,
        "not configured",
    );

    let cfg = node_config(
        3,
        hash,
        &lights(1),
        vec![(Layer::Illumination, PixelFormat::Seed64)],
        &comp.addr,
    );
    let n = band_count(&cfg);
    assert_eq!(
        coord.request(Message::ConfigureNode(cfg)).await,
        Message::Configured { epoch: 3 }
    );
    expect_error(coord.frame(2, 1).await, ErrorCode::BadConfig, "epoch 3");
    assert!(matches!(coord.frame(3, 1).await, Message::FrameDone(_)));
    assert_eq!(comp.take(n).await.len(), n);

    // Reconfigured without a restart to no light at all (the planner's stand-in when nothing is
    // lit): every illumination band is empty.
    let cfg = node_config(
        4,
        hash,
        &[],
        vec![(Layer::Illumination, PixelFormat::Rgb9e5x2)],
        &comp.addr,
    );
    assert_eq!(
        coord.request(Message::ConfigureNode(cfg)).await,
        Message::Configured { epoch: 4 }
    );
    match coord.frame(4, 1).await {
        Message::FrameDone(s) => assert_eq!(s.empty_bands as usize, n, "{s:?}"),
        other => panic!("expected FrameDone, got {other:?}"),
    }
    let bands = comp.take(n).await;
    assert!(
        bands
            .iter()
            .all(|(_, h, p)| h.empty && h.epoch == 4 && p.is_empty())
    );

    // A coordinator that leaves without Shutdown leaves the node running with its scenes.
    drop(coord);
    let mut second = node.coordinator().await;
    let again = Message::SceneOffer {
        hash,
        size: bytes.len() as u64,
    };
    assert_eq!(
        second.request(again).await,
        Message::SceneNeed { hash, need: false }
    );

    // Shutdown from the coordinator stops the daemon cleanly.
    second.send(Message::Shutdown).await;
    let r = tokio::time::timeout(WAIT, node.handle)
        .await
        .expect("node stops")
        .expect("task");
    r.expect("clean stop");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scenes_survive_a_restart_in_the_disk_cache() {
    let dir = std::env::temp_dir().join(format!("lightfold-node-cache-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let comp = start_compositor().await;
    let scene = scene();
    let bytes = scene.to_bytes().unwrap();
    let hash = scene.content_hash();

    let mut node = start_node("node-c", Some(dir.clone())).await;
    let mut coord = node.coordinator().await;
    assert_eq!(coord.send_scene(&scene).await, hash);
    drop(coord);
    node.stop().await;

    // A corrupt file under another hash's name is discarded, not trusted.
    let other = [7u8; 32];
    let bogus = dir.join(format!(
        "{}.scene",
        lightfold_node::daemon::scene_cache::hex(&other)
    ));
    std::fs::write(&bogus, &bytes).unwrap();

    let mut node = start_node("node-c", Some(dir.clone())).await;
    let mut coord = node.coordinator().await;
    let offer = Message::SceneOffer {
        hash,
        size: bytes.len() as u64,
    };
    assert_eq!(
        coord.request(offer).await,
        Message::SceneNeed { hash, need: false }
    );
    let cfg = node_config(
        1,
        hash,
        &lights(1),
        vec![(Layer::Illumination, PixelFormat::Rgb9e5x2)],
        &comp.addr,
    );
    assert_eq!(
        coord.request(Message::ConfigureNode(cfg)).await,
        Message::Configured { epoch: 1 }
    );
    let offer = Message::SceneOffer {
        hash: other,
        size: bytes.len() as u64,
    };
    assert_eq!(
        coord.request(offer).await,
        Message::SceneNeed {
            hash: other,
            need: true
        }
    );
    assert!(!bogus.exists(), "the mismatching file was removed");
    drop(coord);
    node.stop().await;
    let _ = std::fs::remove_dir_all(&dir);
}
