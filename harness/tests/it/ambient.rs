//! A global ambient `c^a` over materials that mix `m^a = m^d` and `m^a = 0` (the paper's eq. 2
//! ambient term), on the GPU and through the cluster.
//!
//! - **GPU against the CPU.** With every light off, a frame is the ambient term alone,
//!   `c^a ⊙ m^a` of the visible surface: the single-device GPU render equals the CPU reference's
//!   (no shadow maps involved), and is black where `m^a = 0`.
//! - **Cluster against the GPU.** The planner folds `c^a` by eq. 7: the folding node sends the
//!   per-pixel mask `I^a` and no ambient layer travels. The lit scene through the in-process
//!   cluster equals the single-device render within the link formats' bound; the same scene
//!   without its ambient (a control) does not, nor does the scene with `m^a = m^d` everywhere
//!   (the control that the mask, not `I^a = 1`, reached the image).

use lightfold_coordinator::plan::{MapSizing, Plan};
use lightfold_coordinator::run::RunOptions;
use lightfold_harness::{
    InProcessCluster, assert_close, gpu, render_on, single_device, small, test_control,
};
use lightfold_protocol::{Layer, PixelFormat};
use lightfold_reference::{compare, render_point_sum};
use lightfold_scene::{Image, Scene};

/// `balls` small, under `c^a = (0.3, 0.25, 0.2)`, every other material with `m^a = m^d` and
/// the rest with `m^a = 0`.
fn mixed_ambient() -> Scene {
    let mut s = small("balls");
    s.ambient = [0.3, 0.25, 0.2];
    for (i, m) in s.materials.iter_mut().enumerate() {
        m.ambient = if i % 2 == 0 { m.diffuse } else { [0.0; 3] };
    }
    s
}

#[test]
fn the_ambient_term_on_the_gpu_equals_the_cpu_reference() {
    let gpu = gpu();
    let mut dark = mixed_ambient();
    for l in &mut dark.lights {
        l.power = 0.0;
    }
    let got = single_device(&gpu, &dark, false);
    let want = render_point_sum(&dark, &[], [1.0; 3]).radiance([1.0; 3], dark.ambient);
    let lit = want.data.iter().filter(|v| **v > 1e-3).count();
    let black = want.data.iter().filter(|v| **v == 0.0).count();
    assert!(
        lit > 500 && black > 500,
        "both kinds of material seen: {lit} lit, {black} black"
    );
    let m = compare(&got, &want, dark.exposure, None).unwrap();
    eprintln!(
        "ambient alone, GPU against CPU: PSNR {:.2} dB, energy bias {:+.5}",
        m.whole.psnr, m.whole.energy_bias
    );
    assert!(m.whole.psnr > 45.0, "PSNR {}", m.whole.psnr);
    assert!(m.whole.energy_bias.abs() < 0.01, "{}", m.whole.energy_bias);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn mixed_ambient_through_the_cluster_equals_the_single_device_render() {
    let gpu = gpu();
    let scene = mixed_ambient();
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
    let got = &out.frames[0].image;
    let plan = &out.plan;
    let link_bytes = |p: &Plan| p.links.iter().map(|l| l.bytes_per_frame).sum::<u64>();
    eprintln!(
        "mixed ambient: the plan's material layers {:?}, ambient mask {:?}, {} link bytes per frame",
        plan.material.layers,
        plan.material.ambient_mask,
        link_bytes(plan)
    );
    // Eq. 7: no ambient layer; the folding node sends I^a in 8-bit sRGB.
    assert!(plan.material.fold_ambient, "{plan}");
    assert!(
        !plan.material.layers.iter().any(|l| l.0 == Layer::Ambient),
        "{plan}"
    );
    assert_eq!(plan.material.ambient_mask, Some(PixelFormat::Rgba8Srgb));
    let masks = plan
        .nodes
        .iter()
        .filter(|n| n.layers.iter().any(|l| l.0 == Layer::AmbientMask))
        .count();
    assert_eq!(masks, 1, "{plan}");
    assert_close(got, &want, "mixed ambient through the cluster");
    // The control: the same scene without its ambient differs.
    let unlit = Scene {
        ambient: [0.0; 3],
        ..scene.clone()
    };
    let without = single_device(&gpu, &unlit, false);
    let differs = channels_apart(got, &without);
    assert!(differs > 500, "the ambient changed only {differs} channels");
    // The control that the mask reached the image: with I^a = 1 everywhere (every material's
    // m^a = m^d) the m^a = 0 materials would take c^a too.
    let mut uniform = scene.clone();
    for m in &mut uniform.materials {
        m.ambient = m.diffuse;
    }
    let unmasked = single_device(&gpu, &uniform, false);
    let differs = channels_apart(got, &unmasked);
    assert!(
        differs > 500,
        "I^a = 1 changed only {differs} channels: the mask did not reach the image"
    );
    session.detach();
    cluster.stop().await.unwrap();
}

/// Channels of `a` and `b` more than 0.01 apart.
fn channels_apart(a: &Image, b: &Image) -> usize {
    a.data
        .iter()
        .zip(&b.data)
        .filter(|(x, y)| (*x - *y).abs() > 0.01)
        .count()
}
