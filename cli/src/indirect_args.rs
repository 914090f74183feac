//! `--indirect` and `--indirect-clamp`: one-bounce indirect light from virtual point lights
//! (`docs/indirect.md`), shared by `render`, `plan`, `demo` and `coordinator`.

use anyhow::bail;
use lightfold_scene::Scene;

#[derive(Debug, Clone, Default, clap::Args, serde::Serialize, serde::Deserialize)]
pub(crate) struct IndirectArgs {
    /// One-bounce indirect light from this many virtual point lights, planned like any light
    /// sample (0: direct light only; default: the scene's `[quality] indirect`).
    #[arg(long, value_name = "M")]
    pub indirect: Option<u32>,
    /// Clamp distance of the virtual point lights' 1/r² falloff, in metres (0: none; default:
    /// the scene's, or 2 % of its bounding diagonal).
    #[arg(long, value_name = "METRES")]
    pub indirect_clamp: Option<f32>,
    /// Drop the scene's animation and render its rest pose.
    #[arg(long)]
    pub still: bool,
}

impl IndirectArgs {
    /// Sets the scene's indirect-light options; refuses a non-finite or negative clamp. An
    /// animated scene's virtual point lights are traced again for every frame's time.
    pub(crate) fn apply(&self, scene: &mut Scene) -> anyhow::Result<()> {
        if let Some(c) = self.indirect_clamp {
            if !(c.is_finite() && c >= 0.0) {
                bail!("--indirect-clamp must be a finite distance ≥ 0 (metres), not {c}");
            }
            scene.quality.indirect_clamp = Some(c);
        }
        if let Some(m) = self.indirect {
            scene.quality.indirect = m;
        }
        if self.still {
            scene.animation = None;
        }
        scene
            .check_limits()
            .map_err(|e| anyhow::anyhow!("{e} (see `lightfold defaults`)"))
    }
}
