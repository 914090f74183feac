//! The cell filter (`ShadowFilter::Cell`: each sample's shadow spread over the shadow of its cell
//! of the light, percentage-closer soft shadows per sample) against PCF 2×2 with and without the
//! screen-space penumbra filter, by samples per area light, against each scene's area-light
//! truth (`docs/shading.md` § The cell filter).
//!
//! `cargo run --release -p lightfold-quality --example cell_filter [-- SCENE...]`
//! (default: balls, box, assets/fox.toml; 400×300; truths of 1 024 points a light, cached under
//! `$LIGHTFOLD_TRUTH_CACHE` when set).
//!
//! Prints CSV: scene, samples, filter, screen-space radius, penumbra and whole-image PSNR (dB),
//! node-seconds of the frame (the sum over nodes of K = 4).
use lightfold_node::gpu::{Gpu, GpuOptions};
use lightfold_quality::accuracy::{
    Setting, TruthOptions, filter_name, load_or_render_truth, measure_group,
};
use lightfold_scene::ShadowFilter;

fn main() -> anyhow::Result<()> {
    let mut names: Vec<String> = std::env::args().skip(1).collect();
    if names.is_empty() {
        names = vec!["balls".into(), "box".into(), "assets/fox.toml".into()];
    }
    let counts: Vec<u32> = std::env::var("COUNTS")
        .ok()
        .map(|s| s.split(',').filter_map(|c| c.parse().ok()).collect())
        .unwrap_or_else(|| vec![4, 8, 16, 32, 64]);
    let gpu = Gpu::new(&GpuOptions::default())?;
    let cache_dir = std::env::var_os("LIGHTFOLD_TRUTH_CACHE").map(Into::into);
    println!("scene,samples,filter,radius,penumbra_db,whole_db,node_seconds");
    for name in names {
        let mut scene = lightfold_scene::load(&name)?;
        (scene.camera.width, scene.camera.height) = (400, 300);
        let truth = load_or_render_truth(
            &scene,
            &TruthOptions {
                samples_per_light: 1024,
                cache_dir: cache_dir.clone(),
            },
        )?;
        for &n in &counts {
            let variants: [(ShadowFilter, &[u32]); 4] = [
                (ShadowFilter::Pcf2x2, &[0, 1, 2]),
                (ShadowFilter::Cell { taps: 2 }, &[0]),
                (ShadowFilter::Cell { taps: 3 }, &[0]),
                (ShadowFilter::Cell { taps: 4 }, &[0]),
            ];
            for (filter, radii) in variants {
                let settings: Vec<Setting> = radii
                    .iter()
                    .map(|&penumbra| Setting {
                        samples: n,
                        filter,
                        penumbra,
                        ..Setting::defaults(&scene)
                    })
                    .collect();
                let measured = measure_group(&gpu, &scene, &settings, 2)?;
                for (s, m) in settings.iter().zip(measured) {
                    let e = truth.truth.compare(&m.image)?;
                    let pen = e.penumbra.filter(|p| p.pixels > 0).unwrap_or(e.whole);
                    let secs: f64 = m.node_seconds.iter().sum();
                    println!(
                        "{name},{n},{},{},{:.2},{:.2},{secs:.3}",
                        filter_name(filter),
                        s.penumbra,
                        pen.psnr,
                        e.whole.psnr
                    );
                }
            }
        }
    }
    Ok(())
}
