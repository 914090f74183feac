//! `seed64` node links with a per-frame scale (issue 23): the coordinator sets each node's next
//! scale from its latest measured maximum (`FrameStats::peak` × `SEED64_HEADROOM`). On a scene
//! whose light comes down towards the ground over the frames (brighter frame by frame), the first
//! frame — at the plan's fixed scale 1 — saturates, and that is counted; every later frame's
//! scale follows the light, nothing saturates, and the image is within `seed64`'s bound of the
//! single-device render of the same pose.

use lightfold_coordinator::control::seed64_scale;
use lightfold_coordinator::run::RunOptions;
use lightfold_harness::{InProcessCluster, render_on, single_device, test_control};
use lightfold_protocol::PixelFormat;
use lightfold_scene::Scene;
use lightfold_scene::animation::{MotionSpec, PathSpec, apply_motions};

const FRAMES: u32 = 8;
const FPS: f32 = 4.0;

/// A grey ground and a ball under a point light that comes down from 3 m to 2 m over the frames,
/// linearly: the brightest illumination (the top of the ball) rises from 1.43 to 4.49, by at most
/// 1.22× from one frame to the next (within `SEED64_HEADROOM`).
fn descending_light() -> Scene {
    use lightfold_scene::primitives::{plane, sphere};
    use lightfold_scene::{Camera, Light, LightShape, Material};
    let mut s = Scene::new("descending light");
    let grey = s.add_material(Material::diffuse("grey", [0.5; 3]));
    s.add_mesh(plane(
        "ground",
        [0.0; 3],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [8.0, 8.0],
        1,
        grey,
    ));
    s.add_mesh(sphere("ball", [0.6, 0.5, 0.3], 0.5, 24, 12, grey));
    s.lights.push(Light {
        name: "lamp".into(),
        shape: LightShape::Point {
            position: [0.0, 3.0, 0.0],
        },
        color: [1.0; 3],
        power: 20.0,
        range: None,
        samples: 1,
    });
    s.camera = Camera {
        position: [0.0, 2.5, 6.0],
        target: [0.0, 0.5, 0.0],
        up: [0.0, 1.0, 0.0],
        fov_y_deg: 45.0,
        width: 64,
        height: 48,
    };
    let last = (FRAMES - 1) as f32 / FPS;
    let motion = MotionSpec {
        object: None,
        light: Some("lamp".to_string()),
        pivot: None,
        spin: None,
        path: Some(PathSpec {
            times: vec![0.0, last, 2.0 * last],
            offsets: vec![[0.0; 3], [0.0, -1.0, 0.0], [0.0; 3]],
            interpolation: None,
        }),
    };
    apply_motions(&mut s, &[motion], &Default::default()).unwrap();
    s
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn seed64_scale_follows_a_brightening_scene() {
    let scene = descending_light();
    let cluster = InProcessCluster::start(3, 3).await.unwrap();
    let mut control = test_control();
    // One frame at a time: each request is sent after the previous frame's reports arrived.
    control.frames_in_flight = 1;
    let mut session = cluster.connect(control).await.unwrap();
    let mut opts = RunOptions {
        control,
        frames: FRAMES,
        fps: Some(FPS),
        ..RunOptions::default()
    };
    opts.plan.formats.node = PixelFormat::Seed64;
    let out = render_on(&mut session, &scene, &opts).await.unwrap();
    session.detach();
    cluster.stop().await.unwrap();
    assert_eq!(out.frames.len(), FRAMES as usize);
    let gpu = lightfold_harness::gpu();
    let nodes: Vec<_> = out
        .plan
        .nodes
        .iter()
        .filter(|n| !n.lights.is_empty())
        .collect();
    let stages = out.plan.stages.len() as f32;
    let mut peaks_before: Vec<f32> = Vec::new();
    for (i, f) in out.frames.iter().enumerate() {
        let stats: Vec<_> = nodes
            .iter()
            .map(|n| f.stats.iter().find(|s| s.daemon_id == n.node).unwrap())
            .collect();
        let saturated: u64 = stats.iter().map(|s| s.saturated).sum();
        let peaks: Vec<f32> = stats.iter().map(|s| s.peak).collect();
        let scales: Vec<f32> = stats.iter().map(|s| s.scale).collect();
        eprintln!(
            "frame {}: peaks {peaks:?}, scales {scales:?}, saturated {saturated}",
            i + 1
        );
        if i == 0 {
            assert!(scales.iter().all(|&s| s == 1.0), "{scales:?}");
            assert!(
                saturated > 0,
                "the first frame is brighter than scale 1 and saturates"
            );
            assert!(out.summary.saturated >= saturated && out.summary.saturated_frames >= 1);
        } else {
            assert_eq!(
                saturated,
                0,
                "frame {}: the scale followed the light",
                i + 1
            );
            for (k, s) in scales.iter().enumerate() {
                assert_eq!(
                    Some(*s),
                    seed64_scale(peaks_before[k]),
                    "frame {} scale",
                    i + 1
                );
            }
            // Within seed64's bound (diffuse scale/4094 + specular scale/2046 per node, times its
            // colour; materials are at most 1) plus the f16x6 chain's half-ulp per stage.
            let t = opts.time_of(i as u32).unwrap();
            let want = single_device(&gpu, &scene.still_at(t), false);
            let mut worst = 0.0f32;
            for (p, (a, b)) in f.image.data.iter().zip(&want.data).enumerate() {
                let c = p % 3;
                let link: f32 = nodes
                    .iter()
                    .zip(&scales)
                    .map(|(n, s)| n.color[c] * s * (1.0 / 4094.0 + 1.0 / 2046.0))
                    .sum();
                let bound = link + stages * b.abs() * 2f32.powi(-11) + 1e-6;
                worst = worst.max((a - b).abs() / bound);
            }
            eprintln!("frame {}: worst error / bound {worst:.3}", i + 1);
            assert!(worst <= 1.0, "frame {}: {worst} of the bound", i + 1);
        }
        peaks_before = peaks;
    }
    let total = |f: &lightfold_coordinator::control::FrameResult| -> f32 {
        f.stats.iter().map(|s| s.peak).sum()
    };
    assert!(
        total(&out.frames[FRAMES as usize - 1]) > 1.8 * total(&out.frames[0]),
        "the scene brightens over the frames"
    );
}
