//! What tests and examples share: the device (or a loud failure), small versions of the scenes,
//! run options with test deadlines and the frame-time figures the scaling examples report.

use lightfold_coordinator::control::{ControlOptions, FrameResult};
use lightfold_coordinator::run::RunOptions;
use lightfold_net::Timeouts;
use lightfold_node::gpu::{Gpu, GpuOptions};
use lightfold_protocol::stats;
use lightfold_scene::Scene;
use std::time::Duration;

/// A small orbit (4° per frame) over `frames` frames at K = `k` with fixed-size shadow maps, so
/// re-plans that change K do not change the maps: the failover and hostile-peer runs.
pub fn orbit_options(frames: u32, k: u32) -> RunOptions {
    let mut opts = RunOptions {
        control: test_control(),
        frames,
        path: lightfold_coordinator::run::FramePath::Orbit { degrees: 4.0 },
        ..RunOptions::default()
    };
    opts.plan.lights_per_node = k;
    opts.plan.map_sizing =
        lightfold_coordinator::plan::MapSizing::Fixed(lightfold_scene::defaults::SHADOW_MAP_SIZE);
    opts
}

/// Control deadlines for tests: short enough to fail fast, long enough for lavapipe.
pub fn test_control() -> ControlOptions {
    ControlOptions {
        link: Timeouts {
            connect: Duration::from_secs(5),
            handshake: Duration::from_secs(5),
            send: Duration::from_secs(30),
            ..Timeouts::default()
        },
        register: Duration::from_secs(60),
        configure: Duration::from_secs(120),
        frame: Duration::from_secs(120),
        frames_in_flight: 2,
        // Generous: these machines are shared, and a false loss costs a re-plan, not a frame.
        heartbeat_timeout: Duration::from_secs(3),
        ..ControlOptions::default()
    }
}

/// The device, or a failed test that says why and what to install: GPU tests never skip, and CI
/// (no real GPU) runs them on lavapipe.
pub fn gpu() -> Gpu {
    Gpu::new(&GpuOptions::default()).unwrap_or_else(|e| {
        panic!("GPU tests need an adapter (CI installs mesa-vulkan-drivers for lavapipe): {e}")
    })
}

/// Small versions of built-in scenes: 2 area lights × 4 samples, 64×48.
pub fn small(name: &str) -> Scene {
    let mut s = lightfold_scene::builtin(name).unwrap();
    s.quality.samples_per_area_light = Some(4);
    s.camera.width = 64;
    s.camera.height = 48;
    s
}

/// `scenes/glass.toml` (coloured shadows, glass seen through: `docs/translucency.md`) small: 4
/// samples per area light, 64×48.
pub fn small_glass() -> Scene {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/glass.toml");
    let mut s = lightfold_scene::load(path).unwrap();
    s.quality.samples_per_area_light = Some(4);
    s.camera.width = 64;
    s.camera.height = 48;
    s
}

/// `scenes/glass-stack.toml` (three staggered panes, glass as the eye sees it with `--peels`:
/// `docs/translucency.md` § Peeled layers) small: 4 samples, 96×72.
pub fn small_glass_stack() -> Scene {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/glass-stack.toml");
    let mut s = lightfold_scene::load(path).unwrap();
    s.quality.samples_per_area_light = Some(4);
    s.camera.width = 96;
    s.camera.height = 72;
    s
}

/// The Khronos FlightHelmet (glTF metallic-roughness with base-colour, metallic-roughness,
/// normal and occlusion textures, metal and dielectric parts) small: its framing light at 4
/// samples, 96×72.
pub fn small_helmet() -> Scene {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../assets/FlightHelmet/FlightHelmet.gltf"
    );
    let mut s = lightfold_scene::load(path).unwrap();
    s.quality.samples_per_area_light = Some(4);
    s.camera.width = 96;
    s.camera.height = 72;
    s
}

/// `d` in milliseconds.
pub fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// The median latency (request to complete image) and interval of the frames after the first,
/// in milliseconds (NaN where there are none): what the scaling examples report (`docs/scaling.md`).
pub fn latency_and_interval(frames: &[FrameResult]) -> (f64, f64) {
    let later = &frames[1.min(frames.len())..];
    let median = |v: Vec<f64>| stats::median(&v).unwrap_or(f64::NAN);
    let latency = median(
        later
            .iter()
            .map(|f| ms(f.received_at - f.requested_at))
            .collect(),
    );
    let interval = median(
        later
            .windows(2)
            .map(|w| ms(w[1].received_at - w[0].received_at))
            .collect(),
    );
    (latency, interval)
}

/// The silhouette scene of antialiasing (`scenes/silhouettes.toml`: lit objects against black,
/// thin poles) at `width × height`.
pub fn silhouettes(width: u32, height: u32) -> Scene {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/silhouettes.toml");
    let mut s = lightfold_scene::load(path).unwrap();
    s.camera.width = width;
    s.camera.height = height;
    s
}
