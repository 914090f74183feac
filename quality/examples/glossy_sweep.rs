//! Point-sampled glossy highlights of an area light against the lobe's truth, by roughness,
//! panel size and samples: the measurement behind the planner's roughness rule
//! (`coordinator/src/plan/gloss.rs`, `docs/planner.md` § Glossy highlights).
//!
//! `cargo run --release -p lightfold-quality --example glossy_sweep [-- --full]`
//!
//! Every sphere (silver) takes its highlight from the samples (`AreaSpecular::Sampled`, what the
//! planner sizes samples for: Blinn-Phong lobes and metallic-roughness above the closed form's
//! range). Prints, per sphere, the sample spacing as seen from the sphere's centre over the lobe's
//! width (`rho`, the rule's variable) and the RMS error over the truth's peak; the truth's own
//! noise is the error at 256 samples, where every `rho` is small.
use lightfold_node::gpu::{Gpu, GpuOptions};
use lightfold_quality::hard::glossy::{Setup, errors, render, setup_scene, truth};
use lightfold_scene::AreaSpecular;

fn main() -> anyhow::Result<()> {
    let full = std::env::args().any(|a| a == "--full");
    let gpu = Gpu::new(&GpuOptions::default())?;
    let roughness = vec![0.3, 0.4, 0.5, 0.6, 0.8];
    println!("scale,samples,roughness,rho,rms_over_peak,peak_ratio,pixels");
    for scale in [1.0f32, 2.0, 3.0] {
        let mut setup = Setup {
            roughness: roughness.clone(),
            area_specular: AreaSpecular::Sampled,
            ..Setup::case()
        };
        setup.light_size = setup.light_size.map(|s| s * scale);
        let t = truth(
            &setup,
            &setup_scene(&setup, full),
            if full { 4096 } else { 1024 },
        );
        for samples in [4u32, 16, 64, 256] {
            setup.samples = samples;
            let scene = setup_scene(&setup, full);
            let (img, _) = render(&gpu, &scene).map_err(|e| anyhow::anyhow!("{e}"))?;
            let light = &scene.lights[0];
            for (i, ((e, peak), px)) in errors(&t, &img).iter().zip(t.pixels()).enumerate() {
                let rho = lightfold_coordinator::plan::gloss::spacing_over_lobe(
                    light,
                    setup.sphere_center(i),
                    lightfold_scene::shading::ggx_alpha(roughness[i]),
                );
                println!(
                    "{scale},{samples},{},{rho:.3},{e:.5},{peak:.3},{px}",
                    roughness[i]
                );
            }
        }
    }
    Ok(())
}
