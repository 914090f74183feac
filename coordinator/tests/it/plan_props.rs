//! Properties of the planner over random small scenes and clusters: every active sample is
//! assigned exactly once, plans are deterministic, a changed input changes only what it must, no
//! stage the scene does not use, and the stage wiring is what the compositors read.

use crate::plan_scenes;

use lightfold_coordinator::plan::{
    ClusterSpec, Downstream, DropReason, MaterialMode, PlanOptions, Source, Topology, plan,
};
use lightfold_protocol::{Layer, OpSource, OpSpec};
use lightfold_scene::shading::irradiance;
use proptest::prelude::*;

fn options(k: u32, topology: Topology, epsilon: f32) -> PlanOptions {
    PlanOptions {
        lights_per_node: k,
        topology,
        epsilon,
        ..PlanOptions::default()
    }
}

/// Enough nodes for any random scene at K = 1 (at most 4 lights × 6 samples + the material node).
const NODES: usize = 26;

fn strategy() -> impl Strategy<Value = (u64, u32, bool, usize, f32)> {
    (
        any::<u64>(),
        1u32..5,
        any::<bool>(),
        1usize..6,
        prop_oneof![Just(0.0f32), Just(1e-3f32)],
    )
}

fn topo(tree: bool) -> Topology {
    if tree {
        Topology::Tree
    } else {
        Topology::Chain
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 96, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn every_active_sample_is_assigned_exactly_once((seed, k, tree, comps, eps) in strategy()) {
        let scene = plan_scenes::random(seed);
        let p = plan(&scene, &ClusterSpec::local(NODES, comps), &options(k, topo(tree), eps)).unwrap();
        let mut assigned: Vec<usize> = p.nodes.iter().flat_map(|n| n.lights.iter().copied()).collect();
        assigned.sort_unstable();
        prop_assert_eq!(&assigned, &p.active);
        let mut all: Vec<usize> = p.active.iter().copied().chain(p.dropped.iter().map(|d| d.0)).collect();
        all.sort_unstable();
        prop_assert_eq!(all, (0..p.samples.len()).collect::<Vec<_>>());
        for n in &p.nodes {
            prop_assert!(n.lights.len() <= p.k as usize);
            prop_assert_eq!(n.lights.len(), n.shadows.len());
        }
        prop_assert!(p.epsilon_used <= eps);
    }

    #[test]
    fn the_same_inputs_give_the_same_plan((seed, k, tree, comps, eps) in strategy()) {
        let scene = plan_scenes::random(seed);
        let cluster = ClusterSpec::local(NODES, comps);
        let o = options(k, topo(tree), eps);
        prop_assert_eq!(plan(&scene, &cluster, &o).unwrap(), plan(&scene, &cluster, &o).unwrap());
    }

    #[test]
    fn dropped_samples_add_nothing_where_receivers_are((seed, _k, _tree, _comps, eps) in strategy()) {
        let scene = plan_scenes::random(seed);
        let p = plan(&scene, &ClusterSpec::local(NODES, 1), &options(4, Topology::Chain, eps)).unwrap();
        for (i, why) in &p.dropped {
            let s = &p.samples[*i];
            for m in &scene.meshes {
                for (v, n) in m.positions.iter().zip(&m.normals) {
                    let c = s.color.iter().fold(0.0f32, |a, &c| a.max(c));
                    let e = irradiance(s, *v, *n).max(irradiance(s, *v, n.map(|c| -c))) * c;
                    match why {
                        DropReason::BelowEpsilon { bound } => {
                            // Radiance ≤ bound; irradiance·max colour·max brdf is what it bounds.
                            let brdf = scene.materials[m.material].diffuse.iter().fold(0.0f32, |a, &c| a.max(c))
                                / std::f32::consts::PI;
                            prop_assert!(e * brdf * scene.exposure <= bound * 1.0001 + 1e-12);
                        }
                        // Invisible meshes may be lit: only the visible ones must be dark.
                        DropReason::Unreached { .. } if m.name == "hidden" => {}
                        _ => prop_assert_eq!(e, 0.0, "sample {} ({:?}) lights {}", i, why, m.name),
                    }
                }
            }
        }
    }

    #[test]
    fn a_changed_light_colour_changes_only_its_groups_colour(seed in any::<u64>(), k in 1u32..5) {
        let mut scene = plan_scenes::random(seed);
        scene.ambient = [0.0; 3];
        let o = options(k, Topology::Chain, 0.0);
        let cluster = ClusterSpec::local(NODES, 3);
        let before = plan(&scene, &cluster, &o).unwrap();
        let Some(&first) = before.active.first() else { return Ok(()) };
        let old = before.samples[first].color;
        let new = [0.3, 0.9, 0.5];
        for l in scene.lights.iter_mut().filter(|l| l.color == old) {
            l.color = new;
        }
        let after = plan(&scene, &cluster, &o).unwrap();
        prop_assert_eq!(&before.active, &after.active);
        prop_assert_eq!(before.nodes.len(), after.nodes.len());
        for (a, b) in before.nodes.iter().zip(&after.nodes) {
            prop_assert_eq!(&a.node, &b.node);
            prop_assert_eq!(&a.lights, &b.lights);
            prop_assert_eq!(&a.shadows, &b.shadows);
            prop_assert_eq!(&a.downstream, &b.downstream);
            // A group of that colour alone changes c_n; mixed (white) groups and others keep it.
            let recoloured = !a.lights.is_empty() && a.lights.iter().all(|&i| before.samples[i].color == old);
            prop_assert_eq!(b.color, if recoloured { new } else { a.color });
        }
        for (a, b) in before.stages.iter().zip(&after.stages) {
            prop_assert_eq!(&a.inputs, &b.inputs);
            prop_assert_eq!(&a.downstream, &b.downstream);
            let names = |s: &lightfold_coordinator::plan::StagePlan| s.ops.iter().map(|o| o.name().to_string()).collect::<Vec<_>>();
            prop_assert_eq!(names(a), names(b));
        }
    }

    #[test]
    fn an_added_compositor_or_node_does_not_reshuffle_lights((seed, k, tree, comps, eps) in strategy()) {
        let scene = plan_scenes::random(seed);
        let o = options(k, topo(tree), eps);
        let base = plan(&scene, &ClusterSpec::local(NODES, comps), &o).unwrap();
        for cluster in [ClusterSpec::local(NODES, comps + 1), ClusterSpec::local(NODES + 1, comps)] {
            let more = plan(&scene, &cluster, &o).unwrap();
            // The illumination nodes; a tree that gains a second leaf also gains a material node
            // of its own (its last stage no longer reads nodes that could carry the layers).
            let lit = |p: &lightfold_coordinator::plan::Plan| -> Vec<lightfold_coordinator::plan::NodePlan> {
                p.nodes.iter().filter(|n| n.layers.iter().any(|l| l.0 == Layer::Illumination)).cloned().collect()
            };
            let (base_lit, more_lit) = (lit(&base), lit(&more));
            prop_assert_eq!(base_lit.len(), more_lit.len());
            for (a, b) in base_lit.iter().zip(&more_lit) {
                prop_assert_eq!(&a.node, &b.node);
                prop_assert_eq!(&a.lights, &b.lights);
                prop_assert_eq!(a.color, b.color);
                prop_assert_eq!(&a.shadows, &b.shadows);
            }
        }
    }

    #[test]
    fn no_stage_or_layer_the_scene_does_not_use((seed, k, tree, comps, eps) in strategy()) {
        let scene = plan_scenes::random(seed);
        let p = plan(&scene, &ClusterSpec::local(NODES, comps), &options(k, topo(tree), eps)).unwrap();
        let layers: Vec<Layer> = p.material.layers.iter().map(|l| l.0).collect();
        let emits = scene.materials.iter().any(|m| m.emissive != [0.0; 3]);
        if !emits {
            prop_assert!(!layers.contains(&Layer::Emissive));
        }
        let ambient_used = scene.ambient != [0.0; 3] && scene.materials.iter().any(|m| m.ambient != [0.0; 3]);
        if !ambient_used || p.material.fold_ambient {
            prop_assert!(!layers.contains(&Layer::Ambient));
        }
        let first = scene.materials[0].specular;
        if scene.materials.iter().all(|m| m.specular == first) {
            prop_assert!(!layers.contains(&Layer::Specular));
            let uniform = matches!(p.material.mode, MaterialMode::UniformSpecular { .. });
            prop_assert!(uniform);
        }
        // Every used compositor stage is reached by something and leads to the sink.
        prop_assert!(p.stages.len() <= comps);
        let roots = p.stages.iter().filter(|s| s.downstream == Downstream::Sink).count();
        prop_assert_eq!(roots, 1);
        // Idle compositors get no configuration; used ones do.
        for s in &p.stages {
            prop_assert!(p.compositor_config(&s.compositor).is_some());
        }
    }

    #[test]
    fn stage_wiring_matches_the_operator_fold((seed, k, tree, comps, eps) in strategy()) {
        let scene = plan_scenes::random(seed);
        let p = plan(&scene, &ClusterSpec::local(NODES, comps), &options(k, topo(tree), eps)).unwrap();
        for s in &p.stages {
            // Operator 0 reads its inputs from the stage; each later one the previous output
            // plus the rest (compositor/src/daemon/config.rs).
            // With explicit wiring, each operator's wires match its input count, name earlier
            // operators only, and read every stage input at least once.
            let mut read = 0;
            let mut wired = vec![false; s.inputs.len()];
            prop_assert!(s.wiring.is_empty() || s.wiring.len() == s.ops.len());
            for (j, op) in s.ops.iter().enumerate() {
                let wanted = match op {
                    OpSpec::Accumulate(p) => p.colors.len() + usize::from(p.upstream),
                    OpSpec::Join(p) => p.inputs as usize,
                    OpSpec::Material(_) => 2,
                    OpSpec::Output(_) => 1,
                    other => panic!("unknown operator {}", other.name()),
                };
                read += wanted - usize::from(j > 0);
                if let Some(wires) = s.wiring.get(j) {
                    prop_assert_eq!(wires.len(), wanted);
                    for w in wires {
                        match *w {
                            OpSource::Input(i) => wired[i as usize] = true,
                            OpSource::Op(k) => prop_assert!((k as usize) < j),
                        }
                    }
                }
            }
            if s.wiring.is_empty() {
                prop_assert_eq!(read, s.inputs.len(), "stage {}", s.compositor);
            } else {
                prop_assert!(wired.iter().all(|w| *w), "stage {}", s.compositor);
            }
            for (i, input) in s.inputs.iter().enumerate() {
                let producer = match &input.source {
                    Source::Node(id) => {
                        let n = p.nodes.iter().find(|n| &n.node == id).unwrap();
                        (n.downstream.clone(), n.input_index)
                    }
                    Source::Stage(id) => {
                        let u = p.stages.iter().find(|u| &u.compositor == id).unwrap();
                        let Downstream::Stage(d) = &u.downstream else { panic!("stage {id} feeds the sink and {}", s.compositor) };
                        (d.clone(), u.input_index)
                    }
                };
                prop_assert_eq!(producer, (s.compositor.clone(), i as u32));
            }
        }
        for n in &p.nodes {
            let c = p.node_config(&n.node).unwrap();
            prop_assert_eq!(c.lights.len(), n.lights.len());
            prop_assert_eq!(c.downstream, p.address(&n.downstream));
        }
    }
}
