//! Highlights of the built-ins' glossy receivers against the area-light truth by samples per area
//! light: what the planner's roughness rule (`coordinator/src/plan/gloss.rs`) raises them to,
//! checked on the scenes it raises (`docs/planner.md` § Glossy highlights).
//!
//! `cargo run --release -p lightfold-quality --example gloss_builtins [-- SCENE...]`
//!
//! Per scene and count: PSNR over the pixels of glossy receivers (materials whose highlight the
//! samples carry), peak the truth's brightest such pixel, and over the whole image.
use lightfold_coordinator::plan::{PlanOptions, gloss, targeted};
use lightfold_node::gpu::{Gpu, GpuOptions};
use lightfold_quality::accuracy::{Setting, TruthOptions, load_or_render_truth, measure_group};
use lightfold_scene::trace::Tracer;

fn main() -> anyhow::Result<()> {
    let mut names: Vec<String> = std::env::args().skip(1).collect();
    if names.is_empty() {
        names = vec!["balls".into(), "box".into()];
    }
    let gpu = Gpu::new(&GpuOptions::default())?;
    println!("scene,samples,glossy_psnr_db,glossy_pixels,whole_psnr_db,seconds");
    for name in names {
        let mut scene = lightfold_scene::builtin(&name)?;
        (scene.camera.width, scene.camera.height) = (400, 300);
        let planned = targeted(&scene, 45.0, &PlanOptions::default())
            .map(|(_, _, t)| t.gloss.iter().map(|g| g.to).max().unwrap_or(t.to));
        eprintln!("{name}: the rule asks {planned:?}");
        let truth = load_or_render_truth(
            &scene,
            &TruthOptions {
                samples_per_light: 1024,
                cache_dir: None,
            },
        )?
        .truth;
        let tracer = Tracer::new(&scene);
        let (w, h) = (scene.camera.width, scene.camera.height);
        let mut glossy = vec![false; (w * h) as usize];
        for y in 0..h {
            for x in 0..w {
                if let Some(hit) = tracer.primary(x, y) {
                    let i = (y * w + x) as usize;
                    glossy[i] =
                        truth.compared[i] && gloss::sampled_lobe(&scene, hit.material).is_some();
                }
            }
        }
        let e = truth.exposure;
        let peak = glossy
            .iter()
            .enumerate()
            .filter(|(_, g)| **g)
            .flat_map(|(i, _)| truth.radiance.data[i * 3..i * 3 + 3].to_vec())
            .fold(0f32, f32::max)
            * e;
        let mut counts = vec![16u32, 32, 64, 256];
        counts.extend(planned);
        counts.sort_unstable();
        counts.dedup();
        for n in counts {
            let setting = Setting {
                samples: n,
                ..Setting::defaults(&scene)
            };
            let t0 = std::time::Instant::now();
            let img = measure_group(&gpu, &scene, &[setting], 1)?.remove(0).image;
            let secs = t0.elapsed().as_secs_f64();
            // The project's metric (`reference::metrics`); the glossy figure's peak is the
            // brightest glossy truth pixel rather than 1.
            let stats = |mask: &[bool]| {
                lightfold_reference::metrics::error_stats(&img, &truth.radiance, e, Some(mask))
            };
            let glossy_stats = stats(&glossy)?;
            let whole = stats(&truth.compared)?.psnr;
            let (g, gp) = (
                20.0 * (f64::from(peak) / glossy_stats.rmse).log10(),
                glossy_stats.pixels,
            );
            println!("{name},{n},{g:.2},{gp},{whole:.2},{secs:.2}");
        }
    }
    Ok(())
}
