//! The cell filter (`ShadowFilter::Cell`: each area-light sample's shadow spread over the shadow
//! its cell of the light casts, the kernel from the blockers' and the receiver's distances)
//! against the area-light truth (`lightfold-reference`, its own sampling of the lights, no
//! renderer code): it brings a few samples' penumbra close to the area light's where one radius
//! per frame of the screen-space filter cannot, and loses nothing over the whole image.

use lightfold_node::gpu::{Gpu, GpuOptions};
use lightfold_quality::accuracy::{Setting, TruthOptions, load_or_render_truth, measure_group};
use lightfold_scene::{Scene, ShadowFilter};

/// Penumbra and whole-image PSNR (dB) of `scene` at `samples` per area light with `filter` and
/// the screen-space filter at `radius` (0: none).
fn psnr(
    gpu: &Gpu,
    scene: &Scene,
    truth: &lightfold_reference::GroundTruth,
    samples: u32,
    filter: ShadowFilter,
    radius: u32,
) -> anyhow::Result<(f64, f64)> {
    let setting = Setting {
        samples,
        filter,
        penumbra: radius,
        ..Setting::defaults(scene)
    };
    let image = measure_group(gpu, scene, &[setting], 1)?.remove(0).image;
    let e = truth.compare(&image)?;
    Ok((
        e.penumbra.expect("the scene has a penumbra").psnr,
        e.whole.psnr,
    ))
}

#[test]
fn cell_filtered_samples_approach_the_area_light_where_one_screen_radius_cannot()
-> anyhow::Result<()> {
    // balls at 200×150: two area lights, spheres resting on the floor (contact shadows a few
    // pixels wide beside penumbrae tens of pixels wide).
    let mut scene = lightfold_scene::load("balls")?;
    (scene.camera.width, scene.camera.height) = (200, 150);
    let dir = tempfile::tempdir()?;
    let truth = load_or_render_truth(
        &scene,
        &TruthOptions {
            samples_per_light: 512,
            cache_dir: Some(dir.path().to_path_buf()),
        },
    )?
    .truth;
    let gpu = Gpu::new(&GpuOptions::default())?;
    let cell = ShadowFilter::Cell {
        taps: lightfold_scene::defaults::CELL_TAPS,
    };
    for n in [4, 16] {
        let (plain, plain_whole) = psnr(&gpu, &scene, &truth, n, ShadowFilter::Pcf2x2, 0)?;
        let (smooth, smooth_whole) = psnr(&gpu, &scene, &truth, n, cell, 0)?;
        let screen: Vec<f64> = [1, 2]
            .into_iter()
            .map(|r| psnr(&gpu, &scene, &truth, n, ShadowFilter::Pcf2x2, r).map(|p| p.0))
            .collect::<anyhow::Result<_>>()?;
        let best_screen = screen.iter().copied().fold(f64::MIN, f64::max);
        eprintln!(
            "{n} samples: PCF 2×2 {plain:.2} dB (whole {plain_whole:.2}), cell {smooth:.2} dB \
             (whole {smooth_whole:.2}), screen radius 1, 2: {screen:.2?}"
        );
        // Each sample's shadow over its cell: at least 4 dB closer to the area light than the
        // point samples (measured +8.9 and +8.8 dB at 400×300) …
        assert!(smooth >= plain + 4.0, "{n}: cell {smooth} vs {plain}");
        // … and 2 dB more than the best single screen radius (+3.9 and +5.1 there), …
        assert!(
            smooth >= best_screen + 2.0,
            "{n}: cell {smooth} vs screen {screen:?}"
        );
        // … with the whole image no worse (the filter works in the maps, so creases and
        // contact shadows keep their edges).
        assert!(
            smooth_whole >= plain_whole,
            "{n}: whole {smooth_whole} vs {plain_whole}"
        );
    }
    Ok(())
}
