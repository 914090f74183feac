//! One stage in-process over real links: it combines an upstream partial sum and a node's bands
//! into the in-memory result within the link formats' bound, applies per-frame light colours,
//! reports `FrameDone` statistics, reconfigures to a new epoch without restarting (dropping the
//! old epoch's bands), relays, and stops on `Shutdown`.

use crate::support;

use lightfold_harness::driver::DriverError;
use lightfold_protocol::{ErrorCode, FrameParams, Layer, Message, PixelFormat};
use support::*;

const ILL: Layer = Layer::Illumination;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stage_accumulates_its_inputs_band_by_band() {
    let size = (37, 23, 6);
    let (w, h, _) = size;
    let stage = start_stage("c1").await;
    let (mut sink, sink_addr) = sink().await;
    let mut ctl = stage.control().await;
    assert_eq!(ctl.capabilities.daemon_id, "c1");
    let ops = [("accumulate", r#"{"colors": [[0.5, 1.0, 2.0]]}"#)];
    let cfg = config(
        1,
        size,
        vec![
            input("up", &[(ILL, PixelFormat::F16x6)]),
            input("n1", &[(ILL, PixelFormat::Rgb9e5x2)]),
        ],
        &ops,
        &[(ILL, PixelFormat::F32x6)],
        &sink_addr,
    );
    ctl.configure(cfg, WAIT).await.unwrap();
    let mut up = stage.producer("up").await;
    let mut node = stage.producer("n1").await;

    let upstream = image(ILL, PixelFormat::F16x6, hdr(1, w, h, ILL, 0..0));
    let local = image(ILL, PixelFormat::Rgb9e5x2, hdr(2, w, h, ILL, 6..12));
    for frame in 1..=2u64 {
        // Frame 2 changes the node's colour without touching the node.
        let (params, colour) = if frame == 1 {
            (no_params(), "[0.5, 1.0, 2.0]")
        } else {
            let p = FrameParams {
                colors: vec![(1, [3.0, 0.25, 1.0])],
                scale: None,
                time: None,
                lights: Vec::new(),
                rows: None,
            };
            (p, "[3.0, 0.25, 1.0]")
        };
        ctl.render(1, frame, params).await.unwrap();
        let s = shape(1, frame, size);
        up.send_frame(&s, std::slice::from_ref(&upstream))
            .await
            .unwrap();
        node.send_frame(&s, std::slice::from_ref(&local))
            .await
            .unwrap();
        let got = sink
            .recv_frame(&s, &[(ILL, PixelFormat::F32x6)], WAIT)
            .await
            .unwrap();
        let stats = ctl.frame_done(frame, WAIT).await.unwrap();

        let ops = format!(r#"{{"colors": [{colour}]}}"#);
        let want = reference(&[("accumulate", &ops)], &[&upstream, &local], w, h);
        let colour: Vec<f32> = serde_json::from_str(colour).unwrap();
        let b_up = link_bound(PixelFormat::F16x6, &upstream.data, 1.0);
        let b_node = link_bound(PixelFormat::Rgb9e5x2, &local.data, 1.0);
        let bound: Vec<f32> = b_up
            .iter()
            .zip(&b_node)
            .enumerate()
            .map(|(k, (a, b))| a + colour[k % 3] * b)
            .collect();
        assert_within(&got[0].data, &want[0], &bound, &format!("frame {frame}"));

        assert_eq!(
            (stats.epoch, stats.frame, stats.daemon_id.as_str()),
            (1, frame, "c1")
        );
        let payload = w as u64 * h as u64 * 24;
        assert!(stats.bytes_out >= payload, "bytes out {}", stats.bytes_out);
        assert!(stats.total_us > 0 && stats.peak_rss_bytes > 0, "{stats:?}");
    }
    assert_eq!(stage.metrics.frames_done(), 2);
    stage.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_new_epoch_reconfigures_without_restart_and_drops_old_bands() {
    let old = (16, 9, 4);
    let new = (21, 11, 5);
    let stage = start_stage("c2").await;
    let (mut sink, sink_addr) = sink().await;
    let mut ctl = stage.control().await;
    let ins = |p| vec![input("a", &[(ILL, p)]), input("b", &[(ILL, p)])];
    let join = [("join", r#"{"inputs": 2}"#)];
    let out = [(ILL, PixelFormat::F32x6)];
    ctl.configure(
        config(1, old, ins(PixelFormat::F16x6), &join, &out, &sink_addr),
        WAIT,
    )
    .await
    .unwrap();
    let mut a = stage.producer("a").await;
    let mut b = stage.producer("b").await;

    // Epoch 2: another size, format and operator, same links.
    let acc = [(
        "accumulate",
        r#"{"upstream": false, "colors": [[1, 1, 1], [2, 2, 2]]}"#,
    )];
    ctl.configure(
        config(2, new, ins(PixelFormat::F32x6), &acc, &out, &sink_addr),
        WAIT,
    )
    .await
    .unwrap();
    // A producer still on epoch 1 sends a whole frame; the stage drops it as stale.
    let (ow, oh, _) = old;
    let stale = image(ILL, PixelFormat::F16x6, hdr(3, ow, oh, ILL, 0..0));
    a.send_frame(&shape(1, 7, old), std::slice::from_ref(&stale))
        .await
        .unwrap();

    let (w, h, _) = new;
    let ia = image(ILL, PixelFormat::F32x6, hdr(4, w, h, ILL, 0..0));
    let ib = image(ILL, PixelFormat::F32x6, hdr(5, w, h, ILL, 0..5));
    ctl.render(2, 8, no_params()).await.unwrap();
    a.send_frame(&shape(2, 8, new), std::slice::from_ref(&ia))
        .await
        .unwrap();
    b.send_frame(&shape(2, 8, new), std::slice::from_ref(&ib))
        .await
        .unwrap();
    let got = sink
        .recv_frame(&shape(2, 8, new), &out, WAIT)
        .await
        .unwrap();
    ctl.frame_done(8, WAIT).await.unwrap();
    let want = reference(&acc, &[&ia, &ib], w, h);
    let zero = vec![0.0; want[0].len()];
    assert_within(&got[0].data, &want[0], &zero, "epoch 2 frame");
    assert_eq!(
        stage.metrics.stale_bands(),
        u64::from(old.1.div_ceil(old.2))
    );

    // A frame requested for an epoch the stage is not in is refused, clearly.
    ctl.render(1, 9, no_params()).await.unwrap();
    match ctl.next_message(WAIT).await.unwrap() {
        Message::Error { code, message, .. } => {
            assert_eq!(code, ErrorCode::BadConfig);
            assert!(
                message.contains("epoch 1") && message.contains("epoch 2"),
                "{message}"
            );
        }
        other => panic!("expected an error, got {other:?}"),
    }
    stage.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stage_without_operators_relays_and_repacks() {
    let size = (13, 10, 3);
    let (w, h, _) = size;
    let stage = start_stage("relay").await;
    let (mut sink, sink_addr) = sink().await;
    let mut ctl = stage.control().await;
    let layers = [
        (ILL, PixelFormat::F16x6),
        (Layer::Depth, PixelFormat::DepthF32),
    ];
    let outs = [
        (Layer::Depth, PixelFormat::DepthF32),
        (ILL, PixelFormat::F32x6),
    ];
    let cfg = config(5, size, vec![input("up", &layers)], &[], &outs, &sink_addr);
    ctl.configure(cfg, WAIT).await.unwrap();
    let mut up = stage.producer("up").await;
    let ill = image(ILL, PixelFormat::F16x6, hdr(6, w, h, ILL, 3..6));
    let depth = image(
        Layer::Depth,
        PixelFormat::DepthF32,
        hdr(7, w, h, Layer::Depth, 0..0),
    );
    ctl.render(5, 1, no_params()).await.unwrap();
    up.send_frame(&shape(5, 1, size), &[ill.clone(), depth.clone()])
        .await
        .unwrap();
    let got = sink
        .recv_frame(&shape(5, 1, size), &outs, WAIT)
        .await
        .unwrap();
    let stats = ctl.frame_done(1, WAIT).await.unwrap();
    assert_eq!(got[0].data, depth.data, "depth relayed bit for bit");
    let bound = link_bound(PixelFormat::F16x6, &ill.data, 1.0);
    assert_within(&got[1].data, &ill.data, &bound, "illumination repacked");
    assert_eq!(stats.empty_bands, 1, "the all-zero band stays empty");
    stage.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_from_the_coordinator_stops_the_stage() {
    let stage = start_stage("c3").await;
    let mut ctl = stage.control().await;
    ctl.send_ping(7).await.unwrap();
    assert_eq!(
        ctl.next_message(WAIT).await.unwrap(),
        Message::Pong { seq: 7 }
    );
    ctl.shutdown().await.unwrap();
    let r = tokio::time::timeout(WAIT, stage.handle)
        .await
        .expect("stops in time");
    r.unwrap().unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_bad_configuration_is_refused_and_the_old_one_kept() {
    let size = (8, 8, 8);
    let img = image(ILL, PixelFormat::F32x6, hdr(10, 8, 8, ILL, 0..0));
    let stage = start_stage("c4").await;
    let (mut sink, sink_addr) = sink().await;
    let mut ctl = stage.control().await;
    let ins = vec![input("n", &[(ILL, PixelFormat::F32x6)])];
    let out = [(ILL, PixelFormat::F32x6)];
    ctl.configure(config(2, size, ins.clone(), &[], &out, &sink_addr), WAIT)
        .await
        .unwrap();
    // A parameter out of range (a negative colour) is refused with the operator's reason.
    let acc = [(
        "accumulate",
        r#"{"upstream": false, "colors": [[1, -1, 1]]}"#,
    )];
    let bad = config(3, size, ins.clone(), &acc, &out, &sink_addr);
    match ctl.configure(bad, WAIT).await {
        Err(DriverError::Refused { code, message }) => {
            assert_eq!(code, ErrorCode::BadConfig);
            assert!(
                message.contains("accumulate")
                    && message.contains("must be finite and non-negative")
                    && message.contains("epoch 3"),
                "{message}"
            );
        }
        other => panic!("expected a refusal, got {other:?}"),
    }
    let mut bad = config(3, size, ins, &[], &out, &sink_addr);
    bad.inputs[0].layers[0].1 = PixelFormat::F16x4;
    match ctl.configure(bad, WAIT).await {
        Err(DriverError::Refused { code, message }) => {
            assert_eq!(code, ErrorCode::UnsupportedFormat, "{message}")
        }
        other => panic!("expected a refusal, got {other:?}"),
    }
    // Epoch 2 still runs.
    let mut n = stage.producer("n").await;
    ctl.render(2, 1, no_params()).await.unwrap();
    n.send_frame(&shape(2, 1, size), std::slice::from_ref(&img))
        .await
        .unwrap();
    let got = sink
        .recv_frame(&shape(2, 1, size), &out, WAIT)
        .await
        .unwrap();
    assert_eq!(got[0].data, img.data);
    ctl.frame_done(1, WAIT).await.unwrap();
    stage.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_reconfiguration_abandons_the_frame_in_progress() {
    let size = (12, 9, 3);
    let (w, h, _) = size;
    let stage = start_stage("c5").await;
    let (mut sink, sink_addr) = sink().await;
    let mut ctl = stage.control().await;
    let ins = vec![input("a", &[(ILL, PixelFormat::F32x6)])];
    let out = [(ILL, PixelFormat::F32x6)];
    ctl.configure(config(1, size, ins.clone(), &[], &out, &sink_addr), WAIT)
        .await
        .unwrap();
    let mut a = stage.producer("a").await;
    let img = image(ILL, PixelFormat::F32x6, hdr(8, w, h, ILL, 0..0));
    // Frame 1 gets one band of three, then the plan changes under it.
    ctl.render(1, 1, no_params()).await.unwrap();
    let (hd, p) = lightfold_harness::driver::pack_band(&shape(1, 1, size), 0, &img).unwrap();
    a.send_band(hd, p).await.unwrap();
    ctl.configure(config(2, size, ins, &[], &out, &sink_addr), WAIT)
        .await
        .unwrap();
    ctl.render(2, 2, no_params()).await.unwrap();
    a.send_frame(&shape(2, 2, size), std::slice::from_ref(&img))
        .await
        .unwrap();
    let got = sink
        .recv_frame(&shape(2, 2, size), &out, WAIT)
        .await
        .unwrap();
    assert_eq!(got[0].data, img.data);
    ctl.frame_done(2, WAIT).await.unwrap();
    assert_eq!(
        stage.metrics.frames_failed(),
        0,
        "an abandoned frame is not a failure"
    );
    stage.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_new_coordinator_and_a_reconnected_producer_take_over() {
    let size = (10, 7, 4);
    let (w, h, _) = size;
    let stage = start_stage("c6").await;
    let (mut sink, sink_addr) = sink().await;
    let out = [(ILL, PixelFormat::F32x6)];
    let img = image(ILL, PixelFormat::F32x6, hdr(9, w, h, ILL, 0..0));
    {
        let mut first = stage.control().await;
        let ins = vec![input("a", &[(ILL, PixelFormat::F32x6)])];
        first
            .configure(config(1, size, ins, &[], &out, &sink_addr), WAIT)
            .await
            .unwrap();
        // The first coordinator leaves without `Shutdown`: the stage keeps its configuration.
    }
    let mut ctl = stage.control().await;
    for frame in 1..=2 {
        // Each frame comes over a new connection from the same producer.
        let mut a = stage.producer("a").await;
        ctl.render(1, frame, no_params()).await.unwrap();
        a.send_frame(&shape(1, frame, size), std::slice::from_ref(&img))
            .await
            .unwrap();
        let got = sink
            .recv_frame(&shape(1, frame, size), &out, WAIT)
            .await
            .unwrap();
        assert_eq!(got[0].data, img.data, "frame {frame}");
        ctl.frame_done(frame, WAIT).await.unwrap();
    }
    stage.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_operators_fold_three_inputs_band_by_band() {
    let size = (23, 14, 4);
    let (w, h, _) = size;
    let stage = start_stage("c7").await;
    let (mut sink, sink_addr) = sink().await;
    let mut ctl = stage.control().await;
    let (f_up, f_node, f_mat) = (
        PixelFormat::F16x6,
        PixelFormat::Rgb9e5x2,
        PixelFormat::Rgba8Linear,
    );
    let dif = Layer::Diffuse;
    let ops = [
        ("accumulate", r#"{"colors": [[2.0, 1.0, 0.5]]}"#),
        ("material", r#"{"stage": "diffuse"}"#),
    ];
    let out = [(Layer::Radiance, PixelFormat::F32x3)];
    let ins = vec![
        input("up", &[(ILL, f_up)]),
        input("n", &[(ILL, f_node)]),
        input("m", &[(dif, f_mat)]),
    ];
    ctl.configure(config(1, size, ins, &ops, &out, &sink_addr), WAIT)
        .await
        .unwrap();
    let up = image(ILL, f_up, quantised(f_up, ILL, hdr(11, w, h, ILL, 8..14)));
    let node = image(
        ILL,
        f_node,
        quantised(f_node, ILL, hdr(12, w, h, ILL, 8..14)),
    );
    let albedo: Vec<f32> = hdr(13, w, h, dif, 0..4)
        .iter()
        .map(|v| (v / 100.0).min(1.0))
        .collect();
    let mat = image(dif, f_mat, quantised(f_mat, dif, albedo));
    let mut producers = [
        stage.producer("up").await,
        stage.producer("n").await,
        stage.producer("m").await,
    ];
    ctl.render(1, 1, no_params()).await.unwrap();
    for (p, img) in producers.iter_mut().zip([&up, &node, &mat]) {
        p.send_frame(&shape(1, 1, size), std::slice::from_ref(img))
            .await
            .unwrap();
    }
    let got = sink
        .recv_frame(&shape(1, 1, size), &out, WAIT)
        .await
        .unwrap();
    let stats = ctl.frame_done(1, WAIT).await.unwrap();
    let want = reference(&ops, &[&up, &node, &mat], w, h);
    assert_eq!(
        got[0].data, want[0],
        "the stage gives the in-memory pipeline's bits"
    );
    // Band 0 has no albedo (an empty band of a required layer, read as zeros); bands 2 and 3
    // have no light, so their radiance leaves empty.
    assert_eq!(stats.empty_bands, 2);
    stage.stop().await;
}

/// A lone `depth` over `f16x6` colour and `depth32` z runs the stage's packed select path
/// (`Depth::apply_packed`); the sink must get the in-memory operator's bits, ties, an empty
/// colour band and an empty depth band (zeros: the nearest surface) included.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_depth_stage_selects_from_packed_bands_bit_for_bit() {
    use lightfold_compositor::ops::{BandMut, BandView, Depth, Operator};
    let size = (29, 17, 4);
    let (w, h, _) = size;
    let (f_ill, f_z) = (PixelFormat::F16x6, PixelFormat::DepthF32);
    let z = Layer::Depth;
    let stage = start_stage("z1").await;
    let (mut sink, sink_addr) = sink().await;
    let mut ctl = stage.control().await;
    let params = r#"{"inputs": 2, "layers": ["illumination"]}"#;
    let ops = [("depth", params)];
    let layers = [(ILL, f_ill), (z, f_z)];
    let out = [(z, f_z), (ILL, f_ill)];
    let ins = vec![input("a", &layers), input("b", &layers)];
    ctl.configure(config(1, size, ins, &ops, &out, &sink_addr), WAIT)
        .await
        .unwrap();
    // Input b: no light in band 0 (an empty band); input a: no depth in band 1; rows 12..14
    // of b copy a's depth (ties go to input 0).
    let ill = [
        quantised(f_ill, ILL, hdr(21, w, h, ILL, 0..0)),
        quantised(f_ill, ILL, hdr(22, w, h, ILL, 0..4)),
    ];
    let za = hdr(23, w, h, z, 4..8);
    let mut zb = hdr(24, w, h, z, 0..0);
    let row = w as usize;
    zb[12 * row..14 * row].copy_from_slice(&za[12 * row..14 * row]);
    let imgs = [
        [image(ILL, f_ill, ill[0].clone()), image(z, f_z, za.clone())],
        [image(ILL, f_ill, ill[1].clone()), image(z, f_z, zb.clone())],
    ];
    let mut producers = [stage.producer("a").await, stage.producer("b").await];
    ctl.render(1, 1, no_params()).await.unwrap();
    for (p, img) in producers.iter_mut().zip(&imgs) {
        p.send_frame(&shape(1, 1, size), img).await.unwrap();
    }
    let got = sink
        .recv_frame(&shape(1, 1, size), &out, WAIT)
        .await
        .unwrap();
    let stats = ctl.frame_done(1, WAIT).await.unwrap();

    let pixels = (w * h) as usize;
    let op = Depth::new(&serde_json::from_str(params).unwrap()).unwrap();
    let views = [
        BandView::new(pixels).with(ILL, &ill[0]).with(z, &za),
        BandView::new(pixels).with(ILL, &ill[1]).with(z, &zb),
    ];
    let (mut want_z, mut want_ill) = (vec![0.0; pixels], vec![0.0; pixels * 6]);
    let mut m = BandMut::new(pixels)
        .with(z, &mut want_z)
        .with(ILL, &mut want_ill);
    op.apply(&views, &mut m).unwrap();
    assert_eq!(got[0].data, want_z, "nearest depth");
    assert_eq!(
        got[1].data, want_ill,
        "the nearest input's colour, bit for bit"
    );
    // Band 1's depth is all zeros (input a sent none and wins every pixel): sent empty.
    assert_eq!(stats.empty_bands, 1);
    stage.stop().await;
}
