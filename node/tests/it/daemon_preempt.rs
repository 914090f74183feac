//! A node whose frame is stuck on its downstream (a compositor that accepts TCP but never
//! completes the handshake) still answers `Ping` at once, and a new configuration preempts the
//! stuck frame: `Configured` comes within seconds, not after the dial's deadline, the stuck and
//! the queued frames of the old epoch are never answered, and the next frame reaches a working
//! compositor. `Shutdown` preempts a stuck frame too. Needs a GPU adapter: fails, never skips,
//! without one.

use crate::daemon_support;

use daemon_support::*;
use lightfold_net::Timeouts;
use lightfold_protocol::{FrameParams, Layer, Message, PixelFormat};
use std::time::{Duration, Instant};
use tokio::net::TcpListener;

/// Longest the old, one-message-at-a-time node would have been stuck: the black hole's
/// handshake deadline and the dial deadline.
const STUCK: Duration = Duration::from_secs(60);

fn frame(epoch: u64, frame: u64) -> Message {
    Message::RenderFrame {
        epoch,
        frame,
        camera: None,
        params: FrameParams {
            colors: Vec::new(),
            scale: None,
            time: None,
            lights: Vec::new(),
            rows: None,
        },
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pings_are_answered_and_a_new_configuration_preempts_a_stuck_frame() {
    let mut node = start_node_with("node-p", |o| {
        o.timeouts = Timeouts {
            handshake: STUCK,
            ..quick()
        };
        o.dial_deadline = STUCK;
    })
    .await;
    let mut comp = start_compositor().await;
    // Accepts connections into its backlog, never speaks: a dial handshakes until its deadline.
    let black_hole = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let hole = black_hole.local_addr().unwrap().to_string();
    let mut coord = node.coordinator().await;
    let hash = coord.send_scene(&scene()).await;
    let layers = vec![(Layer::Illumination, PixelFormat::Rgb9e5x2)];
    let cfg = node_config(1, hash, &lights(1), layers.clone(), &hole);
    assert_eq!(
        coord.request(Message::ConfigureNode(cfg)).await,
        Message::Configured { epoch: 1 }
    );

    // Frame 1 renders, then waits for the data link; frame 2 waits behind it.
    coord.send(frame(1, 1)).await;
    coord.send(frame(1, 2)).await;
    for seq in 1..=3 {
        let t = Instant::now();
        assert_eq!(
            coord.request(Message::Ping { seq }).await,
            Message::Pong { seq }
        );
        let took = t.elapsed();
        assert!(
            took < Duration::from_secs(1),
            "ping {seq} answered in {took:?}"
        );
        // Later pings find the frame past its render, blocked on the dial.
        tokio::time::sleep(Duration::from_millis(300)).await;
    }

    // A new plan points the node at a working compositor: the stuck frame and the queued one are
    // dropped unanswered, so the next message is `Configured`.
    let cfg = node_config(2, hash, &lights(1), layers.clone(), &comp.addr);
    let n = band_count(&cfg);
    let t = Instant::now();
    coord.send(Message::ConfigureNode(cfg)).await;
    let answer = coord.recv_within(Duration::from_secs(10)).await;
    let took = t.elapsed();
    assert_eq!(answer.ok(), Some(Message::Configured { epoch: 2 }));
    assert!(took < Duration::from_secs(3), "Configured after {took:?}");

    match coord.frame(2, 3).await {
        Message::FrameDone(s) => assert_eq!((s.epoch, s.frame), (2, 3)),
        other => panic!("expected FrameDone of frame 3, got {other:?}"),
    }
    let bands = comp.take(n).await;
    assert!(bands.iter().all(|(_, h, _)| (h.epoch, h.frame) == (2, 3)));
    assert!(comp.idle(), "nothing of the abandoned frames arrived");

    // Shutdown preempts a stuck frame as well.
    let cfg = node_config(3, hash, &lights(1), layers, &hole);
    assert_eq!(
        coord.request(Message::ConfigureNode(cfg)).await,
        Message::Configured { epoch: 3 }
    );
    coord.send(frame(3, 4)).await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    coord.send(Message::Shutdown).await;
    let r = tokio::time::timeout(Duration::from_secs(10), node.handle)
        .await
        .expect("the node stops within seconds of Shutdown")
        .expect("node task");
    r.expect("clean stop");
    drop(black_hole);
}
