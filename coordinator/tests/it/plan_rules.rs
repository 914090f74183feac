//! The planner's rules on hand-built scenes: each culling reason, casters, material layers and
//! folding, K raised on short clusters, cost balancing, topologies, map sizes and errors.

use crate::plan_scenes;

use lightfold_coordinator::plan::{
    ClusterSpec, Downstream, DropReason, MapSizing, MaterialMode, MaterialPlacement, PlanError,
    PlanOptions, Topology, plan,
};
use lightfold_protocol::{Capabilities, Layer, OpSource, PixelFormat, Role};
use lightfold_scene::primitives::cuboid;
use lightfold_scene::{Light, LightShape, Material, Scene};
use plan_scenes::{rect, stage};

fn opts() -> PlanOptions {
    PlanOptions::default()
}

fn local() -> ClusterSpec {
    ClusterSpec::local(16, 16)
}

fn point(name: &str, position: [f32; 3], power: f32) -> Light {
    Light {
        name: name.to_string(),
        shape: LightShape::Point { position },
        color: [1.0; 3],
        power,
        range: None,
        samples: 1,
    }
}

fn reasons(scene: &Scene, o: &PlanOptions) -> Vec<DropReason> {
    plan(scene, &local(), o)
        .unwrap()
        .dropped
        .into_iter()
        .map(|d| d.1)
        .collect()
}

#[test]
fn the_stage_scene_plans_one_group_and_one_material_node() {
    let p = plan(&stage(), &local(), &opts()).unwrap();
    assert_eq!(p.active, vec![0, 1, 2, 3]);
    // The material layers are extra targets of the one illumination node the last stage reads.
    assert_eq!(p.nodes.len(), 1);
    assert_eq!(p.nodes[0].lights, vec![0, 1, 2, 3]);
    assert_eq!(p.nodes[0].color, [1.0; 3]);
    assert_eq!(
        p.nodes[0].layers.iter().map(|l| l.0).collect::<Vec<_>>(),
        vec![Layer::Illumination, Layer::Diffuse]
    );
    assert_eq!(
        p.material.placement,
        MaterialPlacement::ExtraTargets {
            node: "node-0".into()
        }
    );
    assert_eq!(
        p.material.mode,
        MaterialMode::UniformSpecular { specular: [0.0; 3] }
    );
    assert_eq!(p.stages.len(), 1);
    let ops: Vec<&str> = p.stages[0].ops.iter().map(|o| o.name()).collect();
    assert_eq!(ops, ["accumulate", "material", "output"]);
    // accumulate reads the node, material the sum and the same node, output the material.
    assert_eq!(
        p.stages[0].wiring,
        vec![
            vec![OpSource::Input(0)],
            vec![OpSource::Op(0), OpSource::Input(0)],
            vec![OpSource::Op(1)],
        ]
    );
    assert_eq!(p.idle_nodes.len(), 15);
    assert!(p.node_config("node-5").is_none());
    assert!(p.compositor_config("comp-3").is_none());
    let text = p.to_string();
    for part in [
        "samples: 4 total, 4 active",
        "stages:",
        "links (bytes per frame):",
        "accumulate",
        "extra targets of node-0",
    ] {
        assert!(text.contains(part), "missing {part:?} in\n{text}");
    }

    // The paper's layout on request: a material node of its own, read by the fold.
    let own = plan(
        &stage(),
        &local(),
        &PlanOptions {
            material_own_node: true,
            ..opts()
        },
    )
    .unwrap();
    assert_eq!(own.nodes.len(), 2);
    assert_eq!(
        own.nodes[1].layers.iter().map(|l| l.0).collect::<Vec<_>>(),
        vec![Layer::Diffuse]
    );
    assert!(own.stages[0].wiring.is_empty());
    assert_eq!(own.stages[0].inputs.len(), 2);
    assert!(own.nodes[0].est_cost_us < p.nodes[0].est_cost_us);
}

#[test]
fn each_provable_zero_is_dropped_with_its_reason() {
    let mut s = stage();
    s.lights.push(rect(
        "up",
        [0.0, 3.0, 0.0],
        [0.0, 1.0, 0.0],
        1.0,
        [1.0; 3],
        1,
    ));
    let mut short = point("short", [0.0, 6.0, 0.0], 10.0);
    short.range = Some(1.0);
    s.lights.push(short);
    s.lights.push(Light {
        name: "spot-up".into(),
        shape: LightShape::Spot {
            position: [0.0, 3.0, 0.0],
            direction: [0.0, 1.0, 0.0],
            inner_angle: 0.2,
            outer_angle: 0.4,
        },
        color: [1.0; 3],
        power: 10.0,
        range: None,
        samples: 1,
    });
    let mut black = point("black", [0.0, 3.0, 1.0], 10.0);
    black.color = [0.0; 3];
    s.lights.push(black);
    let got = reasons(
        &s,
        &PlanOptions {
            epsilon: 0.0,
            ..opts()
        },
    );
    assert_eq!(got.len(), 4, "{got:?}");
    assert!(
        matches!(got[0], DropReason::Unreached { behind: 3, .. }),
        "{got:?}"
    );
    assert!(
        matches!(
            got[1],
            DropReason::Unreached {
                out_of_range: 3,
                ..
            }
        ),
        "{got:?}"
    );
    assert!(
        matches!(
            got[2],
            DropReason::Unreached {
                outside_cone: 3,
                ..
            }
        ),
        "{got:?}"
    );
    assert_eq!(got[3], DropReason::ZeroEmission);
    // Forced: nothing dropped.
    let forced = plan(
        &s,
        &local(),
        &PlanOptions {
            force_all: true,
            ..opts()
        },
    )
    .unwrap();
    assert!(forced.dropped.is_empty());
    assert_eq!(forced.active.len(), forced.samples.len());
}

#[test]
fn a_faint_light_is_dropped_within_epsilon_only() {
    let mut s = stage();
    s.lights.push(point("faint", [0.0, 8.0, 0.0], 1e-3));
    let p = plan(&s, &local(), &opts()).unwrap();
    let Some((4, DropReason::BelowEpsilon { bound })) = p.dropped.first().copied() else {
        panic!("{:?}", p.dropped)
    };
    assert!(bound > 0.0 && bound <= p.epsilon && p.epsilon_used == bound);
    let strict = plan(
        &s,
        &local(),
        &PlanOptions {
            epsilon: 0.0,
            ..opts()
        },
    )
    .unwrap();
    assert!(strict.active.contains(&4));
}

#[test]
fn nothing_in_view_drops_every_light_but_keeps_a_pipeline() {
    let mut s = stage();
    s.camera.target = [0.0, 2.5, 20.0];
    // Untiled (automatic tiles would split the material layers' eye pass over nodes).
    let untiled = PlanOptions { tiles: 1, ..opts() };
    let p = plan(&s, &local(), &untiled).unwrap();
    assert!(p.active.is_empty());
    assert!(
        p.dropped
            .iter()
            .all(|d| d.1 == DropReason::NoVisibleReceiver)
    );
    assert_eq!(
        p.nodes.len(),
        1,
        "one node with no light, carrying the material layers"
    );
    assert!(p.nodes[0].lights.is_empty());
    assert!(p.compositor_config(&p.stages[0].compositor).is_some());
}

#[test]
fn casters_are_the_meshes_between_a_light_and_what_it_lights() {
    let mut s = stage();
    // Beside the light, above everything it lights: cannot shadow a visible receiver.
    s.add_mesh(cuboid("shelf", [3.5, 3.5, 0.0], [0.3, 0.1, 0.3], 0));
    // Behind the camera, out of view and not between the light and the scene.
    s.add_mesh(cuboid("behind", [0.0, 1.0, 30.0], [1.0, 1.0, 1.0], 0));
    let p = plan(&s, &local(), &opts()).unwrap();
    for sh in &p.nodes[0].shadows {
        assert_eq!(sh.casters, vec![0, 1, 2], "floor, box and ball only");
    }
    let forced = plan(
        &s,
        &local(),
        &PlanOptions {
            force_all: true,
            ..opts()
        },
    )
    .unwrap();
    assert_eq!(forced.nodes[0].shadows[0].casters, vec![0, 1, 2, 3, 4]);
}

#[test]
fn material_layers_follow_the_visible_materials() {
    // Emission on a visible mesh needs the emissive layer; on a hidden one it does not.
    let mut s = stage();
    let mut glow = Material::diffuse("glow", [0.5; 3]);
    glow.emissive = [2.0, 1.0, 0.5];
    let g = s.add_material(glow);
    s.meshes[2].material = g;
    let p = plan(&s, &local(), &opts()).unwrap();
    let layers: Vec<Layer> = p.material.layers.iter().map(|l| l.0).collect();
    assert_eq!(layers, [Layer::Diffuse, Layer::Emissive]);
    let material = &crate::params(&p.stages[0].ops[1]);
    assert_eq!(material["emissive"], true);
    let mut hidden = stage();
    hidden.add_mesh(cuboid(
        "lamp",
        [0.0, 1.0, 30.0],
        [0.5; 3],
        g.min(hidden.materials.len()),
    ));
    let mut glow2 = Material::diffuse("glow", [0.5; 3]);
    glow2.emissive = [1.0; 3];
    let m = hidden.add_material(glow2);
    hidden.meshes.last_mut().unwrap().material = m;
    let q = plan(&hidden, &local(), &opts()).unwrap();
    assert_eq!(q.material.layers.len(), 1);

    // Different specular colours need a specular layer.
    let mut spec = stage();
    spec.materials[1].specular = [0.5; 3];
    let r = plan(&spec, &local(), &opts()).unwrap();
    assert_eq!(r.material.mode, MaterialMode::General);
    assert!(r.material.layers.iter().any(|l| l.0 == Layer::Specular));
    assert_eq!(crate::params(&r.stages[0].ops[1])["specular"], true);
}

#[test]
fn ambient_is_folded_when_every_material_has_ma_equal_md() {
    let mut s = stage();
    s.ambient = [0.1, 0.1, 0.1];
    for m in &mut s.materials {
        m.ambient = m.diffuse;
    }
    let p = plan(&s, &local(), &opts()).unwrap();
    assert!(p.material.fold_ambient);
    assert!(!p.material.layers.iter().any(|l| l.0 == Layer::Ambient));
    assert_eq!(
        p.nodes[0].color, [0.1; 3],
        "the folding node carries c_n = c^a"
    );
    let acc = &crate::params(&p.stages[0].ops[0]);
    assert_eq!(acc["ambient"]["input"], 0);
    assert_eq!(acc["ambient"]["mask"], "uniform");

    // m^a ≠ m^d somewhere: an ambient layer and c^a in the material stage.
    s.materials[0].ambient = [0.3; 3];
    let q = plan(&s, &local(), &opts()).unwrap();
    assert!(!q.material.fold_ambient);
    assert!(q.material.layers.iter().any(|l| l.0 == Layer::Ambient));
    assert_eq!(crate::params(&q.stages[0].ops[1])["ambient_color"][0], 0.1);

    // c^a = 0: nothing.
    s.ambient = [0.0; 3];
    let r = plan(&s, &local(), &opts()).unwrap();
    assert!(!r.material.layers.iter().any(|l| l.0 == Layer::Ambient));
}

/// `stage` under `c^a = 0.1`, grey with `m^a = m^d` and red with `m^a = 0` (eq. 7's mixed scene).
fn mixed_ambient_stage() -> Scene {
    let mut s = stage();
    s.ambient = [0.1, 0.1, 0.1];
    s.materials[0].ambient = s.materials[0].diffuse;
    s.materials[1].ambient = [0.0; 3];
    s
}

/// Bytes per frame over every link of a plan.
fn link_bytes(p: &lightfold_coordinator::plan::Plan) -> u64 {
    p.links.iter().map(|l| l.bytes_per_frame).sum()
}

#[test]
fn mixed_ambient_plans_the_eq7_mask_instead_of_an_ambient_layer() {
    let s = mixed_ambient_stage();
    let p = plan(&s, &local(), &opts()).unwrap();
    let text = p.to_string();
    assert!(p.material.fold_ambient, "{text}");
    assert!(
        !p.material.layers.iter().any(|l| l.0 == Layer::Ambient),
        "no ambient material layer: {text}"
    );
    // The folding node (c_n = c^a) renders the mask, in 8-bit sRGB (exact for 0 and 1).
    let folding: Vec<_> = p
        .nodes
        .iter()
        .filter(|n| n.layers.iter().any(|l| l.0 == Layer::AmbientMask))
        .collect();
    assert_eq!(folding.len(), 1, "{text}");
    assert_eq!(
        folding[0].color, [0.1; 3],
        "the folding node carries c_n = c^a"
    );
    assert!(
        folding[0]
            .layers
            .contains(&(Layer::AmbientMask, PixelFormat::Rgba8Srgb))
    );
    let c = p.node_config(&folding[0].node).unwrap();
    assert!(c.layers.iter().any(|l| l.0 == Layer::AmbientMask));
    // Its stage's accumulate reads I^a from that input; the material stage adds no c^a ⊙ m^a.
    let stage = p
        .stages
        .iter()
        .find(|st| st.compositor == folding[0].downstream)
        .unwrap();
    let acc = stage
        .ops
        .iter()
        .map(crate::params)
        .find(|o| o.get("colors").is_some())
        .unwrap();
    assert_eq!(acc["ambient"]["mask"], "layer", "{text}");
    let input = acc["ambient"]["input"].as_u64().unwrap() as usize;
    assert!(
        stage.inputs[input]
            .layers
            .iter()
            .any(|l| l.0 == Layer::AmbientMask),
        "accumulate's folding input carries the mask"
    );
    let last = p.stages.last().unwrap();
    let material = last
        .ops
        .iter()
        .map(crate::params)
        .find(|o| o.get("stage").is_some())
        .unwrap();
    assert!(material["ambient_color"].is_null(), "{material}");
    assert!(
        p.material.notes.iter().any(|n| n.contains("eq. 7")),
        "{:?}",
        p.material.notes
    );
    assert_stages_build(&p);
    // Across several nodes and stages (chain, tree, a material node of its own), the one folding
    // node sends the mask, wherever the material layers are.
    for (topology, own) in [
        (Topology::Chain, false),
        (Topology::Tree, false),
        (Topology::Chain, true),
    ] {
        let o = PlanOptions {
            lights_per_node: 1,
            topology,
            material_own_node: own,
            ..opts()
        };
        let p = plan(&s, &ClusterSpec::local(16, 4), &o).unwrap();
        assert_eq!(mask_senders(&p), 1, "{p}");
        assert!(!p.material.layers.iter().any(|l| l.0 == Layer::Ambient));
        assert!(p.nodes.len() >= 4, "{p}");
        assert_stages_build(&p);
    }

    // Negative control: a textured m^d under m^a = m^d (the mask is a ratio there, not 0 or 1)
    // keeps the ambient layer, and the material stage adds c^a ⊙ m^a.
    let mut textured = s.clone();
    textured.textures.push(lightfold_scene::Texture {
        name: "checker".into(),
        width: 2,
        height: 2,
        srgb: true,
        rgba8: vec![
            255, 255, 255, 255, 64, 64, 64, 255, 64, 64, 64, 255, 255, 255, 255, 255,
        ],
    });
    textured.materials[0].diffuse_texture = Some(0);
    let q = plan(&textured, &local(), &opts()).unwrap();
    assert!(!q.material.fold_ambient);
    assert!(q.material.layers.iter().any(|l| l.0 == Layer::Ambient));
    assert_eq!(mask_senders(&q), 0);
    // The mask saves bytes on the links: 4 a pixel instead of the ambient layer's 8.
    assert!(
        link_bytes(&p) < link_bytes(&q),
        "{} ≥ {}",
        link_bytes(&p),
        link_bytes(&q)
    );
    // Negative control: m^a neither m^d nor 0 (half of it) keeps the ambient layer.
    let mut half = s.clone();
    half.materials[0].ambient = half.materials[0].diffuse.map(|d| d * 0.5);
    let r = plan(&half, &local(), &opts()).unwrap();
    assert!(!r.material.fold_ambient);
    assert!(r.material.layers.iter().any(|l| l.0 == Layer::Ambient));
}

/// The nodes of `p` that send eq. 7's mask.
fn mask_senders(p: &lightfold_coordinator::plan::Plan) -> usize {
    p.nodes
        .iter()
        .filter(|n| n.layers.iter().any(|l| l.0 == Layer::AmbientMask))
        .count()
}

/// Whether a material note of `p` says `text`.
fn noted(p: &lightfold_coordinator::plan::Plan, text: &str) -> bool {
    p.material.notes.iter().any(|n| n.contains(text))
}

#[test]
fn eq7_falls_back_to_the_ambient_layer_where_no_node_can_carry_ca() {
    // c^a with a zero channel, and no group of that colour: no node can take c_n = c^a.
    let mut s = mixed_ambient_stage();
    s.ambient = [0.1, 0.0, 0.1];
    let p = plan(&s, &local(), &opts()).unwrap();
    assert!(!p.material.fold_ambient);
    assert!(p.material.layers.iter().any(|l| l.0 == Layer::Ambient));
    assert_eq!(mask_senders(&p), 0);
    assert!(
        noted(&p, "no node can carry c_n = c^a"),
        "{:?}",
        p.material.notes
    );
    // An ambient layer 8-bit sRGB holds exactly (m^a white or black) takes 4 B/px, as the mask
    // would: no saving, the ambient layer travels.
    let mut white = mixed_ambient_stage();
    white.materials[0].diffuse = [1.0; 3];
    white.materials[0].ambient = [1.0; 3];
    let w = plan(&white, &local(), &opts()).unwrap();
    assert!(!w.material.fold_ambient);
    assert!(
        w.material
            .layers
            .contains(&(Layer::Ambient, PixelFormat::Rgba8Srgb))
    );
    assert!(
        w.material.notes.iter().any(|n| n.contains("no fewer")),
        "{:?}",
        w.material.notes
    );
    // With partitions each part sums its own groups: the ambient layer travels too.
    let parts = PlanOptions {
        partitions: 2,
        ..opts()
    };
    let q = plan(&mixed_ambient_stage(), &local(), &parts).unwrap();
    assert!(!q.material.fold_ambient);
    assert!(q.material.layers.iter().any(|l| l.0 == Layer::Ambient));
    assert_eq!(mask_senders(&q), 0);
    assert!(
        noted(&q, "each part sums its own groups"),
        "{:?}",
        q.material.notes
    );
}

fn caps(max_lights: u32, light_us: u64, fixed_us: u64) -> Option<Capabilities> {
    Some(Capabilities {
        adapter: "test".into(),
        backend: "vulkan".into(),
        max_lights,
        max_texture_size: 8192,
        cost_per_light_us: light_us,
        fixed_cost_us: fixed_us,
        threads: 2,
        version: "0".into(),
        ..Capabilities::unmeasured(Role::Node, "")
    })
}

fn many_lights() -> Scene {
    let mut s = stage();
    s.lights[0].samples = 32;
    s
}

#[test]
fn short_clusters_raise_k_to_the_device_limit_or_say_how_many_nodes_they_need() {
    let s = many_lights();
    let err = plan(&s, &ClusterSpec::local(3, 3), &opts()).unwrap_err();
    assert_eq!(
        err,
        PlanError::NotEnoughNodes {
            active: 32,
            k: 4,
            limit: 4,
            needed: 8,
            available: 3
        }
    );
    assert!(err.to_string().contains("need 8 render nodes"), "{err}");
    let mut cluster = ClusterSpec::local(3, 3);
    for n in &mut cluster.nodes {
        n.capabilities = caps(16, 0, 0);
    }
    let p = plan(&s, &cluster, &opts()).unwrap();
    assert_eq!(p.k, 11);
    assert_eq!(
        p.nodes.iter().map(|n| n.lights.len()).collect::<Vec<_>>(),
        [11, 11, 10]
    );
}

#[test]
fn the_costliest_group_goes_to_the_fastest_node() {
    let mut s = stage();
    s.lights[0].samples = 6; // groups of 4 and 2 at K = 4
    let mut cluster = ClusterSpec::local(3, 2);
    cluster.nodes[0].capabilities = caps(8, 30_000, 90_000);
    cluster.nodes[1].capabilities = caps(8, 6_000, 20_000);
    cluster.nodes[2].capabilities = caps(8, 12_000, 60_000);
    let own = PlanOptions {
        material_own_node: true,
        ..opts()
    };
    let p = plan(&s, &cluster, &own).unwrap();
    let four = p.nodes.iter().find(|n| n.lights.len() == 4).unwrap();
    let two = p.nodes.iter().find(|n| n.lights.len() == 2).unwrap();
    assert_eq!(four.node, "node-1");
    assert_eq!(two.node, "node-2");
    assert_eq!(
        p.material.placement,
        lightfold_coordinator::plan::MaterialPlacement::OwnNode {
            node: "node-0".into()
        }
    );
    assert_eq!(
        p.est_frame_us,
        p.nodes.iter().map(|n| n.est_cost_us).max().unwrap()
    );
}

#[test]
fn a_tree_joins_pairs_and_a_chain_links_stages() {
    let s = many_lights();
    let tree = plan(
        &s,
        &ClusterSpec::local(9, 7),
        &PlanOptions {
            topology: Topology::Tree,
            ..opts()
        },
    )
    .unwrap();
    assert_eq!(tree.stages.len(), 7);
    let joins = tree
        .stages
        .iter()
        .filter(|st| st.ops[0].name() == "join")
        .count();
    assert_eq!(joins, 3);
    let root = tree
        .stages
        .iter()
        .find(|st| st.downstream == Downstream::Sink)
        .unwrap();
    let ops: Vec<&str> = root.ops.iter().map(|o| o.name()).collect();
    // The root joins the two halves, adds the one node it reads itself, and shades with that
    // node's material layers.
    assert_eq!(ops, ["join", "accumulate", "material", "output"]);
    assert_eq!(
        root.wiring,
        vec![
            vec![OpSource::Input(0), OpSource::Input(1)],
            vec![OpSource::Op(0), OpSource::Input(2)],
            vec![OpSource::Op(1), OpSource::Input(2)],
            vec![OpSource::Op(2)],
        ]
    );
    let host = tree.nodes.last().unwrap();
    assert_eq!(
        tree.material.placement,
        MaterialPlacement::ExtraTargets {
            node: host.node.clone()
        }
    );
    assert_eq!(
        (host.downstream.as_str(), host.input_index),
        (root.compositor.as_str(), 2)
    );
    assert_eq!(tree.nodes.len(), 8);
    let chain = plan(&s, &ClusterSpec::local(9, 3), &opts()).unwrap();
    assert_eq!(chain.stages.len(), 3);
    assert_eq!(
        chain.stages[0].downstream,
        Downstream::Stage("comp-1".into())
    );
    assert_eq!(crate::params(&chain.stages[1].ops[0])["upstream"], true);
    assert_eq!(
        crate::params(&chain.stages[0].ops[0])["colors"]
            .as_array()
            .unwrap()
            .len(),
        3
    );
    // Bytes: 8 node links at rgb9e5x2 (one also carrying the material layers), 2 chain links at
    // f16x6, 1 sink link.
    assert_eq!(chain.links.len(), 8 + 2 + 1);
}

#[test]
fn map_sizes_are_powers_of_two_in_range_and_uniform_per_node() {
    let s = many_lights();
    let p = plan(&s, &local(), &opts()).unwrap();
    for n in &p.nodes {
        let sizes: Vec<u32> = n.shadows.iter().map(|s| s.map_size).collect();
        assert!(sizes.windows(2).all(|w| w[0] == w[1]));
        for size in sizes {
            assert!(
                size.is_power_of_two() && (256..=4096).contains(&size),
                "{size}"
            );
        }
    }
    let fixed = plan(
        &s,
        &local(),
        &PlanOptions {
            map_sizing: MapSizing::Fixed(1024),
            ..opts()
        },
    )
    .unwrap();
    assert!(
        fixed
            .nodes
            .iter()
            .flat_map(|n| &n.shadows)
            .all(|s| s.map_size == 1024)
    );
    // A larger image asks for finer maps.
    let mut big = s.clone();
    big.camera.width *= 8;
    big.camera.height *= 8;
    let q = plan(&big, &local(), &opts()).unwrap();
    assert!(q.nodes[0].shadows[0].map_size >= p.nodes[0].shadows[0].map_size);
}

#[test]
fn configurations_carry_the_plan() {
    let p = plan(&stage(), &local(), &opts()).unwrap();
    let n = p.node_config("node-0").unwrap();
    assert_eq!(n.lights.len(), 4);
    assert_eq!(n.lights[2].sample, 2);
    assert_eq!(n.shadows.len(), 4);
    assert_eq!(n.downstream, "127.0.0.1:7500");
    assert_eq!(n.scene, p.scene_hash);
    let c = p.compositor_config("comp-0").unwrap();
    assert_eq!(c.inputs.len(), 1);
    assert_eq!(c.wiring, p.stages[0].wiring);
    assert_eq!(c.downstream, "127.0.0.1:7400");
    for op in &c.ops {
        op.validate().unwrap_or_else(|e| panic!("{e}"));
    }
}

#[test]
fn bad_inputs_give_clear_errors() {
    let s = stage();
    assert_eq!(
        plan(&s, &ClusterSpec::local(0, 1), &opts()),
        Err(PlanError::NoNodes)
    );
    assert_eq!(
        plan(&s, &ClusterSpec::local(2, 0), &opts()),
        Err(PlanError::NoCompositors)
    );
    let mut dup = ClusterSpec::local(2, 1);
    dup.compositors[0].id = "node-1".into();
    assert_eq!(
        plan(&s, &dup, &opts()),
        Err(PlanError::DuplicateDaemon {
            id: "node-1".into()
        })
    );
    let k0 = PlanOptions {
        lights_per_node: 0,
        ..opts()
    };
    assert!(matches!(
        plan(&s, &local(), &k0),
        Err(PlanError::InvalidOptions { .. })
    ));
    let mut bad = stage();
    bad.exposure = f32::NAN;
    assert!(matches!(
        plan(&bad, &local(), &opts()),
        Err(PlanError::InvalidScene { .. })
    ));
    let mut bad = stage();
    bad.meshes[0].material = 99;
    let e = plan(&bad, &local(), &opts()).unwrap_err();
    assert!(e.to_string().contains("names material 99"), "{e}");
}

#[test]
fn a_frame_budget_picks_the_largest_k_that_fits_it() {
    let s = many_lights();
    let big = ClusterSpec::local(64, 64);
    let at_k = |k: u32| {
        plan(
            &s,
            &big,
            &PlanOptions {
                lights_per_node: k,
                ..opts()
            },
        )
        .unwrap()
    };
    // Without the penumbra filter: it would add the eye depth to the material host, one more
    // target than the budgets below were taken from (`plan_budget.rs` tests the filter).
    let with = |budget_us: u64, cluster: &ClusterSpec| {
        plan(
            &s,
            cluster,
            &PlanOptions {
                frame_budget_us: Some(budget_us),
                penumbra_filter: lightfold_coordinator::plan::PenumbraFilter::Off,
                ..opts()
            },
        )
        .unwrap()
    };
    // Budgets exactly at the estimates of K = 2 and K = 8 (the estimate grows with K here).
    let (two, eight) = (at_k(2).est_frame_us, at_k(8).est_frame_us);
    assert!(at_k(3).est_frame_us > two && at_k(9).est_frame_us > eight);
    let (tight, loose) = (with(two, &big), with(eight, &big));
    assert_eq!((tight.k, loose.k), (2, 8));
    assert_eq!((tight.est_frame_us, loose.est_frame_us), (two, eight));
    assert!(loose.nodes.len() < tight.nodes.len());
    assert!(tight.to_string().contains("within the"), "{tight}");
    // No K fits 1 ms: the fastest estimate (K = 1), said plainly.
    let impossible = with(1000, &big);
    assert_eq!(impossible.k, 1);
    assert!(impossible.to_string().contains("over the 1.0 ms budget"));
    // A short cluster: K = 2 needs 16 nodes; rather than raise K to 11 (over the budget) the
    // planner halves the samples until K = 2 fits its 3 nodes (`plan_budget.rs`).
    let short = with(two, &ClusterSpec::local(3, 3));
    assert!(short.nodes.len() <= 3 && short.k == 2, "K = {}", short.k);
    assert!(
        short.est_frame_us <= two && short.samples.len() <= 6,
        "{short}"
    );
}

#[test]
fn transmittance_maps_only_where_a_caster_lets_light_through() {
    // An opaque scene plans none.
    let p = plan(&stage(), &local(), &opts()).unwrap();
    assert!(
        p.nodes
            .iter()
            .flat_map(|n| &n.shadows)
            .all(|s| !s.transmittance)
    );
    // A red pane under the light: a sample gets transmittance maps exactly when its casters
    // include the pane.
    let mut s = stage();
    let glass = s.add_material(Material {
        transmission: Some(lightfold_scene::Transmission {
            color: [0.9, 0.1, 0.1],
            coverage: false,
        }),
        ..Material::diffuse("glass", [0.1; 3])
    });
    let pane = s.add_mesh(cuboid("pane", [0.0, 1.6, 0.0], [0.4, 0.01, 0.4], glass)) as u32;
    let p = plan(&s, &local(), &opts()).unwrap();
    let shadows: Vec<_> = p.nodes.iter().flat_map(|n| &n.shadows).collect();
    assert!(!shadows.is_empty());
    for sh in &shadows {
        assert_eq!(sh.transmittance, sh.casters.contains(&pane), "{sh:?}");
    }
    assert!(shadows.iter().any(|sh| sh.transmittance));
    assert!(p.to_string().contains("transmittance maps"));
    // The cost model knows they cost more: the same pane cast opaque estimates less.
    let mut opaque = s.clone();
    opaque.materials[glass].transmission = None;
    let q = plan(&opaque, &local(), &opts()).unwrap();
    let cost = |p: &lightfold_coordinator::plan::Plan| -> u64 {
        p.nodes.iter().map(|n| n.est_cost_us).sum()
    };
    assert!(cost(&p) > cost(&q), "{} vs {}", cost(&p), cost(&q));
}

/// Every stage of `p` as the compositor builds it from its configuration: the wiring validates
/// against the operators' signatures, and the stage emits the layers it says it sends.
pub(crate) fn assert_stages_build(p: &lightfold_coordinator::plan::Plan) {
    for s in &p.stages {
        let c = p.compositor_config(&s.compositor).unwrap();
        let inputs: Vec<Vec<Layer>> = c
            .inputs
            .iter()
            .map(|i| i.layers.iter().map(|l| l.0).collect())
            .collect();
        let pipeline =
            lightfold_compositor::pipeline::Pipeline::from_wiring(&c.ops, &c.wiring, &inputs)
                .unwrap_or_else(|e| panic!("stage {}: {e}", s.compositor));
        let out = pipeline.output_layers();
        for (l, _) in &c.outputs {
            assert!(
                out.contains(l),
                "stage {} sends {l:?} it does not make",
                s.compositor
            );
        }
    }
}

#[test]
fn partitions_plan_a_grid_of_parts_by_light_groups() {
    // The stage scene at K = 2: two groups of its four samples, three meshes in two parts.
    let scene = stage();
    let o = PlanOptions {
        lights_per_node: 2,
        partitions: 2,
        ..opts()
    };
    let p = plan(&scene, &local(), &o).unwrap();
    assert_eq!(p.partitions.len(), 2);
    let mut meshes: Vec<u32> = p.partitions.concat();
    meshes.sort_unstable();
    assert_eq!(meshes, vec![0, 1, 2], "every mesh in exactly one part");
    // 2 parts × 2 groups: each (part, group) on its own node, every light twice (once a part).
    assert_eq!(p.nodes.len(), 4);
    for part in 0..2 {
        let mut lights: Vec<usize> = p
            .nodes
            .iter()
            .filter(|n| n.part == Some(part))
            .flat_map(|n| n.lights.clone())
            .collect();
        lights.sort_unstable();
        assert_eq!(lights, vec![0, 1, 2, 3], "part {part}");
        // Exactly one node of the part carries its eye depth and material layers.
        let hosts: Vec<_> = p
            .nodes
            .iter()
            .filter(|n| n.part == Some(part) && n.layers.iter().any(|l| l.0 == Layer::Depth))
            .collect();
        assert_eq!(hosts.len(), 1, "part {part}");
        assert!(hosts[0].layers.iter().any(|l| l.0 == Layer::Diffuse));
    }
    // Each node is configured to draw its part, with the casters its lights need there: maps
    // fitted to the part's receivers see no more casters than the whole scene's maps.
    let whole = plan(
        &scene,
        &local(),
        &PlanOptions {
            lights_per_node: 2,
            ..opts()
        },
    )
    .unwrap();
    let whole_casters = |light: usize| {
        let n = whole
            .nodes
            .iter()
            .find(|n| n.lights.contains(&light))
            .unwrap();
        let j = n.lights.iter().position(|&l| l == light).unwrap();
        n.shadows[j].casters.clone()
    };
    for n in &p.nodes {
        let c = p.node_config(&n.node).unwrap();
        assert_eq!(c.eye_meshes.as_ref(), Some(&p.partitions[n.part.unwrap()]));
        for (&l, s) in n.lights.iter().zip(&n.shadows) {
            let all = whole_casters(l);
            assert!(
                s.casters.iter().all(|m| all.contains(m)),
                "{:?} ⊄ {all:?}",
                s.casters
            );
        }
    }
    // Ambient is not folded into one node's colour: each part sums its own groups.
    assert!(!p.material.fold_ambient);
    assert!(
        matches!(p.material.placement, MaterialPlacement::PerPart { ref nodes } if nodes.len() == 2)
    );
    // Two stages along a chain: part 0's sum, then part 1's, depth-composed with it and shaded.
    assert_eq!(p.stages.len(), 2);
    let names = |s: &lightfold_coordinator::plan::StagePlan| -> Vec<String> {
        s.ops.iter().map(|o| o.name().to_string()).collect()
    };
    assert_eq!(names(&p.stages[0]), ["accumulate", "merge"]);
    assert_eq!(
        names(&p.stages[1]),
        ["accumulate", "merge", "depth", "material", "output"]
    );
    assert_eq!(crate::params(&p.stages[1].ops[2])["zero_is_empty"], true);
    assert_eq!(p.stages[0].downstream, Downstream::Stage("comp-1".into()));
    assert_stages_build(&p);
    let text = p.to_string();
    assert!(
        text.contains("partitions: 2 parts × 2 light group(s) = 4 nodes"),
        "{text}"
    );
    // A tree: leaves take runs of parts, `depth` joins pairs above (parts in order, so ties
    // still go to the lower part), the root shades.
    let tree = PlanOptions {
        topology: Topology::Tree,
        partitions: 3,
        ..o.clone()
    };
    let t = plan(&scene, &ClusterSpec::local(16, 5), &tree).unwrap();
    assert_eq!(t.stages.len(), 5, "3 leaves and 2 joins");
    let root = t.stages.last().unwrap();
    assert_eq!(names(root), ["depth", "material", "output"]);
    assert_eq!(
        root.inputs
            .iter()
            .map(|i| match &i.source {
                lightfold_coordinator::plan::Source::Stage(s) => s.clone(),
                other => panic!("{other:?}"),
            })
            .collect::<Vec<_>>(),
        ["comp-3", "comp-2"]
    );
    assert_stages_build(&t);
    // With one compositor, both parts compose in one stage.
    let one = plan(&scene, &ClusterSpec::local(16, 1), &o).unwrap();
    assert_eq!(one.stages.len(), 1);
    assert_eq!(
        names(&one.stages[0]),
        [
            "accumulate",
            "merge",
            "accumulate",
            "merge",
            "depth",
            "material",
            "output"
        ]
    );
    assert_stages_build(&one);
    // Short of nodes (these report no device limit, so K stays), parts × groups are counted.
    assert!(matches!(
        plan(&scene, &ClusterSpec::local(3, 2), &o),
        Err(PlanError::NotEnoughNodes {
            needed: 4,
            available: 3,
            ..
        })
    ));
}

#[test]
fn partitions_are_refused_where_they_cannot_be_planned() {
    let scene = stage();
    let refused = |change: &dyn Fn(&mut PlanOptions)| {
        let mut o = PlanOptions {
            partitions: 2,
            ..opts()
        };
        change(&mut o);
        match plan(&scene, &local(), &o) {
            Err(PlanError::InvalidOptions { reason }) => reason,
            other => panic!("expected a refusal, got {other:?}"),
        }
    };
    assert!(refused(&|o| o.partitions = 4).contains("at most 3 partitions"));
    assert!(refused(&|o| o.partitions = 65).contains("0 (automatic) or 1 to 64"));
    assert!(refused(&|o| o.material_own_node = true).contains("material"));
    // The penumbra filter runs at the last stage on the composed stream, which carries the
    // nearest surface's depth: between `depth` and `material`.
    let p = plan(
        &scene,
        &local(),
        &PlanOptions {
            partitions: 2,
            penumbra_filter: lightfold_coordinator::plan::PenumbraFilter::Radius(2),
            ..opts()
        },
    )
    .unwrap();
    assert_eq!(p.penumbra_radius, 2);
    let root = p.stages.last().unwrap();
    let names: Vec<&str> = root.ops.iter().map(|o| o.name()).collect();
    assert_eq!(
        &names[names.len() - 4..],
        ["depth", "penumbra", "material", "output"]
    );
    assert_stages_build(&p);
}

#[test]
fn automatic_partitions_follow_the_nodes_memory() {
    use lightfold_coordinator::plan::{
        NODE_BYTES_PER_TRIANGLE, SCENE_MEMORY_SHARE, partitions_for,
    };
    let scene = stage();
    let need = scene.triangle_count() as u64 * NODE_BYTES_PER_TRIANGLE;
    let with_memory = |nodes: usize, memory: u64| {
        let mut c = ClusterSpec::local(nodes, 4);
        for n in &mut c.nodes {
            let mut cap = caps(16, 0, 0).unwrap();
            cap.memory_bytes = memory;
            n.capabilities = Some(cap);
        }
        c
    };
    let auto = opts();
    assert_eq!(auto.partitions, 0, "automatic is the default");
    // Unknown memory, or enough of it: the whole scene.
    assert_eq!(partitions_for(&scene, &local(), &auto), 1);
    assert_eq!(partitions_for(&scene, &with_memory(8, 0), &auto), 1);
    let fits = (need as f64 / SCENE_MEMORY_SHARE).ceil() as u64;
    // A third of that, rounded up: three parts fit it.
    let third = fits / 3 + 2;
    assert_eq!(partitions_for(&scene, &with_memory(8, fits), &auto), 1);
    // Three times too little: three parts; the smallest node decides.
    assert_eq!(partitions_for(&scene, &with_memory(8, third), &auto), 3);
    let mut mixed = with_memory(8, 10 * fits);
    mixed.nodes[5].capabilities.as_mut().unwrap().memory_bytes = third;
    assert_eq!(partitions_for(&scene, &mixed, &auto), 3);
    // At most one part per node, and none where partitions cannot be planned.
    assert_eq!(partitions_for(&scene, &with_memory(2, third), &auto), 2);
    let own_material_node = PlanOptions {
        material_own_node: true,
        ..opts()
    };
    assert_eq!(
        partitions_for(&scene, &with_memory(8, third), &own_material_node),
        1
    );
    // Under a frame budget, a scene whose eye pass would not fit half the budget on the
    // fastest node is split too: here 3 ms of eye pass against a 2 ms budget, so 3 parts.
    let with_eye_cost = |ns: u64| {
        let mut c = with_memory(8, 10 * fits);
        for n in &mut c.nodes {
            n.capabilities.as_mut().unwrap().eye_ns_per_triangle = ns;
        }
        c
    };
    let ns = 3_000_000 / scene.triangle_count() as u64;
    let budget = PlanOptions {
        frame_budget_us: Some(2_000),
        ..opts()
    };
    assert_eq!(partitions_for(&scene, &with_eye_cost(ns), &budget), 3);
    // Without a budget, or without a measured eye cost, the eye pass decides nothing.
    assert_eq!(partitions_for(&scene, &with_eye_cost(ns), &auto), 1);
    assert_eq!(partitions_for(&scene, &with_eye_cost(0), &budget), 1);
    // Nor where a node's fixed cost alone is over the budget: no split would meet it (2.5 ms
    // at the scene's size, reported at the calibration size).
    let (cw, ch) = lightfold_protocol::CALIBRATION_SIZE;
    let pixels = u64::from(scene.camera.width) * u64::from(scene.camera.height);
    let mut slow = with_eye_cost(ns);
    for n in &mut slow.nodes {
        n.capabilities.as_mut().unwrap().fixed_cost_us = 2_500 * u64::from(cw * ch) / pixels.max(1);
    }
    assert_eq!(partitions_for(&scene, &slow, &budget), 1);
    // Asked for: as asked.
    let two = PlanOptions {
        partitions: 2,
        ..opts()
    };
    assert_eq!(partitions_for(&scene, &local(), &two), 2);
    // The plan follows: three parts on nodes three times short.
    let p = plan(&scene, &with_memory(8, third), &auto).unwrap();
    assert_eq!(p.partitions.len(), 3);
    let whole = plan(&scene, &with_memory(8, fits), &auto).unwrap();
    assert!(whole.partitions.is_empty() && whole.nodes.iter().all(|n| n.part.is_none()));
}

#[test]
fn automatic_topology_is_a_tree_from_eight_chain_stages() {
    use lightfold_coordinator::plan::AUTO_TREE_STAGES;
    let s = many_lights(); // 32 samples
    let auto = |k: u32, compositors: usize| {
        let o = PlanOptions {
            lights_per_node: k,
            topology: Topology::Auto,
            ..opts()
        };
        plan(&s, &ClusterSpec::local(16, compositors), &o).unwrap()
    };
    // 8 nodes on 16 compositors: a chain would have 8 stages, so a tree (plans say which).
    let p = auto(4, 16);
    assert_eq!((p.nodes.len(), p.topology), (8, Topology::Tree));
    assert!(p.to_string().contains(" · tree · "), "{p}");
    // 4 nodes: a chain; 8 nodes on 4 compositors: a chain of 4.
    assert_eq!(auto(8, 16).topology, Topology::Chain);
    assert_eq!(auto(4, 4).topology, Topology::Chain);
    assert_eq!(AUTO_TREE_STAGES, 8);
    assert_eq!("auto".parse::<Topology>(), Ok(Topology::Auto));
}

/// A cluster of `nodes` render nodes measured alike, node `i` on device `device(i)` ("" for a
/// software rasteriser or a node that reports none).
fn on_devices(nodes: usize, max_lights: u32, device: impl Fn(usize) -> String) -> ClusterSpec {
    let mut c = ClusterSpec::local(nodes, 16);
    for (i, n) in c.nodes.iter_mut().enumerate() {
        let mut caps = caps(max_lights, 2_000, 6_000).unwrap();
        caps.device = device(i);
        n.capabilities = Some(caps);
    }
    c
}

/// Every active sample rendered exactly once.
fn each_once(p: &lightfold_coordinator::plan::Plan) {
    let mut lights: Vec<usize> = p.nodes.iter().flat_map(|n| n.lights.clone()).collect();
    lights.sort_unstable();
    let mut active = p.active.clone();
    active.sort_unstable();
    assert_eq!(lights, active);
}

#[test]
fn nodes_sharing_a_gpu_are_planned_as_one_node_per_gpu() {
    let s = many_lights();
    let o = PlanOptions {
        lights_per_node: 4,
        ..opts()
    };
    // Every node on its own device (or reporting none): K = 4, eight nodes, as ever.
    let apart = plan(&s, &on_devices(8, 85, |i| format!("h/{i}/gpu")), &o).unwrap();
    let unknown = plan(&s, &on_devices(8, 85, |_| String::new()), &o).unwrap();
    for p in [&apart, &unknown] {
        assert_eq!((p.k, p.nodes.len()), (4, 8));
        assert!(p.shared_devices.is_none());
        each_once(p);
    }
    assert_eq!(apart.nodes, unknown.nodes);

    // All eight on one GPU: one node renders the 32 lights, the other seven idle.
    let one = plan(&s, &on_devices(8, 85, |_| "h/0000:01:00.0/gpu".into()), &o).unwrap();
    assert_eq!((one.k, one.nodes.len(), one.idle_nodes.len()), (32, 1, 7));
    let shared = one.shared_devices.expect("says it merged");
    assert_eq!((shared.devices, shared.nodes, shared.k_separate), (1, 8, 4));
    assert!(one.est_frame_us < shared.est_separate_us, "{shared:?}");
    assert!(
        one.brief().to_string().contains("shared GPUs"),
        "{}",
        one.brief()
    );
    each_once(&one);

    // Two GPUs of four nodes: one node on each.
    let two = plan(&s, &on_devices(8, 85, |i| format!("h/{}/gpu", i % 2)), &o).unwrap();
    assert_eq!((two.k, two.nodes.len()), (16, 2));
    let used: Vec<&str> = two.nodes.iter().map(|n| n.node.as_str()).collect();
    assert_eq!(used.len(), 2);
    assert_ne!(used[0], used[1]);
    each_once(&two);

    // A device too small for all its nodes' lights keeps them apart: one node of at most 8
    // lights cannot render 32.
    let small = plan(&s, &on_devices(8, 8, |_| "h/0/gpu".into()), &o).unwrap();
    assert_eq!(small.nodes.len(), 8);
    assert!(small.shared_devices.is_none());

    // Asked not to merge, the planner does not.
    let kept = PlanOptions {
        merge_shared_devices: false,
        ..o.clone()
    };
    let p = plan(&s, &on_devices(8, 85, |_| "h/0/gpu".into()), &kept).unwrap();
    assert_eq!((p.k, p.nodes.len()), (4, 8));
}

#[test]
fn nodes_on_one_machines_cpu_are_estimated_one_after_another() {
    let s = many_lights();
    let o = PlanOptions {
        lights_per_node: 4,
        ..opts()
    };
    let on_cpus = |host: &dyn Fn(usize) -> String| {
        let mut c = on_devices(8, 85, |_| String::new());
        for (i, n) in c.nodes.iter_mut().enumerate() {
            if let Some(caps) = n.capabilities.as_mut() {
                caps.cpu_host = host(i);
            }
        }
        c
    };
    // Eight machines (or nodes that say nothing): the slowest node is the frame.
    let apart = plan(&s, &on_cpus(&|i| format!("boot:{i}")), &o).unwrap();
    let unknown = plan(&s, &on_cpus(&|_| String::new()), &o).unwrap();
    let slowest = |p: &lightfold_coordinator::plan::Plan| {
        p.nodes.iter().map(|n| n.est_cost_us).max().unwrap()
    };
    for p in [&apart, &unknown] {
        assert_eq!((p.k, p.nodes.len()), (4, 8));
        assert_eq!(p.est_frame_us, slowest(p));
        assert!(p.cpu_shared.is_none());
    }
    // One machine's CPU: the same nodes, their frames added up, and the plan says so.
    let one = plan(&s, &on_cpus(&|_| "boot:a".into()), &o).unwrap();
    assert_eq!(one.nodes, apart.nodes);
    let sum: u64 = one.nodes.iter().map(|n| n.est_cost_us).sum();
    assert!(
        one.est_frame_us.abs_diff(sum) <= 8,
        "{} {sum}",
        one.est_frame_us
    );
    let shared = one.cpu_shared.expect("says the CPU is shared");
    assert_eq!((shared.machines, shared.nodes), (1, 8));
    assert_eq!(shared.est_slowest_node_us, slowest(&one));
    assert!(
        one.brief().to_string().contains("shared CPU"),
        "{}",
        one.brief()
    );
    // Two machines of four: each machine's four add up.
    let two = plan(&s, &on_cpus(&|i| format!("boot:{}", i % 2)), &o).unwrap();
    assert_eq!(two.cpu_shared.map(|c| (c.machines, c.nodes)), Some((2, 8)));
    assert!(two.est_frame_us < one.est_frame_us && two.est_frame_us > slowest(&two));

    // A frame budget on one machine's CPU: spreading lights over more nodes only adds their
    // fixed costs, so the budget takes the fewest nodes; on separate machines, more nodes.
    let budget = |us: u64| PlanOptions {
        frame_budget_us: Some(us),
        ..o.clone()
    };
    let b_one = plan(&s, &on_cpus(&|_| "boot:a".into()), &budget(20_000)).unwrap();
    let b_apart = plan(&s, &on_cpus(&|i| format!("boot:{i}")), &budget(20_000)).unwrap();
    assert!(
        b_one.nodes.len() < b_apart.nodes.len(),
        "{} {}",
        b_one.nodes.len(),
        b_apart.nodes.len()
    );
    each_once(&b_one);
    each_once(&b_apart);
}
