//! What motion costs on the nodes: per-frame node time (the sum of every render node's frame
//! time, from their `FrameStats`) and shadow passes on the carousel when nothing moves, when its
//! one travelling light moves, when its one spinning box moves, when both move, and in
//! moving-lights mode (every map every frame, the paper's moving mode); and the cost of posing
//! the skinned models per frame.
//!
//! `cargo run --release -p lightfold-harness --example motion_cost [-- WIDTHxHEIGHT FRAMES]`

use lightfold_coordinator::plan::MapSizing;
use lightfold_coordinator::run::RunOptions;
use lightfold_harness::{InProcessCluster, test_control};
use lightfold_scene::{GltfOptions, Scene};
use std::time::Instant;

fn carousel(w: u32, h: u32, light: bool, object: bool) -> Scene {
    let mut s = lightfold_scene::builtin("carousel").unwrap();
    s.quality.samples_per_area_light = Some(8);
    s.camera.width = w;
    s.camera.height = h;
    let anim = s.animation.as_mut().unwrap();
    if !light {
        anim.lights.clear();
    }
    if !object {
        anim.meshes.clear();
    }
    s
}

#[tokio::main(flavor = "multi_thread", worker_threads = 4)]
async fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let (w, h) = args
        .get(1)
        .and_then(|s| s.split_once('x'))
        .and_then(|(a, b)| Some((a.parse().ok()?, b.parse().ok()?)))
        .unwrap_or((320, 240));
    let frames: u32 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(8);
    let cluster = InProcessCluster::start(4, 4).await?;
    println!(
        "carousel {w}x{h}, 2 lights x 8 samples, K = 4, {frames} frames (first one not counted)"
    );
    println!("| mode | node ms / frame | shadow passes / frame | maps kept / frame |");
    println!("|---|---:|---:|---:|");
    let modes: [(&str, bool, bool, bool, bool); 5] = [
        (
            "static (walkthrough, nothing moves)",
            false,
            false,
            true,
            false,
        ),
        ("one light moves", true, false, true, true),
        ("one object moves", false, true, true, true),
        ("light and object move", true, true, true, true),
        (
            "moving-lights mode (every map every frame)",
            true,
            true,
            false,
            true,
        ),
    ];
    for (name, light, object, walkthrough, timed) in modes {
        let scene = carousel(w, h, light, object);
        let mut opts = RunOptions {
            control: test_control(),
            frames,
            time: timed.then_some(0.0),
            fps: timed.then_some(4.0),
            ..RunOptions::default()
        };
        opts.plan.lights_per_node = 4;
        opts.plan.walkthrough = walkthrough;
        opts.plan.map_sizing = MapSizing::Fixed(scene.quality.shadow_map_size);
        let out = cluster.render(&scene, &opts).await?;
        let nodes: Vec<&str> = out.plan.nodes.iter().map(|n| n.node.as_str()).collect();
        let (mut us, mut passes, mut kept, mut n) = (0u64, 0u64, 0u64, 0u64);
        for f in out.frames.iter().skip(1) {
            for s in f
                .stats
                .iter()
                .filter(|s| nodes.contains(&s.daemon_id.as_str()))
            {
                us += s.total_us;
                passes += u64::from(s.shadow_passes);
                kept += u64::from(s.maps_kept);
            }
            n += 1;
        }
        let n = n.max(1) as f64;
        println!(
            "| {name} | {:.1} | {:.1} | {:.1} |",
            us as f64 / n / 1e3,
            passes as f64 / n,
            kept as f64 / n
        );
    }
    cluster.stop().await?;

    println!();
    println!("| model | vertices | pose ms / frame (CPU) |");
    println!("|---|---:|---:|");
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets");
    for (name, path, scale) in [
        ("Fox", root.join("Fox/Fox.glb"), 0.01),
        ("CesiumMan", root.join("CesiumMan/CesiumMan.gltf"), 1.0),
    ] {
        let opts = GltfOptions {
            scale,
            complete: false,
            ..GltfOptions::default()
        };
        let s = lightfold_scene::load_gltf_with(&path, &opts)?;
        let d = s.animation.as_ref().map_or(1.0, |a| a.duration());
        let vertices: usize = s.meshes.iter().map(|m| m.positions.len()).sum();
        let steps = 50;
        let t0 = Instant::now();
        for i in 0..steps {
            std::hint::black_box(s.pose_meshes(d * i as f32 / steps as f32));
        }
        let ms = t0.elapsed().as_secs_f64() * 1e3 / steps as f64;
        println!("| {name} | {vertices} | {ms:.2} |");
    }
    Ok(())
}
