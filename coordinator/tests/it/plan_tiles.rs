//! Sort-first tiles (`PlanOptions::tiles`): the grid of tiles × light groups, the rows each node
//! is configured with, and the options tiles refuse.

use crate::plan_rules::assert_stages_build;
use crate::plan_scenes::stage;
use lightfold_coordinator::plan::{
    ClusterSpec, MaterialPlacement, PlanError, PlanOptions, Topology, plan,
};
use lightfold_protocol::Layer;

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
        let of_tile: Vec<_> = p.nodes.iter().filter(|n| n.part == Some(t)).collect();
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
    let whole = plan(&scene, &ClusterSpec::local(16, 16), &tiled(0)).unwrap();
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
    assert!(refused(&|o| o.partitions = 2).contains("exclude each other"));
    assert!(refused(&|o| o.tiles = 65).contains("2 to 64"));
    assert!(refused(&|o| o.material_own_node = true).contains("material"));
    let h = scene.camera.height;
    assert!(
        refused(&|o| o.band_height = h).contains("at least as many bands"),
        "one band of rows cannot make two tiles"
    );
}
