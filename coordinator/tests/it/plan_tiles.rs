//! Sort-first tiles (`PlanOptions::tiles`): the grid of tiles × light groups, the rows each node
//! is configured with, and the options tiles refuse.

use crate::plan_rules::assert_stages_build;
use crate::plan_scenes::stage;
use lightfold_coordinator::plan::{
    ClusterSpec, MaterialPlacement, Plan, PlanError, PlanOptions, TILES_MIN_GAIN, Topology, plan,
};
use lightfold_protocol::{Capabilities, Layer, Role};

/// K = 2 and bands of 8 rows (the stage scene is 64×48).
fn tiled(tiles: u32) -> PlanOptions {
    PlanOptions {
        lights_per_node: 2,
        tiles,
        band_height: 8,
        ..PlanOptions::default()
    }
}

#[test]
fn tiles_plan_a_grid_of_row_bands_by_light_groups() {
    // The stage scene at K = 2: two groups of its four samples, in each of three tiles.
    let scene = stage();
    let (h, band) = (scene.camera.height, tiled(3).band_height);
    let p = plan(&scene, &ClusterSpec::local(16, 16), &tiled(3)).unwrap();
    assert!(p.partitions.is_empty(), "tiles are not sort-last parts");
    assert_eq!(p.tiles.len(), 3);
    assert_eq!(p.tiles[0][0], 0);
    assert_eq!(p.tiles[2][1], h);
    for w in p.tiles.windows(2) {
        assert_eq!(w[0][1], w[1][0], "tiles meet: {:?}", p.tiles);
        assert_eq!(w[0][1] % band, 0, "on a band edge: {:?}", p.tiles);
    }
    assert_eq!(p.nodes.len(), 6, "3 tiles × 2 light groups");
    for t in 0..3 {
        let of_tile: Vec<_> = p.nodes.iter().filter(|n| n.tile == Some(t)).collect();
        let mut lights: Vec<usize> = of_tile.iter().flat_map(|n| n.lights.clone()).collect();
        lights.sort_unstable();
        assert_eq!(lights, vec![0, 1, 2, 3], "tile {t} renders every light");
        let hosts = of_tile
            .iter()
            .filter(|n| n.layers.iter().any(|l| l.0 == Layer::Depth))
            .count();
        assert_eq!(
            hosts, 1,
            "one node of tile {t} carries its depth and materials"
        );
        for n in of_tile {
            let c = p.node_config(&n.node).unwrap();
            assert_eq!(c.rows, Some(p.tiles[t]), "{}", n.node);
            assert_eq!(c.eye_meshes, None, "a tile's node draws every mesh");
        }
    }
    // The whole scene's maps: the same casters as without tiles.
    let whole = plan(&scene, &ClusterSpec::local(16, 16), &tiled(1)).unwrap();
    assert!(whole.tiles.is_empty());
    for n in &p.nodes {
        let w = whole.nodes.iter().find(|w| w.lights == n.lights).unwrap();
        assert_eq!(n.shadows, w.shadows, "{}", n.node);
        let c = p.node_config(&n.node).unwrap();
        assert!(c.rows.is_some());
    }
    for n in &whole.nodes {
        assert_eq!(whole.node_config(&n.node).unwrap().rows, None);
    }
    assert!(!p.material.fold_ambient);
    assert!(
        matches!(p.material.placement, MaterialPlacement::PerPart { ref nodes } if nodes.len() == 3)
    );
    assert_eq!(
        crate::params(&p.stages.last().unwrap().ops[2])["zero_is_empty"],
        true,
        "tiles are put together by the depth operator, empty rows losing"
    );
    assert_stages_build(&p);
    let text = p.to_string();
    assert!(
        text.contains("tiles: 3 sort-first tiles × 2 light group(s) = 6 nodes"),
        "{text}"
    );
    assert!(
        text.contains(&format!("tile 0 (rows 0–{})", p.tiles[0][1])),
        "{text}"
    );
    let tree = plan(
        &scene,
        &ClusterSpec::local(16, 16),
        &PlanOptions {
            topology: Topology::Tree,
            ..tiled(3)
        },
    )
    .unwrap();
    assert_stages_build(&tree);
}

/// Both: T tiles × P sort-last parts × G groups. Each node draws its part's meshes into its
/// tile's rows with its part's maps (those of the untiled partitioned plan); every cell renders
/// every light and one node of each carries the cell's depth and materials.
#[test]
fn tiles_and_partitions_plan_a_grid_of_both() {
    let scene = stage();
    let grid = PlanOptions {
        partitions: 2,
        ..tiled(2)
    };
    let cluster = ClusterSpec::local(16, 16);
    let p = plan(&scene, &cluster, &grid).unwrap();
    let parts = plan(
        &scene,
        &cluster,
        &PlanOptions {
            tiles: 1,
            ..grid.clone()
        },
    )
    .unwrap();
    assert_eq!((p.tiles.len(), p.partitions.len()), (2, 2));
    assert_eq!(p.partitions, parts.partitions, "the same sort-last parts");
    assert_eq!(p.nodes.len(), 8, "2 tiles × 2 parts × 2 groups");
    for part in 0..2 {
        for tile in 0..2 {
            let cell: Vec<_> = p
                .nodes
                .iter()
                .filter(|n| n.part == Some(part) && n.tile == Some(tile))
                .collect();
            let mut lights: Vec<usize> = cell.iter().flat_map(|n| n.lights.clone()).collect();
            lights.sort_unstable();
            assert_eq!(lights, vec![0, 1, 2, 3], "part {part} tile {tile}");
            let hosts = cell
                .iter()
                .filter(|n| n.layers.iter().any(|l| l.0 == Layer::Depth))
                .count();
            assert_eq!(hosts, 1, "part {part} tile {tile}: one depth host");
            for n in cell {
                let c = p.node_config(&n.node).unwrap();
                assert_eq!(c.rows, Some(p.tiles[tile]), "{}", n.node);
                assert_eq!(c.eye_meshes, Some(p.partitions[part].clone()), "{}", n.node);
                let untiled = parts
                    .nodes
                    .iter()
                    .find(|m| m.part == Some(part) && m.lights == n.lights)
                    .unwrap();
                assert_eq!(n.shadows, untiled.shadows, "{}: the part's maps", n.node);
            }
        }
    }
    assert_stages_build(&p);
    let text = p.to_string();
    assert!(
        text.contains("tiles: 2 sort-first tiles × 2 sort-last parts × 2 light group(s) = 8 nodes"),
        "{text}"
    );
    assert!(text.contains("part 1 · tile 0 (rows "), "{text}");
}

#[test]
fn short_clusters_take_fewer_tiles() {
    let scene = stage();
    // 4 nodes (reporting no device limit, so K stays at 2: two groups), 4 tiles asked: two
    // tiles × two groups. A lost node leaves a plan, not an error.
    let p = plan(&scene, &ClusterSpec::local(4, 4), &tiled(4)).unwrap();
    assert_eq!((p.tiles.len(), p.nodes.len(), p.k), (2, 4, 2));
    let p = plan(&scene, &ClusterSpec::local(3, 3), &tiled(4)).unwrap();
    assert_eq!((p.tiles.len(), p.nodes.len()), (0, 2), "one tile: none");
    // One node: no tiles at all, and K rises as without tiles.
    let p = plan(&scene, &ClusterSpec::local(1, 1), &tiled(4));
    assert!(
        matches!(p, Err(PlanError::NotEnoughNodes { .. })),
        "as without tiles: {p:?}"
    );
    let p = plan(&scene, &ClusterSpec::local(2, 2), &tiled(2)).unwrap();
    assert!(p.tiles.is_empty(), "two nodes hold the two groups untiled");
    assert_eq!(p.node_config(&p.nodes[0].node).unwrap().rows, None);
}

#[test]
fn tiles_are_refused_where_they_cannot_be_planned() {
    let scene = stage();
    let refused = |change: &dyn Fn(&mut PlanOptions)| {
        let mut o = tiled(2);
        change(&mut o);
        match plan(&scene, &ClusterSpec::local(16, 16), &o) {
            Err(PlanError::InvalidOptions { reason }) => reason,
            other => panic!("expected a refusal, got {other:?}"),
        }
    };
    assert!(refused(&|o| o.tiles = 65).contains("2 to 64"));
    assert!(refused(&|o| o.material_own_node = true).contains("material"));
    let h = scene.camera.height;
    assert!(
        refused(&|o| o.band_height = h).contains("at least as many bands"),
        "one band of rows cannot make two tiles"
    );
}

/// `nodes` render nodes, each on its own GPU, measured at `light_us` a light and `fixed_us` a
/// frame (eye pass and readback) at the calibration size; `device`/`cpu_host` name what node i
/// shares.
fn measured(
    nodes: usize,
    light_us: u64,
    fixed_us: u64,
    share: impl Fn(usize, &mut Capabilities),
) -> ClusterSpec {
    let mut c = ClusterSpec::local(nodes, nodes);
    for (i, n) in c.nodes.iter_mut().enumerate() {
        let mut caps = Capabilities {
            adapter: "test".into(),
            backend: "vulkan".into(),
            max_lights: 16,
            max_texture_size: 8192,
            cost_per_light_us: light_us,
            fixed_cost_us: fixed_us,
            threads: 8,
            version: "0".into(),
            device: format!("host{i}/0000:01:00.0/gpu"),
            ..Capabilities::unmeasured(Role::Node, &n.id)
        };
        share(i, &mut caps);
        n.capabilities = Some(caps);
    }
    c
}

fn apart(_: usize, _: &mut Capabilities) {}

/// The automatic plan (`tiles` 0) with its choice, and the plan the chosen tile count gives
/// when asked for (the same plan, without the choice).
fn automatic(cluster: &ClusterSpec, k: u32) -> Plan {
    let scene = stage();
    let with = |tiles| PlanOptions {
        lights_per_node: k,
        ..tiled(tiles)
    };
    let auto = plan(&scene, cluster, &with(0)).unwrap();
    let d = auto
        .decomposition
        .clone()
        .expect("an automatic plan says why");
    let chosen = auto.tiles.len().max(1) as u32;
    let mut asked = plan(&scene, cluster, &with(chosen)).unwrap();
    assert!(
        asked.decomposition.is_none(),
        "a fixed tile count chose nothing"
    );
    asked.decomposition = Some(d);
    assert_eq!(
        auto, asked,
        "the automatic plan is the plan of its tile count"
    );
    auto
}

/// The cost model chooses the tiles: where a node's frame is mostly pixels (eye pass, readback)
/// and nodes are idle, the tile count with the shortest estimated frame, each candidate's
/// estimate being what the plan of that tile count estimates; where the frame is mostly shadow
/// passes, or the nodes share one machine's CPU or one GPU (their frames run one after
/// another), none — and the plan says why.
#[test]
fn automatic_tiles_follow_the_cost_model() {
    let scene = stage();
    // Pixel-bound: 8 nodes on their own GPUs, two light groups.
    let pixels = measured(8, 500, 400_000, apart);
    let p = automatic(&pixels, 2);
    let d = p.decomposition.clone().unwrap();
    assert!(p.tiles.len() >= 2, "{}", d.why);
    assert!(d.why.starts_with("sort-first"), "{}", d.why);
    assert_eq!(d.candidates[0].tiles, 1, "the untiled plan comes first");
    for c in &d.candidates {
        let q = plan(&scene, &pixels, &tiled(c.tiles)).unwrap();
        assert_eq!(c.est_frame_us, q.est_frame_us, "{c:?}");
        assert_eq!(c.nodes, q.nodes.len(), "{c:?}");
    }
    let best = d.candidates.iter().min_by_key(|c| c.est_frame_us).unwrap();
    assert_eq!(p.tiles.len() as u32, best.tiles, "{:?}", d.candidates);
    assert!(
        best.est_frame_us as f64 <= (1.0 - TILES_MIN_GAIN) * d.candidates[0].est_frame_us as f64
    );
    assert!(p.to_string().contains("decomposition: sort-first"), "{p}");
    assert!(p.brief().to_string().contains("decomposition: sort-first"));

    // Shadow-bound: the same nodes, lights dear and pixels cheap.
    let shadows = automatic(&measured(8, 400_000, 500, apart), 2);
    let d = shadows.decomposition.unwrap();
    assert!(shadows.tiles.is_empty(), "{}", d.why);
    assert!(d.why.starts_with("untiled: no tile count"), "{}", d.why);
    assert!(d.candidates.len() >= 2, "tile counts were weighed: {d:?}");

    // Pixel-bound nodes on one machine's CPU, one light group: frames one after another, so
    // tiles only add shadow passes. (With two groups, tiles of one group each would draw each
    // pixel once where the untiled plan draws it twice: tiles pay on one CPU too.)
    let cpu = measured(8, 500, 400_000, |_, c| {
        c.device.clear();
        c.cpu_host = "boot:one".into();
    });
    let on_cpu = automatic(&cpu, 4);
    let d = on_cpu.decomposition.unwrap();
    assert!(on_cpu.tiles.is_empty(), "{}", d.why);
    assert!(d.why.contains("one machine's CPU"), "{}", d.why);

    // Pixel-bound nodes on one GPU: the tiles' nodes would run one after another there.
    let gpu = measured(8, 500, 400_000, |_, c| {
        c.device = "host/0000:01:00.0/gpu".into()
    });
    let one_group = |tiles| PlanOptions {
        lights_per_node: 4,
        ..tiled(tiles)
    };
    let on_gpu = plan(&scene, &gpu, &one_group(0)).unwrap();
    assert!(on_gpu.tiles.is_empty(), "{on_gpu}");
    // The control: each tiled node's own estimate is shorter (the device's serial time is not).
    let tiled_gpu = plan(&scene, &gpu, &one_group(4)).unwrap();
    assert!(tiled_gpu.est_frame_us < on_gpu.est_frame_us, "{tiled_gpu}");
}

/// What fixes the decomposition before the cost model: partitions (asked for, or needed by the
/// scene's geometry), a material node of its own, one node; a tile count asked for records no
/// choice.
#[test]
fn automatic_tiles_give_way_to_partitions_and_fixed_options() {
    let scene = stage();
    let pixels = measured(8, 500, 400_000, apart);
    let why = |o: PlanOptions, c: &ClusterSpec| {
        let p = plan(&scene, c, &o).unwrap();
        assert!(p.tiles.is_empty(), "{p}");
        p.decomposition.expect("automatic").why
    };
    let parts = PlanOptions {
        partitions: 2,
        ..tiled(0)
    };
    // Shadow-bound nodes: the partitions asked for, untiled.
    let shadows = measured(8, 400_000, 500, apart);
    let said = why(parts.clone(), &shadows);
    assert!(
        said.starts_with("sort-last, 2 partitions (asked for); untiled: no tile count"),
        "{said}"
    );
    // Memory for half the scene: two parts by memory.
    let tight = measured(8, 400_000, 500, |_, c| {
        c.memory_bytes = scene.triangle_count() as u64 * 430
    });
    assert!(why(tiled(0), &tight).contains("the scene's geometry or eye pass needs them"));
    // Pixel-bound nodes: both, a grid of tiles × the parts asked for.
    let both = plan(&scene, &pixels, &parts).unwrap();
    let d = both.decomposition.clone().unwrap();
    assert_eq!(both.partitions.len(), 2, "{}", d.why);
    assert!(both.tiles.len() >= 2, "{}", d.why);
    assert!(
        d.why
            .starts_with("sort-last, 2 partitions (asked for); sort-first,"),
        "{}",
        d.why
    );
    let own = PlanOptions {
        material_own_node: true,
        ..tiled(0)
    };
    assert!(why(own, &pixels).contains("node of their own"));
    let one = measured(1, 500, 400_000, apart);
    let lone = PlanOptions {
        lights_per_node: 4,
        ..tiled(0)
    };
    assert_eq!(why(lone, &one), "untiled: one render node");
    for fixed in [1, 2] {
        let p = plan(&scene, &pixels, &tiled(fixed)).unwrap();
        assert!(p.decomposition.is_none(), "tiles {fixed}");
    }
}
