//! Fitting the cost model to measured frames under a frame budget (`docs/planner.md` § Frame
//! budgets): each settled frame's reports give every node's fixed cost and cost per light over
//! what it registered; once an epoch has measured enough frames, a model that strays from them
//! is corrected (`PlanOptions::cost_scale`), and a re-plan is proposed when the corrected model
//! changes the plan's choices and the frames are over the budget, or well under it with a
//! candidate of more quality. No I/O and no clock: the session core feeds it frames and asks it
//! after each step.

use super::{ClusterSpec, CostScale, Knob, Plan, PlanOptions, light_weight, node_cost, replan};
use lightfold_protocol::{FrameStats, stats};
use lightfold_scene::Scene;
use std::collections::{HashMap, HashSet};

/// Settled frames an epoch measures before the cost model is checked against them, and how far
/// (as a factor either way) the median may stray from the estimate before it is corrected.
pub const ADAPT_FRAMES: usize = 6;
pub const ADAPT_BAND: f64 = 1.25;
/// Frames under this share of the budget may re-plan for more quality.
pub const RAISE_BELOW: f64 = 0.8;

/// The adaptation's state over a session.
#[derive(Debug, Default)]
pub struct Adapt {
    /// Each settled frame of this epoch: its slowest node's measured render time (µs), and per
    /// node and frame the fixed and per-light costs measured over the registered model's.
    measured: Vec<f64>,
    scales: Vec<(f64, f64)>,
    /// Per render node of the plan: its registered model (fixed µs, µs per light), the model's
    /// weights of its lights (whole, shadow passes), and how many of the plan's nodes share its
    /// machine's CPU (1 on a GPU): their work stretches each other's by about that much, which
    /// the cost model counts by adding them up (`plan/cpu_hosts.rs`), not in each node's costs.
    model: HashMap<String, [f64; 5]>,
    /// Plans (`choices`) whose frames were measured over the current budget.
    over_budget: HashSet<String>,
    /// The best plan measured within the current budget: its quality and the cost factors it
    /// was planned under; and the factors the current plan was planned under.
    known_good: Option<((usize, std::cmp::Reverse<usize>), CostScale)>,
    plan_scale: CostScale,
}

impl Adapt {
    /// A new epoch is configured: its nodes' registered model, the factors it was planned
    /// under, and no measurements yet.
    pub fn epoch(&mut self, plan: &Plan, cluster: &ClusterSpec, opts: &PlanOptions) {
        let sharing = super::cpu_hosts::plan_sharing(&plan.nodes, &cluster.nodes);
        self.model = plan
            .nodes
            .iter()
            .zip(sharing)
            .filter_map(|(n, (sharing, _))| {
                let spec = cluster.nodes.iter().find(|d| d.id == n.node)?;
                let (fixed, light) = node_cost(spec, plan);
                let (w_all, w_shadow) = n
                    .shadows
                    .iter()
                    .map(light_weight)
                    .fold((0.0, 0.0), |a, w| (a.0 + w.0, a.1 + w.1));
                Some((
                    n.node.clone(),
                    [fixed, light, w_all, w_shadow, sharing.max(1) as f64],
                ))
            })
            .collect();
        self.plan_scale = opts.learned.cost_scale;
        self.measured.clear();
        self.scales.clear();
    }

    /// The frame budget changed: what was measured against the old one no longer counts.
    pub fn budget_changed(&mut self) {
        self.over_budget.clear();
        self.known_good = None;
    }

    /// Records a settled frame's reports (under a frame budget).
    pub fn measure(&mut self, opts: &PlanOptions, stats: &[FrameStats]) {
        if opts.frame_budget_us.is_none() {
            return;
        }
        let mut slowest = None::<u64>;
        for s in stats {
            let Some(&[fixed_us, light_us, w_all, w_shadow, sharing]) =
                self.model.get(&s.daemon_id)
            else {
                continue;
            };
            let work = s.pose_us + s.setup_us + s.shadow_us + s.eye_us + s.readback_us + s.pack_us;
            slowest = Some(slowest.map_or(work, |w| w.max(work)));
            // Kept maps (walkthrough) hide the shadow passes' cost: no per-light figure.
            if w_shadow <= 0.0 || s.maps_kept > 0 || fixed_us <= 0.0 || light_us <= 0.0 {
                continue;
            }
            // A node's own costs: its time with the machine's CPU shared, over the sharing.
            let per_light = s.shadow_us as f64 / w_shadow / sharing;
            let work = work as f64 / sharing;
            let rest = (work - per_light * w_all).max(0.05 * work);
            self.scales.push((rest / fixed_us, per_light / light_us));
        }
        if let Some(w) = slowest {
            self.measured.push(w as f64);
        }
    }

    /// Under a frame budget, once `ADAPT_FRAMES` settled frames of an epoch are measured: each
    /// node's shadow passes give its cost per light (over the model's shadow weight of its
    /// lights), the rest of its work its fixed cost. When the medians stray from the scales in
    /// use by more than `ADAPT_BAND`×, `opts` takes them (`PlanOptions::cost_scale`). A re-plan
    /// is proposed (the returned reason, for the viewers) only when the corrected model changes
    /// the plan's choices (K, samples, what was given up, lights per node) and the frames are
    /// over the budget, or under `RAISE_BELOW` of it with a candidate of more quality (more
    /// samples or fewer concessions; never only to free nodes); a plan whose frames were
    /// measured over this budget is never chosen again (no oscillation between two plans the
    /// model cannot tell apart).
    pub fn review(
        &mut self,
        scene: &Scene,
        cluster: &ClusterSpec,
        opts: &mut PlanOptions,
        current: &Plan,
    ) -> Option<String> {
        let budget = opts.frame_budget_us?;
        if self.measured.len() < ADAPT_FRAMES || self.scales.is_empty() {
            return None;
        }
        // Both hold at least one value here (checked above).
        let median = |v: &[f64]| stats::median(v).unwrap_or(f64::NAN);
        let took = median(&std::mem::take(&mut self.measured));
        let scales = std::mem::take(&mut self.scales);
        let fixed = median(&scales.iter().map(|s| s.0).collect::<Vec<_>>());
        let light = median(&scales.iter().map(|s| s.1).collect::<Vec<_>>());
        let over = took > budget as f64;
        if over {
            self.over_budget.insert(choices(current));
        } else if self.known_good.is_none_or(|(q, _)| quality(current) > q) {
            self.known_good = Some((quality(current), self.plan_scale));
        }
        // Over the budget where a plan of more quality was measured within it: back to that one
        // (the factors it was planned under give it again on the same cluster).
        if over
            && let Some((q, scale)) = self.known_good
            && q > quality(current)
        {
            self.known_good = None;
            opts.learned.cost_scale = scale;
            return Some(format!(
                "measured frames take {:.1} ms, over the {:.1} ms budget: back to the last plan \
                 measured within it",
                took / 1e3,
                budget as f64 / 1e3
            ));
        }
        let now = opts.learned.cost_scale;
        let strays = |measured: f64, used: f64| (measured / used).ln().abs() > ADAPT_BAND.ln();
        if !(fixed.is_finite() && light.is_finite() && fixed > 0.0 && light > 0.0)
            || !(strays(fixed, now.fixed) || strays(light, now.light))
        {
            return None;
        }
        let mut o = opts.clone();
        o.learned.cost_scale = CostScale {
            fixed: fixed.clamp(1e-4, 1e4),
            light: light.clamp(1e-4, 1e4),
        };
        let candidate = replan(scene, cluster, &o, current).ok()?;
        let text = format!(
            "measured frames ({:.1} ms, the model's estimate {:.1} ms) put the nodes' fixed cost \
             at {fixed:.3}× and their cost per light at {light:.3}× what they registered",
            took / 1e3,
            current.est_frame_us as f64 / 1e3
        );
        opts.learned.cost_scale = o.learned.cost_scale;
        let key = choices(&candidate);
        // Under the budget, only for more quality (not to free nodes: the frames fit as they are).
        let better = quality(&candidate) > quality(current);
        let act = over || (took < RAISE_BELOW * budget as f64 && better);
        if key == choices(current) || !act || self.over_budget.contains(&key) {
            tracing::info!("{text}: the corrected cost model keeps the plan");
            return None;
        }
        Some(format!(
            "{text}: re-planning for the {:.1} ms budget",
            budget as f64 / 1e3
        ))
    }
}

/// What a plan chose, estimates aside: K, what it gave up, the active samples and each node's
/// lights (two plans with the same key render the same frames at the same cost).
fn choices(p: &Plan) -> String {
    let given: Vec<(Knob, &str)> = p
        .concessions
        .iter()
        .map(|c| (c.knob, c.to.as_str()))
        .collect();
    let lights: Vec<&[usize]> = p.nodes.iter().map(|n| n.lights.as_slice()).collect();
    format!(
        "K {} · {given:?} · {} samples, active {:?} · {lights:?}",
        p.k,
        p.samples.len(),
        p.active
    )
}

/// A plan's quality for the budget's purposes: more samples, then fewer concessions.
fn quality(p: &Plan) -> (usize, std::cmp::Reverse<usize>) {
    (p.samples.len(), std::cmp::Reverse(p.concessions.len()))
}
