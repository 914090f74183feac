//! What drawing large meshes in chunks saves (issue 48): `balls` on a ground of `--div N`
//! (2·N² triangles, one mesh), frames whose shadow maps are drawn again every frame (the lights
//! nudged), with every mesh whole and in chunks of 4 096 triangles, alternating, the median of
//! `--frames` each: the shadow passes' and the eye pass's time and the eye pass's vertices. Set
//! `LP_NUM_THREADS` as the bench does.
//!
//! `cargo run --release -p lightfold-node --example chunk_cull -- [--div N] [--frames N] [--size WxH]`

use lightfold_node::gpu::scene_data::CHUNK_TRIANGLES;
use lightfold_node::gpu::{Gpu, GpuOptions, LayerSet, RenderOptions, Renderer};
use lightfold_protocol::stats;
use lightfold_scene::{primitives, sampling};

mod common;

fn main() -> anyhow::Result<()> {
    let args = common::parse("balls", (400, 300), 5, &["--div"])?;
    let (frames, (w, h)) = (args.frames, args.size);
    let div: u32 = args.get("--div", 500)?;
    let mut scene = args.builtin_scene()?;
    // The floor (mesh 0) as one finely divided mesh of the same plane.
    let floor = &scene.meshes[0];
    let (lo, hi) = floor.bounds().ok_or_else(|| anyhow::anyhow!("no floor"))?;
    scene.meshes[0] = primitives::plane(
        "ground",
        [(lo[0] + hi[0]) / 2.0, hi[1], (lo[2] + hi[2]) / 2.0],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [hi[0] - lo[0], hi[2] - lo[2]],
        div,
        floor.material,
    );
    let gpu = Gpu::new(&GpuOptions::default())?;
    let samples: Vec<_> = sampling::direct_samples(&scene)
        .into_iter()
        .take(4)
        .collect();
    println!(
        "balls on a ground of {} triangles: {} triangles, {} meshes, {w}×{h}, {} lights, maps \
         drawn every frame",
        scene.meshes[0].triangle_count(),
        scene.triangle_count(),
        scene.meshes.len(),
        samples.len()
    );
    let mut renderers = Vec::new();
    for chunk_triangles in [0, CHUNK_TRIANGLES] {
        let opts = RenderOptions {
            chunk_triangles,
            ..RenderOptions::from_quality(&scene.quality)
        };
        let mut r = Renderer::new(&gpu, &scene, opts)?;
        r.render(&gpu, &samples, None, [1.0; 3], LayerSet::all())?;
        renderers.push(r);
    }
    let mut times = [[Vec::new(), Vec::new()], [Vec::new(), Vec::new()]];
    let mut vertices = [0u32; 2];
    for frame in 0..frames {
        // Nudged lights: every map is drawn again.
        let nudged: Vec<_> = samples
            .iter()
            .map(|s| {
                let mut s = *s;
                s.position[0] += 1e-3 * (frame + 1) as f32;
                s
            })
            .collect();
        for (k, r) in renderers.iter_mut().enumerate() {
            let f = r.render(&gpu, &nudged, None, [1.0; 3], LayerSet::all())?;
            times[k][0].push(f.stats.shadow_us as f64 / 1e3);
            times[k][1].push(f.stats.eye_us as f64 / 1e3);
            vertices[k] = r.eye_vertices();
        }
    }
    let med = |v: &Vec<f64>| stats::median(v).unwrap_or(f64::NAN);
    let (s0, s1) = (med(&times[0][0]), med(&times[1][0]));
    let (e0, e1) = (med(&times[0][1]), med(&times[1][1]));
    println!(
        "shadow passes {s0:.1} → {s1:.1} ms in chunks ({:.2}×); eye pass {e0:.1} → {e1:.1} ms \
         ({:.2}×), its vertices {} → {}",
        s1 / s0,
        e1 / e0,
        vertices[0],
        vertices[1]
    );
    Ok(())
}
