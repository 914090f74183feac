//! The planner's error model on the command line (`--error-model`, `--calibrate`,
//! `--model-cache`), shared by `plan`, `coordinator`, `demo` and `accuracy --planned`: a scene's
//! own calibration from the cache (or made now), else the default scene's sweep. With a
//! calibration and no `--target-psnr`, the plan aims at [`DEFAULT_TARGET_DB`] penumbra PSNR at
//! the least node-seconds the calibration measured (`docs/planner.md` § Error model).

use anyhow::Context;
use lightfold_coordinator::plan::{ErrorModel, PlanOptions};
use lightfold_quality::calibrate::{self, Calibration, CalibrationOptions};
use lightfold_scene::Scene;
use std::path::PathBuf;

/// The penumbra PSNR (dB, against the area-light truth) a plan with a calibration aims at when
/// no target is given.
pub(crate) const DEFAULT_TARGET_DB: f32 = 45.0;

/// Points per area light per pixel of a calibration's truth.
pub(crate) const TRUTH_SAMPLES: u32 = 256;

#[derive(Debug, Clone, PartialEq, clap::Args, serde::Serialize, serde::Deserialize)]
pub(crate) struct ModelArgs {
    /// The planner's error model: `auto` (this scene's calibration at this size from the cache
    /// when there is one, else the default scene's sweep), `default` (the default scene's sweep),
    /// or a model file as `lightfold calibrate` writes it. With a calibration and no
    /// --target-psnr the plan aims at 45 dB penumbra PSNR against the area-light truth at the
    /// least node-seconds the calibration measured.
    #[arg(long, default_value = "auto")]
    pub error_model: String,
    /// Calibrate the scene first when the cache has no model of it: a few renders at up to
    /// 400×300 on this machine's GPU against the CPU area-light truth (a few minutes on a
    /// 2-core machine without a GPU; `lightfold calibrate` does it alone).
    #[arg(long)]
    pub calibrate: bool,
    /// Where calibrations and their truths are cached (default: the user's cache folder,
    /// e.g. ~/.cache/lightfold).
    #[arg(long)]
    pub model_cache: Option<PathBuf>,
}

impl ModelArgs {
    /// The cache folders: models, truths.
    pub(crate) fn cache(&self) -> CalibrationOptions {
        let root = self.model_cache.clone().unwrap_or_else(|| {
            dirs::cache_dir()
                .map_or_else(|| PathBuf::from("lightfold-cache"), |d| d.join("lightfold"))
        });
        CalibrationOptions::standard(
            TRUTH_SAMPLES,
            Some(root.join("accuracy")),
            Some(root.join("calibration")),
        )
    }

    /// The model for `scene` (at its image size), `None` for the default scene's.
    pub(crate) fn model(&self, scene: &Scene) -> anyhow::Result<Option<ErrorModel>> {
        match self.error_model.as_str() {
            "default" => Ok(None),
            "auto" => {
                // A scene without area lights has no samples to choose: nothing to calibrate.
                if self.calibrate && scene.area_samples().is_some() {
                    return Ok(Some(run_calibration(scene, &self.cache())?.model));
                }
                Ok(calibrate::cached_model(scene, &self.cache()))
            }
            path => {
                let model = calibrate::read_model(std::path::Path::new(path))
                    .map_err(|e| anyhow::anyhow!("cannot read the error model {path}: {e}"))?;
                let ours = calibrate::model_key(scene, &self.cache());
                if !model.key.is_empty() && model.key != ours {
                    tracing::warn!(
                        "the error model {path} was calibrated for another scene or image size \
                         (key {}, this one's {ours}): its figures may not hold here",
                        model.key
                    );
                }
                Ok(Some(model))
            }
        }
    }

    /// `options` with the model for `scene`, and with a calibration the default target when
    /// none was asked for.
    pub(crate) fn apply(&self, scene: &Scene, options: &mut PlanOptions) -> anyhow::Result<()> {
        let model = self.model(scene)?;
        if model.as_ref().is_some_and(|m| m.calibrated) && options.target_penumbra_db.is_none() {
            options.target_penumbra_db = Some(DEFAULT_TARGET_DB);
        }
        options.learned.error_model = model;
        Ok(())
    }
}

/// Calibrates `scene` (or reads its model from the cache) on this machine's GPU, saying so on
/// stderr.
pub(crate) fn run_calibration(
    scene: &Scene,
    opts: &CalibrationOptions,
) -> anyhow::Result<Calibration> {
    // A cached model needs no device.
    if let Some(c) = calibrate::cached(scene, opts) {
        return Ok(c);
    }
    eprintln!(
        "calibrating the error model of this scene at {}×{} (truth and renders; cached after)…",
        scene.camera.width, scene.camera.height
    );
    let gpu = lightfold_node::gpu::Gpu::new(&lightfold_node::gpu::GpuOptions::default())
        .context("calibration needs a GPU adapter (or lavapipe)")?;
    let c = calibrate::calibrate(&gpu, scene, opts)?;
    eprintln!(
        "calibrated in {:.1} s (truth {:.1} s, renders {:.1} s), key {}",
        c.seconds + c.truth_seconds,
        c.truth_seconds,
        c.seconds,
        c.key
    );
    Ok(c)
}
