//! Peeled translucency through the cluster (`docs/translucency.md` § Peeled layers): three
//! staggered glass panes (`scenes/glass-stack.toml`, small) planned with `--peels auto`, so one
//! opaque and three translucent eye layers, each a node rendering every sample, shaded at the
//! stages and blended back to front.
//!
//! - The frame equals the same layers rendered on one device and blended on the CPU, within the
//!   link formats' bound.
//! - Against the CPU reference that sees every layer (`radiance_peeled`), over the pixels where
//!   glass is in view: nearer than the classic image (glass only tints: its own reflection and
//!   highlights missing) and nearer than one peeled layer (the panes behind the first dropped,
//!   their tint too) — both kept as negative controls, each must be measurably worse.

use lightfold_coordinator::plan::{MapSizing, Peels};
use lightfold_coordinator::run::RunOptions;
use lightfold_harness::{
    InProcessCluster, assert_close, gpu, render_on, single_device, single_device_peeled,
    small_glass_stack, test_control,
};
use lightfold_protocol::OpSpec;
use lightfold_reference::metrics::compare_over;
use lightfold_reference::radiance_peeled;
use lightfold_scene::trace::Tracer;
use lightfold_scene::{Image, Scene};

/// Whole-image PSNR of `test` against `reference` over the pixels of `mask`.
fn psnr_over(scene: &Scene, test: &Image, reference: &Image, mask: &[bool]) -> f64 {
    compare_over(test, reference, scene.exposure, Some(mask), None)
        .unwrap()
        .whole
        .psnr
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn peeled_glass_through_the_cluster_equals_its_layers_and_nears_the_reference() {
    let gpu = gpu();
    let scene = small_glass_stack();
    // Four eye layers × one light group (4 samples at K = 4): four nodes.
    let cluster = InProcessCluster::start(4, 2).await.unwrap();
    let mut session = cluster.connect(test_control()).await.unwrap();
    let mut opts = RunOptions {
        control: test_control(),
        ..RunOptions::default()
    };
    opts.plan.lights_per_node = 4;
    opts.plan.peels = Peels::Auto;
    opts.plan.map_sizing = MapSizing::Fixed(scene.quality.shadow_map_size);
    let out = render_on(&mut session, &scene, &opts).await.unwrap();
    let plan = &out.plan;
    let layers = plan.peels.as_ref().map(|c| c.layers);
    assert_eq!(layers, Some(3), "{plan}");
    assert!(
        plan.stages
            .iter()
            .flat_map(|s| &s.ops)
            .any(|o| matches!(o, OpSpec::Blend(_))),
        "{plan}"
    );
    let got = out.frames[0].image.clone();
    session.detach();
    cluster.stop().await.unwrap();

    let want = single_device_peeled(&gpu, &scene, 3);
    assert_close(&got, &want, "peeled glass through the cluster");

    // Where glass is in view, and where two or more panes are.
    let tracer = Tracer::new(&scene);
    let (w, h) = (scene.camera.width, scene.camera.height);
    let count = |x: u32, y: u32| tracer.translucent_count(x as f32 + 0.5, y as f32 + 0.5, 8);
    let counts: Vec<usize> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| count(x, y))
        .collect();
    let glass: Vec<bool> = counts.iter().map(|&c| c >= 1).collect();
    let stacked: Vec<bool> = counts.iter().map(|&c| c >= 2).collect();
    let (n_glass, n_stacked) = (
        glass.iter().filter(|g| **g).count(),
        stacked.iter().filter(|g| **g).count(),
    );
    assert!(
        n_glass > 1000 && n_stacked > 300,
        "{n_glass} glass pixels, {n_stacked} behind two panes or more"
    );
    let samples = lightfold_scene::vpl::frame_samples(&scene);
    let reference = radiance_peeled(&scene, &samples, 8);
    let classic = single_device(&gpu, &scene, false);
    let one = single_device_peeled(&gpu, &scene, 1);
    let peeled_db = psnr_over(&scene, &got, &reference, &glass);
    let classic_db = psnr_over(&scene, &classic, &reference, &glass);
    let one_db = psnr_over(&scene, &one, &reference, &stacked);
    let peeled_stacked_db = psnr_over(&scene, &got, &reference, &stacked);
    eprintln!(
        "glass pixels ({n_glass}): peeled {peeled_db:.2} dB, classic {classic_db:.2} dB; \
         behind two panes or more ({n_stacked}): peeled {peeled_stacked_db:.2} dB, one layer \
         {one_db:.2} dB"
    );
    assert!(peeled_db > 35.0, "peeled: {peeled_db:.2} dB");
    assert!(
        peeled_db > classic_db + 6.0,
        "the classic image (glass only tints) must be measurably worse: {classic_db:.2} dB \
         against {peeled_db:.2} dB"
    );
    assert!(
        peeled_stacked_db > one_db + 6.0,
        "one peeled layer must be measurably worse behind two panes: {one_db:.2} dB against \
         {peeled_stacked_db:.2} dB"
    );
}
