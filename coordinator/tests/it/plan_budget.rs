//! Frame budgets the fastest K cannot meet: the planner lowers shadow maps, then samples per area
//! light, then ε (`plan/budget.rs`, `docs/planner.md` § Frame budgets), says what it gave up, and
//! gives the same plan for the same inputs.

use lightfold_coordinator::plan::{
    ClusterSpec, Curve, ErrorModel, Knob, MAX_EPSILON, PenumbraFilter, Plan, PlanOptions,
    expected_penumbra_db, plan, replan, scene_hash,
};
use lightfold_protocol::{Layer, OpSource};
use lightfold_scene::Scene;
use proptest::prelude::*;

fn balls() -> Scene {
    let mut s = lightfold_scene::builtin("balls").unwrap();
    // A small image keeps the planner's probes cheap; sizes still vary per light.
    s.camera.width = 320;
    s.camera.height = 240;
    s
}

/// Eight render nodes: 32 samples need K ≥ 4, so the budget cannot be met by smaller K alone.
fn eight() -> ClusterSpec {
    ClusterSpec::local(8, 8)
}

fn with_budget(s: &Scene, budget_us: Option<u64>) -> Plan {
    plan(
        s,
        &eight(),
        &PlanOptions {
            frame_budget_us: budget_us,
            ..PlanOptions::default()
        },
    )
    .unwrap()
}

/// Energy of the active samples per source light (the point sum's weights).
fn energy(p: &Plan) -> Vec<f64> {
    let lights = p.samples.iter().map(|s| s.light).max().unwrap_or(0) as usize + 1;
    let mut e = vec![0.0; lights];
    for s in &p.samples {
        e[s.light as usize] += f64::from(s.intensity);
    }
    e
}

#[test]
fn a_budget_the_requested_quality_meets_gives_nothing_up() {
    let s = balls();
    let free = with_budget(&s, None);
    let loose = with_budget(&s, Some(10_000_000));
    assert!(loose.concessions.is_empty());
    assert_eq!(loose.samples, free.samples);
    assert!(!loose.to_string().contains("gave up"), "{loose}");
}

#[test]
fn a_tight_budget_lowers_maps_then_samples_then_epsilon_and_says_so() {
    let s = balls();
    let free = with_budget(&s, None);
    // Half the requested quality's estimate: K alone cannot get there on 8 nodes.
    let p = with_budget(&s, Some(free.est_frame_us / 2));
    assert!(!p.concessions.is_empty());
    assert!(p.est_frame_us <= free.est_frame_us / 2, "{p}");
    // The ladder's order, each knob's steps together.
    let order: Vec<Knob> = p.concessions.iter().map(|c| c.knob).collect();
    let rank = |k: Knob| match k {
        Knob::ShadowMaps => 0,
        Knob::SamplesPerAreaLight => 1,
        Knob::Epsilon => 2,
    };
    assert!(
        order.windows(2).all(|w| rank(w[0]) <= rank(w[1])),
        "{order:?}"
    );
    assert!(order.contains(&Knob::SamplesPerAreaLight), "{order:?}");
    // Fewer samples, the same light: the point sum's weights keep each light's energy.
    assert!(p.samples.len() < free.samples.len());
    for (a, b) in energy(&p).iter().zip(energy(&free)) {
        assert!((a - b).abs() <= 1e-4 * b.abs(), "{a} against {b}");
    }
    // The model's figure is the sum of the steps', and the printed plan names them.
    let db: f32 = p.concessions.iter().filter_map(|c| c.expected_db).sum();
    assert!(db < -4.0, "{db}");
    let text = p.to_string();
    assert!(text.contains("gave up for the budget: "), "{text}");
    assert!(text.contains("samples per area light 16 → "), "{text}");
    assert!(text.contains("within the"), "{text}");
    // Nodes were sent the scene as it is: the plan names that scene, not the lowered copy.
    assert_eq!(p.scene_hash, scene_hash(&s));
}

#[test]
fn an_impossible_budget_stops_where_no_step_lowers_the_estimate() {
    let s = balls();
    let free = with_budget(&s, None);
    let p = with_budget(&s, Some(1));
    assert!(p.est_frame_us < free.est_frame_us);
    let text = p.to_string();
    assert!(text.contains("over the 0.0 ms budget"), "{text}");
    // Two area lights of 16 on 8 nodes: 4 each puts one light on every node (K = 1); halving
    // again would leave the estimate where it is, so the ladder stops there and ε is not raised
    // (it drops nothing of balls that would lower it).
    assert_eq!(p.k, 1);
    let samples = p
        .concessions
        .iter()
        .rev()
        .find(|c| c.knob == Knob::SamplesPerAreaLight)
        .unwrap();
    // The default `Budget` filter would ride on the lowered samples (radius 2 at 4), but no
    // radius fits the last stage within a budget of 1 µs, so none is added.
    assert_eq!(samples.to, "4");
    assert_eq!(p.penumbra_radius, 0);
    let mut fewer = s.clone();
    fewer.quality.samples_per_area_light = Some(2);
    fewer.quality.map_sizing = lightfold_scene::MapSizing::Fixed;
    assert!(with_budget(&fewer, None).est_frame_us >= p.est_frame_us);
    assert!(p.concessions.iter().all(|c| c.knob != Knob::Epsilon));
    let db: f32 = p.concessions.iter().filter_map(|c| c.expected_db).sum();
    let want = expected_penumbra_db(4) - expected_penumbra_db(16);
    assert!((db - want).abs() < 1e-3, "{db} against {want}");
}

/// balls with a faint point light above it: kept at the default ε, dropped at [`MAX_EPSILON`].
fn balls_and_a_faint_light(power: f32) -> Scene {
    let mut s = balls();
    s.lights.push(lightfold_scene::Light {
        name: "faint".into(),
        shape: lightfold_scene::LightShape::Point {
            position: [0.0, 6.0, 0.0],
        },
        color: [1.0; 3],
        power,
        range: None,
        samples: 1,
    });
    s
}

#[test]
fn epsilon_drops_the_least_important_samples_when_nothing_else_is_left() {
    // Two nodes: at one sample per area light three lights still put two on one node; only
    // dropping the faint one lowers the estimate further (K = 1), two ε steps up (its bound,
    // 5.1e-3, is above the first step's 4e-3).
    let s = balls_and_a_faint_light(0.1);
    let two = ClusterSpec::local(2, 2);
    let o = |e: f32, b: Option<u64>| PlanOptions {
        epsilon: e,
        frame_budget_us: b,
        ..PlanOptions::default()
    };
    // Preconditions: kept at the default ε, dropped at the ladder's largest.
    let faint = s.lights.len() as u32 - 1;
    let active_faint = |p: &Plan| p.active.iter().any(|&i| p.samples[i].light == faint);
    let wide = ClusterSpec::local(40, 40);
    assert!(active_faint(&plan(&s, &wide, &o(1e-3, None)).unwrap()));
    assert!(!active_faint(
        &plan(&s, &wide, &o(MAX_EPSILON, None)).unwrap()
    ));
    let p = plan(&s, &two, &o(1e-3, Some(1))).unwrap();
    assert!(!active_faint(&p), "{p}");
    let eps: Vec<&str> = p
        .concessions
        .iter()
        .filter(|c| c.knob == Knob::Epsilon)
        .map(|c| c.to.as_str())
        .collect();
    assert_eq!(eps, ["4.0e-3", "1.6e-2"]);
    assert_eq!(p.k, 1);
    assert!(p.epsilon_used > 4e-3 && p.epsilon_used <= p.epsilon);
    let text = p.to_string();
    assert!(text.contains("ε 1.0e-3 → 1.6e-2"), "{text}");
    assert!(
        text.contains("dropped samples add at most 5.1e-3"),
        "{text}"
    );
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 12, ..ProptestConfig::default() })]

    /// For any budget: within it whenever the ladder left anything to lower, lower budgets never
    /// expect more accuracy, and planning again with nothing changed gives the same plan.
    #[test]
    fn budgets_are_met_monotone_and_stable(frac in 0.05f64..1.2) {
        let s = balls();
        let free = with_budget(&s, None);
        let budget = (free.est_frame_us as f64 * frac) as u64;
        let p = with_budget(&s, Some(budget));
        // Over the budget only where the ladder ran out: the fastest estimate any budget gets.
        let fastest = with_budget(&s, Some(1)).est_frame_us;
        prop_assert!(p.est_frame_us <= budget || p.est_frame_us == fastest, "{} over {}", p.est_frame_us, budget);
        let db = |p: &Plan| p.concessions.iter().filter_map(|c| c.expected_db).sum::<f32>();
        let tighter = with_budget(&s, Some(budget * 3 / 4));
        prop_assert!(db(&tighter) <= db(&p) + 1e-6);
        prop_assert!(tighter.samples.len() <= p.samples.len());
        // Re-planning over the same cluster keeps every choice (the control loop's case).
        let options = PlanOptions { frame_budget_us: Some(budget), epoch: 2, ..PlanOptions::default() };
        let again = replan(&s, &eight(), &options, &p).unwrap();
        prop_assert_eq!(&again.concessions, &p.concessions);
        prop_assert_eq!(&again.samples, &p.samples);
        prop_assert_eq!(&again.nodes, &p.nodes);
    }
}

#[test]
fn an_error_target_picks_the_fewest_samples_the_model_expects_to_reach_it() {
    let s = balls();
    let with_target = |t: f32| {
        plan(
            &s,
            &ClusterSpec::local(64, 64),
            &PlanOptions {
                target_penumbra_db: Some(t),
                penumbra_filter: PenumbraFilter::Off,
                ..PlanOptions::default()
            },
        )
        .unwrap()
    };
    let free = with_budget(&s, None);
    // balls has two area lights of 16: the model's 8 → 42.4, 16 → 47.5, 32 → 51.5 dB.
    for (target, per_light) in [(40.0, 8u32), (47.0, 16), (50.0, 32), (20.0, 1)] {
        let p = with_target(target);
        let t = p.target.clone().unwrap();
        assert_eq!((t.from, t.to), (16, per_light), "target {target}");
        assert!(t.reachable && t.expected_db >= target, "{t:?}");
        // One fewer halving would miss it (or it is already one sample).
        assert!(per_light == 1 || expected_penumbra_db(per_light / 2) < target);
        assert_eq!(p.samples.len(), 2 * per_light as usize);
        for (a, b) in energy(&p).iter().zip(energy(&free)) {
            assert!((a - b).abs() <= 1e-4 * b.abs(), "{a} against {b}");
        }
        assert!(
            p.to_string()
                .contains(&format!("error target {target:.1} dB"))
        );
        assert_eq!(p.scene_hash, scene_hash(&s));
    }
    // Beyond what the model expects of any count it measured: its last (256), out of reach.
    let p = plan(
        &s,
        &ClusterSpec::local(256, 256),
        &PlanOptions {
            target_penumbra_db: Some(90.0),
            penumbra_filter: PenumbraFilter::Off,
            ..PlanOptions::default()
        },
    )
    .unwrap();
    let t = p.target.clone().unwrap();
    assert!(!t.reachable && t.to == 256, "{t:?}");
    assert!(p.to_string().contains("out of reach"));
    // A budget lowers from the target's choice, not from the scene's.
    let both = plan(
        &s,
        &eight(),
        &PlanOptions {
            target_penumbra_db: Some(50.0),
            frame_budget_us: Some(free.est_frame_us),
            penumbra_filter: PenumbraFilter::Off,
            ..PlanOptions::default()
        },
    )
    .unwrap();
    let first = both
        .concessions
        .iter()
        .find(|c| c.knob == Knob::SamplesPerAreaLight)
        .unwrap();
    assert_eq!(first.from, "32");
    // Bad targets are refused.
    for bad in [0.0, -3.0, f32::NAN, 250.0] {
        let o = PlanOptions {
            target_penumbra_db: Some(bad),
            ..PlanOptions::default()
        };
        assert!(plan(&s, &eight(), &o).is_err(), "{bad}");
    }
}

/// The last stage with the penumbra filter at `radius`: `penumbra` between the sum and
/// `material`, reading what `material` read (the sum, and the input with the material layers,
/// which carries the eye depth), `material` reading its output; bands at least the halo; and a
/// compositor accepts the configuration.
fn assert_filtered(p: &Plan, radius: u32) {
    assert_eq!(p.penumbra_radius, radius, "{p}");
    let root = p.stages.last().unwrap();
    let names: Vec<&str> = root.ops.iter().map(|o| o.name()).collect();
    let k = names
        .iter()
        .position(|n| *n == "penumbra")
        .expect("a penumbra stage");
    assert_eq!(&names[k..], ["penumbra", "material", "output"], "{names:?}");
    assert_eq!(crate::params(&root.ops[k])["radius"], radius);
    assert_eq!(crate::params(&root.ops[k])["width"], p.width);
    let w = &root.wiring;
    assert_eq!(w[k][0], OpSource::Op(k as u32 - 1));
    let OpSource::Input(m) = w[k][1] else {
        panic!("{w:?}")
    };
    assert_eq!(w[k + 1], vec![OpSource::Op(k as u32), OpSource::Input(m)]);
    assert_eq!(w[k + 2], vec![OpSource::Op(k as u32 + 1)]);
    let layers: Vec<Layer> = root.inputs[m as usize].layers.iter().map(|l| l.0).collect();
    assert!(
        layers.contains(&Layer::Depth) && layers.contains(&Layer::Diffuse),
        "{layers:?}"
    );
    assert!(p.band_height >= radius.max(2));
    let cfg = p.compositor_config(&root.compositor).unwrap();
    lightfold_compositor::daemon::StagePlan::new(cfg, 64 << 20).expect("the stage accepts it");
}

fn unfiltered(p: &Plan) {
    assert_eq!(p.penumbra_radius, 0);
    for s in &p.stages {
        assert!(s.ops.iter().all(|o| o.name() != "penumbra"), "{p}");
        assert!(
            s.inputs
                .iter()
                .all(|i| i.layers.iter().all(|l| l.0 != Layer::Depth))
        );
    }
}

#[test]
fn the_penumbra_filter_rides_on_lowered_samples_and_error_targets() {
    let s = balls();
    let with = |filter: PenumbraFilter, budget: Option<u64>, target: Option<f32>| {
        // Enough nodes for a target's 32 samples per light (eight set the budget's ladder).
        let nodes = if target.is_some() { 64 } else { 8 };
        plan(
            &s,
            &ClusterSpec::local(nodes, nodes),
            &PlanOptions {
                penumbra_filter: filter,
                frame_budget_us: budget,
                target_penumbra_db: target,
                // The untiled ladder (tiles would meet the budget with fewer steps).
                tiles: 1,
                ..PlanOptions::default()
            },
        )
        .unwrap()
    };
    // Nothing lowered: the scene as it asks (Budget, the default), or filtered by request.
    let free = with(PenumbraFilter::Budget, None, None);
    unfiltered(&free);
    unfiltered(&with(PenumbraFilter::Budget, Some(10_000_000), None));
    assert_filtered(&with(PenumbraFilter::Auto, None, None), 1);
    assert_filtered(&with(PenumbraFilter::Radius(3), None, None), 3);
    // A budget that halves the samples adds the filter at the model's radius for the count it
    // reached, and says so; with `Off` the same budget gives the same samples unfiltered.
    let tight = free.est_frame_us / 2;
    let p = with(PenumbraFilter::Budget, Some(tight), None);
    let per_light = p.samples.len() as u32 / 2;
    assert!(per_light < 16, "{p}");
    let radius = lightfold_coordinator::plan::filter_radius(per_light);
    assert!(radius > 0);
    assert_filtered(&p, radius);
    let step = p
        .concessions
        .iter()
        .rfind(|c| c.knob == Knob::SamplesPerAreaLight)
        .unwrap();
    assert!(
        step.to.ends_with(&format!("penumbra filter r{radius}")),
        "{step:?}"
    );
    assert!(p.brief().to_string().contains("penumbra filter: radius"));
    let off = with(PenumbraFilter::Off, Some(tight), None);
    unfiltered(&off);
    assert_eq!(off.samples.len(), p.samples.len());
    // The filtered model's figure is higher than the unfiltered one's for the same step.
    let gain: f32 = p.concessions.iter().filter_map(|c| c.expected_db).sum();
    let plain: f32 = off.concessions.iter().filter_map(|c| c.expected_db).sum();
    assert!(gain > plain, "{gain} vs {plain}");
    // Error targets: the filter lets fewer samples reach them (50 dB: 16 + r1 against 32
    // unfiltered; 40 dB: 4 + r2 against 8).
    for (target, per_light, radius) in [(50.0, 16, 1), (40.0, 4, 2), (47.0, 16, 1), (20.0, 1, 4)] {
        let p = with(PenumbraFilter::Budget, None, Some(target));
        let t = p.target.clone().unwrap();
        assert_eq!(
            (t.to, t.penumbra_radius),
            (per_light, radius),
            "{target}: {t:?}"
        );
        assert!(t.reachable && t.expected_db >= target, "{t:?}");
        assert_filtered(&p, radius);
        assert!(
            p.to_string()
                .contains(&format!("+ penumbra filter r{radius}"))
        );
    }
    let plain = with(PenumbraFilter::Off, None, Some(50.0));
    assert_eq!(plain.target.unwrap().to, 32);
    // A radius out of range is refused.
    for bad in [0, 9] {
        let o = PlanOptions {
            penumbra_filter: PenumbraFilter::Radius(bad),
            ..PlanOptions::default()
        };
        assert!(plan(&s, &eight(), &o).is_err(), "{bad}");
    }
}

#[test]
fn the_last_stage_filters_between_the_sum_and_the_material_in_every_layout() {
    use lightfold_coordinator::plan::Topology;
    let s = balls();
    for (topology, own_node) in [
        (Topology::Chain, false),
        (Topology::Chain, true),
        (Topology::Tree, false),
        (Topology::Tree, true),
    ] {
        for radius in [1, 4] {
            let o = PlanOptions {
                topology,
                material_own_node: own_node,
                penumbra_filter: PenumbraFilter::Radius(radius),
                band_height: 2,
                // The untiled layouts (tiled, the filter reads the tiles' composed depth).
                tiles: 1,
                ..PlanOptions::default()
            };
            let p = plan(&s, &ClusterSpec::local(16, 16), &o).unwrap();
            assert_filtered(&p, radius);
            // Bands are raised to the halo (the radius and the 2 rows the crease test reads
            // each tap's slope from) and no further.
            assert_eq!(p.band_height, radius + 2, "{topology:?} {own_node}");
        }
    }
}

/// A compositor that says how many cores it has.
fn with_threads(mut cluster: ClusterSpec, threads: u32) -> ClusterSpec {
    use lightfold_protocol::{Capabilities, Role};
    for c in &mut cluster.compositors {
        c.capabilities = Some(Capabilities {
            threads,
            ..Capabilities::unmeasured(Role::Compositor, &c.id)
        });
    }
    cluster
}

#[test]
fn the_filter_is_added_only_where_the_last_stage_can_run_it_within_the_budget() {
    use lightfold_coordinator::plan::{CostScale, filter_cost_us};
    // 1080p, nodes a thousand times faster than the default model (so the budget is the last
    // stage's alone), `auto`: the model's radius at 16 samples (1) takes about 98 ms a frame on
    // one core and 6 ms on sixteen.
    let mut s = balls();
    s.camera.width = 1920;
    s.camera.height = 1080;
    let budget_ms = 20;
    let with = |threads: u32, filter: PenumbraFilter| {
        plan(
            &s,
            &with_threads(ClusterSpec::local(8, 8), threads),
            &PlanOptions {
                frame_budget_us: Some(budget_ms * 1000),
                learned: lightfold_coordinator::plan::Learned {
                    cost_scale: CostScale::uniform(1e-3),
                    ..Default::default()
                },
                penumbra_filter: filter,
                ..PlanOptions::default()
            },
        )
        .unwrap()
    };
    let (one, many) = (
        with(1, PenumbraFilter::Auto),
        with(16, PenumbraFilter::Auto),
    );
    assert!(
        one.concessions.is_empty() && many.concessions.is_empty(),
        "{many}"
    );
    let cost = |p: &Plan, threads| {
        filter_cost_us(p.penumbra_radius, p.width, p.height, p.band_height, threads) / 1e3
    };
    assert_eq!(many.penumbra_radius, 1, "{many}");
    assert!(cost(&many, 16) <= budget_ms as f64);
    assert_eq!(one.penumbra_radius, 0, "{one}");
    assert!(filter_cost_us(1, 1920, 1080, one.band_height, 1) / 1e3 > budget_ms as f64);
    // An explicit radius is kept whatever it costs.
    assert_eq!(with(1, PenumbraFilter::Radius(4)).penumbra_radius, 4);
}

/// A calibration of a scene whose shadows need large maps (as the Fox's do): more samples at
/// the scene's own floor stop gaining, 2048² maps reach further, the filter gains at few samples.
fn map_bound_model() -> ErrorModel {
    ErrorModel {
        source: "test calibration".into(),
        calibrated: true,
        truth_floor_db: 0.0,
        key: String::new(),
        curves: vec![
            Curve {
                map_floor: 512,
                unfiltered: vec![(4, 29.0), (16, 35.5), (64, 37.5), (128, 37.8)],
                filtered: vec![(4, 2, 31.0)],
                seconds_per_sample: 0.010,
                cell: vec![],
                cell_seconds_per_sample: 0.0,
            },
            Curve {
                map_floor: 2048,
                unfiltered: vec![(4, 30.0), (16, 40.0), (64, 46.0), (128, 48.0)],
                filtered: vec![(4, 2, 32.0)],
                seconds_per_sample: 0.030,
                cell: vec![],
                cell_seconds_per_sample: 0.0,
            },
        ],
    }
}

#[test]
fn a_calibrated_target_chooses_samples_map_floor_and_filter_at_the_least_measured_cost() {
    let s = balls();
    let at = |target: f32, model: Option<ErrorModel>| {
        plan(
            &s,
            &ClusterSpec::local(256, 256),
            &PlanOptions {
                target_penumbra_db: Some(target),
                learned: lightfold_coordinator::plan::Learned {
                    error_model: model,
                    ..Default::default()
                },
                ..PlanOptions::default()
            },
        )
        .unwrap()
    };
    // 45 dB: only 2048² maps reach it, at 64 samples per light (46 dB; 32 would give 43).
    let p = at(45.0, Some(map_bound_model()));
    let t = p.target.clone().unwrap();
    assert_eq!(
        (t.to, t.map_floor, t.penumbra_radius),
        (64, 2048, 0),
        "{t:?}"
    );
    assert!(t.calibrated && t.reachable && (t.expected_db - 46.0).abs() < 1e-4);
    assert_eq!(p.samples.len(), 2 * 64);
    // Every map at least the floor, where the rule alone gives smaller ones.
    let sides = |p: &Plan| {
        p.nodes
            .iter()
            .flat_map(|n| n.shadows.iter().map(|m| m.map_size))
            .collect::<Vec<_>>()
    };
    assert!(sides(&p).iter().all(|&n| n >= 2048), "{:?}", sides(&p));
    let rule = at(20.0, None);
    assert!(sides(&rule).iter().any(|&n| n < 2048), "{:?}", sides(&rule));
    let text = p.to_string();
    assert!(
        text.contains("shadow maps from 2048²") && text.contains("this scene's calibration"),
        "{text}"
    );
    // 35 dB: the scene's floor at 16 samples is cheapest (0.16 s against 0.48 s at 2048²).
    let t = at(35.0, Some(map_bound_model())).target.unwrap();
    assert_eq!((t.to, t.map_floor), (16, 0), "{t:?}");
    // 30.5 dB: 4 samples filtered (31 dB) beat 16 unfiltered; the plan filters at the model's
    // radius.
    let p = at(30.5, Some(map_bound_model()));
    let t = p.target.clone().unwrap();
    assert_eq!(
        (t.to, t.penumbra_radius, p.penumbra_radius),
        (4, 2, 2),
        "{t:?}"
    );
    // Control: the default scene's model, which knows nothing of maps, expects 45 dB from 16
    // samples at the scene's floor — what this scene's calibration says gives 35.5 dB.
    let t = at(45.0, None).target.unwrap();
    assert_eq!((t.to, t.map_floor), (16, 0), "{t:?}");
    assert!(!t.calibrated && map_bound_model().curve(512).db(16) < 40.0);
}

#[test]
fn one_map_size_asked_for_keeps_its_size_under_a_calibrated_target() {
    let s = balls();
    let p = plan(
        &s,
        &ClusterSpec::local(256, 256),
        &PlanOptions {
            target_penumbra_db: Some(45.0),
            learned: lightfold_coordinator::plan::Learned {
                error_model: Some(map_bound_model()),
                ..Default::default()
            },
            map_sizing: lightfold_coordinator::plan::MapSizing::Fixed(1024),
            ..PlanOptions::default()
        },
    )
    .unwrap();
    let t = p.target.clone().unwrap();
    assert_eq!(t.map_floor, 0, "{t:?}");
    assert!(
        p.nodes
            .iter()
            .flat_map(|n| &n.shadows)
            .all(|m| m.map_size == 1024)
    );
    // Out of reach on the floor it has: the most it measured, said so.
    assert!(!t.reachable && t.to == 128, "{t:?}");
}
