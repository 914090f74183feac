//! The in-process cluster against a single-device render (issue 9): the same image within the
//! link formats' bounds for two built-in scenes, chain and tree topologies and K = 2 and 4, with
//! every node rendering exactly its planned lights; a light colour change without re-rendering;
//! and clear errors within deadlines for daemons that never answer or fail authentication.

use lightfold_coordinator::control::{DaemonAddr, Session};
use lightfold_coordinator::plan::{MapSizing, Topology};
use lightfold_coordinator::run::{ColorChange, RunOptions};
use lightfold_harness::{
    InProcessCluster, assert_close, render_on, single_device, small, test_control,
};
use lightfold_protocol::Role;
use std::time::{Duration, Instant};

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn cluster_matches_single_device_render() {
    let cluster = InProcessCluster::start(5, 5).await.unwrap();
    let mut session = cluster.connect(test_control()).await.unwrap();
    let gpu = lightfold_harness::gpu();
    for name in ["box", "balls"] {
        let scene = small(name);
        let want = single_device(&gpu, &scene, false);
        for topology in [Topology::Chain, Topology::Tree] {
            for k in [2, 4] {
                let mut opts = RunOptions {
                    control: test_control(),
                    ..RunOptions::default()
                };
                opts.plan.lights_per_node = k;
                opts.plan.topology = topology;
                opts.plan.map_sizing = MapSizing::Fixed(scene.quality.shadow_map_size);
                let out = render_on(&mut session, &scene, &opts).await.unwrap();
                let what = format!("{name} {topology} K={k}");
                assert_eq!(out.plan.k, k, "{what}: the plan kept K");
                assert_close(&out.frames[0].image, &want, &what);
                for node in &out.plan.nodes {
                    let stats = out.frames[0]
                        .stats
                        .iter()
                        .find(|s| s.daemon_id == node.node)
                        .unwrap();
                    let planned: Vec<u32> = node.lights.iter().map(|&l| l as u32).collect();
                    assert_eq!(
                        stats.lights_rendered, planned,
                        "{what}: {} rendered its planned lights",
                        node.node
                    );
                }
                let rendered: usize = out.frames[0]
                    .stats
                    .iter()
                    .map(|s| s.lights_rendered.len())
                    .sum();
                assert_eq!(
                    rendered,
                    out.plan.active.len(),
                    "{what}: every active light rendered once"
                );
            }
        }
    }
    session.detach();
    cluster.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn light_colour_change_needs_no_rerender() {
    let scene = small("balls");
    let cluster = InProcessCluster::start(3, 3).await.unwrap();
    let mut opts = RunOptions {
        control: test_control(),
        frames: 2,
        ..RunOptions::default()
    };
    opts.plan.lights_per_node = 4;
    opts.plan.walkthrough = true;
    opts.plan.map_sizing = MapSizing::Fixed(scene.quality.shadow_map_size);
    let new_color = [0.3, 0.6, 1.0];
    opts.color_changes = vec![ColorChange {
        frame: 2,
        light: 0,
        color: new_color,
    }];
    let out = cluster.render(&scene, &opts).await.unwrap();
    assert_eq!(out.frames.len(), 2);
    let gpu = lightfold_harness::gpu();
    // Walkthrough nodes fit their maps to every receiver: compare with a single-device render
    // that does the same, within the link formats' bound.
    assert_close(
        &out.frames[0].image,
        &single_device(&gpu, &scene, true),
        "frame 1",
    );
    let mut recoloured = scene.clone();
    recoloured.lights[0].color = new_color;
    assert_close(
        &out.frames[1].image,
        &single_device(&gpu, &recoloured, true),
        "frame 2 (new colour)",
    );
    for node in &out.plan.nodes {
        let s = out.frames[1]
            .stats
            .iter()
            .find(|s| s.daemon_id == node.node)
            .unwrap();
        assert!(
            s.lights_rendered.is_empty(),
            "{} re-rendered for a colour change",
            node.node
        );
        assert_eq!(
            s.shadow_passes, 0,
            "{} rendered shadow maps again",
            node.node
        );
    }
    cluster.stop().await.unwrap();
}

#[tokio::test]
async fn silent_daemon_is_named_within_the_deadline() {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let _hold = tokio::spawn(async move {
        let _conn = listener.accept().await;
        tokio::time::sleep(Duration::from_secs(30)).await;
    });
    let mut control = test_control();
    control.link.handshake = Duration::from_millis(500);
    let sink = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let t = Instant::now();
    let d = [DaemonAddr {
        address: addr.clone(),
        role: Role::Node,
        id: None,
    }];
    let me = lightfold_net::Identity::new(b"t", Role::Coordinator, "coordinator");
    let e = Session::connect(&d, sink, None, me, control)
        .await
        .unwrap_err();
    assert!(
        t.elapsed() < Duration::from_secs(5),
        "took {:?}",
        t.elapsed()
    );
    let msg = e.to_string();
    assert!(msg.contains(&addr) && msg.contains("timed out"), "{msg}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn wrong_token_and_unreachable_daemon_are_clear_errors() {
    let cluster = InProcessCluster::start(0, 1).await.unwrap();
    let sink = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let me =
        lightfold_net::Identity::new(b"not the cluster token", Role::Coordinator, "coordinator");
    let d = [DaemonAddr {
        address: cluster.compositors[0].clone(),
        role: Role::Compositor,
        id: None,
    }];
    let e = Session::connect(&d, sink, None, me, test_control())
        .await
        .unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains(&cluster.compositors[0]) && msg.contains("handshake"),
        "{msg}"
    );

    // A closed port: refused dials are retried (daemons may still be starting) until the
    // registration deadline, then reported with the address.
    let closed = {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        l.local_addr().unwrap().to_string()
    };
    let sink = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let d = [DaemonAddr {
        address: closed.clone(),
        role: Role::Node,
        id: None,
    }];
    let mut quick = test_control();
    quick.register = Duration::from_secs(1);
    let t = Instant::now();
    let e = Session::connect(&d, sink, None, cluster.identity(), quick)
        .await
        .unwrap_err();
    assert!(e.to_string().contains(&closed), "{e}");
    assert!(
        t.elapsed() < Duration::from_secs(5),
        "took {:?}",
        t.elapsed()
    );

    // The daemon listed as a node is a compositor.
    let sink = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let d = [DaemonAddr {
        address: cluster.compositors[0].clone(),
        role: Role::Node,
        id: None,
    }];
    let e = Session::connect(&d, sink, None, cluster.identity(), test_control())
        .await
        .unwrap_err();
    assert!(e.to_string().contains("Compositor"), "{e}");
    cluster.stop().await.unwrap();
}

#[tokio::test]
async fn wrong_protocol_version_is_a_clear_error() {
    use bytes::BytesMut;
    use lightfold_protocol::frame::{Codec, Frame};
    use lightfold_protocol::handshake::{Hello, MAGIC};
    use tokio::io::AsyncWriteExt;
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let _peer = tokio::spawn(async move {
        let (mut s, _) = listener.accept().await.unwrap();
        let hello = Hello {
            magic: MAGIC,
            version: 99,
            role: Role::Node,
            daemon_id: "future".into(),
            nonce: [7; 32],
        };
        let mut buf = BytesMut::new();
        Codec::new(1 << 20)
            .encode(&Frame::Hello(hello), &mut buf)
            .unwrap();
        s.write_all(&buf).await.unwrap();
        tokio::time::sleep(Duration::from_secs(5)).await;
    });
    let sink = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let me = lightfold_net::Identity::new(b"t", Role::Coordinator, "coordinator");
    let d = [DaemonAddr {
        address: addr.clone(),
        role: Role::Node,
        id: None,
    }];
    let e = Session::connect(&d, sink, None, me, test_control())
        .await
        .unwrap_err();
    let msg = e.to_string();
    assert!(msg.contains(&addr) && msg.contains("version"), "{msg}");
}
