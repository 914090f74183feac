//! Soft suns (a directional light with an angle) and tube lights (cylinders) on the GPU, each
//! against a truth that shares no code with the sampler.
//!
//! - **Soft sun.** A sun straight overhead, 10° across, over the edge of a wide thin slab 1 m up:
//!   the floor's lit fraction across the edge is the fraction of the sun's disk (weighted by
//!   cos θ) that the edge leaves visible, integrated here in closed form over φ and by
//!   quadrature over θ. The single-device frame (64 parallel lights) follows it within a few
//!   percent; the parallel sun (the control) casts a hard edge that does not. A surface facing
//!   the sun gets the same irradiance from the soft sun as from the parallel one.
//! - **Tube.** A cylinder light over a floor with a box: the CPU area truth (fresh points on the
//!   tube's side per pixel) equals the test's own quadrature of `L·cos θs·cos θr / d²` over the
//!   side at an unshadowed floor point, and the GPU frame equals that truth; the same frame
//!   against the truth of the tube turned a quarter (the control) does not.
//! - **Cluster.** Both lights through the in-process cluster equal the single-device render.

use lightfold_coordinator::plan::MapSizing;
use lightfold_coordinator::run::RunOptions;
use lightfold_harness::{
    InProcessCluster, assert_close, gpu, render_on, single_device, test_control,
};
use lightfold_reference::{AreaOptions, Tracer, compare, radiance_area};
use lightfold_scene::{Light, LightShape, Material, Scene, primitives};
use std::f64::consts::TAU;

/// Height of the slab's top and bottom faces; its edge is the plane x = 0.
const SLAB: (f64, f64) = (1.005, 0.995);
const ALBEDO: f32 = 0.8;

fn floor_scene(name: &str, width: u32, height: u32) -> Scene {
    let mut s = Scene::new(name);
    let white = s.add_material(Material::diffuse("floor", [ALBEDO; 3]));
    s.add_mesh(primitives::plane(
        "floor",
        [0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [8.0, 8.0],
        1,
        white,
    ));
    s.camera.width = width;
    s.camera.height = height;
    s.quality.samples_per_area_light = None;
    s
}

/// The sun overhead (`angle` degrees across, `samples` parallel lights) over a slab covering
/// x < 0 at 1 m; the camera under the slab looks at the floor across the edge.
fn sun_scene(angle_deg: f32, samples: u32) -> Scene {
    let mut s = floor_scene("soft sun", 160, 120);
    let grey = s.add_material(Material::diffuse("slab", [0.5; 3]));
    s.add_mesh(primitives::cuboid(
        "slab",
        [-2.0, 1.0, 0.0],
        [2.0, 0.005, 4.0],
        grey,
    ));
    s.lights = vec![Light {
        name: "sun".into(),
        shape: LightShape::Directional {
            direction: [0.0, -1.0, 0.0],
            angle: angle_deg.to_radians(),
        },
        color: [1.0; 3],
        power: 2.0,
        range: None,
        samples,
    }];
    s.camera.position = [0.0, 0.45, 1.2];
    s.camera.target = [0.0, 0.0, 0.0];
    s.camera.up = [0.0, 1.0, 0.0];
    s.camera.fov_y_deg = 30.0;
    s
}

/// The fraction of an overhead sun of half-angle `alpha`, weighted by cos θ, that a floor point
/// at `x` sees past the slab's edge. A direction back to the sun `(sin θ cos φ, cos θ, ·)` is
/// blocked when it is still over x < 0 at the slab's height `h` (the top face beside the slab,
/// the bottom one under it): `sin θ cos φ < −x·cos θ / h`, an arc of φ of length
/// `2π − 2·acos(c)` for `c = −x / (h·tan θ)` in (−1, 1).
fn sun_visible(x: f64, alpha: f64) -> f64 {
    let h = if x >= 0.0 { SLAB.0 } else { SLAB.1 };
    let steps = 4000;
    let (mut seen, mut all) = (0.0, 0.0);
    let lo = alpha.cos();
    for i in 0..steps {
        // Midpoints in cos θ: equal solid angle per step.
        let c = lo + (1.0 - lo) * (i as f64 + 0.5) / steps as f64;
        let t = (1.0 - c * c).sqrt() / c;
        let blocked = if t == 0.0 {
            if x < 0.0 { TAU } else { 0.0 }
        } else {
            let k = -x / (h * t);
            if k <= -1.0 {
                0.0
            } else if k >= 1.0 {
                TAU
            } else {
                TAU - 2.0 * k.acos()
            }
        };
        seen += c * (TAU - blocked);
        all += c * TAU;
    }
    seen / all
}

/// `(x, pixel index)` of the floor pixels within `reach` of the edge, by the CPU tracer's eye
/// rays.
fn floor_pixels(scene: &Scene, reach: f64) -> Vec<(f64, usize)> {
    let tracer = Tracer::new(scene);
    let (w, h) = (scene.camera.width, scene.camera.height);
    let mut out = Vec::new();
    for y in 0..h {
        for x in 0..w {
            if let Some(hit) = tracer.primary(x, y)
                && hit.material == 0
                && hit.position[0].abs() < reach
            {
                out.push((hit.position[0], (y * w + x) as usize));
            }
        }
    }
    out
}

/// `(mean, max)` absolute difference between the frame's lit fraction (red channel over the
/// fully lit floor's `m_d·E`) and the sun's visible fraction.
fn profile_error(scene: &Scene, frame: &lightfold_scene::Image, alpha: f64) -> (f64, f64) {
    let pixels = floor_pixels(scene, 0.3);
    assert!(
        pixels.len() > 2000,
        "{} floor pixels near the edge",
        pixels.len()
    );
    // Outgoing radiance m_d·E/π of the floor under the sun's whole irradiance.
    let full = f64::from(ALBEDO) * 2.0 / std::f64::consts::PI;
    let (mut sum, mut max) = (0.0f64, 0.0f64);
    for &(x, i) in &pixels {
        let got = f64::from(frame.data[i * frame.channels]) / full;
        let d = (got - sun_visible(x, alpha)).abs();
        sum += d;
        max = max.max(d);
    }
    (sum / pixels.len() as f64, max)
}

#[test]
fn a_soft_sun_casts_the_penumbra_of_its_disk() {
    let gpu = gpu();
    let alpha = 5f64.to_radians();
    // The truth's own sanity: half the disk past the edge at x = 0, all of it far beside.
    assert!((sun_visible(0.0, alpha) - 0.5).abs() < 1e-3);
    assert!(sun_visible(0.2, alpha) > 0.999 && sun_visible(-0.2, alpha) < 1e-3);
    let soft = sun_scene(10.0, 64);
    let frame = single_device(&gpu, &soft, false);
    let (mean, max) = profile_error(&soft, &frame, alpha);
    // The parallel sun (the control) at the same power: a hard edge.
    let hard = sun_scene(0.0, 1);
    let hard_frame = single_device(&gpu, &hard, false);
    let (hard_mean, hard_max) = profile_error(&hard, &hard_frame, alpha);
    eprintln!(
        "soft sun 10°, 64 parallel lights: lit fraction off by {mean:.4} mean, {max:.4} max; \
         the parallel sun: {hard_mean:.4} mean, {hard_max:.4} max"
    );
    assert!(
        mean < 0.01 && max < 0.06,
        "soft sun: {mean} mean, {max} max"
    );
    assert!(
        hard_mean > 3.0 * mean && hard_max > 0.3,
        "the control: {hard_mean}, {hard_max}"
    );
    // The parallel sun is wrong only in the penumbra: black under the slab (a sun straight
    // overhead once lit the floor there, its map leaving no room for the receiver's bias).
    assert!(
        hard_mean < 0.15,
        "the parallel sun off by {hard_mean} on average"
    );
    // Far from the edge both give a surface facing them the same irradiance (the soft sun's
    // lights carry 1/(1 − (1 − cos α)/2) of an even share: without it, −0.19 % here).
    let lit: Vec<usize> = floor_pixels(&soft, 1.0)
        .into_iter()
        .filter(|&(x, _)| x > 0.35)
        .map(|(_, i)| i)
        .collect();
    assert!(lit.len() > 100);
    let mean_red = |f: &lightfold_scene::Image| {
        lit.iter()
            .map(|&i| f64::from(f.data[i * f.channels]))
            .sum::<f64>()
            / lit.len() as f64
    };
    let (s, p) = (mean_red(&frame), mean_red(&hard_frame));
    assert!(
        (s / p - 1.0).abs() < 5e-4,
        "lit floor: soft {s}, parallel {p}"
    );
}

/// A tube 2 m long along `axis` 1.2 m over the floor, over a box.
fn tube_scene(axis: [f32; 3]) -> Scene {
    let mut s = floor_scene("tube", 96, 72);
    let red = s.add_material(Material::diffuse("box", [0.7, 0.3, 0.2]));
    s.add_mesh(primitives::cuboid(
        "box",
        [0.3, 0.25, 0.2],
        [0.2, 0.25, 0.2],
        red,
    ));
    s.lights = vec![Light {
        name: "tube".into(),
        shape: LightShape::Cylinder {
            center: [0.0, 1.2, 0.0],
            axis,
            length: 2.0,
            radius: 0.05,
        },
        color: [1.0, 0.9, 0.8],
        power: 3.0,
        range: None,
        samples: 64,
    }];
    s.camera.position = [0.0, 2.2, 3.2];
    s.camera.target = [0.0, 0.2, 0.0];
    s.camera.up = [0.0, 1.0, 0.0];
    s.camera.fov_y_deg = 45.0;
    s
}

/// `∫ L·cos θs·cos θr / d² dA` over the side of the tube of `tube_scene([1, 0, 0])` at floor
/// point `p` (unshadowed), by the midpoint rule.
fn tube_irradiance(p: [f64; 3], radiance: f64) -> f64 {
    let (n_len, n_phi) = (800, 400);
    let (len, r, c) = (2.0, 0.05, [0.0, 1.2, 0.0]);
    let d_a = (len / n_len as f64) * (TAU * r / n_phi as f64);
    let mut sum = 0.0;
    for i in 0..n_len {
        let t = -len / 2.0 + len * (i as f64 + 0.5) / n_len as f64;
        for j in 0..n_phi {
            let phi = TAU * (j as f64 + 0.5) / n_phi as f64;
            let n = [0.0, phi.cos(), phi.sin()];
            let q = [c[0] + t, c[1] + r * n[1], c[2] + r * n[2]];
            let d = [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
            let d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
            let dist = d2.sqrt();
            let cos_s = (n[0] * d[0] + n[1] * d[1] + n[2] * d[2]) / dist;
            let cos_r = -d[1] / dist;
            if cos_s > 0.0 && cos_r > 0.0 {
                sum += radiance * cos_s * cos_r / d2 * d_a;
            }
        }
    }
    sum
}

#[test]
fn a_tube_light_equals_its_area_truth() {
    let gpu = gpu();
    let scene = tube_scene([1.0, 0.0, 0.0]);
    let opts = AreaOptions {
        samples_per_light: 256,
        ..AreaOptions::default()
    };
    let truth = radiance_area(&scene, &opts);
    // The truth against the quadrature at unshadowed floor pixels left of the box.
    let tracer = Tracer::new(&scene);
    let (mut checked, mut bias) = (0u32, 0.0);
    for y in (0..scene.camera.height).step_by(6) {
        for x in (0..scene.camera.width / 3).step_by(6) {
            let Some(hit) = tracer.primary(x, y) else {
                continue;
            };
            if hit.material != 0 {
                continue;
            }
            let want =
                f64::from(ALBEDO) * tube_irradiance(hit.position, 3.0) / std::f64::consts::PI;
            let i = (y * scene.camera.width + x) as usize * truth.channels;
            let off = f64::from(truth.data[i]) / want - 1.0;
            // One pixel's truth is an estimate (256 points, half of them on the far side).
            assert!(
                off.abs() < 0.1,
                "truth at {:?}: {off:+.3} off",
                hit.position
            );
            bias += off;
            checked += 1;
        }
    }
    assert!(checked > 20, "{checked} floor points checked");
    let bias = bias / f64::from(checked);
    assert!(
        bias.abs() < 0.01,
        "the truth is {bias:+.4} off the quadrature on average"
    );
    let frame = single_device(&gpu, &scene, false);
    let m = compare(&frame, &truth, scene.exposure, None).unwrap();
    let turned = radiance_area(&tube_scene([0.0, 0.0, 1.0]), &opts);
    let control = compare(&frame, &turned, scene.exposure, None).unwrap();
    eprintln!(
        "tube, 64 samples against its 256-point truth: {:.2} dB (the tube turned: {:.2} dB), \
         the truth {bias:+.4} off the quadrature over {checked} floor points",
        m.whole.psnr, control.whole.psnr
    );
    assert!(m.whole.psnr > 40.0, "PSNR {}", m.whole.psnr);
    assert!(
        control.whole.psnr < m.whole.psnr - 10.0,
        "control {}",
        control.whole.psnr
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn soft_suns_and_tubes_through_the_cluster_equal_the_single_device_render() {
    let gpu = gpu();
    let mut scene = tube_scene([1.0, 0.0, 0.3]);
    scene.lights[0].samples = 8;
    scene.lights.push(sun_scene(6.0, 8).lights.remove(0));
    let LightShape::Directional { direction, .. } = &mut scene.lights[1].shape else {
        unreachable!()
    };
    *direction = [0.3, -1.0, -0.2];
    let want = single_device(&gpu, &scene, false);
    let cluster = InProcessCluster::start(3, 3).await.unwrap();
    let mut session = cluster.connect(test_control()).await.unwrap();
    let mut opts = RunOptions {
        control: test_control(),
        ..RunOptions::default()
    };
    opts.plan.lights_per_node = 4;
    opts.plan.map_sizing = MapSizing::Fixed(scene.quality.shadow_map_size);
    let out = render_on(&mut session, &scene, &opts).await.unwrap();
    assert_eq!(
        out.plan.samples.len(),
        16,
        "8 points of the tube, 8 of the sun"
    );
    assert_close(
        &out.frames[0].image,
        &want,
        "soft sun and tube through the cluster",
    );
}
