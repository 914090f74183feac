//! What the hard cases share: loading a case's scene file (at CI or full size), the device (a
//! missing adapter is an error, never a skip), GPU renders beside the CPU reference, per-pixel
//! shadow states and the edge mask the GPU correctness tests use, and non-finite counting.
//!
//! Edge mask: a pixel is compared only when its 3×3 neighbourhood has one shadow state (the same
//! set of samples lights it and is visible from it) and touches no silhouette; shadow maps and
//! ray tracing legitimately disagree on the rest.

use super::{CaseReport, HardCaseError};
use lightfold_node::gpu::{Gpu, GpuOptions, LayerSet, RenderOptions, Renderer};
use lightfold_scene::{Camera, Image, LightSample, Scene};
use std::path::PathBuf;

/// Per-pixel tolerance of "agrees with the reference" (as in the GPU correctness tests).
pub(super) const REL_TOL: f32 = 1e-3;
pub(super) const ABS_TOL: f32 = 1e-4;

/// `scenes/hard/` of the repository.
pub(super) fn scene_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scenes/hard")
}

/// Loads `scenes/hard/<file>`; the CI version renders at `small` (width, height).
pub(super) fn load_case_scene(
    case: &'static str,
    file: &str,
    full_size: bool,
    small: (u32, u32),
) -> Result<Scene, HardCaseError> {
    let path = scene_dir().join(file);
    let mut scene = lightfold_scene::load(&path.to_string_lossy())
        .map_err(|source| HardCaseError::Scene { case, source })?;
    if !full_size {
        scene.camera.width = small.0;
        scene.camera.height = small.1;
    }
    Ok(scene)
}

pub(super) fn count_non_finite(v: &[f32]) -> usize {
    v.iter().filter(|x| !x.is_finite()).count()
}

pub(super) fn gpu() -> Result<Gpu, HardCaseError> {
    Gpu::new(&GpuOptions::default()).map_err(|e| HardCaseError::Gpu {
        message: format!("hard cases need an adapter (lavapipe will do): {e}"),
    })
}

/// The GPU illumination (6 channels) of `samples` with node colour `c_n` under `opts`.
pub(super) fn gpu_illumination(
    case: &'static str,
    gpu: &Gpu,
    scene: &Scene,
    samples: &[LightSample],
    c_n: [f32; 3],
    opts: RenderOptions,
) -> Result<Image, HardCaseError> {
    let err = |e: lightfold_node::gpu::RenderError| HardCaseError::Render {
        case,
        message: e.to_string(),
    };
    let mut r = Renderer::new(gpu, scene, opts).map_err(err)?;
    let frame = r
        .render(gpu, samples, None, c_n, LayerSet::illumination())
        .map_err(err)?;
    frame.illumination.ok_or(HardCaseError::Render {
        case,
        message: "no illumination layer".into(),
    })
}

pub(super) use lightfold_reference::masks::{ShadowStates, shadow_states};

/// Whether every channel of pixel `i` agrees within the per-pixel tolerance.
pub(super) fn pixel_agrees(a: &Image, b: &Image, i: usize) -> bool {
    let c = a.channels;
    a.data[i * c..i * c + c]
        .iter()
        .zip(&b.data[i * c..i * c + c])
        .all(|(x, y)| (x - y).abs() <= REL_TOL * y.abs() + ABS_TOL)
}

/// Fraction of the `mask` pixels where `gpu` and `reference` disagree.
pub(super) fn disagreement(gpu: &Image, reference: &Image, mask: &[bool]) -> (f64, usize) {
    let (mut n, mut bad) = (0usize, 0usize);
    for (i, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
        n += 1;
        bad += usize::from(!pixel_agrees(gpu, reference, i));
    }
    (bad as f64 / n.max(1) as f64, n)
}

/// Sum of the six channels of pixel `i`.
pub(super) fn pixel_sum(img: &Image, i: usize) -> f32 {
    let c = img.channels;
    img.data[i * c..i * c + c].iter().sum()
}

/// A report skeleton for cases whose details are filled in by the caller.
pub(super) fn report(
    name: &'static str,
    metric: &'static str,
    (measured, bound): (f64, f64),
    control: &'static str,
    control_value: f64,
    non_finite: usize,
) -> CaseReport {
    CaseReport {
        name,
        metric,
        measured,
        bound,
        control,
        control_value,
        non_finite,
        details: Vec::new(),
    }
}

pub(super) use lightfold_reference::masks::comparable;

/// The GPU illumination of `samples` seen by each of `cameras`, one renderer whose shadow maps
/// are fitted to every receiver of the scene (not just what a camera sees), so every camera
/// looks at the same maps.
pub(super) fn gpu_illumination_views(
    case: &'static str,
    gpu: &Gpu,
    scene: &Scene,
    samples: &[LightSample],
    opts: RenderOptions,
    cameras: &[Camera],
) -> Result<Vec<Image>, HardCaseError> {
    let err = |e: lightfold_node::gpu::RenderError| HardCaseError::Render {
        case,
        message: e.to_string(),
    };
    let mut r = Renderer::new(gpu, scene, opts).map_err(err)?;
    r.set_fit_to_camera(false);
    let mut out = Vec::with_capacity(cameras.len());
    for cam in cameras {
        r.set_camera(cam);
        let frame = r
            .render(gpu, samples, None, [1.0; 3], LayerSet::illumination())
            .map_err(err)?;
        out.push(frame.illumination.ok_or(HardCaseError::Render {
            case,
            message: "no illumination layer".into(),
        })?);
    }
    Ok(out)
}

/// What the reference says about one view of a scene: the exact point sum, the same without
/// shadows, per-pixel shadow states and the comparable-pixel mask.
pub(super) struct ReferenceView {
    pub scene: Scene,
    pub shadowed: lightfold_reference::Layers,
    pub unshadowed: Image,
    pub states: ShadowStates,
    pub mask: Vec<bool>,
}

impl ReferenceView {
    pub(super) fn new(scene: &Scene, camera: Camera, samples: &[LightSample]) -> ReferenceView {
        use lightfold_reference::{PointSumOptions, render_point_sum, render_point_sum_with};
        let mut scene = scene.clone();
        scene.camera = camera;
        let shadowed = render_point_sum(&scene, samples, [1.0; 3]);
        let unshadowed = render_point_sum_with(
            &scene,
            samples,
            [1.0; 3],
            PointSumOptions { shadows: false },
        )
        .illumination;
        let states = shadow_states(&scene, samples);
        let mask = comparable(&shadowed.depth, &shadowed.coverage, &states.visible);
        ReferenceView {
            scene,
            shadowed,
            unshadowed,
            states,
            mask,
        }
    }

    /// Every sample that would light pixel `i` reaches it.
    pub(super) fn fully_lit(&self, i: usize) -> bool {
        let (l, v) = (self.states.lit[i], self.states.visible[i]);
        l != 0 && l == v
    }

    /// Some sample would light pixel `i` but none reaches it.
    pub(super) fn fully_shadowed(&self, i: usize) -> bool {
        self.states.lit[i] != 0 && self.states.visible[i] == 0
    }
}
