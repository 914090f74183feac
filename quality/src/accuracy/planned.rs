//! `lightfold accuracy --planned`: the planner's default choice for a scene (with its error
//! model) against the scene as it asks, each rendered on one device as the sweep renders a
//! point and compared with the area-light truth.

use super::{CachedTruth, Setting, measure_prepared};
use lightfold_coordinator::plan::{
    ClusterSpec, ErrorModel, Learned, MapSizing as PlanSizing, PlanOptions, plan, targeted,
};
use lightfold_node::gpu::Gpu;
use lightfold_scene::{Scene, ShadowFilter};

/// One row of the comparison.
#[derive(Debug, Clone)]
pub struct Row {
    /// "as the scene asks", "planned", "planned, filter off".
    pub what: String,
    /// Samples per area light (a range where the planner raised single lights).
    pub samples: String,
    /// The shadow-map floor the plan raised maps to, or "rule" (the scene's own sizing).
    pub floor: String,
    /// The penumbra filter: "cell N×N", "rN" or "—".
    pub filter: String,
    pub penumbra_db: f64,
    /// What the error model expected of the planned row.
    pub expected_db: Option<f32>,
    pub whole_db: f64,
    /// Node-seconds of the frame.
    pub node_seconds: f64,
}

/// The scene as it asks and the planner's choice for `target_db` of penumbra PSNR (`model`:
/// the scene's calibrated error model, `None` for the default one), rendered on `gpu` with
/// `repeats` timings each and compared with `truth`.
pub fn measure(
    gpu: &Gpu,
    scene: &Scene,
    target_db: f32,
    model: Option<ErrorModel>,
    truth: &CachedTruth,
    repeats: u32,
) -> anyhow::Result<Vec<Row>> {
    let options = PlanOptions {
        target_penumbra_db: Some(target_db),
        learned: Learned {
            error_model: model,
            ..Learned::default()
        },
        ..PlanOptions::default()
    };
    let p = plan(scene, &ClusterSpec::local(256, 256), &options)?;
    let defaults = Setting::defaults(scene);
    // The planner's choice, as it made it: the scene with its samples per area light and the
    // options with its map sizing (`plan::targeted`), its filter and K from the plan.
    let (mut planned, sizing, floor) = match targeted(scene, target_db, &options) {
        Some((s, o, t)) => (s, o.map_sizing, t.map_floor),
        None => (scene.clone(), options.map_sizing, 0),
    };
    let samples = planned.area_samples().unwrap_or(defaults.samples);
    // Where the plan sizes maps other than by the scene's own rule (a raised floor), the scene
    // the device renders takes that rule.
    match sizing {
        PlanSizing::Mismatch { min, max, target } => {
            let rule = lightfold_scene::Mismatch { min, max, target };
            planned.quality.map_sizing = lightfold_scene::MapSizing::Mismatch(rule);
            planned.quality.shadow_map_size = min;
        }
        PlanSizing::Fixed(n) => {
            planned.quality.map_sizing = lightfold_scene::MapSizing::Fixed;
            planned.quality.shadow_map_size = n;
        }
        PlanSizing::Scene => {}
    }
    let largest = match PlanSizing::Scene.resolve(&planned.quality) {
        PlanSizing::Mismatch { max, .. } => max,
        PlanSizing::Fixed(n) => n,
        PlanSizing::Scene => planned.quality.shadow_map_size,
    };
    // The scenes' own filters render (`measure_prepared`); the settings say which.
    let setting = |samples: u32, k: u32, penumbra: u32| Setting {
        samples,
        map_size: largest,
        k,
        penumbra,
        ..defaults
    };
    // Each case: what, the scene rendered, its settings (one render; a second setting is the
    // same images unfiltered), the model's figure.
    let unfiltered = (p.penumbra_radius > 0).then(|| setting(samples, p.k, 0));
    let cases = [
        (
            "as the scene asks",
            scene,
            vec![setting(defaults.samples, defaults.k, 0)],
            None,
        ),
        (
            "planned",
            &planned,
            std::iter::once(setting(samples, p.k, p.penumbra_radius))
                .chain(unfiltered)
                .collect(),
            p.target.as_ref().map(|t| t.expected_db),
        ),
    ];
    let mut rows = Vec::new();
    for (what, s, settings, expected) in cases {
        let measured = measure_prepared(gpu, s, &settings, repeats)?;
        for (i, (setting, m)) in settings.iter().zip(&measured).enumerate() {
            let metrics = truth.truth.compare(&m.image)?;
            // The planner may raise single lights (glossy highlights, `plan::gloss`).
            let counts: Vec<u32> = s
                .lights
                .iter()
                .filter(|l| l.is_area())
                .map(|l| s.quality.samples_of(l))
                .collect();
            rows.push(Row {
                what: if i == 0 {
                    what.to_string()
                } else {
                    format!("{what}, filter off")
                },
                samples: match (counts.iter().min(), counts.iter().max()) {
                    (Some(a), Some(b)) if a != b => format!("{a}–{b}"),
                    _ => setting.samples.to_string(),
                },
                floor: match (what, floor) {
                    ("planned", f) if f > 0 => format!("{f}²"),
                    _ => "rule".to_string(),
                },
                filter: match (setting.penumbra, s.quality.filter) {
                    (_, ShadowFilter::Cell { taps }) => format!("cell {taps}×{taps}"),
                    (0, _) => "—".into(),
                    (r, _) => format!("r{r}"),
                },
                penumbra_db: metrics.penumbra.map_or(f64::NAN, |e| e.psnr),
                expected_db: if i == 0 { expected } else { None },
                whole_db: metrics.whole.psnr,
                node_seconds: m.node_seconds.iter().sum::<f64>(),
            });
        }
    }
    Ok(rows)
}
