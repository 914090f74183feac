//! Frame budgets the fastest K cannot meet: the planner lowers shadow maps, then samples per area
//! light, then ε (`plan/budget.rs`, `docs/planner.md` § Frame budgets), says what it gave up, and
//! gives the same plan for the same inputs.

use lightfold_coordinator::plan::{
    ClusterSpec, Knob, MAX_EPSILON, Plan, PlanOptions, expected_penumbra_db, plan, replan,
    scene_hash,
};
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
    assert_eq!(samples.to, "4");
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
