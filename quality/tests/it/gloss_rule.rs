//! The planner's roughness rule (`coordinator/src/plan/gloss.rs`) against hard case 19's
//! independent truth of glossy highlights (the GGX lobe importance-sampled over the panel, per
//! pixel; no `scene::ltc`, no renderer code): where an error target raises a light for its
//! glossy receivers, the highlights at the raised count are within the bound, and at the
//! scene's own count (the control) they are spotted beyond it.

use lightfold_coordinator::plan::{PlanOptions, targeted};
use lightfold_node::gpu::{Gpu, GpuOptions};
use lightfold_quality::hard::glossy::{Setup, errors, render, setup_scene, truth};
use lightfold_scene::AreaSpecular;

/// Worst sphere's RMS error over its truth's peak the raised count must keep (it measured
/// 0.4 % in `glossy_sweep`), and the least the control must show (2.2 % there).
const BOUND: f64 = 0.01;

#[test]
fn a_target_raises_a_large_panel_for_glossy_spheres_to_smooth_highlights() -> anyhow::Result<()> {
    // A panel three times hard case 19's (4.8 × 2.4 m at 2.9 m): 16 samples' cells are wider
    // than the lobes of roughness 0.4 and 0.5, whose highlights the samples carry.
    let mut setup = Setup {
        roughness: vec![0.4, 0.5],
        area_specular: AreaSpecular::Sampled,
        ..Setup::case()
    };
    setup.light_size = setup.light_size.map(|s| s * 3.0);
    let scene = setup_scene(&setup, false);
    let (raised, _, choice) =
        targeted(&scene, 45.0, &PlanOptions::default()).expect("the scene has an area light");
    let g = choice
        .gloss
        .first()
        .expect("the panel is raised for its spheres");
    // Raised above the count the target chose (which, paying for the raise, may itself take
    // more than the scene's 16).
    assert!(g.reached && g.from >= 16 && g.to > g.from, "{g:?}");
    assert!(
        g.material.contains("r0.4"),
        "the narrower lobe asks most: {g:?}"
    );
    let n = raised.lights[0].samples;
    assert_eq!(n, g.to);
    // A lower target asks for fewer (never more).
    let (_, _, loose) = targeted(&scene, 35.0, &PlanOptions::default()).unwrap();
    assert!(loose.gloss.first().is_none_or(|l| l.to <= n), "{loose:?}");

    let gpu = Gpu::new(&GpuOptions::default())?;
    let t = truth(&setup, &scene, 1024);
    let worst = |samples: u32| -> anyhow::Result<f64> {
        let mut s = setup.clone();
        s.samples = samples;
        let (img, _) = render(&gpu, &setup_scene(&s, false)).map_err(|e| anyhow::anyhow!("{e}"))?;
        Ok(errors(&t, &img).iter().map(|e| e.0).fold(0.0, f64::max))
    };
    let (at_raised, at_scene) = (worst(n)?, worst(16)?);
    eprintln!("{n} samples: worst {at_raised:.4}; 16 samples (control): {at_scene:.4}");
    assert!(at_raised <= BOUND, "{n} samples: {at_raised}");
    assert!(at_scene > 1.5 * BOUND, "the control must fail: {at_scene}");
    Ok(())
}
