//! A node on loopback receives a scene and a configuration from a test coordinator and streams a
//! frame to a test compositor; unpacked, it equals a direct render of the same lights within each
//! link format's bound. Walkthrough frames with nothing changed are resent without rendering.
//! Needs a GPU adapter (lavapipe in CI): fails, never skips, without one.

use crate::daemon_support;

use daemon_support::*;
use lightfold_node::daemon::render_thread::{shadow_filter, take_layer};
use lightfold_node::gpu::{LayerSet, RenderOptions, Renderer};
use lightfold_protocol::{ErrorCode, FrameParams, Layer, Message, NodeConfig, PixelFormat, Role};
use lightfold_scene::wire::camera_to_wire;

/// The options a direct render of what `config` asks of a node renders with.
fn direct_options(scene: &lightfold_scene::Scene, config: &NodeConfig) -> RenderOptions {
    RenderOptions {
        shadow_map_size: scene.quality.shadow_map_size,
        map_sizing: scene.quality.map_sizing,
        filter: shadow_filter(config.filter),
        depth_bias: config.depth_bias,
        slope_bias: config.slope_bias,
        ..RenderOptions::default()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_streamed_frame_equals_a_direct_render() {
    let mut node = start_node("node-a", None).await;
    let mut comp = start_compositor().await;
    let mut coord = node.coordinator().await;
    let caps = coord.client.capabilities.clone();
    eprintln!("registered: {caps:?}");
    assert_eq!((caps.role, caps.daemon_id.as_str()), (Role::Node, "node-a"));
    assert!(caps.max_lights >= 4, "max lights {}", caps.max_lights);
    assert!(
        caps.cost_per_light_us > 0 && caps.fixed_cost_us > 0,
        "{caps:?}"
    );
    assert!(caps.formats.contains(&PixelFormat::Rgb9e5x2));
    assert!(
        caps.memory_bytes > 0,
        "the node reports its memory: {caps:?}"
    );
    // Measured at start-up (0 where the dense ball's frame was no slower); a triangle cannot
    // cost a millisecond.
    assert!(caps.eye_ns_per_triangle < 1_000_000, "{caps:?}");

    let scene = scene();
    let hash = coord.send_scene(&scene).await;
    let lights = lights(4);
    let layers = vec![
        (Layer::Illumination, PixelFormat::Rgb9e5x2),
        (Layer::Diffuse, PixelFormat::Rgba8Linear),
        (Layer::Depth, PixelFormat::DepthF32),
    ];
    let mut config = node_config(7, hash, &lights, layers.clone(), &comp.addr);
    config.color = [1.0, 0.8, 0.5];
    assert_eq!(
        coord.request(Message::ConfigureNode(config.clone())).await,
        Message::Configured { epoch: 7 }
    );
    let stats = match coord.frame(7, 1).await {
        Message::FrameDone(s) => s,
        other => panic!("expected FrameDone, got {other:?}"),
    };
    let bands = comp.take(band_count(&config)).await;
    assert!(comp.idle(), "exactly the configured bands arrive");
    eprintln!("frame: {stats:?}");

    // Band-major order, layers in configuration order, stamped with epoch and frame.
    for (i, (peer, h, _)) in bands.iter().enumerate() {
        assert_eq!(peer, "node-a");
        assert_eq!((h.epoch, h.frame), (7, 1));
        assert_eq!(h.y0, (i / layers.len()) as u32 * config.band_height);
        assert_eq!((h.layer, h.format), layers[i % layers.len()]);
    }
    assert_eq!(stats.lights_rendered, vec![0, 1, 2, 3]);
    assert!(stats.shadow_passes >= 4, "{stats:?}");
    assert!(stats.bytes_out > 0 && stats.peak_rss_bytes > 0, "{stats:?}");
    let flagged = bands.iter().filter(|(_, h, _)| h.empty).count() as u32;
    assert_eq!(stats.empty_bands, flagged);

    // The same lights rendered directly on this process's own device.
    let gpu = crate::gpu_support::gpu();
    let options = direct_options(&scene, &config);
    let mut renderer = Renderer::new(&gpu, &scene, options).expect("renderer");
    renderer.set_camera(&scene.camera);
    let wanted: Vec<Layer> = layers.iter().map(|(l, _)| *l).collect();
    let mut direct = renderer
        .render(
            &gpu,
            &lights,
            None,
            config.color,
            LayerSet::of(wanted.iter().copied()),
        )
        .expect("direct render");
    for (layer, format) in &layers {
        let want = take_layer(&mut direct, *layer).expect("direct layer");
        let got = assemble(&bands, *layer, WIDTH, HEIGHT);
        let excess = worst_excess(*format, &got, &want, config.scale);
        eprintln!("{layer:?} in {format:?}: worst excess over the bound {excess:e}");
        assert!(
            excess <= 0.0,
            "{layer:?} in {format:?} exceeds its bound by {excess}"
        );
        // Exactly the bands whose values are all zero are flagged empty.
        let row = (WIDTH as usize) * layer.channels();
        for (_, h, _) in bands.iter().filter(|(_, h, _)| h.layer == *layer) {
            let rows = &want.data[h.y0 as usize * row..(h.y0 + h.height) as usize * row];
            assert_eq!(
                h.empty,
                rows.iter().all(|v| *v == 0.0),
                "band at row {}",
                h.y0
            );
        }
    }
    let illum = assemble(&bands, Layer::Illumination, WIDTH, HEIGHT);
    assert!(illum.data.iter().any(|v| *v > 0.0), "the frame is lit");

    drop(coord);
    node.stop().await;
}

/// A node packing on the device streams the very bands a node packing on the CPU streams (same
/// headers, same payload bytes), and reads back only what it sends.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_node_packing_on_the_device_streams_the_cpu_packs_bands() {
    use lightfold_node::daemon::PackOn;
    let scene = scene();
    let lights = lights(4);
    let configs = [
        vec![
            (Layer::Illumination, PixelFormat::Rgb9e5x2),
            (Layer::Diffuse, PixelFormat::Rgba8Srgb),
            (Layer::Depth, PixelFormat::DepthF32),
        ],
        vec![(Layer::Illumination, PixelFormat::Seed64)],
    ];
    let mut streams = Vec::new();
    for pack in [PackOn::Device, PackOn::Cpu] {
        let mut node = start_node_with("node-p", |o| o.pack = pack).await;
        let mut comp = start_compositor().await;
        let mut coord = node.coordinator().await;
        let hash = coord.send_scene(&scene).await;
        let mut got = Vec::new();
        for (i, layers) in configs.iter().enumerate() {
            let epoch = 3 + i as u64;
            let mut config = node_config(epoch, hash, &lights, layers.clone(), &comp.addr);
            config.scale = 0.75;
            assert_eq!(
                coord.request(Message::ConfigureNode(config.clone())).await,
                Message::Configured { epoch }
            );
            let stats = match coord.frame(epoch, 1).await {
                Message::FrameDone(s) => s,
                other => panic!("{pack:?}: expected FrameDone, got {other:?}"),
            };
            let bands = comp.take(band_count(&config)).await;
            let link: u64 = layers.iter().map(|(_, f)| f.bytes_per_pixel() as u64).sum();
            let pixels = u64::from(WIDTH * HEIGHT);
            eprintln!("{pack:?} {layers:?}: {} bytes read back", stats.read_bytes);
            match pack {
                // The packed bytes and a few words a band.
                PackOn::Device => assert!(
                    stats.read_bytes >= pixels * link && stats.read_bytes < pixels * (link + 1),
                    "{stats:?}"
                ),
                _ => assert!(stats.read_bytes >= pixels * 16, "{stats:?}"),
            }
            got.push((bands, stats.peak, stats.saturated, stats.empty_bands));
        }
        drop(coord);
        node.stop().await;
        streams.push(got);
    }
    let (device, cpu) = (&streams[0], &streams[1]);
    for ((d, c), layers) in device.iter().zip(cpu).zip(&configs) {
        assert_eq!(
            (d.1, d.2, d.3),
            (c.1, c.2, c.3),
            "{layers:?}: peak, saturated, empty"
        );
        assert_eq!(d.0.len(), c.0.len());
        for ((_, dh, dp), (_, ch, cp)) in d.0.iter().zip(&c.0) {
            assert_eq!(dh, ch, "{layers:?}");
            assert_eq!(dp, cp, "{layers:?}: band at row {}", dh.y0);
        }
    }
}

/// Frame requests that arrive while a frame is rendering are rendered on the device while the
/// previous frame's bands stream: every band of frame n still precedes frame n + 1's, and each
/// frame is the same bits as when frames are requested one at a time.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frames_requested_ahead_render_while_the_last_one_streams() {
    use lightfold_protocol::WireCamera;
    let mut node = start_node("node-q", None).await;
    let mut comp = start_compositor().await;
    let mut coord = node.coordinator().await;
    let scene = scene();
    let hash = coord.send_scene(&scene).await;
    let lights = lights(4);
    let layers = vec![
        (Layer::Illumination, PixelFormat::Rgb9e5x2),
        (Layer::Depth, PixelFormat::DepthF32),
    ];
    let config = node_config(5, hash, &lights, layers, &comp.addr);
    let per_frame = band_count(&config);
    assert_eq!(
        coord.request(Message::ConfigureNode(config.clone())).await,
        Message::Configured { epoch: 5 }
    );
    // Three cameras, each frame a different view so no frame can be a copy of another.
    let camera = |i: u64| -> WireCamera {
        let mut c = scene.camera;
        c.position[0] += 0.2 * i as f32;
        camera_to_wire(&c)
    };
    let request = |frame: u64| Message::RenderFrame {
        epoch: 5,
        frame,
        camera: Some(camera(frame)),
        params: FrameParams {
            colors: Vec::new(),
            scale: None,
            time: None,
            lights: Vec::new(),
            rows: None,
        },
    };
    // One at a time: the reference bits.
    let mut alone = Vec::new();
    for f in 1..=3 {
        match coord.request(request(f)).await {
            Message::FrameDone(s) => assert!(!s.prefetched, "{s:?}"),
            other => panic!("expected FrameDone, got {other:?}"),
        }
        alone.push(comp.take(per_frame).await);
    }
    // All three requested at once, as a coordinator with frames in flight does.
    for f in 11..=13 {
        coord.send(request(f - 10)).await;
    }
    let mut prefetched = 0;
    for f in 1..=3u64 {
        match coord.recv().await {
            Message::FrameDone(s) => {
                assert_eq!(s.frame, f, "answers in request order");
                prefetched += u32::from(s.prefetched);
            }
            other => panic!("expected FrameDone, got {other:?}"),
        }
    }
    assert!(
        prefetched >= 1,
        "no frame was rendered while another streamed"
    );
    let ahead = comp.take(3 * per_frame).await;
    assert!(comp.idle());
    // Band order: frame by frame, never interleaved.
    let frames: Vec<u64> = ahead.iter().map(|(_, h, _)| h.frame).collect();
    let mut sorted = frames.clone();
    sorted.sort();
    assert_eq!(
        frames, sorted,
        "every band of a frame precedes the next frame's"
    );
    for (i, one) in alone.iter().enumerate() {
        let got = &ahead[i * per_frame..(i + 1) * per_frame];
        for ((_, a, pa), (_, b, pb)) in one.iter().zip(got) {
            assert_eq!((a.layer, a.y0, a.checksum), (b.layer, b.y0, b.checksum));
            assert_eq!(pa, pb, "frame {} band at row {}", i + 1, a.y0);
        }
    }
    drop(coord);
    node.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn walkthrough_frames_reuse_what_did_not_change() {
    let mut node = start_node("node-w", None).await;
    let mut comp = start_compositor().await;
    let mut coord = node.coordinator().await;
    let scene = scene();
    let hash = coord.send_scene(&scene).await;
    let mut config = node_config(
        1,
        hash,
        &lights(2),
        vec![(Layer::Illumination, PixelFormat::F16x6)],
        &comp.addr,
    );
    config.walkthrough = true;
    assert_eq!(
        coord.request(Message::ConfigureNode(config.clone())).await,
        Message::Configured { epoch: 1 }
    );
    let n = band_count(&config);
    let first = match coord.frame(1, 1).await {
        Message::FrameDone(s) => s,
        other => panic!("expected FrameDone, got {other:?}"),
    };
    let a = comp.take(n).await;
    assert_eq!(first.lights_rendered, vec![0, 1]);
    assert!(first.shadow_passes >= 2);

    // Nothing changed: the cached bands go out again under the new frame number.
    let second = match coord.frame(1, 2).await {
        Message::FrameDone(s) => s,
        other => panic!("expected FrameDone, got {other:?}"),
    };
    let b = comp.take(n).await;
    assert!(second.lights_rendered.is_empty(), "{second:?}");
    assert_eq!((second.shadow_passes, second.eye_us), (0, 0));
    assert_eq!(second.bytes_out, first.bytes_out);
    for ((_, ha, pa), (_, hb, pb)) in a.iter().zip(&b) {
        assert_eq!(hb.frame, 2);
        assert_eq!((ha.y0, ha.layer, ha.empty), (hb.y0, hb.layer, hb.empty));
        assert_eq!(pa, pb);
    }

    // The camera moves: the eye pass runs again; the lights did not move.
    let mut cam = scene.camera;
    cam.position[0] += 0.5;
    let third = match coord
        .request(Message::RenderFrame {
            epoch: 1,
            frame: 3,
            camera: Some(camera_to_wire(&cam)),
            params: FrameParams {
                colors: Vec::new(),
                scale: None,
                time: None,
                lights: Vec::new(),
                rows: None,
            },
        })
        .await
    {
        Message::FrameDone(s) => s,
        other => panic!("expected FrameDone, got {other:?}"),
    };
    let c = comp.take(n).await;
    assert_eq!(third.lights_rendered, vec![0, 1]);
    assert_eq!(
        third.shadow_passes, 0,
        "walkthrough keeps the shadow maps: {third:?}"
    );
    assert!(
        c.iter().zip(&b).any(|((_, _, pc), (_, _, pb))| pc != pb),
        "the view changed"
    );

    // A camera of another size does not fit the plan.
    cam.width += 1;
    let refused = coord
        .request(Message::RenderFrame {
            epoch: 1,
            frame: 4,
            camera: Some(camera_to_wire(&cam)),
            params: FrameParams {
                colors: Vec::new(),
                scale: None,
                time: None,
                lights: Vec::new(),
                rows: None,
            },
        })
        .await;
    assert!(
        matches!(&refused, Message::Error { code: ErrorCode::BadConfig, message, .. } if message.contains("161x120")),
        "{refused:?}"
    );
    // A scene time that is not a number is refused, and the node still renders.
    let refused = coord
        .request(Message::RenderFrame {
            epoch: 1,
            frame: 5,
            camera: None,
            params: FrameParams {
                colors: Vec::new(),
                scale: None,
                time: Some(f32::NAN),
                lights: Vec::new(),
                rows: None,
            },
        })
        .await;
    assert!(
        matches!(&refused, Message::Error { code: ErrorCode::BadConfig, message, .. } if message.contains("not finite")),
        "{refused:?}"
    );
    assert!(matches!(coord.frame(1, 6).await, Message::FrameDone(_)));
    comp.take(n).await;
    drop(coord);
    node.stop().await;
}

/// A compositor that lets the node's data link go between frames (a re-plan left the node out of
/// its inputs for an epoch) does not cost the next frame: the node sees the link closed and
/// dials afresh instead of writing into it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_link_the_compositor_let_go_is_dialled_again() {
    let mut node = start_node("node-r", None).await;
    let mut comp = start_compositor().await;
    let mut coord = node.coordinator().await;
    let hash = coord.send_scene(&scene()).await;
    let config = node_config(
        1,
        hash,
        &lights(1),
        vec![(Layer::Illumination, PixelFormat::F16x6)],
        &comp.addr,
    );
    assert_eq!(
        coord.request(Message::ConfigureNode(config.clone())).await,
        Message::Configured { epoch: 1 }
    );
    let n = band_count(&config);
    for frame in 1..=3 {
        match coord.frame(1, frame).await {
            Message::FrameDone(_) => {}
            other => panic!("frame {frame}: expected FrameDone, got {other:?}"),
        }
        let bands = comp.take(n).await;
        assert!(bands.iter().all(|(_, h, _)| h.frame == frame));
        comp.let_go();
        // The close reaches the node well before the next frame is asked for.
        tokio::time::sleep(std::time::Duration::from_millis(200)).await;
    }
    node.stop().await;
}

/// A sort-last part (issue 24): a node configured with `eye_meshes` streams what a direct render
/// of those meshes alone gives (shadows still from every caster), and a mesh the scene lacks is
/// refused with a clear error.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_node_draws_only_its_part_of_the_scene() {
    let mut node = start_node("node-p", None).await;
    let mut comp = start_compositor().await;
    let mut coord = node.coordinator().await;
    let scene = scene();
    assert!(
        scene.meshes.len() >= 2,
        "the test scene has a part to leave out"
    );
    let hash = coord.send_scene(&scene).await;
    let lights = lights(2);
    let layers = vec![
        (Layer::Illumination, PixelFormat::F32x6),
        (Layer::Depth, PixelFormat::DepthF32),
    ];
    let part = vec![0u32];
    let mut config = node_config(3, hash, &lights, layers.clone(), &comp.addr);
    config.eye_meshes = Some(part.clone());
    assert_eq!(
        coord.request(Message::ConfigureNode(config.clone())).await,
        Message::Configured { epoch: 3 }
    );
    match coord.frame(3, 1).await {
        Message::FrameDone(_) => {}
        other => panic!("expected FrameDone, got {other:?}"),
    }
    let bands = comp.take(band_count(&config)).await;

    let gpu = crate::gpu_support::gpu();
    let options = direct_options(&scene, &config);
    let render = |eye: Option<Vec<u32>>| {
        let mut r = Renderer::new(&gpu, &scene, options).expect("renderer");
        r.set_camera(&scene.camera);
        // As the daemon: a part's maps are fitted to the part.
        r.set_fit_to_eye_meshes(eye.is_some());
        r.set_eye_meshes(eye);
        r.render(
            &gpu,
            &lights,
            None,
            config.color,
            LayerSet::of([Layer::Illumination, Layer::Depth]),
        )
        .expect("direct render")
    };
    let mut direct = render(Some(part));
    let mut whole = render(None);
    let got = assemble(&bands, Layer::Depth, WIDTH, HEIGHT);
    let want = take_layer(&mut direct, Layer::Depth).expect("depth");
    assert!(worst_excess(PixelFormat::DepthF32, &got, &want, 1.0) <= 0.0);
    let all = take_layer(&mut whole, Layer::Depth).expect("depth");
    let left_out = all
        .data
        .iter()
        .zip(&got.data)
        .filter(|(a, b)| **a > 0.0 && **b == 0.0)
        .count();
    assert!(
        left_out > 100,
        "only {left_out} pixels left to the other part"
    );
    let got = assemble(&bands, Layer::Illumination, WIDTH, HEIGHT);
    let want = take_layer(&mut direct, Layer::Illumination).expect("illumination");
    assert!(worst_excess(PixelFormat::F32x6, &got, &want, 1.0) <= 0.0);

    // A mesh the scene does not have.
    let mut bad = node_config(4, hash, &lights, layers, &comp.addr);
    bad.eye_meshes = Some(vec![scene.meshes.len() as u32]);
    match coord.request(Message::ConfigureNode(bad)).await {
        Message::Error { code, message, .. } => {
            assert_eq!(code, ErrorCode::BadConfig);
            assert!(message.contains("eye pass"), "{message}");
        }
        other => panic!("expected an error, got {other:?}"),
    }
    drop(coord);
    node.stop().await;
}

/// Maps the scene's mismatch rule sizes above its base size share the node's shadow budget: a
/// configuration within the light limit at the base size renders even when each light's map is
/// 2048² (the renderer halves the largest to fit), where the device's limit at 2048² alone is
/// lower. Before, the configuration was accepted and every frame then failed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn maps_above_the_base_size_share_the_budget() {
    let gpu = crate::gpu_support::gpu();
    let mut scene = scene();
    scene.quality.map_sizing =
        lightfold_scene::MapSizing::Mismatch(lightfold_scene::defaults::MAP_MISMATCH);
    scene.quality.shadow_map_size = 512;
    let n = gpu.max_lights(2048) as usize + 1;
    assert!(
        n <= gpu.max_lights(512) as usize,
        "the base size takes {n} lights"
    );
    let mut node = start_node("node-m", None).await;
    let mut comp = start_compositor().await;
    let mut coord = node.coordinator().await;
    let hash = coord.send_scene(&scene).await;
    let lights = lights(n);
    let layers = vec![(Layer::Illumination, PixelFormat::Rgb9e5x2)];
    let mut config = node_config(3, hash, &lights, layers, &comp.addr);
    let all: Vec<u32> = (0..scene.meshes.len() as u32).collect();
    config.shadows = (0..n as u32)
        .map(|light| lightfold_protocol::WireShadow {
            light,
            map_size: 2048,
            casters: all.clone(),
        })
        .collect();
    assert_eq!(
        coord.request(Message::ConfigureNode(config.clone())).await,
        Message::Configured { epoch: 3 }
    );
    match coord.frame(3, 1).await {
        Message::FrameDone(s) => assert_eq!(s.lights_rendered.len(), n),
        other => panic!("expected FrameDone, got {other:?}"),
    }
    comp.take(band_count(&config)).await;
    node.stop().await;
}
