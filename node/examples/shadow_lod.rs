//! What levels of detail save (issue 48, `gpu::lod`): a scene's frames with every map drawn
//! again (the lights nudged), full detail against the levels (the shadow casters' and the eye
//! pass's lossless ones), alternating, the median of `--frames` each: the shadow passes' and the
//! eye pass's time and vertices, the levels' build time and triangles, and how many pixels of
//! the illumination agree (`docs/scaling.md` § Level of detail). Set `LP_NUM_THREADS` as the
//! bench does.
//!
//! `cargo run --release -p lightfold-node --example shadow_lod -- [--scene city:1m] [--frames N] [--size WxH] [--lights N]`

use lightfold_node::gpu::{Gpu, GpuOptions, LayerSet, RenderOptions, Renderer};
use lightfold_protocol::stats;
use lightfold_scene::sampling;
use std::time::Instant;

mod common;

fn main() -> anyhow::Result<()> {
    let args = common::parse("city:1m", (400, 300), 5, &["--lights"])?;
    let (name, frames, (w, h)) = (args.scene.clone(), args.frames, args.size);
    let lights: usize = args.get("--lights", 4)?;
    let scene = args.builtin_scene()?;
    let gpu = Gpu::new(&GpuOptions::default())?;
    let samples: Vec<_> = sampling::direct_samples(&scene)
        .into_iter()
        .take(lights)
        .collect();
    println!(
        "{name}: {} triangles, {} meshes, {w}×{h}, {} lights, maps drawn every frame",
        scene.triangle_count(),
        scene.meshes.len(),
        samples.len()
    );
    let mut renderers = Vec::new();
    for shadow_lod in [false, true] {
        let opts = RenderOptions {
            shadow_lod,
            eye_lod: shadow_lod,
            ..RenderOptions::from_quality(&scene.quality)
        };
        let t = Instant::now();
        let r = Renderer::new(&gpu, &scene, opts)?;
        println!(
            "  LOD {}: renderer built in {:.2} s{}",
            if shadow_lod { "on " } else { "off" },
            t.elapsed().as_secs_f64(),
            if shadow_lod {
                format!(", {} triangles in levels", r.lod_triangles())
            } else {
                String::new()
            }
        );
        renderers.push(r);
    }
    let mut shadow_ms = [Vec::new(), Vec::new()];
    let mut frame_ms = [Vec::new(), Vec::new()];
    let mut eye_ms = [Vec::new(), Vec::new()];
    let mut eye_vertices = [0u32; 2];
    let mut vertices = [(0u64, 0u64); 2];
    let mut last = Vec::new();
    for frame in 0..frames {
        let nudged: Vec<_> = samples
            .iter()
            .map(|s| {
                let mut s = *s;
                s.position[0] += 1e-3 * (frame + 1) as f32;
                s
            })
            .collect();
        last.clear();
        for (k, r) in renderers.iter_mut().enumerate() {
            let f = r.render(&gpu, &nudged, None, [1.0; 3], LayerSet::illumination())?;
            shadow_ms[k].push(f.stats.shadow_us as f64 / 1e3);
            let s = &f.stats;
            eye_ms[k].push(s.eye_us as f64 / 1e3);
            eye_vertices[k] = r.eye_vertices();
            frame_ms[k].push((s.setup_us + s.shadow_us + s.eye_us + s.readback_us) as f64 / 1e3);
            vertices[k] = (f.stats.shadow_vertices, f.stats.shadow_lod_vertices);
            last.push(
                f.illumination
                    .ok_or_else(|| anyhow::anyhow!("no illumination"))?,
            );
        }
    }
    let med = |v: &Vec<f64>| stats::median(v).unwrap_or(f64::NAN);
    let (s0, s1) = (med(&shadow_ms[0]), med(&shadow_ms[1]));
    let (f0, f1) = (med(&frame_ms[0]), med(&frame_ms[1]));
    let (e0, e1) = (med(&eye_ms[0]), med(&eye_ms[1]));
    let max = last[0]
        .data
        .iter()
        .fold(0f32, |a, &v| a.max(v.abs()))
        .max(1e-30);
    let differ = last[0]
        .data
        .chunks(6)
        .zip(last[1].data.chunks(6))
        .filter(|(a, b)| a.iter().zip(*b).any(|(x, y)| (x - y).abs() > 1e-3 * max))
        .count();
    println!(
        "frame {f0:.1} → {f1:.1} ms with LOD ({:.2}×); shadow passes {s0:.1} → {s1:.1} ms \
         ({:.2}×); their vertices {} → {} ({} from levels); pixels differing by over 0.1 % of \
         the brightest: {differ} of {}",
        f1 / f0,
        s1 / s0,
        vertices[0].0,
        vertices[1].0,
        vertices[1].1,
        w * h
    );
    println!(
        "eye pass {e0:.1} → {e1:.1} ms ({:.2}×); its vertices {} → {}",
        e1 / e0,
        eye_vertices[0],
        eye_vertices[1]
    );
    Ok(())
}
