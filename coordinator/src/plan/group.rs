//! Groups of at most K active samples with a node colour `c_n` (by colour where the scene allows,
//! so a light's colour can change per frame by changing `c_n` alone), and their assignment to
//! render nodes balanced by measured or estimated cost (ARCHITECTURE §9).

use super::types::{DaemonSpec, ShadowPlan};
use lightfold_scene::LightSample;

/// Estimated cost of one light at 800×600 with one 512² shadow view (docs/platform.md: ≈ 12 ms).
pub const DEFAULT_LIGHT_US: u64 = 12_000;
/// Estimated fixed cost of a frame at 800×600: the eye pass and readback (docs/platform.md: ≈ 60 ms).
pub const DEFAULT_FIXED_US: u64 = 60_000;
/// Pixels the default costs were measured at.
const REFERENCE_PIXELS: f64 = 800.0 * 600.0;
/// Cost of each extra material render target, as a fraction of the fixed eye-pass cost.
pub(super) const TARGET_FRACTION: f64 = 0.05;

/// A group of samples that one node renders.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Group {
    pub lights: Vec<usize>,
    pub color: [f32; 3],
}

/// Forms groups of at most `k` from `active` (ascending sample indices): each colour class is cut
/// into runs of `k`; the remainders stay apart (keeping their colour) unless mixing them saves
/// nodes, in which case mixed groups get `c_n` = white.
pub(crate) fn form_groups(active: &[usize], samples: &[LightSample], k: u32) -> Vec<Group> {
    let k = k.max(1) as usize;
    let mut classes: Vec<([f32; 3], Vec<usize>)> = Vec::new();
    for &i in active {
        let c = samples[i].color;
        match classes.iter_mut().find(|(cc, _)| bits(*cc) == bits(c)) {
            Some((_, v)) => v.push(i),
            None => classes.push((c, vec![i])),
        }
    }
    let mut groups = Vec::new();
    let mut rest: Vec<([f32; 3], Vec<usize>)> = Vec::new();
    for (c, members) in classes {
        let full = members.len() / k * k;
        for chunk in members[..full].chunks(k) {
            groups.push(Group {
                lights: chunk.to_vec(),
                color: node_colour(c),
            });
        }
        if full < members.len() {
            rest.push((c, members[full..].to_vec()));
        }
    }
    let total: usize = rest.iter().map(|r| r.1.len()).sum();
    if total.div_ceil(k) < rest.len() {
        let all: Vec<(usize, [f32; 3])> = rest
            .iter()
            .flat_map(|(c, m)| m.iter().map(move |&i| (i, *c)))
            .collect();
        for chunk in all.chunks(k) {
            let first = chunk[0].1;
            let same = chunk.iter().all(|(_, c)| bits(*c) == bits(first));
            groups.push(Group {
                lights: chunk.iter().map(|(i, _)| *i).collect(),
                color: if same { node_colour(first) } else { [1.0; 3] },
            });
        }
    } else {
        groups.extend(rest.into_iter().map(|(c, lights)| Group {
            lights,
            color: node_colour(c),
        }));
    }
    groups.sort_by_key(|g| g.lights[0]);
    groups
}

/// A class colour as `c_n`; compositors take only non-negative colours, so others become white
/// (the node then carries the light colour itself).
fn node_colour(c: [f32; 3]) -> [f32; 3] {
    if c.iter().all(|&v| v >= 0.0) {
        c
    } else {
        [1.0; 3]
    }
}

fn bits(c: [f32; 3]) -> [u32; 3] {
    c.map(f32::to_bits)
}

/// A node's cost model at a plan's image size: measured when it reported it (at
/// `CALIBRATION_SIZE`), otherwise the defaults (at 800×600); either scaled by the pixels the same
/// way, the fixed cost (eye pass, readback) in proportion, a light's cost half (its eye-pass
/// share) in proportion and half (its shadow passes) not.
#[derive(Debug, Clone, Copy)]
pub(crate) struct NodeCost {
    pub light_us: f64,
    pub fixed_us: f64,
}

/// Pixels the measured costs are for.
const CALIBRATION_PIXELS: f64 =
    (lightfold_protocol::CALIBRATION_SIZE.0 * lightfold_protocol::CALIBRATION_SIZE.1) as f64;

/// A fixed cost measured at `CALIBRATION_SIZE`, at `pixels`.
pub(crate) fn measured_fixed_us(fixed_us: u64, pixels: u64) -> f64 {
    fixed_us as f64 * pixels as f64 / CALIBRATION_PIXELS
}

impl NodeCost {
    pub(super) fn of(spec: &DaemonSpec, pixels: u64) -> NodeCost {
        let caps = spec.capabilities.as_ref();
        let measured = |v: Option<u64>| v.filter(|&v| v > 0).map(|v| v as f64);
        let light = measured(caps.map(|c| c.cost_per_light_us));
        let fixed = measured(caps.map(|c| c.fixed_cost_us));
        let at = |reference: f64| pixels as f64 / reference;
        NodeCost {
            light_us: match light {
                Some(l) => l * (0.5 + 0.5 * at(CALIBRATION_PIXELS)),
                None => DEFAULT_LIGHT_US as f64 * (0.5 + 0.5 * at(REFERENCE_PIXELS)),
            },
            fixed_us: match fixed {
                Some(f) => measured_fixed_us(f as u64, pixels),
                None => DEFAULT_FIXED_US as f64 * at(REFERENCE_PIXELS),
            },
        }
    }

    /// The live loop's correction from measured frames.
    pub(super) fn scaled(self, k: super::CostScale) -> NodeCost {
        NodeCost {
            light_us: self.light_us * k.light,
            fixed_us: self.fixed_us * k.fixed,
        }
    }

    /// One light: half eye-pass share, half shadow passes (per view, growing with the map side).
    pub(super) fn light(&self, shadow: &ShadowPlan) -> f64 {
        self.light_us * super::light_weight(shadow).0
    }

    pub(super) fn frame(&self, shadows: &[&ShadowPlan], extra_targets: usize) -> f64 {
        self.fixed_us * (1.0 + TARGET_FRACTION * extra_targets as f64)
            + shadows.iter().map(|s| self.light(s)).sum::<f64>()
    }
}

/// The largest K a frame budget may choose when no node reports its device limit.
pub(super) const BUDGET_MAX_K: u32 = 32;

/// The estimated frame (µs) when `groups` are assigned by cost: the slowest node, or a machine's
/// CPU nodes (`hosts`, `plan/cpu_hosts.rs`) one after another.
fn slowest<'s>(
    groups: &[Group],
    costs: &[NodeCost],
    hosts: &[Option<usize>],
    views: &impl Fn(&Group) -> Vec<&'s ShadowPlan>,
) -> f64 {
    let group_costs: Vec<Vec<f64>> = groups
        .iter()
        .map(|g| {
            let v = views(g);
            costs.iter().map(|c| c.frame(&v, 0)).collect()
        })
        .collect();
    let on_nodes = assign(&group_costs)
        .into_iter()
        .zip(&group_costs)
        .map(|(n, c)| (n, c.get(n).copied().unwrap_or(0.0)));
    super::cpu_hosts::frame_estimate(on_nodes, hosts)
}

/// With a frame budget: the largest K up to `limit` (the fewest nodes) whose slowest node fits
/// `budget_us`, among the K whose groups `fit` the cluster; the fastest estimate when none fits.
/// The estimate leaves out extra targets and per-node map-size rounding (`docs/planner.md`).
pub(crate) fn budget_k<'s>(
    budget_us: f64,
    limit: u32,
    costs: &[NodeCost],
    hosts: &[Option<usize>],
    groups_for: impl Fn(u32) -> Vec<Group>,
    fit: impl Fn(&[Group]) -> bool,
    views: impl Fn(&Group) -> Vec<&'s ShadowPlan>,
) -> u32 {
    let mut best: Option<(f64, u32)> = None;
    for k in (1..=limit).rev() {
        let groups = groups_for(k);
        if !fit(&groups) {
            // Smaller K only makes more groups.
            break;
        }
        let est = slowest(&groups, costs, hosts, &views);
        if est <= budget_us {
            return k;
        }
        if best.is_none_or(|(b, _)| est < b) {
            best = Some((est, k));
        }
    }
    best.map_or(limit, |b| b.1)
}

/// Largest K the nodes' devices take (the smallest reported limit; `k` when none reported).
pub(crate) fn device_limit(nodes: &[DaemonSpec], k: u32) -> u32 {
    nodes
        .iter()
        .filter_map(|n| n.capabilities.as_ref().map(|c| c.max_lights))
        .filter(|&m| m > 0)
        .min()
        .unwrap_or(k)
        .max(k)
}

/// The map size nodes report `Capabilities::max_lights` at.
pub(crate) const REPORTED_MAP_SIZE: u32 = lightfold_scene::defaults::SHADOW_MAP_SIZE;

/// Largest K every node's device takes with `map`² shadow maps, `None` when no node reports a
/// limit. A node's limit is the smaller of a layer count (independent of the size) and a memory
/// budget (∝ 1/map²), reported at 512²: above 512² the reported limit scaled by (512/map)² is
/// never more than the node's own, so a plan within it is never refused (`TooManyLights`).
pub(crate) fn device_limit_at(nodes: &[DaemonSpec], map: u32) -> Option<u32> {
    let reported = nodes
        .iter()
        .filter_map(|n| n.capabilities.as_ref().map(|c| c.max_lights))
        .filter(|&m| m > 0)
        .min()?;
    if map <= REPORTED_MAP_SIZE {
        return Some(reported);
    }
    let r = u64::from(REPORTED_MAP_SIZE).pow(2);
    let scaled = u64::from(reported) * r / u64::from(map).pow(2);
    Some(scaled.clamp(1, u64::from(reported)) as u32)
}

/// Assigns each group to its own node: the costliest group first, each to the free node that
/// finishes it soonest (ties: cluster order). Returns, per group, the node index (`usize::MAX`
/// when nodes ran out, which the caller rules out first).
pub(crate) fn assign(group_costs: &[Vec<f64>]) -> Vec<usize> {
    let groups = group_costs.len();
    let nodes = group_costs.first().map_or(0, Vec::len);
    // Identical nodes: any assignment is as good, so keep group i on node i (stable plans).
    if nodes >= groups
        && group_costs
            .iter()
            .all(|row| row.iter().all(|c| c.to_bits() == row[0].to_bits()))
    {
        return (0..groups).collect();
    }
    let mut order: Vec<usize> = (0..groups).collect();
    // Costliest first, judged on the first node (costs differ across nodes only by a factor).
    order.sort_by(|&a, &b| {
        group_costs[b][0]
            .total_cmp(&group_costs[a][0])
            .then(a.cmp(&b))
    });
    let mut free = vec![true; nodes];
    let mut out = vec![usize::MAX; groups];
    for g in order {
        let best = (0..nodes).filter(|&n| free[n]).min_by(|&a, &b| {
            group_costs[g][a]
                .total_cmp(&group_costs[g][b])
                .then(a.cmp(&b))
        });
        if let Some(n) = best {
            free[n] = false;
            out[g] = n;
        }
    }
    out
}

/// Slack a re-plan may add to the slowest node's estimate to keep lights where they were.
pub(super) const STICKY_SLACK: f64 = 1.05;

/// Re-plans move few lights: each group goes to the node that already rendered most of its
/// lights (`had`, per node), largest overlaps first, as long as that node's cost for the group
/// stays within `STICKY_SLACK` of the slowest node `fresh` (the cost-balanced assignment) gives;
/// groups left over take the cheapest free node. Returns, per group, the node index.
pub(crate) fn sticky(
    group_costs: &[Vec<f64>],
    fresh: &[usize],
    lights: &[&[usize]],
    had: &[Vec<usize>],
) -> Vec<usize> {
    let nodes = had.len();
    let slowest = fresh
        .iter()
        .zip(group_costs)
        .filter_map(|(&n, c)| c.get(n))
        .fold(0.0f64, |a, &b| a.max(b));
    let cap = slowest * STICKY_SLACK;
    let mut pairs: Vec<(usize, usize, usize)> = Vec::new();
    for (g, ls) in lights.iter().enumerate() {
        for (n, h) in had.iter().enumerate() {
            let overlap = ls.iter().filter(|l| h.contains(l)).count();
            if overlap > 0 && group_costs[g][n] <= cap {
                pairs.push((overlap, g, n));
            }
        }
    }
    // Largest overlap first; ties in group then node order (deterministic).
    pairs.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let mut out = vec![usize::MAX; lights.len()];
    let mut free = vec![true; nodes];
    for (_, g, n) in pairs {
        if out[g] == usize::MAX && free[n] {
            out[g] = n;
            free[n] = false;
        }
    }
    for g in 0..lights.len() {
        if out[g] != usize::MAX {
            continue;
        }
        // Prefer the fresh choice when it is free, else the cheapest free node.
        let pick = Some(fresh[g])
            .filter(|&n| n < nodes && free[n])
            .or_else(|| {
                (0..nodes).filter(|&n| free[n]).min_by(|&a, &b| {
                    group_costs[g][a]
                        .total_cmp(&group_costs[g][b])
                        .then(a.cmp(&b))
                })
            });
        if let Some(n) = pick {
            out[g] = n;
            free[n] = false;
        }
    }
    out
}
