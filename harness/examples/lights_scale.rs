//! How the cluster's frame grows with lights and K (issue 24's lights × K table,
//! `docs/scaling.md`): L light samples at K per node on L/K render nodes (and as many
//! compositors, at most 16) in one process (`InProcessCluster`), chain topology, at a small image
//! with 128² maps so the fixed costs show: planning time, configure + first frame, the median
//! frame latency and interval over the frames after the first, and the CPU time of the whole
//! process (every daemon and the coordinator) per frame over the run, configure included.
//!
//! `cargo run --profile test -p lightfold-harness --example lights_scale [-- L:K,L:K,... FRAMES]`

use lightfold_coordinator::plan::{ClusterSpec, MapSizing, PlanOptions, plan};
use lightfold_coordinator::run::RunOptions;
use lightfold_harness::{InProcessCluster, latency_and_interval, ms, render_on, test_control};
use std::time::Instant;

/// CPU seconds (user + system, all threads) this process has used.
fn cpu_seconds() -> f64 {
    procfs::process::Process::myself()
        .and_then(|p| p.stat())
        .map_or(0.0, |s| {
            (s.utime + s.stime) as f64 / procfs::ticks_per_second().max(1) as f64
        })
}

#[tokio::main(flavor = "multi_thread", worker_threads = 4)]
async fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let configs: Vec<(u32, u32)> = args
        .get(1)
        .map(|s| {
            s.split(',')
                .filter_map(|x| {
                    let (l, k) = x.split_once(':')?;
                    Some((l.parse().ok()?, k.parse().ok()?))
                })
                .collect()
        })
        .unwrap_or_else(|| vec![(32, 4), (32, 16), (256, 16), (256, 64), (1024, 64)]);
    let frames: u32 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(6);
    println!(
        "| lights | K | nodes | stages | plan ms | configure + first frame ms | latency ms (median) | \
         interval ms (median) | CPU ms per frame |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for &(lights, k) in &configs {
        // 2 area lights × lights/2 samples.
        let mut scene = lightfold_scene::builtin("balls")?;
        scene.quality.samples_per_area_light = Some(lights.div_ceil(2));
        scene.camera.width = 64;
        scene.camera.height = 48;
        scene.quality.shadow_map_size = 128;
        scene.quality.map_sizing = lightfold_scene::MapSizing::Fixed;
        let nodes = lights.div_ceil(k) as usize;
        let compositors = nodes.min(16);
        let mut opts = RunOptions {
            control: test_control(),
            frames,
            path: lightfold_coordinator::run::FramePath::Orbit { degrees: 2.0 },
            ..RunOptions::default()
        };
        opts.plan.lights_per_node = k;
        opts.plan.map_sizing = MapSizing::Fixed(128);
        // Every sample rendered: the table is about the count, not what culling would drop.
        opts.plan.force_all = true;
        let plan_options = PlanOptions {
            ..opts.plan.clone()
        };
        let t = Instant::now();
        let reps = 3;
        let mut stages = 0;
        for _ in 0..reps {
            let p = plan(
                &scene,
                &ClusterSpec::local(nodes, compositors),
                &plan_options,
            )?;
            stages = p.stages.len();
        }
        let plan_ms = ms(t.elapsed()) / f64::from(reps);
        // Started after planning: the nodes calibrate their cost on start, which would load
        // the cores the planner is timed on.
        let cluster = InProcessCluster::start(nodes, compositors).await?;
        let mut session = cluster.connect(opts.control).await?;
        let cpu0 = cpu_seconds();
        let t = Instant::now();
        let out = render_on(&mut session, &scene, &opts).await?;
        let total = t.elapsed();
        let cpu_ms = (cpu_seconds() - cpu0) * 1e3 / f64::from(frames);
        session.detach();
        let first = out.frames.first().map(|f| f.received_at);
        let configure_ms = first.map_or(f64::NAN, |at| ms(at.duration_since(t).min(total)));
        let (latency, interval) = latency_and_interval(&out.frames);
        println!(
            "| {lights} | {k} | {nodes} | {stages} | {plan_ms:.2} | {configure_ms:.0} | \
             {latency:.1} | {interval:.1} | {cpu_ms:.0} |"
        );
        cluster.stop().await?;
    }
    Ok(())
}
