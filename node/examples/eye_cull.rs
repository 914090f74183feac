//! What eye-pass culling saves (issue 48): the `city` at N triangles seen from its own camera
//! (most of it in view) and from a street-level camera looking down one street (most of it
//! out), eye-pass time with culling off and on, alternating, the median of `--frames` each, with
//! the vertices each drew. Set `LP_NUM_THREADS` as the bench does.
//!
//! `cargo run --release -p lightfold-node --example eye_cull -- [city:N] [--frames N] [--size WxH]`

use lightfold_node::gpu::{Gpu, GpuOptions, LayerSet, RenderOptions, Renderer};
use lightfold_protocol::stats;
use lightfold_scene::sampling;

mod common;

fn main() -> anyhow::Result<()> {
    let args = common::parse("city", (800, 600), 5, &[])?;
    let (name, frames, (w, h)) = (args.scene.clone(), args.frames, args.size);
    let scene = args.builtin_scene()?;
    let gpu = Gpu::new(&GpuOptions::default())?;
    let samples: Vec<_> = sampling::direct_samples(&scene)
        .into_iter()
        .take(4)
        .collect();
    let street = common::street_camera(&scene.camera);
    println!(
        "{name}: {} triangles, {} meshes, {w}×{h}, {} lights, walkthrough (maps kept)",
        scene.triangle_count(),
        scene.meshes.len(),
        samples.len()
    );
    for (what, camera) in [("own camera", scene.camera), ("street level", street)] {
        let opts = RenderOptions {
            walkthrough: true,
            ..RenderOptions::from_quality(&scene.quality)
        };
        let mut r = Renderer::new(&gpu, &scene, opts)?;
        r.set_camera(&camera);
        // Maps drawn once, pipelines warm.
        r.render(&gpu, &samples, None, [1.0; 3], LayerSet::all())?;
        let (mut off, mut on) = (Vec::new(), Vec::new());
        let (mut v_off, mut v_on) = (0, 0);
        for _ in 0..frames {
            for culling in [false, true] {
                r.set_eye_culling(culling);
                let f = r.render(&gpu, &samples, None, [1.0; 3], LayerSet::all())?;
                let us = f.stats.eye_us as f64 / 1e3;
                if culling {
                    on.push(us);
                    v_on = r.eye_vertices();
                } else {
                    off.push(us);
                    v_off = r.eye_vertices();
                }
            }
        }
        let (a, b) = (
            stats::median(&off).unwrap_or(f64::NAN),
            stats::median(&on).unwrap_or(f64::NAN),
        );
        println!(
            "{what}: eye pass {a:.1} ms → {b:.1} ms with culling ({:.2}×), vertices {v_off} → {v_on}",
            b / a
        );
    }
    Ok(())
}
