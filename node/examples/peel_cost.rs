//! What a peeled eye layer costs a node (`docs/translucency.md` § Peeled layers): the eye phase
//! of the classic pass (filters multiplied in), of peel 0 (the opaque layer) and of peels 1..=D
//! (depth peeling: two rasters of the scene per peel), with the material layers (and the
//! transmittance for d ≥ 1), in the same run, alternating frame by frame. Walkthrough mode keeps
//! the shadow maps, so a frame is its eye phase. Set `LP_NUM_THREADS` as the bench does (1).
//!
//! `cargo run -p lightfold-node --example peel_cost -- [--frames N] [--scene S] [--size WxH]
//! [--peels D] [K]`

use lightfold_node::gpu::{EyeVariant, Gpu, GpuOptions, LayerSet, RenderOptions, Renderer};
use lightfold_protocol::stats;
use lightfold_scene::LightSample;

fn main() -> anyhow::Result<()> {
    let mut frames = 8u32;
    let mut scene_name =
        concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/glass-stack.toml").to_string();
    let mut size = (400u32, 300u32);
    let mut peels = 3u32;
    let mut k = 4usize;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--frames" => frames = args.next().unwrap_or_default().parse()?,
            "--scene" => scene_name = args.next().unwrap_or_default(),
            "--peels" => peels = args.next().unwrap_or_default().parse()?,
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
    let opts = RenderOptions {
        walkthrough: true,
        ..RenderOptions::from_quality(&scene.quality)
    };
    let mut r = Renderer::new(&gpu, &scene, opts)?;
    // The classic pass and peel 0 in both variants, then the translucent peels (forward).
    let modes: Vec<(Option<u32>, EyeVariant)> = [
        (None, EyeVariant::Deferred),
        (None, EyeVariant::Forward),
        (Some(0), EyeVariant::Deferred),
    ]
    .into_iter()
    .chain((0..=peels).map(|d| (Some(d), EyeVariant::Forward)))
    .collect();
    let mut times: Vec<Vec<f64>> = vec![Vec::new(); modes.len()];
    for f in 0..2 + frames {
        for (m, &(peel, variant)) in modes.iter().enumerate() {
            r.set_peel(peel);
            r.set_variant(variant);
            let layers = LayerSet {
                transmittance: peel.is_some_and(|d| d >= 1),
                ..LayerSet::all()
            };
            let frame = r.render(&gpu, &lights, None, [1.0; 3], layers)?;
            if f >= 2 {
                times[m].push(frame.stats.eye_us as f64 / 1000.0);
            }
        }
    }
    println!(
        "scene {} at {}×{}, K = {k}, eye phase with the material layers; medians of {frames} \
         frames on {}",
        scene.name, size.0, size.1, gpu.info.name
    );
    println!("| eye layer | eye ms | × classic |");
    println!("|---|---:|---:|");
    let classic = stats::median(&times[0]).expect("timed frames");
    for ((peel, variant), t) in modes.iter().zip(&times) {
        let ms = stats::median(t).expect("timed frames");
        let name = match peel {
            None => format!("classic (peel None), {variant:?}"),
            Some(0) => format!("peel 0 (opaque), {variant:?}"),
            Some(d) => format!("peel {d}"),
        };
        println!("| {name} | {ms:.1} | {:.2} |", ms / classic);
    }
    Ok(())
}
