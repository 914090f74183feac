//! Issue 46: the Cornell box's camera on the room's axis puts the floor–wall junctions through a
//! whole diagonal of pixel centres. Whichever surface such a pixel shows is a tie: the rasteriser
//! shows the floor, the ray-traced truth the wall, and those few pixels alone held the box's
//! penumbra PSNR at about 43 dB whatever the samples or maps. The truth leaves them out
//! (`masks::ties`); counted as before they are the control.

use lightfold_node::gpu::{Gpu, GpuOptions};
use lightfold_quality::accuracy::{Setting, TruthOptions, load_or_render_truth, measure_group};
use lightfold_reference::masks::penumbra_mask;
use lightfold_reference::metrics::compare;

#[test]
fn cornell_converges_to_its_truth_once_ties_are_left_out() -> anyhow::Result<()> {
    let mut scene = lightfold_scene::load("cornell")?;
    // The calibration's size: there the ties' truth is partly shadowed (the shadow rays of a
    // point on the junction graze the other plane), so they also fall in the penumbra mask.
    scene.camera.width = 400;
    scene.camera.height = 300;
    let truth = load_or_render_truth(
        &scene,
        &TruthOptions {
            samples_per_light: 256,
            cache_dir: None,
        },
    )?;
    let t = &truth.truth;
    assert!(
        t.tie_pixels() > 0,
        "the junctions run through pixel centres"
    );
    let gpu = Gpu::new(&GpuOptions::default())?;
    let setting = Setting {
        samples: 64,
        ..Setting::defaults(&scene)
    };
    let image = measure_group(&gpu, &scene, &[setting], 1)?.remove(0).image;
    let now = t.compare(&image)?;
    let pen = now.penumbra.expect("a penumbra").psnr;
    // The control: the same image against the same truth with the ties counted.
    let with_ties = penumbra_mask(&t.radiance, &t.unoccluded, &t.depth, &t.coverage);
    let before = compare(&image, &t.radiance, t.exposure, Some(&with_ties))?;
    let pen_before = before.penumbra.expect("a penumbra").psnr;
    eprintln!(
        "cornell 400×300, 64 samples: penumbra {pen:.2} dB (ties counted: {pen_before:.2} dB), \
         whole {:.2} dB ({:.2} dB), {} ties, truth floor {:.2} dB",
        now.whole.psnr,
        before.whole.psnr,
        t.tie_pixels(),
        truth.floor.penumbra.map_or(f64::NAN, |p| p.psnr)
    );
    assert!(pen >= 50.0, "penumbra {pen:.2} dB");
    assert!(
        now.whole.psnr >= 60.0,
        "whole image {:.2} dB",
        now.whole.psnr
    );
    assert!(
        pen_before < 45.0,
        "the control: penumbra {pen_before:.2} dB"
    );
    assert!(
        before.whole.psnr < 55.0,
        "the control: whole image {:.2} dB",
        before.whole.psnr
    );
    Ok(())
}
