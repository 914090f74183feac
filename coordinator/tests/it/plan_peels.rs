//! Peeled translucency planned (`PlanOptions::peels`, docs/translucency.md § Peeled layers): the
//! depth complexity that sets D, one cell of light groups per eye layer, back to front, the
//! stages that shade each layer and blend them, and what a peeled plan refuses.

use crate::plan_rules::assert_stages_build;
use crate::plan_scenes::stage;

use lightfold_coordinator::plan::{
    ClusterSpec, MAX_PEELS, Peels, Plan, PlanError, PlanOptions, depth_complexity, plan,
};
use lightfold_protocol::pipeline::OpSpec;
use lightfold_protocol::{Layer, OpSource};
use lightfold_scene::primitives::cuboid;
use lightfold_scene::{Material, Scene, Transmission};

/// The stage scene with `panes` red glass panes stacked over the box and ball, between them
/// and the camera (0.3 m apart), each 2.4 m wide.
fn panes(panes: usize) -> Scene {
    let mut s = stage();
    let glass = s.add_material(Material {
        transmission: Some(Transmission {
            color: [0.9, 0.1, 0.1],
            coverage: false,
        }),
        specular: [0.5; 3],
        shininess: 64.0,
        ..Material::diffuse("glass", [0.05; 3])
    });
    for i in 0..panes {
        let z = 1.2 + 0.3 * i as f32;
        s.add_mesh(cuboid("pane", [0.0, 0.8, z], [1.2, 0.8, 0.005], glass));
    }
    s
}

fn peeled(peels: Peels, lights_per_node: u32) -> PlanOptions {
    PlanOptions {
        peels,
        lights_per_node,
        ..PlanOptions::default()
    }
}

/// The ops of the stage that ends in `output`, and where each reads from.
fn root(p: &Plan) -> &lightfold_coordinator::plan::StagePlan {
    p.stages
        .iter()
        .find(|s| s.ops.iter().any(|o| matches!(o, OpSpec::Output(_))))
        .expect("a root stage")
}

#[test]
fn depth_complexity_counts_translucent_surfaces_in_front_of_the_opaque_one() {
    // A pane is a thin box: its front face and (seen through) its back face are two surfaces.
    assert_eq!(depth_complexity(&stage(), 8), 0, "nothing translucent");
    assert_eq!(depth_complexity(&panes(1), 8), 2);
    assert_eq!(depth_complexity(&panes(2), 8), 4);
    // The count stops at the cap.
    assert_eq!(depth_complexity(&panes(3), 3), 3);
    // A pane behind the camera is not in view.
    let mut behind = panes(1);
    let last = behind.meshes.len() - 1;
    for p in &mut behind.meshes[last].positions {
        p[2] += 10.0;
    }
    assert_eq!(depth_complexity(&behind, 8), 0);
}

#[test]
fn auto_peels_the_depth_complexity_one_cell_per_layer_back_to_front() {
    let s = panes(1);
    let p = plan(&s, &ClusterSpec::local(16, 4), &peeled(Peels::Auto, 2)).unwrap();
    let choice = p.peels.as_ref().expect("asked to peel");
    assert_eq!(choice.layers, 2);
    assert_eq!(choice.depth_complexity, Some(2));
    // 3 eye layers × 2 light groups (4 samples at K = 2), no tiles, no parts.
    assert_eq!(p.nodes.len(), 6);
    assert!(p.tiles.is_empty() && p.partitions.is_empty());
    for layer in 0..=2 {
        let nodes: Vec<_> = p.nodes.iter().filter(|n| n.peel == Some(layer)).collect();
        assert_eq!(nodes.len(), 2, "layer {layer}");
        let mut lights: Vec<usize> = nodes.iter().flat_map(|n| n.lights.clone()).collect();
        lights.sort_unstable();
        assert_eq!(lights, vec![0, 1, 2, 3], "every light lights every layer");
        // One node of the layer carries its material layers; a translucent layer's its
        // transmittance too. No depth travels (layers blend, they are not depth-composed).
        let hosts: Vec<_> = nodes
            .iter()
            .filter(|n| n.layers.iter().any(|l| l.0 == Layer::Diffuse))
            .collect();
        assert_eq!(hosts.len(), 1, "layer {layer}");
        let transmits = hosts[0].layers.iter().any(|l| l.0 == Layer::Transmittance);
        assert_eq!(transmits, layer > 0, "layer {layer}");
        assert!(
            nodes
                .iter()
                .all(|n| n.layers.iter().all(|l| l.0 != Layer::Depth))
        );
        // Each node is configured with its layer.
        for n in &nodes {
            assert_eq!(p.node_config(&n.node).unwrap().peel, Some(layer));
        }
    }
    // The stages build, and blend the opaque layer, then layer 2, then layer 1 (the nearest
    // last): along the stages, each layer's `material` is read in that order.
    assert_stages_build(&p);
    let mut order = Vec::new();
    for st in &p.stages {
        for (k, op) in st.ops.iter().enumerate() {
            if matches!(op, OpSpec::Material(_)) {
                let OpSource::Input(i) = st.wiring[k][1] else {
                    panic!("material reads its layer's first node")
                };
                let node = match &st.inputs[i as usize].source {
                    lightfold_coordinator::plan::Source::Node(id) => id.clone(),
                    other => panic!("{other:?}"),
                };
                order.push(p.nodes.iter().find(|n| n.node == node).unwrap().peel);
            }
        }
    }
    assert_eq!(order, vec![Some(0), Some(2), Some(1)]);
    let blends: u32 = p
        .stages
        .iter()
        .flat_map(|s| &s.ops)
        .map(|o| match o {
            OpSpec::Blend(b) => b.inputs - 1,
            _ => 0,
        })
        .sum();
    assert_eq!(blends, 2, "two layers laid over the back");
    assert!(matches!(root(&p).outputs[0].0, Layer::Radiance));
    let text = p.to_string();
    assert!(text.contains("peels: 2 translucent layer(s)"), "{text}");
    assert!(
        text.contains("3 eye layers × 2 light group(s) = 6 nodes"),
        "{text}"
    );
    assert!(text.contains("translucent layer 1 ·"), "{text}");
}

#[test]
fn peeling_is_off_by_default_and_none_without_translucency_in_view() {
    let s = panes(1);
    let classic = plan(&s, &ClusterSpec::local(16, 4), &peeled(Peels::Off, 2)).unwrap();
    assert!(classic.peels.is_none());
    assert!(classic.nodes.iter().all(|n| n.peel.is_none()));
    assert!(
        classic
            .stages
            .iter()
            .flat_map(|s| &s.ops)
            .all(|o| !matches!(o, OpSpec::Blend(_)))
    );
    // Auto on an opaque scene: the classic plan, with the reason.
    let opaque = stage();
    let o = PlanOptions {
        tiles: 1,
        ..peeled(Peels::Auto, 2)
    };
    let p = plan(&opaque, &ClusterSpec::local(16, 4), &o).unwrap();
    assert_eq!(p.peels.as_ref().map(|c| c.layers), Some(0));
    let mut q = plan(
        &opaque,
        &ClusterSpec::local(16, 4),
        &PlanOptions {
            peels: Peels::Off,
            ..o
        },
    )
    .unwrap();
    q.peels = p.peels.clone();
    assert_eq!(p, q, "nothing but the reason differs");
    assert!(
        p.to_string()
            .contains("peels: none: no translucent surface")
    );
}

#[test]
fn peels_are_capped_by_the_layers_and_the_nodes_and_refuse_what_they_do_not_take() {
    // Two panes (4 surfaces) capped at MAX_PEELS.
    let p = plan(
        &panes(2),
        &ClusterSpec::local(32, 4),
        &peeled(Peels::Auto, 4),
    )
    .unwrap();
    assert_eq!(p.peels.as_ref().unwrap().layers, MAX_PEELS.min(4));
    // Three render nodes hold the opaque layer and two translucent ones at most.
    let p = plan(
        &panes(2),
        &ClusterSpec::local(3, 4),
        &peeled(Peels::Auto, 4),
    )
    .unwrap();
    let c = p.peels.as_ref().unwrap();
    assert_eq!(c.layers, 2);
    assert!(c.why.contains("3 nodes"), "{}", c.why);
    // Asked for more layers than nodes (a live session that lost nodes): the layers the nodes
    // hold, and why; one node holds none.
    let p = plan(
        &panes(1),
        &ClusterSpec::local(2, 4),
        &peeled(Peels::Layers(2), 4),
    )
    .unwrap();
    let c = p.peels.as_ref().unwrap();
    assert_eq!(c.layers, 1);
    assert!(
        c.why.contains("1 translucent layer(s) of the 2 asked"),
        "{}",
        c.why
    );
    assert_eq!(p.nodes.len(), 2);
    let p = plan(
        &panes(1),
        &ClusterSpec::local(1, 4),
        &peeled(Peels::Layers(2), 4),
    )
    .unwrap();
    assert_eq!(p.peels.as_ref().unwrap().layers, 0);
    assert!(p.nodes.iter().all(|n| n.peel.is_none()));
    // Tiles, partitions, the material node of its own, the penumbra filter asked for.
    let refused = [
        PlanOptions {
            tiles: 2,
            ..peeled(Peels::Layers(1), 2)
        },
        PlanOptions {
            partitions: 2,
            ..peeled(Peels::Layers(1), 2)
        },
        PlanOptions {
            material_own_node: true,
            ..peeled(Peels::Layers(1), 2)
        },
        PlanOptions {
            penumbra_filter: lightfold_coordinator::plan::PenumbraFilter::Radius(2),
            ..peeled(Peels::Layers(1), 2)
        },
        peeled(Peels::Layers(MAX_PEELS + 1), 2),
    ];
    for o in refused {
        let e = plan(&panes(1), &ClusterSpec::local(16, 4), &o).unwrap_err();
        assert!(matches!(e, PlanError::InvalidOptions { .. }), "{o:?}: {e}");
    }
    // Tiles left automatic: none.
    let p = plan(
        &panes(1),
        &ClusterSpec::local(16, 4),
        &PlanOptions {
            tiles: 0,
            ..peeled(Peels::Layers(1), 2)
        },
    )
    .unwrap();
    assert!(p.tiles.is_empty() && p.decomposition.is_none());
    assert_eq!(p.nodes.iter().filter(|n| n.peel == Some(1)).count(), 2);
}
