//! Sort-first tiles through the daemon: a node configured with rows (`NodeConfig::rows`) streams
//! every band, those wholly outside its rows flagged empty, and the rest equal to a direct render
//! of that tile within each format's bound (zero outside the rows); `FrameParams::rows` moves the
//! tile from that frame on (a frame without rows keeps them); rows outside the image are refused
//! with `BadConfig` naming them, for a configuration and for a frame, and the node goes on.

use crate::daemon_support;

use daemon_support::*;
use lightfold_node::daemon::render_thread::{shadow_filter, take_layer};
use lightfold_node::gpu::{LayerSet, RenderOptions, Renderer};
use lightfold_protocol::{
    BandHeader, ErrorCode, FrameParams, FrameStats, Layer, Message, NodeConfig, PixelFormat,
};

/// The rows of a 120-row frame in bands of 32: [0, 32), [32, 64), [64, 96), [96, 120).
const BAND: u32 = 32;

fn params(rows: Option<[u32; 2]>) -> FrameParams {
    FrameParams {
        colors: Vec::new(),
        scale: None,
        time: None,
        lights: Vec::new(),
        rows,
    }
}

fn expect_error(m: &Message, needle: &str) {
    match m {
        Message::Error { code, message, .. }
            if *code == ErrorCode::BadConfig && message.contains(needle) => {}
        other => panic!("expected BadConfig mentioning {needle:?}, got {other:?}"),
    }
}

/// Checks one streamed frame of `config`'s layers rendered at `rows` against a direct render
/// of the same tile: bands wholly outside the rows are empty, the rest within the format's
/// bound, and every row outside zero.
#[allow(clippy::too_many_arguments)]
fn check_frame(
    gpu: &lightfold_node::gpu::Gpu,
    renderer: &mut Renderer,
    config: &NodeConfig,
    lights: &[lightfold_scene::LightSample],
    bands: &[(String, bytes::Bytes)],
    headers: &[BandHeader],
    stats: &FrameStats,
    [y0, y1]: [u32; 2],
) {
    let outside = |h: &BandHeader| h.y0 + h.height <= y0 || h.y0 >= y1;
    let out_of_tile = headers.iter().filter(|h| outside(h)).count();
    assert!(out_of_tile > 0, "rows {y0}..{y1} leave some band out");
    for h in headers.iter().filter(|h| outside(h)) {
        assert!(h.empty, "band at row {} outside {y0}..{y1} is empty", h.y0);
    }
    let flagged = headers.iter().filter(|h| h.empty).count() as u32;
    assert_eq!(stats.empty_bands, flagged);
    let full: Vec<(String, BandHeader, bytes::Bytes)> = bands
        .iter()
        .zip(headers)
        .map(|((p, b), h)| (p.clone(), *h, b.clone()))
        .collect();
    renderer.set_rows(Some([y0, y1]));
    let wanted: Vec<Layer> = config.layers.iter().map(|(l, _)| *l).collect();
    let mut direct = renderer
        .render(gpu, lights, None, config.color, LayerSet::of(wanted))
        .expect("direct render");
    for (layer, format) in &config.layers {
        let want = take_layer(&mut direct, *layer).expect("direct layer");
        let got = assemble(&full, *layer, WIDTH, HEIGHT);
        let excess = worst_excess(*format, &got, &want, config.scale);
        assert!(
            excess <= 0.0,
            "{layer:?} rows {y0}..{y1}: over its bound by {excess}"
        );
        let row = WIDTH as usize * layer.channels();
        let (a, b) = (y0 as usize * row, y1 as usize * row);
        assert!(
            got.data[..a]
                .iter()
                .chain(&got.data[b..])
                .all(|v| *v == 0.0)
        );
        assert!(
            got.data[a..b].iter().any(|v| *v != 0.0),
            "{layer:?} shows the tile"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_tiled_node_streams_its_rows_and_empty_bands_elsewhere() {
    let mut node = start_node("node-tiles", None).await;
    let mut comp = start_compositor().await;
    let mut coord = node.coordinator().await;
    let scene = scene();
    let hash = coord.send_scene(&scene).await;
    let lights = lights(2);
    let layers = vec![
        (Layer::Illumination, PixelFormat::Rgb9e5x2),
        (Layer::Diffuse, PixelFormat::Rgba8Linear),
        (Layer::Depth, PixelFormat::DepthF32),
    ];
    let mut config = node_config(3, hash, &lights, layers, &comp.addr);
    config.band_height = BAND;

    // Rows beyond the image: refused, and the node stays unconfigured.
    let bad = NodeConfig {
        rows: Some([60, HEIGHT + 1]),
        ..config.clone()
    };
    let m = coord.request(Message::ConfigureNode(bad)).await;
    expect_error(&m, &format!("rows 60..{}", HEIGHT + 1));
    let empty = NodeConfig {
        rows: Some([50, 50]),
        ..config.clone()
    };
    expect_error(
        &coord.request(Message::ConfigureNode(empty)).await,
        "rows 50..50",
    );

    config.rows = Some([40, 90]);
    assert_eq!(
        coord.request(Message::ConfigureNode(config.clone())).await,
        Message::Configured { epoch: 3 }
    );
    let options = RenderOptions {
        shadow_map_size: scene.quality.shadow_map_size,
        map_sizing: scene.quality.map_sizing,
        filter: shadow_filter(config.filter),
        depth_bias: config.depth_bias,
        slope_bias: config.slope_bias,
        ..RenderOptions::default()
    };
    let gpu = crate::gpu_support::gpu();
    let mut direct = Renderer::new(&gpu, &scene, options).expect("renderer");
    direct.set_camera(&scene.camera);

    // Frame 1 at the configured rows, frame 2 moved, frame 3 keeps frame 2's rows.
    let mut read = Vec::new();
    for (frame, asked, rows) in [
        (1, None, [40, 90]),
        (2, Some([70, 120]), [70, 120]),
        (3, None, [70, 120]),
        (4, Some([0, 120]), [0, 120]),
    ] {
        let m = coord
            .request(Message::RenderFrame {
                epoch: 3,
                frame,
                camera: None,
                params: params(asked),
            })
            .await;
        let Message::FrameDone(stats) = m else {
            panic!("frame {frame}: expected FrameDone, got {m:?}");
        };
        let got = comp.take(band_count(&config)).await;
        assert!(comp.idle(), "exactly the configured bands arrive");
        let headers: Vec<BandHeader> = got.iter().map(|(_, h, _)| *h).collect();
        assert!(headers.iter().all(|h| h.frame == frame));
        let bands: Vec<(String, bytes::Bytes)> = got.into_iter().map(|(p, _, b)| (p, b)).collect();
        read.push(stats.read_bytes);
        if rows == [0, HEIGHT] {
            // The whole image: nothing is left out.
            assert!(stats.read_bytes > read[0], "{read:?}");
            continue;
        }
        check_frame(
            &gpu,
            &mut direct,
            &config,
            &lights,
            &bands,
            &headers,
            &stats,
            rows,
        );
    }
    eprintln!("bytes read back per frame: {read:?}");

    // A frame's rows beyond the image: refused with the frame's error; the next frame renders.
    for bad in [[100, 130], [30, 10]] {
        let m = coord
            .request(Message::RenderFrame {
                epoch: 3,
                frame: 5,
                camera: None,
                params: params(Some(bad)),
            })
            .await;
        expect_error(&m, &format!("rows {}..{}", bad[0], bad[1]));
        assert!(matches!(m, Message::Error { frame: Some(5), .. }), "{m:?}");
    }
    let m = coord
        .request(Message::RenderFrame {
            epoch: 3,
            frame: 6,
            camera: None,
            params: params(Some([10, 60])),
        })
        .await;
    assert!(matches!(m, Message::FrameDone(_)), "{m:?}");
    let got = comp.take(band_count(&config)).await;
    let headers: Vec<BandHeader> = got.iter().map(|(_, h, _)| *h).collect();
    // Rows 10..60 meet bands 0 and 1 only.
    assert!(headers.iter().filter(|h| h.y0 >= 64).all(|h| h.empty));
    node.stop().await;
}
