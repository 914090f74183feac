//! The planner's shadow passes are the node's: for every built-in scene, in moving-light and in
//! walkthrough mode, each planned light's view count equals the number of maps the GPU renderer
//! fits for it (moving lights fit views to what the camera sees, walkthrough maps to every
//! receiver). The planner balances nodes by these counts, so a mismatch misprices every light.

use lightfold_coordinator::plan::{ClusterSpec, PlanOptions, plan};
use lightfold_node::gpu::{Gpu, GpuOptions, LayerSet, RenderOptions, Renderer};

#[test]
fn planned_passes_equal_the_renderers() {
    let gpu = Gpu::new(&GpuOptions::default()).expect("a GPU adapter (install lavapipe)");
    let mut total = [0usize; 2];
    for name in lightfold_scene::builtin_names() {
        let mut scene = lightfold_scene::builtin(name).unwrap();
        scene.camera.width = 64;
        scene.camera.height = 48;
        for (mode, walkthrough) in [(0, false), (1, true)] {
            let options = PlanOptions {
                walkthrough,
                ..PlanOptions::default()
            };
            let p = plan(&scene, &ClusterSpec::local(64, 8), &options).unwrap();
            for n in p.nodes.iter().filter(|n| !n.lights.is_empty()) {
                let lights: Vec<_> = n.lights.iter().map(|&i| p.samples[i]).collect();
                let opts = RenderOptions {
                    shadow_map_size: n.shadows[0].map_size,
                    walkthrough,
                    ..RenderOptions::from_quality(&scene.quality)
                };
                let mut r = Renderer::new(&gpu, &scene, opts).unwrap();
                r.set_map_sides(Some(n.shadows.iter().map(|s| s.map_size).collect()));
                let frame = r
                    .render(&gpu, &lights, None, n.color, LayerSet::illumination())
                    .unwrap();
                let planned: Vec<u32> = n.shadows.iter().map(|s| s.views.count() as u32).collect();
                assert_eq!(
                    planned, frame.stats.passes_per_light,
                    "{name} (walkthrough {walkthrough}) {}: planned views per light vs the renderer's",
                    n.node
                );
                total[mode] += planned.iter().sum::<u32>() as usize;
            }
        }
    }
    // Walkthrough maps cover receivers the camera does not see, so they never need fewer views.
    assert!(
        total[1] >= total[0],
        "passes: moving {} > walkthrough {}",
        total[0],
        total[1]
    );
    println!(
        "shadow passes over all built-ins: moving {}, walkthrough {}",
        total[0], total[1]
    );
}
