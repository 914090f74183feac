//! Render nodes that share one GPU (`Capabilities::device`): their device work runs one after
//! another and each pays its own fixed cost (eye pass, readback, the process's CPU work), so
//! eight nodes of K = 4 on one GPU cost that GPU eight frames of four lights where one node of
//! K = 32 costs one. When the cluster has such nodes, the planner also plans the cluster with one
//! node per device (raising K as far as each device takes, the rule it uses when nodes are
//! short) and keeps that plan when its cost model says it is faster than the ordinary plan with
//! each device's nodes run one after another. Nodes on distinct devices, on software
//! rasterisers (which report no device) or that report nothing are never merged. The merged
//! plan says so (`Plan::shared_devices`) and lists the nodes it leaves idle.

use super::types::{ClusterSpec, Plan, PlanOptions, SharedDevices};

/// Node indices of `cluster` per shared device, for devices two or more nodes report.
fn shared(cluster: &ClusterSpec) -> Vec<Vec<usize>> {
    let mut by_device: Vec<(&str, Vec<usize>)> = Vec::new();
    for (i, n) in cluster.nodes.iter().enumerate() {
        let Some(device) = n
            .capabilities
            .as_ref()
            .map(|c| c.device.as_str())
            .filter(|d| !d.is_empty())
        else {
            continue;
        };
        match by_device.iter_mut().find(|(d, _)| *d == device) {
            Some((_, nodes)) => nodes.push(i),
            None => by_device.push((device, vec![i])),
        }
    }
    by_device
        .into_iter()
        .map(|(_, nodes)| nodes)
        .filter(|n| n.len() >= 2)
        .collect()
}

/// The cluster with one node per shared device (the first it lists) and every other node.
fn one_per_device(cluster: &ClusterSpec, devices: &[Vec<usize>]) -> (ClusterSpec, Vec<String>) {
    let left_out: Vec<usize> = devices
        .iter()
        .flat_map(|d| d[1..].iter().copied())
        .collect();
    let nodes = cluster
        .nodes
        .iter()
        .enumerate()
        .filter(|(i, _)| !left_out.contains(i))
        .map(|(_, n)| n.clone())
        .collect();
    let idle = left_out
        .iter()
        .map(|&i| cluster.nodes[i].id.clone())
        .collect();
    (
        ClusterSpec {
            nodes,
            ..cluster.clone()
        },
        idle,
    )
}

/// The most nodes `plan` puts on one of `devices`.
fn stacked(plan: &Plan, cluster: &ClusterSpec, devices: &[Vec<usize>]) -> usize {
    devices
        .iter()
        .map(|d| {
            plan.nodes
                .iter()
                .filter(|n| d.iter().any(|&i| cluster.nodes[i].id == n.node))
                .count()
        })
        .max()
        .unwrap_or(0)
}

/// `plan`'s estimated frame with the nodes it puts on one shared device of `cluster` run one
/// after another (each at most the slowest node's estimate): its estimate where no device
/// carries two of its nodes.
pub(crate) fn serial_est_us(plan: &Plan, cluster: &ClusterSpec) -> u64 {
    let stack = stacked(plan, cluster, &shared(cluster)).max(1);
    plan.est_frame_us.saturating_mul(stack as u64)
}

/// `separate` (the ordinary plan) or, where nodes share devices and the model prefers it, the
/// plan `plan_one` makes on one node per device.
pub(crate) fn prefer_merged<E>(
    cluster: &ClusterSpec,
    options: &PlanOptions,
    separate: Result<Plan, E>,
    plan_one: impl FnOnce(&ClusterSpec) -> Result<Plan, E>,
) -> Result<Plan, E> {
    if !options.merge_shared_devices {
        return separate;
    }
    let devices = shared(cluster);
    if devices.is_empty() {
        return separate;
    }
    let stack = match &separate {
        Ok(p) => stacked(p, cluster, &devices),
        Err(_) => 0,
    };
    if separate.is_ok() && stack < 2 {
        return separate;
    }
    let (reduced, idle) = one_per_device(cluster, &devices);
    let Ok(mut merged) = plan_one(&reduced) else {
        return separate;
    };
    // The ordinary plan's frame on a shared device: its nodes one after another (each at most
    // the slowest node's estimate).
    let serial_us = separate
        .as_ref()
        .map_or(u64::MAX, |p| p.est_frame_us.saturating_mul(stack as u64));
    if merged.est_frame_us > serial_us {
        return separate;
    }
    merged.idle_nodes.extend(idle);
    merged.shared_devices = Some(SharedDevices {
        devices: devices.len(),
        nodes: devices.iter().map(Vec::len).sum(),
        k_separate: separate.as_ref().map_or(0, |p| p.k),
        stacked: stack as u32,
        est_separate_us: serial_us,
    });
    Ok(merged)
}
