//! The bound on a local cluster's processes (`lightfold demo`): a scene needing more is refused
//! with the smallest K that fits.

use lightfold_coordinator::plan::{ClusterSpec, PlanOptions, plan};
use lightfold_harness::local_cluster::{MIN_MAX_PROCESSES, check_processes, default_max_processes};

#[test]
fn a_scene_needing_too_many_processes_is_refused_with_a_k_that_fits() {
    // 2 area lights × 500 samples: at K = 4 it used to start 250 nodes and 250 compositors.
    let mut scene = lightfold_scene::builtin("balls").unwrap();
    let opts0 = PlanOptions {
        lights_per_node: 4,
        // Untiled: automatic tiles would take the synthetic cluster's 256 nodes (the demo's
        // probe cluster reports this machine's CPU or GPU, where they do not).
        tiles: 1,
        ..PlanOptions::default()
    };
    scene.quality.samples_per_area_light = Some(500);
    let probe = plan(&scene, &ClusterSpec::local(256, 256), &opts0).unwrap();
    assert!(probe.nodes.len() > 200, "{} nodes", probe.nodes.len());
    let e = check_processes(&scene, &opts0, &probe, Some(32))
        .unwrap_err()
        .to_string();
    assert!(e.contains("at K = 4 needs"), "{e}");
    assert!(e.contains("--max-processes allows 32"), "{e}");
    let k: u32 = e
        .split("-K ")
        .nth(1)
        .and_then(|r| r.split(' ').next())
        .and_then(|k| k.parse().ok())
        .unwrap_or_else(|| panic!("no -K in {e}"));
    assert!(
        e.contains(&format!("--frame-budget loose enough for K ≥ {k}")),
        "{e}"
    );
    let mut opts = opts0.clone();
    opts.lights_per_node = k;
    let fits = plan(&scene, &ClusterSpec::local(256, 256), &opts).unwrap();
    assert!(fits.nodes.len() + fits.stages.len() < 32, "{e}");
    opts.lights_per_node = k - 1;
    let short = plan(&scene, &ClusterSpec::local(256, 256), &opts).unwrap();
    assert!(
        short.nodes.len() + short.stages.len() >= 32,
        "K {k} is not the smallest"
    );
    // The default scene fits the default on any machine; a larger limit admits the scene.
    let small = lightfold_scene::builtin("balls").unwrap();
    let p = plan(&small, &ClusterSpec::local(256, 256), &opts0).unwrap();
    check_processes(&small, &opts0, &p, None).unwrap();
    check_processes(&scene, &opts0, &probe, Some(1000)).unwrap();
    assert!(default_max_processes() >= MIN_MAX_PROCESSES);
}
