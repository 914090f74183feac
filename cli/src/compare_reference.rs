//! The error summary of a cluster image: compared with the CPU reference's exact sum over the same
//! point samples (ray-traced shadows), so what remains is shadow-map and link-precision error.

use anyhow::Context;
use lightfold_reference::masks::{penumbra_mask, ties};
use lightfold_reference::metrics::compare_over;
use lightfold_reference::point_sum::{PointSumOptions, render_point_sum_with};
use lightfold_scene::{Image, LightSample, Scene};
use lightfold_telemetry::outln;
use std::path::Path;
use std::time::Instant;

/// Renders the reference for `scene` and prints the metrics of the image in `exr` against it.
/// With `aa` > 1 (the image's `--aa`) the reference is traced with `aa × aa` rays per pixel and
/// resolved the same way (radiance box-filtered, depth nearest; coverage where a block has any).
/// `which` names the point samples `samples` are (`the same 32 point samples`, or what they
/// differ by).
pub(crate) fn report(
    scene: &Scene,
    samples: &[LightSample],
    which: &str,
    exr: &Path,
    aa: u32,
) -> anyhow::Result<()> {
    let test = Image::read_exr(exr).with_context(|| format!("cannot read {}", exr.display()))?;
    let t = Instant::now();
    let mut scene = scene.clone();
    scene.camera = scene.camera.supersampled(aa)?;
    let shadowed =
        render_point_sum_with(&scene, samples, [1.0; 3], PointSumOptions { shadows: true });
    let open = render_point_sum_with(
        &scene,
        samples,
        [1.0; 3],
        PointSumOptions { shadows: false },
    );
    let reference = shadowed.radiance([1.0; 3], scene.ambient).box_resolve(aa)?;
    let unoccluded = open.radiance([1.0; 3], scene.ambient).box_resolve(aa)?;
    let depth = shadowed.depth.nearest_depth_resolve(aa)?;
    let coverage: Vec<bool> = if aa > 1 {
        depth.data.iter().map(|&z| z > 0.0).collect()
    } else {
        shadowed.coverage
    };
    // One ray a pixel: pixel centres on a boundary between two surfaces are ties a rasteriser
    // may give to the other side, left out as the area-light truth leaves them out (with more
    // rays a pixel the resolve averages both sides).
    let compared: Option<Vec<bool>> = (aa == 1).then(|| ties(&scene).iter().map(|t| !t).collect());
    let mut mask = penumbra_mask(&reference, &unoccluded, &depth, &coverage);
    if let Some(c) = &compared {
        mask.iter_mut().zip(c).for_each(|(m, &c)| *m &= c);
    }
    let m = compare_over(
        &test,
        &reference,
        scene.exposure,
        compared.as_deref(),
        Some(&mask),
    )?;
    outln!(
        "error against the CPU reference (exact sum over {which}, ray-traced shadows, {aa}×{aa} rays per pixel; {:.1} s on the CPU):",
        t.elapsed().as_secs_f64()
    );
    outln!("{m}");
    Ok(())
}
