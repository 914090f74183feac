//! How the cluster's fixed costs grow with daemons (issue 24's scale-out table, `docs/scaling.md`):
//! for N render nodes and N compositors in one process (`InProcessCluster`), chain and tree
//! topologies, at a small image so the nodes' own rendering stays small: planning time (the pure
//! planner on a synthetic cluster of that size), registration (connecting a session to every
//! daemon, after a warm-up run), configure + first frame, and the median frame latency (request to complete image) and
//! interval over the frames after the first.
//!
//! `cargo run --profile test -p lightfold-harness --example scale_out [-- N,N,... FRAMES]`

use lightfold_coordinator::plan::{ClusterSpec, MapSizing, PlanOptions, Topology, plan};
use lightfold_coordinator::run::RunOptions;
use lightfold_harness::{InProcessCluster, latency_and_interval, ms, render_on, test_control};
use std::time::Instant;

#[tokio::main(flavor = "multi_thread", worker_threads = 4)]
async fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let sizes: Vec<usize> = args
        .get(1)
        .map(|s| s.split(',').filter_map(|x| x.parse().ok()).collect())
        .unwrap_or_else(|| vec![4, 8, 16, 32]);
    let frames: u32 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(8);
    println!(
        "| daemons | nodes | topology | stages | plan ms | register ms | configure + first frame ms | \
         latency ms (median) | interval ms (median) |"
    );
    println!("|---:|---:|---|---:|---:|---:|---:|---:|---:|");
    for &n in &sizes {
        // One sample per node at K = 1: 2 area lights × n/2 samples.
        let mut scene = lightfold_scene::builtin("balls")?;
        scene.quality.samples_per_area_light = Some((n as u32).div_ceil(2));
        scene.camera.width = 64;
        scene.camera.height = 48;
        scene.quality.shadow_map_size = 128;
        scene.quality.map_sizing = lightfold_scene::MapSizing::Fixed;
        let cluster = InProcessCluster::start(n, n).await?;
        // Warm-up: the nodes open their devices, take the scene and compile their pipelines.
        {
            let mut opts = RunOptions {
                control: test_control(),
                frames: 1,
                ..RunOptions::default()
            };
            opts.plan.lights_per_node = 1;
            opts.plan.map_sizing = MapSizing::Fixed(128);
            let mut session = cluster.connect(opts.control).await?;
            render_on(&mut session, &scene, &opts).await?;
            session.detach();
        }
        for topology in [Topology::Chain, Topology::Tree] {
            let mut opts = RunOptions {
                control: test_control(),
                frames,
                path: lightfold_coordinator::run::FramePath::Orbit { degrees: 2.0 },
                ..RunOptions::default()
            };
            opts.plan.lights_per_node = 1;
            opts.plan.topology = topology;
            opts.plan.map_sizing = MapSizing::Fixed(128);
            let plan_options = PlanOptions {
                ..opts.plan.clone()
            };
            let t = Instant::now();
            let reps = 5;
            let mut stages = 0;
            for _ in 0..reps {
                let p = plan(&scene, &ClusterSpec::local(n, n), &plan_options)?;
                stages = p.stages.len();
            }
            let plan_ms = ms(t.elapsed()) / f64::from(reps);
            let t = Instant::now();
            let mut session = cluster.connect(opts.control).await?;
            let register_ms = ms(t.elapsed());
            let t = Instant::now();
            let out = render_on(&mut session, &scene, &opts).await?;
            let total = t.elapsed();
            session.detach();
            let first = out.frames.first().map(|f| f.received_at);
            let configure_ms = first.map_or(f64::NAN, |at| ms(at.duration_since(t).min(total)));
            let (latency, interval) = latency_and_interval(&out.frames);
            println!(
                "| {} | {n} | {topology} | {stages} | {plan_ms:.2} | {register_ms:.0} | \
                 {configure_ms:.0} | {latency:.1} | {interval:.1} |",
                2 * n
            );
        }
        cluster.stop().await?;
    }
    Ok(())
}
