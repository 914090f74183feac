//! What a sort-first tile saves at the node (`Renderer::set_rows`): `balls` at `--size` (800×600)
//! with 4 lights in walkthrough mode (maps kept, so a frame is its eye pass), the whole image
//! and each half of its rows rendered in turn, the median of `--frames` each: eye pass,
//! readback and the CPU pack of `rgb9e5x2` illumination + `f16x4` diffuse + depth (the lavapipe
//! node's path), bytes read back and eye vertices. Set `LP_NUM_THREADS` as the bench does.
//!
//! `cargo run --release -p lightfold-node --example tile_cost -- [scene] [--frames N] [--size WxH]`

use lightfold_node::daemon::bands::{BandLayout, LayerImages, pack_frame};
use lightfold_node::daemon::render_thread::take_layer;
use lightfold_node::gpu::{Gpu, GpuOptions, LayerSet, RenderOptions, Renderer};
use lightfold_protocol::{Layer, PixelFormat, stats};
use lightfold_scene::sampling;
use std::sync::Arc;
use std::time::Instant;

mod common;

fn main() -> anyhow::Result<()> {
    let args = common::parse("balls", (800, 600), 5, &[])?;
    let (name, frames, (w, h)) = (args.scene.clone(), args.frames, args.size);
    let scene = args.builtin_scene()?;
    let gpu = Gpu::new(&GpuOptions::default())?;
    let all = sampling::direct_samples(&scene);
    let samples: Vec<_> = all
        .iter()
        .step_by((all.len() / 4).max(1))
        .take(4)
        .copied()
        .collect();
    let layers = [
        (Layer::Illumination, PixelFormat::Rgb9e5x2),
        (Layer::Diffuse, PixelFormat::F16x4),
        (Layer::Depth, PixelFormat::DepthF32),
    ];
    let set = LayerSet::of(layers.iter().map(|(l, _)| *l));
    let opts = RenderOptions {
        walkthrough: true,
        ..RenderOptions::from_quality(&scene.quality)
    };
    let mut r = Renderer::new(&gpu, &scene, opts)?;
    println!(
        "{name}: {} triangles, {w}×{h}, {} lights, walkthrough (maps kept), layers {layers:?}",
        scene.triangle_count(),
        samples.len()
    );
    // Maps drawn once, pipelines warm.
    r.render(&gpu, &samples, None, [1.0; 3], set)?;
    let tiles = [None, Some([0, h / 2]), Some([h / 2, h])];
    // Per tile: eye, readback, pack (ms), bytes read, vertices.
    let mut eye = vec![Vec::new(); tiles.len()];
    let mut readback = vec![Vec::new(); tiles.len()];
    let mut pack = vec![Vec::new(); tiles.len()];
    let mut bytes = vec![0u64; tiles.len()];
    let mut vertices = vec![0u32; tiles.len()];
    for _ in 0..frames {
        for (i, &rows) in tiles.iter().enumerate() {
            r.set_rows(rows);
            let mut f = r.render(&gpu, &samples, None, [1.0; 3], set)?;
            eye[i].push(f.stats.eye_us as f64 / 1e3);
            readback[i].push(f.stats.readback_us as f64 / 1e3);
            bytes[i] = f.stats.read_bytes;
            vertices[i] = r.eye_vertices();
            let images: LayerImages = layers
                .iter()
                .map(|&(l, format)| (l, format, Arc::new(take_layer(&mut f, l).expect("layer"))))
                .collect();
            let layout = BandLayout {
                epoch: 1,
                frame: 1,
                width: w,
                height: h,
                band_height: 64,
                scale: 1.0,
            };
            let (tx, mut rx) = tokio::sync::mpsc::channel(4096);
            let t = Instant::now();
            pack_frame(&layout, &images, rows, &tx)?;
            pack[i].push(t.elapsed().as_secs_f64() * 1e3);
            drop(tx);
            while rx.try_recv().is_ok() {}
        }
    }
    let med = |v: &[f64]| stats::median(v).unwrap_or(f64::NAN);
    for (i, rows) in tiles.iter().enumerate() {
        let what = match rows {
            None => "whole".to_string(),
            Some([a, b]) => format!("rows {a}..{b}"),
        };
        println!(
            "{what:>14}: eye {:6.1} ms, readback {:5.1} ms, pack {:5.1} ms, read {:5.2} MB, \
             eye vertices {}",
            med(&eye[i]),
            med(&readback[i]),
            med(&pack[i]),
            bytes[i] as f64 / 1e6,
            vertices[i]
        );
    }
    Ok(())
}
