//! Start-up calibration: a few renders of a tiny scene with one and with eight lights, so that
//! registration reports a measured cost per light and a fixed cost per frame for this device
//! (the planner sizes K from them on heterogeneous machines), and one-light renders drawing a
//! dense ball in the eye pass instead of the small one, for the eye pass's cost per triangle
//! (automatic partitioning reads it). Takes well under a second on
//! lavapipe. The figures are for the calibration scene at its small size; the planner scales
//! them to a plan's image size (the fixed cost and the eye pass's half of a light's cost by the
//! pixels), which predicts a frame of a simple scene (`docs/planner.md` § Cost model).

use crate::gpu::{Gpu, LayerSet, RenderError, RenderOptions, Renderer};
use lightfold_scene::primitives::{plane, sphere};
use lightfold_scene::{Camera, LightSample, Material, SampleKind, Scene};
use std::time::Instant;

/// Calibration image size (the planner scales the figures from it) and map size.
pub const WIDTH: u32 = lightfold_protocol::CALIBRATION_SIZE.0;
pub const HEIGHT: u32 = lightfold_protocol::CALIBRATION_SIZE.1;
pub const MAP_SIZE: u32 = 256;
/// Lights of the second calibration render (more lights, more signal over the machine's noise).
const MANY: usize = 8;
/// Timed repetitions of each render (the fastest counts: the machine is shared and noisy).
const REPEATS: usize = 3;

/// What one frame costs on this device, measured.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Calibration {
    pub cost_per_light_us: u64,
    pub fixed_cost_us: u64,
    /// The eye pass's cost per triangle drawn, nanoseconds (0: not measurable here).
    pub eye_ns_per_triangle: u64,
}

/// Segments of the dense ball the eye cost per triangle is measured with (`DENSE_SEGMENTS`
/// around, half as many rings: about 40 000 triangles).
const DENSE_SEGMENTS: u32 = 200;

/// Nanoseconds per triangle from the fastest one-light frame drawing the small ball in the eye
/// pass (`small_us`) and the dense one (`dense_us`), `extra` triangles more: 0 when the dense
/// frame was no slower (a fast device, or noise).
pub fn eye_ns_per_triangle(small_us: u64, dense_us: u64, extra: u64) -> u64 {
    if dense_us > small_us && extra > 0 {
        (dense_us - small_us) * 1000 / extra
    } else {
        0
    }
}

/// A ground plane and a ball: shadows to cast, little geometry.
pub fn calibration_scene() -> Scene {
    let mut s = Scene::new("calibration");
    let grey = s.add_material(Material::diffuse("grey", [0.7, 0.7, 0.7]));
    let red = s.add_material(Material {
        specular: [0.3, 0.3, 0.3],
        shininess: 32.0,
        ..Material::diffuse("red", [0.8, 0.2, 0.2])
    });
    s.add_mesh(plane(
        "floor",
        [0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [6.0, 6.0],
        4,
        grey,
    ));
    s.add_mesh(sphere("ball", [0.0, 0.6, 0.0], 0.6, 24, 12, red));
    s.camera = Camera {
        position: [0.0, 2.5, 4.5],
        target: [0.0, 0.4, 0.0],
        up: [0.0, 1.0, 0.0],
        fov_y_deg: 45.0,
        width: WIDTH,
        height: HEIGHT,
    };
    s.quality.shadow_map_size = MAP_SIZE;
    s.quality.map_sizing = lightfold_scene::MapSizing::Fixed;
    s
}

/// `n` cosine-lobe samples of a small square emitter above the ball, facing down.
pub fn calibration_lights(n: usize) -> Vec<LightSample> {
    let side = (n as f32).sqrt().ceil() as usize;
    (0..n)
        .map(|i| {
            let (x, z) = ((i % side) as f32, (i / side) as f32);
            LightSample {
                position: [-0.5 + x * 0.3, 3.0, -0.5 + z * 0.3],
                direction: [0.0, -1.0, 0.0],
                kind: SampleKind::CosineLobe,
                intensity: 4.0 / n as f32,
                color: [1.0, 1.0, 1.0],
                range: None,
                light: 0,
                area: None,
                cell: 0.0,
            }
        })
        .collect()
}

/// The calibration from the fastest frame with one light (`t1`, µs) and with `many` (`tk`): the
/// difference per extra light, and the rest as the fixed cost. When `many` lights took no longer
/// than one (noise: nodes calibrating at once on a loaded machine), the cost per light is taken
/// as a fifth of the frame (the default model's 12 ms per light to 60 ms per frame), not as
/// nothing: a cost per light of zero made a frame budget put every light on one node.
pub fn from_times(t1: u64, tk: u64, many: u64) -> Calibration {
    let per_light = if tk > t1 && many > 1 {
        (tk - t1) / (many - 1)
    } else {
        t1 / 5
    };
    Calibration {
        cost_per_light_us: per_light.max(1),
        fixed_cost_us: t1.saturating_sub(per_light).max(1),
        eye_ns_per_triangle: 0,
    }
}

/// Longest a node waits for other nodes on its machine's CPU to finish calibrating. A node
/// authenticates peers while it calibrates and registers once it has, so a coordinator waits for
/// it under its register deadline (10 s by default, `--connect-timeout`) and, once another
/// daemon has registered, 15 s after the latest one: a node that waited this long calibrates
/// beside the others rather than miss either. About thirteen nodes of a local cluster calibrate
/// alone within it (about 0.6 s each on 2 cores with lavapipe).
const LOCK_WAIT: std::time::Duration = std::time::Duration::from_secs(8);

/// Nodes rendering on one machine's CPU calibrate one at a time, so each measures the cores
/// alone: the planner adds up the frames of nodes sharing a machine's CPU
/// (`Capabilities::cpu_host`), and figures measured while the others calibrate would count the
/// sharing twice. The lock is an abstract Unix socket name (Linux): held while bound, gone with
/// the process that bound it, no file left anywhere; in-process nodes take it too. Its reach is
/// one network namespace (nodes in separate namespaces or containers calibrate as they come).
/// `None` (calibrate anyway) when it cannot be bound, or is still held after `LOCK_WAIT`.
fn cpu_lock() -> Option<std::os::unix::net::UnixListener> {
    use std::os::linux::net::SocketAddrExt;
    let name = std::os::unix::net::SocketAddr::from_abstract_name(b"lightfold/calibration").ok()?;
    let deadline = Instant::now() + LOCK_WAIT;
    loop {
        match std::os::unix::net::UnixListener::bind_addr(&name) {
            Ok(held) => return Some(held),
            Err(e) if e.kind() == std::io::ErrorKind::AddrInUse && Instant::now() < deadline => {
                std::thread::sleep(std::time::Duration::from_millis(20));
            }
            Err(e) => {
                tracing::info!(
                    "calibrating while other nodes on this machine may be too ({e}): the \
                     figures may count them"
                );
                return None;
            }
        }
    }
}

/// Measures this device. Shadow maps are recomputed every frame (moving-light cost). A software
/// rasteriser (`on_cpu`) calibrates with the machine's other such nodes held off.
pub fn run(gpu: &Gpu, on_cpu: bool) -> Result<Calibration, RenderError> {
    let _alone = if on_cpu { cpu_lock() } else { None };
    let start = Instant::now();
    // The calibration scene with a dense ball in the small one's place (mesh 2), which only the
    // eye-cost frames draw, in the eye pass alone: every frame's shadows come from the floor and
    // the small ball (meshes 0 and 1).
    let mut scene = calibration_scene();
    let red = scene.meshes[1].material;
    let small = scene.meshes[1].triangle_count() as u64;
    scene.add_mesh(sphere(
        "dense ball",
        [0.0, 0.6, 0.0],
        0.6,
        DENSE_SEGMENTS,
        DENSE_SEGMENTS / 2,
        red,
    ));
    let dense = scene.meshes[2].triangle_count() as u64;
    let options = RenderOptions::default().fixed_maps(MAP_SIZE);
    let mut renderer = Renderer::new(gpu, &scene, options)?;
    renderer.set_camera(&scene.camera);
    let layers = LayerSet::illumination();
    let few = calibration_lights(1);
    let many = calibration_lights(MANY);
    let mut time = |lights: &[LightSample], ball: u32| -> Result<u64, RenderError> {
        renderer.set_eye_meshes(Some(vec![0, ball]));
        let casters = vec![vec![0, 1]; lights.len()];
        let t = Instant::now();
        renderer.render(gpu, lights, Some(&casters), [1.0; 3], layers)?;
        Ok(t.elapsed().as_micros() as u64)
    };
    // The first renders compile shaders: not part of any frame's cost.
    time(&many, 1)?;
    time(&few, 2)?;
    let (mut t1, mut tk, mut td) = (u64::MAX, u64::MAX, u64::MAX);
    for _ in 0..REPEATS {
        t1 = t1.min(time(&few, 1)?);
        tk = tk.min(time(&many, 1)?);
        td = td.min(time(&few, 2)?);
    }
    let c = Calibration {
        eye_ns_per_triangle: eye_ns_per_triangle(t1, td, dense.saturating_sub(small)),
        ..from_times(t1, tk, MANY as u64)
    };
    if tk <= t1 {
        tracing::info!(
            one_light_us = t1,
            many_lights_us = tk,
            "calibration could not tell {MANY} lights from one (a loaded machine?): cost per \
             light taken as a fifth of the one-light frame"
        );
    }
    tracing::info!(
        per_light_us = c.cost_per_light_us,
        fixed_us = c.fixed_cost_us,
        eye_ns_per_triangle = c.eye_ns_per_triangle,
        ms = start.elapsed().as_millis() as u64,
        "calibrated"
    );
    Ok(c)
}

#[cfg(test)]
mod tests {
    use super::{eye_ns_per_triangle, from_times};

    #[test]
    fn the_eye_cost_per_triangle_is_the_difference_or_unknown() {
        assert_eq!(eye_ns_per_triangle(10_000, 14_000, 40_000), 100);
        assert_eq!(eye_ns_per_triangle(10_000, 9_000, 40_000), 0);
        assert_eq!(eye_ns_per_triangle(10_000, 14_000, 0), 0);
    }

    #[test]
    fn the_cost_per_light_is_the_difference_or_a_fifth_of_the_frame_never_zero() {
        let c = from_times(20_000, 48_000, 8);
        assert_eq!((c.cost_per_light_us, c.fixed_cost_us), (4_000, 16_000));
        // Noise: eight lights no slower than one.
        for tk in [20_000, 19_000, 0] {
            let c = from_times(20_000, tk, 8);
            assert_eq!(
                (c.cost_per_light_us, c.fixed_cost_us),
                (4_000, 16_000),
                "{tk}"
            );
        }
        let c = from_times(0, 0, 8);
        assert!(c.cost_per_light_us >= 1 && c.fixed_cost_us >= 1);
    }
}
