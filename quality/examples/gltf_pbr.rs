//! The glTF models of `assets/` under the specification's metallic-roughness BRDF (issue 23),
//! for `docs/accuracy/gltf.md`:
//!
//! ```sh
//! LP_NUM_THREADS=2 NODEVICE_SELECT=1 cargo run --profile test -p lightfold-quality \
//!     --example gltf_pbr [-- --size 400x300 --frames 5]
//! ```
//!
//! Per model (loaded with its framing light), with the same point samples throughout:
//! - the GPU render (deferred, batches of K = 16) against the CPU reference's exact sum
//!   (ray-traced shadows): PSNR and energy bias over the whole image;
//! - the former mapping onto Blinn-Phong (what the loader made of metallic-roughness before:
//!   `m^d = base·(1 − m)`, `m^s = mix(0.04, base, m)`, the Beckmann-matched exponent of the mean
//!   roughness, normal, occlusion and emissive textures dropped) rendered on the GPU against the
//!   same reference: how far the former images were from the specification's;
//! - the GPU time of a frame (median of `--frames`, after a warm-up) under both, measured in the
//!   same run, alternating.
use anyhow::Context;
use lightfold_node::gpu::{Gpu, GpuOptions};
use lightfold_protocol::stats;
use lightfold_quality::gpu_radiance;
use lightfold_reference::metrics::error_stats;
use lightfold_reference::render_point_sum;
use lightfold_scene::shading::shininess_from_roughness;
use lightfold_scene::{Material, Scene, load_gltf, sampling};
use std::path::Path;

/// Mean (roughness, metallic) of a metallic-roughness texture, 1 where there is none.
fn texture_means(scene: &Scene, t: Option<usize>) -> (f32, f32) {
    let Some(tex) = t.and_then(|t| scene.textures.get(t)) else {
        return (1.0, 1.0);
    };
    let n = (tex.rgba8.len() / 4).max(1) as f64 * 255.0;
    let sum = |c: usize| {
        tex.rgba8
            .chunks_exact(4)
            .map(|p| f64::from(p[c]))
            .sum::<f64>()
    };
    ((sum(1) / n) as f32, (sum(2) / n) as f32)
}

/// The scene as the former loader made it.
fn former(scene: &Scene) -> Scene {
    let mut s = scene.clone();
    for m in &mut s.materials {
        let Some(p) = m.pbr.take() else { continue };
        let (mean_r, mean_m) = texture_means(scene, p.metallic_roughness_texture);
        let metallic = (p.metallic * mean_m).clamp(0.0, 1.0);
        *m = Material {
            diffuse: p
                .base_color
                .map(|c| c * (1.0 - metallic) * (1.0 - p.transmission)),
            specular: p.base_color.map(|c| 0.04 + (c - 0.04) * metallic),
            shininess: shininess_from_roughness(p.roughness * mean_r),
            ambient: [0.0; 3],
            ..m.clone()
        };
    }
    s
}

fn median(v: &[f64]) -> f64 {
    stats::median(v).expect("timed frames")
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let value = |flag: &str| {
        args.iter()
            .position(|a| a == flag)
            .and_then(|i| args.get(i + 1))
            .cloned()
    };
    let (w, h) = value("--size")
        .and_then(|s| {
            let (a, b) = s.split_once('x')?;
            Some((a.parse().ok()?, b.parse().ok()?))
        })
        .unwrap_or((400u32, 300u32));
    let frames: usize = value("--frames").and_then(|s| s.parse().ok()).unwrap_or(5);
    let gpu = Gpu::new(&GpuOptions::default()).context("a GPU adapter (lavapipe will do)")?;
    println!(
        "| model | triangles | samples | PSNR vs reference (dB) | energy bias | former mapping: PSNR vs the same reference (dB) | energy bias | GPU ms | former GPU ms | ratio |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets");
    for (model, file) in [
        ("BoxTextured", "BoxTextured.gltf"),
        ("AlphaBlendModeTest", "AlphaBlendModeTest.gltf"),
        ("CesiumMan", "CesiumMan.gltf"),
        ("Fox", "Fox.glb"),
        ("FlightHelmet", "FlightHelmet.gltf"),
    ] {
        let mut scene = load_gltf(&root.join(model).join(file))?;
        scene.animation = None;
        scene.camera.width = w;
        scene.camera.height = h;
        let samples = sampling::direct_samples(&scene);
        let reference =
            render_point_sum(&scene, &samples, [1.0; 3]).radiance([1.0; 3], scene.ambient);
        let old = former(&scene);
        let (mut now_ms, mut old_ms) = (Vec::new(), Vec::new());
        let (mut img, mut old_img) = (None, None);
        for _ in 0..frames {
            let (i, s) = gpu_radiance(&gpu, &scene, &samples)?;
            now_ms.push(s * 1e3);
            img = Some(i);
            let (i, s) = gpu_radiance(&gpu, &old, &samples)?;
            old_ms.push(s * 1e3);
            old_img = Some(i);
        }
        let now = error_stats(&img.context("no frame")?, &reference, scene.exposure, None)?;
        let was = error_stats(
            &old_img.context("no frame")?,
            &reference,
            scene.exposure,
            None,
        )?;
        let (a, b) = (median(&now_ms), median(&old_ms));
        println!(
            "| {model} | {} | {} | {:.2} | {:+.3} % | {:.2} | {:+.2} % | {a:.1} | {b:.1} | {:.2}× |",
            scene.triangle_count(),
            samples.len(),
            now.psnr,
            now.energy_bias * 100.0,
            was.psnr,
            was.energy_bias * 100.0,
            a / b
        );
    }
    Ok(())
}
