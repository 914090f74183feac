//! Refinement when idle (`docs/live-view.md` § Refinement when idle): once no viewer has changed
//! anything for a while, the view asks for the same frame again at a higher quality, one step a
//! frame — the samples per area light doubled up to a cap, then the antialiasing factor doubled up
//! to a cap — and any input drops back to the session's quality (its frame budget's) in the next
//! frame requested.

use lightfold_coordinator::control::Refine;
use lightfold_scene::Scene;
use std::time::Duration;

/// Default cap on the samples per area light: this many times the scene's largest count ...
pub const DEFAULT_SAMPLES_FACTOR: u32 = 4;
/// ... and no more than this.
pub const DEFAULT_MAX_SAMPLES: u32 = 256;

/// How the view refines while idle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RefineOptions {
    /// No input for this long (and the frame showing the last input delivered): the first step.
    pub after: Duration,
    /// Samples per area light the steps double up to; 0: `DEFAULT_SAMPLES_FACTOR` × the scene's
    /// largest count, at most `DEFAULT_MAX_SAMPLES`.
    pub max_samples: u32,
    /// Antialiasing factor the steps double up to once the samples are at their cap (1: no
    /// antialiasing steps).
    pub max_supersample: u32,
}

impl Default for RefineOptions {
    fn default() -> Self {
        RefineOptions {
            after: Duration::from_millis(500),
            max_samples: 0,
            max_supersample: 2,
        }
    }
}

/// One refinement step a frame was requested at.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Step {
    /// 1 for the first step.
    pub level: u32,
    /// Steps there are.
    pub of: u32,
    pub refine: Refine,
}

/// The steps of a session, from its scene and antialiasing factor.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Ladder {
    pub after: Duration,
    steps: Vec<Refine>,
}

impl Ladder {
    /// The steps for `scene` rendered at antialiasing factor `supersample` (the session's):
    /// the samples per area light doubled from the scene's largest count up to the cap (the last
    /// step at the cap itself), then, at those samples, the factor doubled up to its cap.
    pub fn new(scene: &Scene, supersample: u32, opts: &RefineOptions) -> Ladder {
        let mut steps = Vec::new();
        let mut samples = 0;
        if let Some(from) = scene.area_samples() {
            let cap = if opts.max_samples > 0 {
                opts.max_samples
            } else {
                (from.saturating_mul(DEFAULT_SAMPLES_FACTOR)).min(DEFAULT_MAX_SAMPLES)
            }
            .min(lightfold_scene::limits::MAX_SAMPLES_PER_AREA_LIGHT);
            let mut n = from;
            while n < cap {
                n = n.saturating_mul(2).min(cap);
                steps.push(Refine {
                    samples_per_area_light: n,
                    supersample: supersample.max(1),
                });
            }
            samples = n;
        }
        let mut factor = supersample.max(1);
        while factor < opts.max_supersample {
            factor = factor.saturating_mul(2).min(opts.max_supersample);
            steps.push(Refine {
                samples_per_area_light: samples,
                supersample: factor,
            });
        }
        Ladder {
            after: opts.after,
            steps,
        }
    }

    /// Steps there are (the highest level).
    pub fn top(&self) -> u32 {
        self.steps.len() as u32
    }

    /// Step `level` (`None` at level 0, the session's quality, and above the top).
    pub fn step(&self, level: u32) -> Option<Step> {
        let i = level.checked_sub(1)? as usize;
        self.steps.get(i).map(|&refine| Step {
            level,
            of: self.top(),
            refine,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn steps(l: &Ladder) -> Vec<(u32, u32)> {
        (1..=l.top())
            .map(|i| {
                let r = l.step(i).unwrap().refine;
                (r.samples_per_area_light, r.supersample)
            })
            .collect()
    }

    #[test]
    fn samples_double_to_their_cap_then_antialiasing() {
        let mut scene = lightfold_scene::builtin("balls").unwrap();
        scene.quality.samples_per_area_light = Some(4);
        let l = Ladder::new(&scene, 1, &RefineOptions::default());
        // 4× the scene's 4, then 2× antialiasing at those samples.
        assert_eq!(steps(&l), [(8, 1), (16, 1), (16, 2)]);
        assert_eq!(l.step(0), None, "level 0 is the session's quality");
        assert_eq!(l.step(4), None, "nothing above the top");
        assert_eq!(l.step(3).unwrap().of, 3);
        // A cap that is no power-of-two multiple is the last step; the factor from the session's.
        let opts = RefineOptions {
            max_samples: 24,
            max_supersample: 6,
            ..RefineOptions::default()
        };
        let l = Ladder::new(&scene, 2, &opts);
        assert_eq!(steps(&l), [(8, 2), (16, 2), (24, 2), (24, 4), (24, 6)]);
        // The default cap stops at 256; a scene above the cap gets antialiasing steps only.
        scene.quality.samples_per_area_light = Some(128);
        let l = Ladder::new(&scene, 1, &RefineOptions::default());
        assert_eq!(steps(&l), [(256, 1), (256, 2)]);
        scene.quality.samples_per_area_light = Some(512);
        let l = Ladder::new(&scene, 1, &RefineOptions::default());
        assert_eq!(steps(&l), [(512, 2)]);
        // No area light: antialiasing only, the samples as the scene has them (0).
        scene.lights.retain(|l| !l.is_area());
        let l = Ladder::new(&scene, 1, &RefineOptions::default());
        assert_eq!(steps(&l), [(0, 2)]);
        // Off: no step.
        let opts = RefineOptions {
            max_samples: 1,
            max_supersample: 1,
            ..RefineOptions::default()
        };
        assert_eq!(Ladder::new(&scene, 1, &opts).top(), 0);
    }
}
