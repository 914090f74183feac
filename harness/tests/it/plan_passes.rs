//! The planner's shadow passes are the node's: for every built-in scene, in moving-light and in
//! walkthrough mode, each planned light's view count equals the number of maps the GPU renderer
//! fits for it (moving lights fit views to what the camera sees, walkthrough maps to every
//! receiver). The planner balances nodes by these counts, so a mismatch misprices every light.

use lightfold_coordinator::plan::{ClusterSpec, PlanOptions, plan};
use lightfold_node::gpu::{LayerSet, RenderOptions, Renderer};

#[test]
fn planned_passes_equal_the_renderers() {
    let gpu = lightfold_harness::gpu();
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

/// What the planner plans, the daemons take: over random light colours (saturated ones with zero
/// channels, black, HDR), frame budgets, partitions, topologies and clusters that lose daemons
/// (re-plans), every node configuration passes the render node's own check
/// (`node::daemon::configure::check`) and every compositor configuration the stage's
/// (`StagePlan::new`). A configuration a daemon refuses used to end a live session: a pure-red
/// light (`[1, 0, 0]`) was such a colour.
mod daemons_take_every_plan {
    use lightfold_coordinator::plan::{ClusterSpec, PlanOptions, Topology, plan, replan};
    use lightfold_protocol::frame::DEFAULT_MAX_FRAME;
    use lightfold_scene::{Light, Scene};
    use proptest::prelude::*;

    const COLOURS: [[f32; 3]; 7] = [
        [1.0, 0.0, 0.0],
        [1.0, 0.125, 0.0],
        [0.0, 0.0, 1.0],
        [0.0, 0.0, 0.0],
        [1.0, 1.0, 1.0],
        [3.0, 0.5, 0.0],
        [0.25, 0.8, 0.6],
    ];

    /// `balls` with one to three of its area lights, recoloured, of `samples` samples each.
    fn scene(colours: &[usize], samples: u32) -> Scene {
        let mut s = lightfold_scene::builtin("balls").unwrap();
        let base = std::mem::take(&mut s.lights);
        s.lights = colours
            .iter()
            .enumerate()
            .map(|(i, &c)| Light {
                name: format!("light-{i}"),
                color: COLOURS[c],
                samples,
                ..base[i % base.len()].clone()
            })
            .collect();
        s.camera.width = 96;
        s.camera.height = 64;
        s
    }

    fn check_plan(scene: &Scene, p: &lightfold_coordinator::plan::Plan) -> Result<(), String> {
        for n in &p.nodes {
            let cfg = p.node_config(&n.node).ok_or("no node config")?;
            lightfold_node::daemon::configure::check(cfg, scene, |_| 256, 8192, DEFAULT_MAX_FRAME)
                .map_err(|e| format!("{} refuses its configuration: {e}", n.node))?;
        }
        for s in &p.stages {
            let cfg = p
                .compositor_config(&s.compositor)
                .ok_or("no stage config")?;
            lightfold_compositor::daemon::StagePlan::new(cfg, DEFAULT_MAX_FRAME)
                .map_err(|e| format!("{} refuses its configuration: {e}", s.compositor))?;
        }
        Ok(())
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 48, failure_persistence: None, ..ProptestConfig::default() })]

        #[test]
        fn over_colours_budgets_partitions_and_losses(
            colours in proptest::collection::vec(0usize..COLOURS.len(), 1..4),
            samples in prop_oneof![Just(1u32), Just(4), Just(8)],
            k in 1u32..5,
            budget_ms in proptest::option::of(5u64..400),
            partitions in 1u32..3,
            tree in any::<bool>(),
            lose in 0usize..3,
        ) {
            let scene = scene(&colours, samples);
            let opts = PlanOptions {
                lights_per_node: k,
                topology: if tree { Topology::Tree } else { Topology::Chain },
                frame_budget_us: budget_ms.map(|ms| ms * 1000),
                partitions,
                ..PlanOptions::default()
            };
            let cluster = ClusterSpec::local(64, 6);
            let first = plan(&scene, &cluster, &opts).map_err(|e| TestCaseError::fail(e.to_string()))?;
            check_plan(&scene, &first).map_err(TestCaseError::fail)?;
            // Failover: the same scene over the daemons left.
            let left = ClusterSpec {
                nodes: cluster.nodes[lose..].to_vec(),
                compositors: cluster.compositors[lose.min(2)..].to_vec(),
                sink: cluster.sink.clone(),
            };
            let again = PlanOptions { epoch: 2, ..opts };
            if let Ok(next) = replan(&scene, &left, &again, &first) {
                check_plan(&scene, &next).map_err(TestCaseError::fail)?;
            }
        }
    }
}
