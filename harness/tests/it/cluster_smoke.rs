//! Smoke test of the in-process cluster: one frame of a small scene.

use lightfold_coordinator::run::RunOptions;
use lightfold_harness::{InProcessCluster, test_control};

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn in_process_cluster_renders_a_frame() {
    let mut scene = lightfold_scene::builtin("box").unwrap();
    scene.camera.width = 96;
    scene.camera.height = 72;
    let cluster = InProcessCluster::start(4, 5).await.unwrap();
    let mut opts = RunOptions {
        control: test_control(),
        ..RunOptions::default()
    };
    opts.plan.lights_per_node = 8;
    let out = cluster.render(&scene, &opts).await.unwrap();
    println!("{}", out.plan);
    let img = &out.frames[0].image;
    let mean: f32 = img.data.iter().sum::<f32>() / img.data.len() as f32;
    println!("mean {mean}");
    assert!(mean > 0.0);
    cluster.stop().await.unwrap();
}
