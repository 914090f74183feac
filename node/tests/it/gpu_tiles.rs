//! Sort-first tiles at the node (`Renderer::set_rows`): a renderer asked for image rows
//! `[y0, y1)` gives, inside them, exactly the bits of every layer a node streams (illumination,
//! the four material layers, depth) that the whole image gives, and zero in every other row — so
//! the tiles of a split, put together, are the whole image bit for bit. Splits of 2 and 3 tiles,
//! not aligned to any band height, over three built-in scenes in both eye variants. The tile
//! culls meshes against its own sub-frustum and reads back less. Negative controls: a raster one
//! row low (`Fault::TileRowsOffByOne`) and a flipped culling sub-frustum
//! (`Fault::TileFrustumFlipped`) must break the comparison. The device pack of a tile reads back
//! only its bands and gives the CPU pack's bands bit for bit.

use crate::gpu_support;

use gpu_support::*;
use lightfold_node::daemon::bands::{
    BandLayout, LayerImages, PackedBand, assemble_frame, pack_frame,
};
use lightfold_node::gpu::{
    EyeVariant, Fault, Gpu, LayerSet, NodeFrame, RenderError, RenderOptions, Renderer,
};
use lightfold_protocol::{Layer, PixelFormat};
use lightfold_scene::{Image, LightSample, Scene, sampling};
use std::sync::Arc;

const W: u32 = 96;
const H: u32 = 72;

/// Splits of the image into tiles: 2 and 3 tiles, rows not multiples of any band height used.
const SPLITS: [&[[u32; 2]]; 2] = [&[[0, 37], [37, 72]], &[[0, 21], [21, 50], [50, 72]]];

/// A built-in scene at W×H and a handful of its light samples, spread over its lights.
fn case(name: &str) -> (Scene, Vec<LightSample>) {
    let mut scene = lightfold_scene::builtin(name).expect("built-in scene");
    scene.camera.width = W;
    scene.camera.height = H;
    let all = sampling::direct_samples(&scene);
    let step = (all.len() / 4).max(1);
    let samples = all.into_iter().step_by(step).take(4).collect();
    (scene, samples)
}

fn renderer(gpu: &Gpu, scene: &Scene, variant: EyeVariant, fault: Option<Fault>) -> Renderer {
    let opts = RenderOptions {
        fault,
        ..RenderOptions::from_quality(&scene.quality)
    };
    let mut r = Renderer::new(gpu, scene, opts).expect("renderer");
    r.set_variant(variant);
    r
}

fn render(
    gpu: &Gpu,
    r: &mut Renderer,
    samples: &[LightSample],
    rows: Option<[u32; 2]>,
) -> NodeFrame {
    r.set_rows(rows);
    r.render(gpu, samples, None, C_N, LayerSet::all())
        .expect("frame")
}

/// Every layer a node streams, named.
fn layers(f: &NodeFrame) -> Vec<(&'static str, &Image)> {
    [
        ("illumination", &f.illumination),
        ("diffuse", &f.diffuse),
        ("specular", &f.specular),
        ("ambient", &f.ambient),
        ("emissive", &f.emissive),
        ("depth", &f.depth),
    ]
    .into_iter()
    .map(|(n, l)| (n, l.as_ref().expect("every layer rendered")))
    .collect()
}

/// Where `tile` (rendered at `rows`) departs from the whole render: values inside the rows whose
/// bits differ and values outside that are not +0, per layer. Empty when it is exact.
fn departures(whole: &NodeFrame, tile: &NodeFrame, [y0, y1]: [u32; 2]) -> Vec<String> {
    let mut out = Vec::new();
    for ((name, w), (_, t)) in layers(whole).into_iter().zip(layers(tile)) {
        assert_eq!(
            (w.width, w.height, w.channels),
            (t.width, t.height, t.channels)
        );
        let row = (W as usize) * w.channels;
        let (a, b) = (y0 as usize * row, y1 as usize * row);
        let differ = (a..b)
            .filter(|&i| w.data[i].to_bits() != t.data[i].to_bits())
            .count();
        let outside = (0..a)
            .chain(b..w.data.len())
            .filter(|&i| t.data[i].to_bits() != 0)
            .count();
        if differ + outside > 0 {
            out.push(format!(
                "{name}: {differ} values differ inside, {outside} not zero outside"
            ));
        }
    }
    out
}

#[test]
fn tiles_equal_the_whole_image_bit_for_bit_and_zero_elsewhere() {
    let gpu = gpu();
    let mut culled = false;
    for name in ["balls", "box", "cornell"] {
        let (scene, samples) = case(name);
        for variant in [EyeVariant::Deferred, EyeVariant::Forward] {
            let mut r = renderer(&gpu, &scene, variant, None);
            let whole = render(&gpu, &mut r, &samples, None);
            let drawn_whole = r.eye_vertices();
            let lit = whole.illumination.as_ref().unwrap();
            assert!(
                lit.data.iter().any(|v| *v > 0.0),
                "{name}: the frame is lit"
            );
            for split in SPLITS {
                // The tiles' union, value by value.
                let mut union: Vec<Vec<u32>> = layers(&whole)
                    .iter()
                    .map(|(_, l)| vec![0; l.data.len()])
                    .collect();
                for &rows in split {
                    let tile = render(&gpu, &mut r, &samples, Some(rows));
                    let bad = departures(&whole, &tile, rows);
                    assert!(bad.is_empty(), "{name} {variant:?} rows {rows:?}: {bad:?}");
                    assert!(r.eye_vertices() <= drawn_whole);
                    culled |= r.eye_vertices() < drawn_whole;
                    // A tile reads back its rows only (every layer, f32).
                    let share = f64::from(rows[1] - rows[0]) / f64::from(H);
                    let ratio = tile.stats.read_bytes as f64 / whole.stats.read_bytes as f64;
                    assert!(
                        ratio <= share + 0.02,
                        "{name} rows {rows:?}: read {} of {} bytes",
                        tile.stats.read_bytes,
                        whole.stats.read_bytes
                    );
                    for (u, (_, l)) in union.iter_mut().zip(layers(&tile)) {
                        for (u, v) in u.iter_mut().zip(&l.data) {
                            *u |= v.to_bits();
                        }
                    }
                }
                for (u, (layer, l)) in union.iter().zip(layers(&whole)) {
                    let want: Vec<u32> = l.data.iter().map(|v| v.to_bits()).collect();
                    assert!(*u == want, "{name} {variant:?} {split:?}: {layer} union");
                }
            }
            // The renderer goes back to the whole image.
            let again = render(&gpu, &mut r, &samples, None);
            assert!(departures(&whole, &again, [0, H]).is_empty(), "{name}");
        }
    }
    assert!(
        culled,
        "no tile culled a mesh: the sub-frustum proves nothing"
    );
}

#[test]
fn negative_controls_a_row_off_or_a_flipped_sub_frustum_break_the_tiles() {
    let gpu = gpu();
    for fault in [Fault::TileRowsOffByOne, Fault::TileFrustumFlipped] {
        let mut caught = Vec::new();
        for name in ["balls", "box", "cornell"] {
            let (scene, samples) = case(name);
            let mut good = renderer(&gpu, &scene, EyeVariant::Deferred, None);
            let whole = render(&gpu, &mut good, &samples, None);
            let mut wrong = renderer(&gpu, &scene, EyeVariant::Deferred, Some(fault));
            // The faulty renderer's whole image is right: only tiles go wrong.
            let its_whole = render(&gpu, &mut wrong, &samples, None);
            assert!(departures(&whole, &its_whole, [0, H]).is_empty());
            for split in SPLITS {
                for &rows in split {
                    let tile = render(&gpu, &mut wrong, &samples, Some(rows));
                    let bad = departures(&whole, &tile, rows);
                    if !bad.is_empty() {
                        caught.push(format!("{name} {rows:?}: {bad:?}"));
                    }
                }
            }
        }
        eprintln!("{fault:?}: {caught:?}");
        assert!(!caught.is_empty(), "{fault:?} changed no tile");
    }
}

#[test]
fn rows_outside_the_image_are_an_error_not_a_panic() {
    let gpu = gpu();
    let (scene, samples) = case("box");
    let mut r = renderer(&gpu, &scene, EyeVariant::Deferred, None);
    for rows in [[10, 10], [20, 5], [0, H + 1], [H, H + 1]] {
        r.set_rows(Some(rows));
        let e = r
            .render(&gpu, &samples, None, C_N, LayerSet::all())
            .expect_err("refused");
        assert!(matches!(e, RenderError::Rows { .. }), "{rows:?}: {e}");
        assert!(
            e.to_string()
                .contains(&format!("rows {}..{}", rows[0], rows[1])),
            "{e}"
        );
    }
    // The renderer is still good.
    r.set_rows(Some([0, H]));
    let full_rows = r
        .render(&gpu, &samples, None, C_N, LayerSet::all())
        .unwrap();
    let whole = render(&gpu, &mut r, &samples, None);
    assert!(departures(&whole, &full_rows, [0, H]).is_empty());
}

/// Bands in protocol order, from a channel big enough for the frame.
fn bands(f: impl FnOnce(&tokio::sync::mpsc::Sender<PackedBand>)) -> Vec<PackedBand> {
    let (tx, mut rx) = tokio::sync::mpsc::channel(1024);
    f(&tx);
    drop(tx);
    let mut out = Vec::new();
    while let Ok(b) = rx.try_recv() {
        out.push(b);
    }
    out
}

#[test]
fn a_tiles_device_pack_reads_only_its_bands_and_equals_the_cpu_pack() {
    let gpu = gpu();
    let (scene, samples) = case("balls");
    let layers = [
        (Layer::Illumination, PixelFormat::Rgb9e5x2),
        (Layer::Diffuse, PixelFormat::F16x4),
        (Layer::Depth, PixelFormat::DepthF32),
    ];
    let band_height = 16;
    let mut r = renderer(&gpu, &scene, EyeVariant::Deferred, None);
    let set = LayerSet::of(layers.iter().map(|(l, _)| *l));
    let mut whole_read = 0;
    for rows in [None, Some([21, 50]), Some([5, 40]), Some([64, 72])] {
        r.set_rows(rows);
        let (packed, stats) = r
            .render_packed(&gpu, &samples, None, C_N, &layers, band_height, 1.0)
            .expect("frame")
            .expect("this device packs");
        let mut frame = r.render(&gpu, &samples, None, C_N, set).expect("frame");
        let images: LayerImages = layers
            .iter()
            .map(|&(layer, format)| {
                let img = lightfold_node::daemon::render_thread::take_layer(&mut frame, layer)
                    .expect("layer");
                (layer, format, Arc::new(img))
            })
            .collect();
        let layout = BandLayout {
            epoch: 1,
            frame: 1,
            width: W,
            height: H,
            band_height,
            scale: 1.0,
        };
        let device = bands(|tx| {
            assemble_frame(&layout, &layers, &packed, tx).expect("device bands");
        });
        let cpu = bands(|tx| {
            pack_frame(&layout, &images, rows, tx).expect("CPU bands");
        });
        assert_eq!(device.len(), cpu.len());
        for (d, c) in device.iter().zip(&cpu) {
            assert_eq!(d.header, c.header, "{rows:?}");
            assert_eq!(d.payload, c.payload, "{rows:?}");
        }
        // Bands wholly outside the rows are empty.
        if let Some([y0, y1]) = rows {
            for b in &cpu {
                let (b0, b1) = (b.header.y0, b.header.y0 + b.header.height);
                if b1 <= y0 || b0 >= y1 {
                    assert!(b.header.empty, "band at {b0} outside {rows:?}");
                }
            }
            assert!(
                cpu.iter().any(|b| !b.header.empty),
                "{rows:?}: the tile shows something"
            );
            assert!(
                stats.read_bytes < whole_read,
                "{rows:?}: {} bytes read, the whole frame {whole_read}",
                stats.read_bytes
            );
        } else {
            whole_read = stats.read_bytes;
        }
    }
}
