//! The error summary of a cluster image: compared with the CPU reference's exact sum over the same
//! point samples (ray-traced shadows), so what remains is shadow-map and link-precision error.

use crate::out::outln;
use anyhow::Context;
use lightfold_reference::masks::penumbra_mask;
use lightfold_reference::metrics::compare;
use lightfold_reference::point_sum::{PointSumOptions, render_point_sum_with};
use lightfold_scene::{Image, LightSample, Scene};
use std::path::Path;
use std::time::Instant;

/// Renders the reference for `scene` and prints the metrics of the image in `exr` against it.
pub fn report(scene: &Scene, samples: &[LightSample], exr: &Path) -> anyhow::Result<()> {
    let test = Image::read_exr(exr).with_context(|| format!("cannot read {}", exr.display()))?;
    let t = Instant::now();
    let shadowed =
        render_point_sum_with(scene, samples, [1.0; 3], PointSumOptions { shadows: true });
    let open = render_point_sum_with(scene, samples, [1.0; 3], PointSumOptions { shadows: false });
    let reference = shadowed.radiance([1.0; 3], scene.ambient);
    let unoccluded = open.radiance([1.0; 3], scene.ambient);
    let mask = penumbra_mask(&reference, &unoccluded, &shadowed.depth, &shadowed.coverage);
    let m = compare(&test, &reference, scene.exposure, Some(&mask))?;
    outln!(
        "error against the CPU reference (exact sum over the same {} point samples, ray-traced shadows; {:.1} s on the CPU):",
        samples.len(),
        t.elapsed().as_secs_f64()
    );
    outln!("{m}");
    Ok(())
}
