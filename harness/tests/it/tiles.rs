//! Sort-first tiles through the cluster (`docs/planner.md` § Tiles): every light group is
//! rendered once per band of rows by a node drawing only those rows, and the stages put the
//! tiles together. The frame equals the untiled cluster's frame (bit for bit where both have
//! one light group, within the link formats' bound otherwise) and the single-device render,
//! while the coordinator moves rows between tiles frame by frame. Negative control: the frame
//! with one tile's rows missing fails the same comparison.

use lightfold_coordinator::plan::PlanOptions;
use lightfold_coordinator::run::RunOptions;
use lightfold_harness::{
    InProcessCluster, RunOutput, assert_close, gpu, render_on, single_device, single_device_parts,
    small, small_glass, test_control,
};
use lightfold_scene::{Image, Scene};

/// Renders `frames` frames of `scene` with `tiles` tiles at K = 4 and bands of 8 rows.
async fn run(cluster: &InProcessCluster, scene: &Scene, tiles: u32, frames: u32) -> RunOutput {
    let plan = PlanOptions {
        tiles,
        lights_per_node: 4,
        band_height: 8,
        partitions: 1,
        ..PlanOptions::default()
    };
    run_with(cluster, scene, plan, frames).await
}

async fn run_with(
    cluster: &InProcessCluster,
    scene: &Scene,
    plan: PlanOptions,
    frames: u32,
) -> RunOutput {
    let mut session = cluster.connect(test_control()).await.unwrap();
    let opts = RunOptions {
        control: test_control(),
        frames,
        plan,
        ..RunOptions::default()
    };
    let out = render_on(&mut session, scene, &opts).await.unwrap();
    session.detach();
    out
}

/// How many values of `a` equal `b`'s bit for bit.
fn bit_equal(a: &Image, b: &Image) -> usize {
    a.data
        .iter()
        .zip(&b.data)
        .filter(|(x, y)| x.to_bits() == y.to_bits())
        .count()
}

/// `image` with rows `[y0, y1)` set to zero.
fn without_rows(image: &Image, rows: [u32; 2]) -> Image {
    let mut out = image.clone();
    let row = image.width as usize * image.channels;
    out.data[rows[0] as usize * row..rows[1] as usize * row].fill(0.0);
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_tiled_cluster_frame_equals_the_untiled_one_while_rows_move() {
    let cluster = InProcessCluster::start(6, 3).await.unwrap();
    let gpu = gpu();
    let mut exact_checked = 0;
    for (scene, tiles) in [(small("balls"), 2), (small("balls"), 3), (small_glass(), 2)] {
        let untiled = run(&cluster, &scene, 1, 1).await;
        assert!(untiled.plan.tiles.is_empty());
        let tiled = run(&cluster, &scene, tiles, 6).await;
        let what = format!("{} T={tiles}", scene.name);
        assert_eq!(tiled.plan.tiles.len(), tiles as usize, "{what}");
        assert!(tiled.plan.nodes.iter().all(|n| n.tile.is_some()), "{what}");
        assert!(
            tiled.summary.tile_steps > 0,
            "{what}: the rows were balanced"
        );
        let truth = single_device(&gpu, &scene, false);
        for f in &tiled.frames {
            let exact = bit_equal(&f.image, &untiled.frames[0].image);
            eprintln!(
                "{what} frame {}: {exact} of {} values equal the untiled frame's bit for bit; \
                 rows at the end {:?}",
                f.frame,
                f.image.data.len(),
                tiled.summary.tile_rows
            );
            // With one light group the untiled frame is one node's layers through the same
            // operators: the tiled frame must equal it bit for bit. With more, the untiled
            // chain sums groups across stages in the chain's link format and the tiled grid
            // within a tile: the link formats' bound.
            if untiled.plan.nodes.len() == 1 {
                assert_eq!(exact, f.image.data.len(), "{what}: bit for bit");
                exact_checked += 1;
            }
            assert_close(
                &f.image,
                &untiled.frames[0].image,
                &format!("{what} frame {} vs untiled", f.frame),
            );
            assert_close(
                &f.image,
                &truth,
                &format!("{what} frame {} vs render", f.frame),
            );
        }
        // Negative control: without the rows of its last tile the frame is not the image.
        let last = *tiled.plan.tiles.last().unwrap();
        let missing = without_rows(&tiled.frames[0].image, last);
        let failed = std::panic::catch_unwind(|| assert_close(&missing, &truth, "control"));
        assert!(failed.is_err(), "{what}: a missing tile went unnoticed");
    }
    assert!(exact_checked > 0, "no scene was checked bit for bit");
    cluster.stop().await.unwrap();
}

/// Both decompositions at once: 2 sort-first tiles × 2 sort-last parts of `balls`, one light
/// group (K = 32), so each of the 4 nodes draws one part's meshes into one tile's rows with the
/// part's maps. Every frame equals the partitioned untiled cluster's frame bit for bit (one
/// group: the same layers through selections only) while the rows move, and the single-device
/// render of the same parts (`single_device_parts`) within the link formats' bound; control:
/// without its last tile's rows it fails.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_grid_of_tiles_and_parts_equals_the_partitioned_frame() {
    let cluster = InProcessCluster::start(4, 3).await.unwrap();
    let gpu = gpu();
    let scene = small("balls");
    let options = |tiles| PlanOptions {
        tiles,
        partitions: 2,
        lights_per_node: 32,
        band_height: 8,
        ..PlanOptions::default()
    };
    let parts = run_with(&cluster, &scene, options(1), 1).await;
    assert_eq!(
        (parts.plan.partitions.len(), parts.plan.tiles.len()),
        (2, 0)
    );
    let grid = run_with(&cluster, &scene, options(2), 4).await;
    assert_eq!((grid.plan.partitions.len(), grid.plan.tiles.len()), (2, 2));
    assert_eq!(grid.plan.nodes.len(), 4, "2 tiles × 2 parts × 1 group");
    assert!(
        grid.plan
            .nodes
            .iter()
            .all(|n| n.part.is_some() && n.tile.is_some())
    );
    // The render the partitioned cluster matches: each part's maps fitted to the part.
    let chunked = lightfold_coordinator::plan::scene_for(
        &scene,
        &lightfold_coordinator::plan::ClusterSpec::local(1, 1),
        &options(1),
    )
    .into_owned();
    let truth = single_device_parts(&gpu, &chunked, &grid.plan.partitions, false);
    for f in &grid.frames {
        let exact = bit_equal(&f.image, &parts.frames[0].image);
        eprintln!(
            "grid frame {}: {exact} of {} values equal the partitioned frame's bit for bit; rows \
             at the end {:?}",
            f.frame,
            f.image.data.len(),
            grid.summary.tile_rows
        );
        assert_eq!(exact, f.image.data.len(), "grid vs partitions: bit for bit");
        assert_close(&f.image, &truth, "grid vs render of the parts");
    }
    let last = *grid.plan.tiles.last().unwrap();
    let missing = without_rows(&grid.frames[0].image, last);
    let failed = std::panic::catch_unwind(|| assert_close(&missing, &truth, "control"));
    assert!(failed.is_err(), "a missing tile went unnoticed");
    cluster.stop().await.unwrap();
}
