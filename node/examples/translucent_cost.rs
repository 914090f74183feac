//! What coloured shadows cost and how close they are (`docs/translucency.md`): one render node's
//! shadow phase with transmittance maps (the glass scene's panes translucent) against the same
//! geometry cast as opaque casters, in the same run, alternating frame by frame; and the error
//! of both images against the CPU reference of the translucent scene (the exact point sum over
//! the same samples, shadow rays carrying the transmittance). Set `LP_NUM_THREADS` as the bench
//! does (1) before running.
//!
//! `cargo run --release -p lightfold-node --example translucent_cost -- [--frames N] [--scene S]
//! [--size WxH] [K]`

use lightfold_node::gpu::{Gpu, GpuOptions, LayerSet, RenderOptions, Renderer};
use lightfold_protocol::stats;
use lightfold_reference::render_point_sum;
use lightfold_scene::{Image, LightSample, Scene};

fn median(v: &[f64]) -> f64 {
    stats::median(v).expect("timed frames")
}

/// The scene with every translucent caster made opaque: the same triangles, black shadows.
fn opaque(scene: &Scene) -> Scene {
    let mut s = scene.clone();
    for m in &mut s.materials {
        m.transmission = None;
    }
    s
}

/// Relative RMSE of illumination `a` against `b` over covered pixels, and the largest error.
fn error(a: &Image, b: &Image) -> (f64, f64) {
    let (mut se, mut sr, mut max) = (0.0f64, 0.0f64, 0.0f64);
    for (x, y) in a.data.iter().zip(&b.data) {
        let d = f64::from(x - y);
        se += d * d;
        sr += f64::from(*y) * f64::from(*y);
        max = max.max(d.abs());
    }
    ((se / sr.max(1e-30)).sqrt(), max)
}

fn main() -> anyhow::Result<()> {
    let mut frames = 8u32;
    let mut scene_name = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/glass.toml").to_string();
    let mut size = (400u32, 300u32);
    let mut k = 4usize;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--frames" => frames = args.next().unwrap_or_default().parse()?,
            "--scene" => scene_name = args.next().unwrap_or_default(),
            "--size" => {
                let s = args.next().unwrap_or_default();
                let (w, h) = s
                    .split_once('x')
                    .ok_or_else(|| anyhow::anyhow!("--size WxH"))?;
                size = (w.parse()?, h.parse()?);
            }
            n => k = n.parse()?,
        }
    }
    let mut scene = lightfold_scene::load(&scene_name)?;
    scene.camera.width = size.0;
    scene.camera.height = size.1;
    let samples = lightfold_scene::sampling::direct_samples(&scene);
    let lights: Vec<LightSample> = (0..k)
        .map(|i| samples[(i * samples.len() / k) % samples.len()])
        .collect();
    let gpu = Gpu::new(&GpuOptions::default())?;
    let opts = RenderOptions::from_quality(&scene.quality);
    let solid = opaque(&scene);
    let mut translucent = Renderer::new(&gpu, &scene, opts)?;
    let mut plain = Renderer::new(&gpu, &solid, opts)?;
    // Moving lights: every frame renders every map (a light moved by nothing is still redrawn,
    // as walkthrough mode is off).
    let (mut shadow_t, mut shadow_o, mut eye_t, mut eye_o) = (vec![], vec![], vec![], vec![]);
    // The eye pass with the material layers: the glass is seen through (its filter pass) where
    // the opaque copy draws it as a surface.
    let (mut layers_t, mut layers_o) = (vec![], vec![]);
    let (mut transmit_views, mut views) = (0, 0);
    let mut last = None;
    for f in 0..2 + frames {
        let a = translucent.render(&gpu, &lights, None, [1.0; 3], LayerSet::illumination())?;
        let b = plain.render(&gpu, &lights, None, [1.0; 3], LayerSet::illumination())?;
        if f >= 2 {
            shadow_t.push(a.stats.shadow_us as f64 / 1000.0);
            shadow_o.push(b.stats.shadow_us as f64 / 1000.0);
            eye_t.push(a.stats.eye_us as f64 / 1000.0);
            eye_o.push(b.stats.eye_us as f64 / 1000.0);
        }
        let c = translucent.render(&gpu, &lights, None, [1.0; 3], LayerSet::all())?;
        let d = plain.render(&gpu, &lights, None, [1.0; 3], LayerSet::all())?;
        if f >= 2 {
            layers_t.push(c.stats.eye_us as f64 / 1000.0);
            layers_o.push(d.stats.eye_us as f64 / 1000.0);
        }
        transmit_views = a.stats.transmit_passes;
        views = a.stats.shadow_passes;
        last = Some((a, b));
    }
    let (a, b) = last.expect("frames ran");
    let (st, so) = (median(&shadow_t), median(&shadow_o));
    let (et, eo) = (median(&eye_t), median(&eye_o));
    let (lt, lo) = (median(&layers_t), median(&layers_o));
    println!(
        "scene {} at {}×{}, K = {k}, {views} views of which {transmit_views} with transmittance \
         maps; medians of {frames} frames on {}",
        scene.name, size.0, size.1, gpu.info.name
    );
    println!("| phase | opaque casters ms | translucent ms | ratio | per light ms |");
    println!("|---|---|---|---|---|");
    for (what, t, o) in [
        ("shadow", st, so),
        ("eye", et, eo),
        ("eye + material layers", lt, lo),
    ] {
        println!(
            "| {what} | {o:.1} | {t:.1} | {:.2} | {:+.2} |",
            t / o,
            (t - o) / k as f64
        );
    }
    // Against the translucent scene's reference; the opaque casters also against their own
    // (the shadow maps' error without translucency, the floor of the first line).
    let reference = render_point_sum(&scene, &lights, [1.0; 3]).illumination;
    let solid_reference = render_point_sum(&solid, &lights, [1.0; 3]).illumination;
    for (what, frame, truth) in [
        ("translucent vs its reference", &a, &reference),
        ("opaque casters vs their reference", &b, &solid_reference),
        (
            "opaque casters vs the translucent reference",
            &b,
            &reference,
        ),
    ] {
        let il = frame.illumination.as_ref().expect("illumination");
        let (rel, max) = error(il, truth);
        println!("{what}: illumination relative RMSE {rel:.2e}, max {max:.2e}");
    }
    Ok(())
}
