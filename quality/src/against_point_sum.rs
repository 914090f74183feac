//! A cluster image's error against the CPU reference's exact sum over the same point samples
//! (ray-traced shadows), so what remains is shadow-map and link-precision error (`lightfold
//! demo`'s closing figures).

use lightfold_reference::masks::{penumbra_mask, ties};
use lightfold_reference::metrics::{Metrics, compare_over};
use lightfold_reference::point_sum::{PointSumOptions, render_point_sum_with};
use lightfold_scene::{Image, LightSample, Scene};
use std::time::Instant;

/// Renders the reference for `scene` and measures `test` (a cluster's image) against it,
/// returning the metrics and the reference's seconds on the CPU. With `peels` > 0 the reference
/// sees that many translucent layers (`render_peeled`: their own reflection, blended back to
/// front; `docs/translucency.md` § Peeled layers), its penumbra mask taken against the classic
/// unoccluded image.
/// With `aa` > 1 (the image's `--aa`) the reference is traced with `aa × aa` rays per pixel and
/// resolved the same way (radiance box-filtered, depth nearest; coverage where a block has any).
pub fn measure(
    scene: &Scene,
    samples: &[LightSample],
    test: &Image,
    aa: u32,
    peels: u32,
) -> anyhow::Result<(Metrics, f64)> {
    let (mut m, seconds) = measure_each(scene, samples, test, aa, &[peels])?;
    Ok((m.remove(0), seconds))
}

/// [`measure`] against a reference per entry of `peels` (0: the classic one), the classic
/// renders they share traced once.
pub fn measure_each(
    scene: &Scene,
    samples: &[LightSample],
    test: &Image,
    aa: u32,
    peels: &[u32],
) -> anyhow::Result<(Vec<Metrics>, f64)> {
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
    let unoccluded = open.radiance([1.0; 3], scene.ambient).box_resolve(aa)?;
    let depth = shadowed.depth.nearest_depth_resolve(aa)?;
    let coverage: Vec<bool> = if aa > 1 {
        depth.data.iter().map(|&z| z > 0.0).collect()
    } else {
        shadowed.coverage.clone()
    };
    // One ray a pixel: pixel centres on a boundary between two surfaces are ties a rasteriser
    // may give to the other side, left out as the area-light truth leaves them out (with more
    // rays a pixel the resolve averages both sides).
    let compared: Option<Vec<bool>> = (aa == 1).then(|| ties(&scene).iter().map(|t| !t).collect());
    let mut all = Vec::with_capacity(peels.len());
    for &peels in peels {
        let reference = if peels > 0 {
            lightfold_reference::peel::radiance_peeled(&scene, samples, peels)
        } else {
            shadowed.radiance([1.0; 3], scene.ambient)
        }
        .box_resolve(aa)?;
        let mut mask = penumbra_mask(&reference, &unoccluded, &depth, &coverage);
        if let Some(c) = &compared {
            mask.iter_mut().zip(c).for_each(|(m, &c)| *m &= c);
        }
        all.push(compare_over(
            test,
            &reference,
            scene.exposure,
            compared.as_deref(),
            Some(&mask),
        )?);
    }
    Ok((all, t.elapsed().as_secs_f64()))
}
