//! Things that move, through the in-process cluster: animated frames (a skinned glTF, the
//! carousel's spinning box and travelling light) equal the single-device render of the scene
//! posed at each frame's time; at two times the images differ; a moving light re-renders only
//! the node holding its samples and a moving object only the maps it may cast into (from the
//! nodes' frame statistics). (Culling over the motion: `plan_culling.rs`, and the first test,
//! whose single-device renders draw every caster.)

use lightfold_coordinator::plan::MapSizing;
use lightfold_coordinator::run::RunOptions;
use lightfold_harness::{
    InProcessCluster, RunOutput, assert_close, gpu, single_device, small, test_control,
};
use lightfold_node::gpu::Gpu;
use lightfold_scene::{GltfOptions, Scene};

fn animated_options(scene: &Scene, frames: u32, time: f32, fps: f32, k: u32) -> RunOptions {
    let mut opts = RunOptions {
        control: test_control(),
        frames,
        time: Some(time),
        fps: Some(fps),
        ..RunOptions::default()
    };
    opts.plan.lights_per_node = k;
    opts.plan.walkthrough = true;
    opts.plan.map_sizing = MapSizing::Fixed(scene.quality.shadow_map_size);
    opts
}

fn cesium_man() -> Scene {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/CesiumMan/CesiumMan.gltf");
    let mut s = lightfold_scene::load_gltf_with(&path, &GltfOptions::default()).unwrap();
    s.quality.samples_per_area_light = Some(4);
    s.camera.width = 64;
    s.camera.height = 48;
    s
}

/// Share of channels that differ by more than 0.01 between two images.
fn changed(a: &lightfold_scene::Image, b: &lightfold_scene::Image) -> f64 {
    let n = a
        .data
        .iter()
        .zip(&b.data)
        .filter(|(x, y)| (*x - *y).abs() > 0.01)
        .count();
    n as f64 / a.data.len() as f64
}

fn check_frames(gpu: &Gpu, scene: &Scene, opts: &RunOptions, out: &RunOutput, what: &str) {
    assert_eq!(out.frames.len(), opts.frames as usize, "{what}");
    for (i, f) in out.frames.iter().enumerate() {
        let t = opts.time_of(i as u32).unwrap();
        let want = single_device(gpu, &scene.still_at(t), true);
        assert_close(&f.image, &want, &format!("{what} at t = {t}"));
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn animated_frames_match_the_single_device_render_of_each_pose() {
    let gpu = gpu();
    let cluster = InProcessCluster::start(3, 3).await.unwrap();
    let cases = [
        ("carousel", small("carousel"), 0.5, 1.5),
        ("animal", small("animal"), 0.3, 1.0),
        ("CesiumMan", cesium_man(), 0.2, 1.6),
    ];
    for (name, scene, time, fps) in cases {
        assert!(scene.is_animated(), "{name}");
        let opts = animated_options(&scene, 2, time, fps, 4);
        let out = cluster.render(&scene, &opts).await.unwrap();
        check_frames(&gpu, &scene, &opts, &out, name);
        let moved = changed(&out.frames[0].image, &out.frames[1].image);
        println!(
            "{name}: {:.2} % of channels changed between t = {time} and t = {}",
            100.0 * moved,
            time + 1.0 / fps
        );
        assert!(moved > 0.002, "{name}: the picture did not move ({moved})");
        // Negative control: the rest pose is not what the cluster rendered.
        let rest = single_device(&gpu, &scene, true);
        assert!(
            changed(&out.frames[1].image, &rest) > 0.002,
            "{name}: frame 2 is the rest pose"
        );
    }
    cluster.stop().await.unwrap();
}

/// The carousel with only its light moving (`Some(true)`), only its box (`Some(false)`), or
/// nothing (`None`: a still scene whose frames still carry times).
fn carousel_moving(light: Option<bool>) -> Scene {
    let mut s = small("carousel");
    let anim = s.animation.as_mut().unwrap();
    if light != Some(false) {
        anim.meshes.clear();
    }
    if light != Some(true) {
        anim.lights.clear();
    }
    // A wall washer in front of the back wall, facing it: the spinner is behind its samples, so
    // it casts into none of their maps (the planner's caster lists say so).
    s.lights.push(lightfold_scene::Light {
        name: "wall washer".into(),
        shape: lightfold_scene::LightShape::Rect {
            center: [0.0, 1.5, -2.6],
            normal: [0.0, 0.0, -1.0],
            u_axis: [1.0, 0.0, 0.0],
            size: [0.4, 0.4],
        },
        color: [0.6, 1.0, 0.6],
        power: 10.0,
        range: None,
        samples: 4,
    });
    s
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn only_what_moved_is_rendered_again() {
    let cluster = InProcessCluster::start(3, 3).await.unwrap();
    // Negative control: frames with times over a scene where nothing moves draw no map.
    let still = carousel_moving(None);
    assert!(!still.is_animated());
    let out = cluster
        .render(&still, &animated_options(&still, 3, 0.2, 4.0, 4))
        .await
        .unwrap();
    for f in &out.frames[1..] {
        assert!(
            f.stats.iter().all(|s| s.shadow_passes == 0),
            "still: {:?}",
            f.stats
        );
    }
    for light in [true, false] {
        let scene = carousel_moving(Some(light));
        let what = if light { "moving light" } else { "moving box" };
        let opts = animated_options(&scene, 3, 0.2, 4.0, 4);
        let out = cluster.render(&scene, &opts).await.unwrap();
        let spinner = scene
            .meshes
            .iter()
            .position(|m| m.name == "spinner")
            .unwrap() as u32;
        let moving_light = scene
            .animation
            .as_ref()
            .unwrap()
            .moving_lights(scene.lights.len());
        for node in out.plan.nodes.iter().filter(|n| !n.lights.is_empty()) {
            // Lights of this node whose maps must be drawn again each frame.
            let redraw = node
                .lights
                .iter()
                .zip(&node.shadows)
                .filter(|(l, sh)| {
                    let s = &out.plan.samples[**l];
                    if light {
                        moving_light[s.light as usize]
                    } else {
                        sh.casters.contains(&spinner) && sh.views.count() > 0
                    }
                })
                .count() as u32;
            for f in &out.frames[1..] {
                let st = f.stats.iter().find(|s| s.daemon_id == node.node).unwrap();
                println!(
                    "{what}: {} frame {}: {} passes, {} of {} lights' maps kept (expected to redraw {redraw})",
                    node.node,
                    f.frame,
                    st.shadow_passes,
                    st.maps_kept,
                    node.lights.len()
                );
                assert_eq!(
                    st.maps_kept,
                    node.lights.len() as u32 - redraw,
                    "{what}: {} kept the maps of every light that did not move",
                    node.node
                );
                assert_eq!(st.shadow_passes == 0, redraw == 0, "{what}: {}", node.node);
            }
        }
        if !light {
            // The wall washer's node keeps its maps while the box spins.
            let washer = scene.lights.len() as u32 - 1;
            let node = out
                .plan
                .nodes
                .iter()
                .find(|n| {
                    n.lights
                        .iter()
                        .any(|&l| out.plan.samples[l].light == washer)
                })
                .unwrap();
            assert!(
                node.shadows.iter().all(|s| !s.casters.contains(&spinner)),
                "the spinner is no caster of the wall washer"
            );
            for f in &out.frames[1..] {
                let st = f.stats.iter().find(|s| s.daemon_id == node.node).unwrap();
                assert!(st.maps_kept >= 4, "{}: {st:?}", node.node);
            }
        }
        if light {
            // The light's samples are on some node and the other light's on another: one
            // node renders again, one does not.
            let idle = out
                .plan
                .nodes
                .iter()
                .filter(|n| !n.lights.is_empty())
                .any(|n| {
                    out.frames[2]
                        .stats
                        .iter()
                        .any(|s| s.daemon_id == n.node && s.shadow_passes == 0)
                });
            assert!(idle, "a node whose lights stood still drew nothing");
        }
    }
    cluster.stop().await.unwrap();
}
