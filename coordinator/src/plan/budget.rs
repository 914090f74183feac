//! Meeting a frame budget by the cheapest loss of accuracy (`docs/planner.md` § Frame budgets).
//!
//! With `PlanOptions::frame_budget_us` the planner first picks K (the largest whose slowest node
//! fits: fewest nodes, no accuracy lost). When even the fastest K is over the budget it lowers
//! quality one step at a time, planning again after each, until the estimate fits or nothing is
//! left to lower. Steps are kept only when they lower the estimate (once every node carries one
//! light, fewer samples would only idle nodes), so a budget no plan meets gets the fastest
//! estimate at the least loss, said to be over the budget:
//!
//! 1. **shadow maps**: the largest map the mismatch rule may give is halved down to the rule's
//!    floor (a fixed size above the default is halved down to the default). Against the
//!    area-light truth this costs nothing measurable on `balls` (`docs/accuracy/balls`: 1024² →
//!    512² → 256² maps gave 46.70 → 47.53 → 48.46 dB penumbra PSNR at 16 samples, the wider PCF
//!    footprint blurring like a penumbra), but the thin casters and near shadows of the
//!    shadow-map hard cases need the larger maps (`docs/hard-cases.md`), so it stops at the floor;
//! 2. **samples per area light**, halved down to one: the error model below, about −4 to −5 dB a
//!    halving for half the lights' cost;
//! 3. **ε**, ×4 a step up to [`MAX_EPSILON`]: the least important samples — those whose bound on
//!    any visible pixel is smallest — are dropped, each step adding at most ε to a pixel (a bias
//!    bound, not a PSNR figure).
//!
//! An error target (`PlanOptions::target_penumbra_db`) comes first: the area lights' sample
//! counts are halved or doubled to the fewest the error model below expects to reach it
//! (`Plan::target`); the budget's ladder then starts from there.
//!
//! **The screen-space penumbra filter** (`PlanOptions::penumbra_filter`, by default `Budget`)
//! rides on the samples: wherever the budget lowers the samples per area light below the
//! scene's, or an error target chooses them (at any count), the last stage filters the illumination sum at the radius the filtered
//! error model ([`FILTERED`]) gains most at that count (16 or fewer samples: +2.6 to +5.2 dB on
//! `balls` for under 2 % of the frame), and the step's expected figure includes it. The
//! filter's cost is the last stage's, not a node's, so it does not enter the frame estimate.
//!
//! The plan records each step (`Plan::concessions`) with the estimate after it; the same inputs
//! give the same steps, so a live session re-planning with nothing changed keeps its plan.

use super::error_model::{Curve, ErrorModel};
use super::{
    ClusterSpec, Concession, Knob, MapSizing, PenumbraFilter, Plan, PlanError, PlanOptions,
    TargetChoice, scene_hash,
};
use lightfold_scene::{Scene, ShadowFilter};

/// The most ε a frame budget raises the culling bound to (display units: about 4 8-bit sRGB
/// steps at mid-grey).
pub const MAX_EPSILON: f32 = 1.6e-2;

/// The default scene's model ([`ErrorModel::balls`]) at `n` samples per area light: what plans
/// without a calibration of their own expect.
pub fn expected_penumbra_db(n: u32) -> f32 {
    BALLS_MODEL.base().db(n)
}

/// The penumbra filter's radius the default scene's model expects to gain the most at `n`
/// samples per area light, 0 above the counts where it measured a gain.
pub fn filter_radius(n: u32) -> u32 {
    BALLS_MODEL.base().filter_radius(n)
}

/// The curve a plan with `options` reads: its model's (the default scene's when it has none),
/// at the map floor its sizing gives.
fn curve<'a>(options: &'a PlanOptions, scene: &Scene) -> &'a Curve {
    model(options).curve(map_floor(options, scene))
}

/// The model a plan with `options` reads (the default scene's when it has none).
fn model(options: &PlanOptions) -> &ErrorModel {
    options.learned.error_model.as_ref().unwrap_or(&BALLS_MODEL)
}

/// The default scene's model, built once.
static BALLS_MODEL: std::sync::LazyLock<ErrorModel> = std::sync::LazyLock::new(ErrorModel::balls);

/// The shadow-map floor `options`' sizing sets (the mismatch rule's smallest map), 0 when it
/// sets none (the scene's rule, or one size for every map).
fn map_floor(options: &PlanOptions, scene: &Scene) -> u32 {
    match options.map_sizing.resolve(&scene.quality) {
        MapSizing::Mismatch { min, .. } => min,
        _ => 0,
    }
}

/// The filter's radius at `n` samples per area light when the scene asks for `from`: what
/// `filter` resolves to. `Budget` filters counts lowered below the scene's, and any count where
/// an error target chose the samples (`from` is `None` then: the target asked for the cheapest
/// plan that reaches it).
fn resolve_radius(curve: &Curve, filter: PenumbraFilter, from: Option<u32>, n: Option<u32>) -> u32 {
    match (filter, n) {
        (PenumbraFilter::Off, _) | (_, None) => 0,
        (PenumbraFilter::Radius(r), _) => r,
        (PenumbraFilter::Auto, Some(n)) => curve.filter_radius(n),
        (PenumbraFilter::Budget, Some(n)) => {
            if from.is_none_or(|f| n < f) {
                curve.filter_radius(n)
            } else {
                0
            }
        }
    }
}

/// `options` with the penumbra filter resolved for `scene` (a count lowered from `from`): a
/// radius, or off, which is all `plan_once` reads.
fn resolved(options: &PlanOptions, from: Option<u32>, scene: &Scene, threads: u32) -> PlanOptions {
    let r = capped_radius(options, from, scene, scene.area_samples(), threads);
    PlanOptions {
        penumbra_filter: if r > 0 {
            PenumbraFilter::Radius(r)
        } else {
            PenumbraFilter::Off
        },
        ..options.clone()
    }
}

/// [`resolve_radius`] for `scene` at `n` samples per area light, and under a frame budget no
/// larger than the last stage can filter within it (on `threads` cores): a smaller radius, or
/// none. An explicit radius is kept: it was asked for.
fn capped_radius(
    options: &PlanOptions,
    from: Option<u32>,
    scene: &Scene,
    n: Option<u32>,
    threads: u32,
) -> u32 {
    let mut r = resolve_radius(curve(options, scene), options.penumbra_filter, from, n);
    if let (Some(budget), false) = (
        options.frame_budget_us,
        matches!(options.penumbra_filter, PenumbraFilter::Radius(_)),
    ) {
        let cam = &scene.camera;
        while r > 0
            && filter_cost_us(r, cam.width, cam.height, options.band_height, threads)
                > budget as f64
        {
            r -= 1;
        }
    }
    r
}

/// The fewest cores a compositor of `cluster` reports (1 when none does): what the last stage
/// is assumed to filter on.
fn stage_threads(cluster: &ClusterSpec) -> u32 {
    cluster
        .compositors
        .iter()
        .filter_map(|c| c.capabilities.as_ref().map(|c| c.threads))
        .min()
        .unwrap_or(1)
        .max(1)
}

/// The penumbra filter's time per pixel on one core, `a + b·(2r+1)²` nanoseconds, fitted to the
/// operator's benchmark (`docs/operators.md`: radius 1 at 42 ns a pixel, radius 2 at 75 ns, at
/// 800×600 and 1080p on the 2-core development machine), with the crease test the planner
/// always gives it: 1.13× and 1.26× those in one run (`penumbra_r1_crease`, `_r2_crease`), so
/// 47 and 94 ns.
const FILTER_NS: (f64, f64) = (20.9, 2.94);

/// The filter's estimated time a frame at the last stage, microseconds: every pixel of a
/// `width × height` image, bands of `band_height` rows re-run with their halo, over `threads`
/// cores of the stage's pool.
pub fn filter_cost_us(radius: u32, width: u32, height: u32, band_height: u32, threads: u32) -> f64 {
    if radius == 0 {
        return 0.0;
    }
    let side = f64::from(2 * radius + 1);
    // The planned filter has the crease test: its halo is the radius + 2 rows.
    let rows = lightfold_protocol::pipeline::halo_rows(radius, true);
    let band = f64::from(band_height.max(rows));
    let halo = 1.0 + 2.0 * f64::from(rows) / band;
    let pixels = f64::from(width) * f64::from(height);
    pixels * (FILTER_NS.0 + FILTER_NS.1 * side * side) * halo / 1e3 / f64::from(threads.max(1))
}

/// The scene with every area light's sample count (and the quality's override, if any) mapped
/// by `f` (given counts of at least one).
fn with_area_samples(scene: &Scene, f: impl Fn(u32) -> u32) -> Scene {
    let mut s = scene.clone();
    s.quality.samples_per_area_light = s.quality.samples_per_area_light.map(|c| f(c.max(1)));
    for l in s.lights.iter_mut().filter(|l| l.is_area()) {
        l.samples = f(l.samples.max(1));
    }
    s
}

fn maps_text(m: MapSizing) -> String {
    match m {
        MapSizing::Fixed(n) => format!("{n}²"),
        MapSizing::Mismatch { min, max, .. } => format!("{min}²–{max}²"),
        MapSizing::Scene => "the scene's".to_string(),
    }
}

/// One step down of `knob` from `(scene, options)`, or `None` when it is at its floor. `from` is
/// the scene's own count of samples per area light (what `Budget` filters below).
fn lower(
    knob: Knob,
    scene: &Scene,
    options: &PlanOptions,
    from: Option<u32>,
    threads: u32,
) -> Option<(Scene, PlanOptions, String, String, Option<f32>)> {
    match knob {
        Knob::ShadowMaps => {
            let floor = lightfold_scene::defaults::SHADOW_MAP_SIZE;
            let now = options.map_sizing.resolve(&scene.quality);
            let next = match now {
                MapSizing::Mismatch { min, max, target } if max > min => MapSizing::Mismatch {
                    min,
                    max: (max / 2).max(min),
                    target,
                },
                MapSizing::Fixed(n) if n > floor => MapSizing::Fixed((n / 2).max(floor)),
                _ => return None,
            };
            let o = PlanOptions {
                map_sizing: next,
                ..options.clone()
            };
            Some((scene.clone(), o, maps_text(now), maps_text(next), Some(0.0)))
        }
        Knob::SamplesPerAreaLight => {
            let n = scene.area_samples()?;
            if n <= 1 {
                return None;
            }
            let s = with_area_samples(scene, |c| (c / 2).max(1));
            let m = s.area_samples()?;
            let radius = |k| capped_radius(options, from, scene, Some(k), threads);
            let (rn, rm) = (radius(n), radius(m));
            let c = curve(options, scene);
            let db = c.expected_db(m, rm) - c.expected_db(n, rn);
            let text = |k: u32, r: u32| {
                if r > 0 {
                    format!("{k} + penumbra filter r{r}")
                } else {
                    k.to_string()
                }
            };
            Some((s, options.clone(), text(n, rn), text(m, rm), Some(db)))
        }
        Knob::Epsilon => {
            if options.force_all || options.epsilon >= MAX_EPSILON {
                return None;
            }
            let next = if options.epsilon > 0.0 {
                (options.epsilon * 4.0).min(MAX_EPSILON)
            } else {
                super::DEFAULT_EPSILON
            };
            let o = PlanOptions {
                epsilon: next,
                ..options.clone()
            };
            let text = |e: f32| format!("{e:.1e}");
            Some((scene.clone(), o, text(options.epsilon), text(next), None))
        }
    }
}

/// Plans one setting (the planner's `plan_once`).
type PlanOnce = fn(&Scene, &ClusterSpec, &PlanOptions, Option<&Plan>) -> Result<Plan, PlanError>;

/// The ladder's order (the module documentation says why).
const LADDER: [Knob; 3] = [Knob::ShadowMaps, Knob::SamplesPerAreaLight, Knob::Epsilon];

/// Plans `scene`, lowering quality step by step while a frame budget is not met (module
/// documentation). `plan_once` plans one setting.
pub(crate) fn within_budget(
    scene: &Scene,
    cluster: &ClusterSpec,
    options: &PlanOptions,
    previous: Option<&Plan>,
    plan_once: PlanOnce,
) -> Result<Plan, PlanError> {
    let targeted = options
        .target_penumbra_db
        .and_then(|t| targeted(scene, t, options));
    let threads = stage_threads(cluster);
    // What `Budget` filters below: the scene's count, or any count an error target chose.
    let from = if targeted.is_some() {
        None
    } else {
        scene.area_samples()
    };
    let (start, options) = targeted
        .as_ref()
        .map_or((scene, options), |(s, o, _)| (s, o));
    let fit = |s: &Scene, o: &PlanOptions| {
        fit_budget(
            s,
            cluster,
            &resolved(o, from, s, threads),
            previous,
            plan_once,
        )
    };
    let mut first = fit(start, options)?;
    first.scene_hash = scene_hash(scene);
    first.target = targeted.as_ref().map(|(_, _, t)| t.clone());
    let Some(budget) = options.frame_budget_us else {
        return Ok(first);
    };
    let target = first.target.clone();
    let (mut scene_now, mut options_now) = (start.clone(), options.clone());
    let mut best = first;
    let mut concessions = Vec::new();
    for knob in LADDER {
        'knob: while best.est_frame_us > budget {
            // The fewest further steps of this knob that lower the estimate (one ε step may
            // drop nothing; the next may drop a light and free a node).
            let (mut s, mut o) = (scene_now.clone(), options_now.clone());
            let mut steps = Vec::new();
            loop {
                let Some((s2, o2, was, to, db)) = lower(knob, &s, &o, from, threads) else {
                    break 'knob;
                };
                let p = match fit(&s2, &o2) {
                    Ok(p) => p,
                    // Only a lowered setting fails here (e.g. ε drops every sample of a group
                    // the cluster cannot spare): the knob stops where it is.
                    Err(_) => break 'knob,
                };
                steps.push(Concession {
                    knob,
                    from: was,
                    to,
                    est_frame_us: p.est_frame_us,
                    expected_db: db,
                });
                (s, o) = (s2, o2);
                if p.est_frame_us < best.est_frame_us {
                    concessions.append(&mut steps);
                    (scene_now, options_now, best) = (s, o, p);
                    break;
                }
            }
        }
    }
    // Over the budget with nothing left to lower, the plan is the fastest estimate: the filter's
    // eye depth is one more target on the material host, so it goes where a plan without it is
    // faster (an explicit radius stays).
    if best.est_frame_us > budget
        && best.penumbra_radius > 0
        && !matches!(options.penumbra_filter, PenumbraFilter::Radius(_))
    {
        let off = PlanOptions {
            penumbra_filter: PenumbraFilter::Off,
            ..options_now.clone()
        };
        if let Ok(p) = fit_budget(&scene_now, cluster, &off, previous, plan_once)
            && p.est_frame_us < best.est_frame_us
        {
            best = p;
            unfilter(&mut concessions, curve(&options_now, &scene_now));
        }
    }
    // Nodes hold the scene they were sent: the plan names it, not the lowered copy the samples
    // were drawn from (the samples travel in the configurations).
    best.scene_hash = scene_hash(scene);
    best.concessions = concessions;
    best.target = target;
    Ok(best)
}

/// The concessions of samples per area light as they read without the penumbra filter: the
/// counts alone, and the unfiltered model's figures.
fn unfilter(concessions: &mut [Concession], curve: &Curve) {
    let count = |t: &str| t.split(" + ").next().unwrap_or(t).to_string();
    for c in concessions
        .iter_mut()
        .filter(|c| c.knob == Knob::SamplesPerAreaLight)
    {
        (c.from, c.to) = (count(&c.from), count(&c.to));
        if let (Ok(n), Ok(m)) = (c.from.parse::<u32>(), c.to.parse::<u32>()) {
            c.expected_db = Some(curve.db(m) - curve.db(n));
        }
    }
}

/// One plan under the budget. K is chosen by an estimate without the material host's extra
/// targets, so the plan can come out a little over a budget its K was chosen to meet; then K is
/// chosen again against the budget less that overshoot (doubled up to 3 times), and the first
/// such plan that fits is kept.
fn fit_budget(
    scene: &Scene,
    cluster: &ClusterSpec,
    options: &PlanOptions,
    previous: Option<&Plan>,
    plan_once: PlanOnce,
) -> Result<Plan, PlanError> {
    let p = plan_once(scene, cluster, options, previous)?;
    let Some(budget) = options.frame_budget_us else {
        return Ok(p);
    };
    if p.est_frame_us <= budget || p.est_frame_us > budget + budget / 5 {
        return Ok(p);
    }
    // The overshoot, doubled each try, is taken off the budget K is chosen against.
    let mut cut = p.est_frame_us - budget;
    for _ in 0..4 {
        let tighter = PlanOptions {
            frame_budget_us: Some(budget.saturating_sub(cut).max(1)),
            ..options.clone()
        };
        if let Ok(mut q) = plan_once(scene, cluster, &tighter, previous)
            && q.est_frame_us <= budget
        {
            q.frame_budget_us = Some(budget);
            return Ok(q);
        }
        cut *= 2;
    }
    Ok(p)
}

/// The scene and options an error target asks for, and what was chosen; `None` for a scene
/// without area lights. With the default scene's model the area lights' sample counts are halved
/// or doubled (each by the same factor) to the fewest whose expected penumbra PSNR reaches
/// `target_db` (with the penumbra filter where `options` lets the planner add it and the model
/// expects a gain). With a scene's own calibration ([`ErrorModel::cheapest`]) every area light
/// takes the chosen count, and the mismatch rule's smallest map is raised to the chosen floor:
/// the cheapest setting the calibration measured to reach the target. Counts are raised no
/// further than the model measured (beyond it the model would be a guess, and a target it does
/// not reach there is out of reach).
pub fn targeted(
    scene: &Scene,
    target_db: f32,
    options: &PlanOptions,
) -> Option<(Scene, PlanOptions, TargetChoice)> {
    let from = scene.area_samples()?;
    let max = lightfold_scene::limits::MAX_SAMPLES_PER_AREA_LIGHT;
    let model = model(options);
    let sizing = options.map_sizing.resolve(&scene.quality);
    // Floors are the calibration's to choose only where the mismatch rule sizes the maps (one
    // size asked for every map is kept) and only above the rule's own smallest map.
    let floors_free = model.calibrated && matches!(sizing, MapSizing::Mismatch { .. });
    let only_base;
    let pick_from = if floors_free {
        model
    } else {
        only_base = ErrorModel {
            curves: vec![model.curve(map_floor(options, scene)).clone()],
            ..model.clone()
        };
        &only_base
    };
    let filter = options.penumbra_filter;
    // A radius asked for is kept, so the cell filter (which replaces it) is no choice then.
    let without_cell;
    let pick_from = if matches!(filter, PenumbraFilter::Radius(_)) {
        without_cell = ErrorModel {
            curves: pick_from
                .curves
                .iter()
                .map(|c| Curve {
                    cell: Vec::new(),
                    ..c.clone()
                })
                .collect(),
            ..pick_from.clone()
        };
        &without_cell
    } else {
        pick_from
    };
    // The scene at `n` samples per area light, as the choice sets it.
    let at = |n: u32| {
        if model.calibrated {
            with_area_samples(scene, |_| n.min(max))
        } else {
            with_area_samples(scene, |c| {
                if n >= from {
                    (c * (n / from)).min(max)
                } else {
                    (c / (from / n)).max(1)
                }
            })
        }
    };
    // Highlights: each area light raised to what its visible glossy receivers need, after the
    // choice; the choice pays for it (a count the raise undoes saves nothing).
    let receivers = super::cull::receivers(scene, &super::geom::mesh_bounds(scene));
    let rho = super::gloss::max_spacing_over_lobe(target_db);
    let area_total = |s: &Scene| -> f64 {
        s.lights
            .iter()
            .filter(|l| l.is_area())
            .map(|l| f64::from(s.quality.samples_of(l)))
            .sum()
    };
    let raised = |n: u32| -> f64 {
        let s = at(n);
        match super::gloss::raise(&s, &receivers, rho) {
            Some((r, _)) => area_total(&r) / area_total(&s).max(1.0),
            None => 1.0,
        }
    };
    let choice = pick_from.cheapest_raised(
        target_db,
        from,
        |c, n| resolve_radius(c, filter, None, Some(n)),
        raised,
    );
    let n = choice.samples;
    let s = at(n);
    let (s, gloss) = super::gloss::raise(&s, &receivers, rho).unwrap_or((s, Vec::new()));
    let mut s = s;
    if choice.cell {
        s.quality.filter = ShadowFilter::Cell {
            taps: lightfold_scene::defaults::CELL_TAPS,
        };
    }
    let mut o = options.clone();
    if choice.cell {
        // Each sample's shadow is already spread over its cell: no screen filter on top.
        o.penumbra_filter = PenumbraFilter::Off;
    }
    let mut floor = 0;
    if floors_free && let MapSizing::Mismatch { min, max, target } = sizing {
        let f = choice.map_floor.max(min);
        o.map_sizing = MapSizing::Mismatch {
            min: f,
            max: max.max(f),
            target,
        };
        // Recorded only where raised.
        floor = if f > min { f } else { 0 };
    }
    Some((
        s,
        o,
        TargetChoice {
            target_db,
            from,
            to: n,
            expected_db: choice.db,
            reachable: choice.db >= target_db,
            penumbra_radius: choice.radius,
            map_floor: floor,
            cell_filter: choice.cell,
            calibrated: model.calibrated,
            gloss,
        },
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn budget_filters_only_counts_lowered_below_the_scenes_and_auto_any_it_helps() {
        let balls = ErrorModel::balls();
        let c = balls.base();
        let b = PenumbraFilter::Budget;
        assert_eq!(resolve_radius(c, b, Some(16), Some(16)), 0);
        assert_eq!(resolve_radius(c, b, Some(16), Some(4)), 2);
        assert_eq!(resolve_radius(c, b, None, Some(16)), 1);
        assert_eq!(
            resolve_radius(c, PenumbraFilter::Auto, Some(16), Some(16)),
            1
        );
        assert_eq!(resolve_radius(c, PenumbraFilter::Off, Some(16), Some(4)), 0);
        assert_eq!(
            resolve_radius(c, PenumbraFilter::Radius(5), Some(16), Some(64)),
            5
        );
    }

    #[test]
    fn the_filter_cost_follows_the_benchmark_and_its_inputs() {
        // 800×600 in one band, its halo of radius + 2 rows taken out: 47 ns a pixel at radius
        // 1, 94 at radius 2 (the bench, with the crease test).
        let one = |r: u32| {
            let halo = 1.0 + 2.0 * f64::from(r + 2) / 600.0;
            filter_cost_us(r, 800, 600, 600, 1) / (800.0 * 600.0) * 1e3 / halo
        };
        assert!((one(1) - 47.4).abs() < 0.5, "{}", one(1));
        assert!((one(2) - 94.4).abs() < 0.5, "{}", one(2));
        assert_eq!(filter_cost_us(0, 800, 600, 16, 1), 0.0);
        // Halos of 3 rows on bands of 16 add 3/8; threads divide.
        let banded = filter_cost_us(1, 800, 600, 16, 1) / filter_cost_us(1, 800, 600, 600, 1);
        assert!(
            (banded - 1.375 / (1.0 + 6.0 / 600.0)).abs() < 1e-9,
            "{banded}"
        );
        let (t1, t4) = (
            filter_cost_us(2, 1920, 1080, 16, 1),
            filter_cost_us(2, 1920, 1080, 16, 4),
        );
        assert!((t1 / t4 - 4.0).abs() < 1e-9);
    }
}
