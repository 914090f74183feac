//! The area-light ground truth as a bundle (shadowed and unoccluded radiance, depth, coverage and
//! the penumbra mask), its noise floor, and the split of a GPU image's error into shadow-map error
//! and light-sampling error.

use crate::area::{AreaOptions, render_area};
use crate::masks::{penumbra_mask, ties};
use crate::metrics::{Metrics, MetricsError, compare_over};
use lightfold_scene::{Image, Scene};

/// Everything a comparison against the truth needs.
#[derive(Debug, Clone)]
pub struct GroundTruth {
    pub options: AreaOptions,
    /// The scene's exposure (metrics compare `exposure·L`).
    pub exposure: f32,
    /// Linear radiance with shadows.
    pub radiance: Image,
    /// Linear radiance without shadows (for the penumbra mask).
    pub unoccluded: Image,
    pub depth: Image,
    pub coverage: Vec<bool>,
    /// Pixels compared: all but those whose centre lies on a boundary between two surfaces
    /// ([`ties`]), where a rasteriser may show either.
    pub compared: Vec<bool>,
    /// Penumbra minus dilated silhouettes and ties.
    pub penumbra: Vec<bool>,
}

impl GroundTruth {
    /// Renders the truth with `options` (shadows forced on) and an unoccluded image at a quarter
    /// of the samples (at least 16): it is smooth and only decides the mask.
    pub fn render(scene: &Scene, options: &AreaOptions) -> GroundTruth {
        let shadowed = render_area(
            scene,
            &AreaOptions {
                shadows: true,
                ..*options
            },
        );
        let unoccluded = render_area(
            scene,
            &AreaOptions {
                shadows: false,
                samples_per_light: (options.samples_per_light / 4).max(16),
                ..*options
            },
        );
        let radiance = shadowed.radiance([1.0; 3], scene.ambient);
        let unoccluded = unoccluded.radiance([1.0; 3], scene.ambient);
        GroundTruth::assemble(
            scene,
            *options,
            radiance,
            unoccluded,
            shadowed.depth,
            shadowed.coverage,
        )
    }

    /// The truth of `scene` from its rendered layers (a cache's, or [`GroundTruth::render`]'s):
    /// the masks are derived here, the tie mask by tracing the scene's eye rays again.
    pub fn assemble(
        scene: &Scene,
        options: AreaOptions,
        radiance: Image,
        unoccluded: Image,
        depth: Image,
        coverage: Vec<bool>,
    ) -> GroundTruth {
        let compared: Vec<bool> = ties(scene).into_iter().map(|t| !t).collect();
        let penumbra = penumbra_mask(&radiance, &unoccluded, &depth, &coverage)
            .into_iter()
            .zip(&compared)
            .map(|(p, &c)| p && c)
            .collect();
        GroundTruth {
            options,
            exposure: scene.exposure,
            radiance,
            unoccluded,
            depth,
            coverage,
            compared,
            penumbra,
        }
    }

    /// Metrics of `test` against the truth, whole image (the compared pixels) and penumbra.
    pub fn compare(&self, test: &Image) -> Result<Metrics, MetricsError> {
        self.compare_with(test, &self.radiance)
    }

    /// Metrics of `test` against `reference` over the truth's masks.
    pub fn compare_with(&self, test: &Image, reference: &Image) -> Result<Metrics, MetricsError> {
        compare_over(
            test,
            reference,
            self.exposure,
            Some(&self.compared),
            Some(&self.penumbra),
        )
    }

    /// Number of pixels left out as ties ([`ties`]).
    pub fn tie_pixels(&self) -> usize {
        self.compared.iter().filter(|&&c| !c).count()
    }

    /// Number of penumbra pixels.
    pub fn penumbra_pixels(&self) -> usize {
        self.penumbra.iter().filter(|&&p| p).count()
    }
}

/// The truth's own noise: the metrics between this truth and one rendered with the next seed.
pub fn noise_floor_of(scene: &Scene, truth: &GroundTruth) -> Metrics {
    let other = render_area(
        scene,
        &AreaOptions {
            seed: truth.options.seed.wrapping_add(1),
            shadows: true,
            ..truth.options
        },
    )
    .radiance([1.0; 3], scene.ambient);
    match truth.compare(&other) {
        Ok(m) => m,
        // Both images come from the same camera, so their sizes agree.
        Err(e) => unreachable!("renders of one scene differ in size: {e}"),
    }
}

/// The noise floor of the truth at `samples_per_light`: renders seeds 1 and 2 and compares them.
pub fn noise_floor(scene: &Scene, samples_per_light: u32) -> Metrics {
    let truth = GroundTruth::render(
        scene,
        &AreaOptions {
            samples_per_light,
            seed: 1,
            shadows: true,
        },
    );
    noise_floor_of(scene, &truth)
}

/// A GPU image's error against the truth and its two parts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ErrorSplit {
    /// GPU − truth.
    pub total: Metrics,
    /// GPU − exact point sum of the same samples: shadow-map and precision error.
    pub shadow_map: Metrics,
    /// Exact point sum − truth: light-sampling error (too few point samples).
    pub light_sampling: Metrics,
}

/// Splits `gpu`'s error using the exact point sum of the same samples and the truth; all three
/// use the truth's masks.
pub fn split_error(
    gpu: &Image,
    point_sum: &Image,
    truth: &GroundTruth,
) -> Result<ErrorSplit, MetricsError> {
    Ok(ErrorSplit {
        total: truth.compare(gpu)?,
        shadow_map: truth.compare_with(gpu, point_sum)?,
        light_sampling: truth.compare(point_sum)?,
    })
}

impl std::fmt::Display for ErrorSplit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "total (gpu − truth)\n{}", self.total)?;
        writeln!(f, "shadow map (gpu − point sum)\n{}", self.shadow_map)?;
        write!(
            f,
            "light sampling (point sum − truth)\n{}",
            self.light_sampling
        )
    }
}
