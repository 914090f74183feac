//! The point-sample sum approaches the area-light truth as the number of samples grows, and the
//! truth's own noise floor sits well below the point-sum error.

use crate::common;

use common::*;
use lightfold_reference::{AreaOptions, GroundTruth, radiance_point_sum, split_error, truth};
use lightfold_scene::sampling::direct_samples;
use lightfold_scene::{Material, Scene};

/// A box floating over the ground under a 1 m² light: a wide penumbra on the ground. The box is
/// turned by `yaw` about the vertical: edges parallel to the light's sample rows make every row
/// of the grid switch at once (the worst case for a grid).
fn penumbra_scene(yaw: f32) -> Scene {
    let cam = camera(
        [0.0, 3.0, 3.5],
        [0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        45.0,
        64,
        48,
    );
    let mut block = occluder([0.0, 0.8, 0.0], [0.35, 0.1, 0.35], 1);
    let (s, c) = yaw.to_radians().sin_cos();
    for p in block.positions.iter_mut().chain(block.normals.iter_mut()) {
        *p = [c * p[0] + s * p[2], p[1], -s * p[0] + c * p[2]];
    }
    scene(
        vec![ground(0), block],
        vec![
            Material::diffuse("ground", [0.8; 3]),
            Material::diffuse("box", [0.6, 0.4, 0.3]),
        ],
        vec![rect_light([0.2, 2.2, -0.1], [1.0, 1.0], 4.0, 16)],
        cam,
    )
}

#[test]
fn point_sum_converges_to_area_truth_in_the_penumbra() {
    let aligned = convergence(0.0);
    let turned = convergence(30.0);
    assert!(
        aligned > -0.65,
        "aligned edges converge about as N^-0.5: N^{aligned:.2}"
    );
    assert!(
        turned < -0.65,
        "turned edges converge faster: N^{turned:.2}"
    );
}

/// Penumbra RMSE of the grid point sum against the truth for N = 4, 16, 64; asserts it falls
/// monotonically and returns the fitted exponent.
fn convergence(yaw: f32) -> f64 {
    let mut s = penumbra_scene(yaw);
    let truth = GroundTruth::render(
        &s,
        &AreaOptions {
            samples_per_light: 1024,
            seed: 1,
            shadows: true,
        },
    );
    assert!(
        truth.penumbra_pixels() > 100,
        "penumbra pixels: {}",
        truth.penumbra_pixels()
    );
    let mut rmse = Vec::new();
    for n in [4u32, 16, 64] {
        s.quality.samples_per_area_light = Some(n);
        let img = radiance_point_sum(&s, &direct_samples(&s));
        let m = truth.compare(&img).unwrap();
        let pen = m.penumbra.unwrap();
        eprintln!("yaw {yaw}, N = {n:>2}: penumbra {pen}");
        rmse.push((f64::from(n), pen.rmse));
    }
    for w in rmse.windows(2) {
        assert!(w[1].1 < w[0].1, "penumbra RMSE must fall with N: {rmse:?}");
    }
    // Least-squares slope of log RMSE against log N.
    let k = rmse.len() as f64;
    let (sx, sy) = rmse
        .iter()
        .fold((0.0, 0.0), |a, &(n, e)| (a.0 + n.ln(), a.1 + e.ln()));
    let (sxx, sxy) = rmse.iter().fold((0.0, 0.0), |a, &(n, e)| {
        (a.0 + n.ln() * n.ln(), a.1 + n.ln() * e.ln())
    });
    let slope = (k * sxy - sx * sy) / (k * sxx - sx * sx);
    eprintln!("yaw {yaw}: fitted penumbra RMSE ∝ N^{slope:.2}");

    let floor = truth::noise_floor_of(&s, &truth);
    eprintln!("noise floor (1024 spp): {floor}");
    assert!(
        floor.penumbra.unwrap().rmse < 0.5 * rmse[2].1,
        "the truth is not noisier than N = 64"
    );
    slope
}

#[test]
fn noise_floor_falls_with_samples_and_error_split_adds_up() {
    let mut s = penumbra_scene(30.0);
    s.camera.width = 32;
    s.camera.height = 24;
    let coarse = truth::noise_floor(&s, 16);
    let fine = truth::noise_floor(&s, 256);
    assert!(coarse.whole.rmse > 0.0 && fine.whole.rmse > 0.0);
    assert!(
        fine.whole.rmse < 0.5 * coarse.whole.rmse,
        "{coarse} vs {fine}"
    );
    assert!(fine.within_floor(&fine) && !coarse.within_floor(&Metrics0::scaled(&fine, 0.01)));

    let truth = GroundTruth::render(
        &s,
        &AreaOptions {
            samples_per_light: 64,
            ..Default::default()
        },
    );
    s.quality.samples_per_area_light = Some(16);
    let point_sum = radiance_point_sum(&s, &direct_samples(&s));
    // A "GPU" image: the point sum with a uniform 1 % gain error.
    let mut gpu = point_sum.clone();
    gpu.data.iter_mut().for_each(|v| *v *= 1.01);
    let split = split_error(&gpu, &point_sum, &truth).unwrap();
    assert!((split.shadow_map.whole.energy_bias - 0.01).abs() < 1e-6);
    assert_eq!(split.light_sampling, truth.compare(&point_sum).unwrap());
    assert_eq!(split.total, truth.compare(&gpu).unwrap());
}

/// Builds a floor with every RMSE scaled, to test `within_floor` against a tiny floor.
struct Metrics0;
impl Metrics0 {
    fn scaled(m: &lightfold_reference::Metrics, f: f64) -> lightfold_reference::Metrics {
        let mut m = *m;
        m.whole.rmse *= f;
        if let Some(p) = &mut m.penumbra {
            p.rmse *= f;
        }
        m
    }
}
