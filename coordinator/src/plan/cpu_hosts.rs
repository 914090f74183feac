//! Render nodes that render on one machine's CPU (software rasterisers reporting the same
//! `Capabilities::cpu_host`): each node calibrated with the machine's cores to itself, and a
//! software rasteriser spreads one frame over all of them, so their frames run one after another
//! as far as time goes. The cost model adds them up: a frame's estimate is its slowest node or
//! the sum over the nodes one machine's CPU runs, whichever is larger. Nodes on GPUs never count
//! here (two nodes sharing a GPU: `plan/shared.rs`).

use super::types::{CpuShared, DaemonSpec, NodePlan};

/// Per node of `nodes`: the index of the machine whose CPU it shares with at least one other
/// node of `nodes`, or `None`.
pub(crate) fn cpu_hosts(nodes: &[DaemonSpec]) -> Vec<Option<usize>> {
    fn host(n: &DaemonSpec) -> Option<&str> {
        n.capabilities
            .as_ref()
            .map(|c| c.cpu_host.as_str())
            .filter(|h| !h.is_empty())
    }
    let mut machines: Vec<&str> = Vec::new();
    let shared: Vec<Option<&str>> = nodes
        .iter()
        .map(|n| host(n).filter(|h| nodes.iter().filter(|m| host(m) == Some(h)).count() >= 2))
        .collect();
    shared
        .into_iter()
        .map(|h| {
            h.map(|h| match machines.iter().position(|m| *m == h) {
                Some(i) => i,
                None => {
                    machines.push(h);
                    machines.len() - 1
                }
            })
        })
        .collect()
}

/// A frame's estimate from `(node index, estimate)` pairs: the slowest node, or the sum of the
/// nodes one machine's CPU runs where that is larger.
pub(crate) fn frame_estimate(
    per_node: impl IntoIterator<Item = (usize, f64)>,
    hosts: &[Option<usize>],
) -> f64 {
    let mut slowest = 0.0f64;
    let mut machines: Vec<f64> = Vec::new();
    for (n, cost) in per_node {
        slowest = slowest.max(cost);
        if let Some(&Some(m)) = hosts.get(n) {
            if machines.len() <= m {
                machines.resize(m + 1, 0.0);
            }
            machines[m] += cost;
        }
    }
    machines.into_iter().fold(slowest, f64::max)
}

/// Per node of the plan (`nodes`, in order): how many of the plan's nodes render on its
/// machine's CPU, itself included (1 on a GPU or a machine of its own), and that machine.
pub(crate) fn plan_sharing(
    nodes: &[NodePlan],
    cluster: &[DaemonSpec],
) -> Vec<(usize, Option<usize>)> {
    let hosts = cpu_hosts(cluster);
    let machine = |id: &str| {
        let i = cluster.iter().position(|d| d.id == id)?;
        hosts[i]
    };
    let machines: Vec<Option<usize>> = nodes.iter().map(|n| machine(&n.node)).collect();
    machines
        .iter()
        .map(|&m| {
            let sharing = m.map_or(1, |m| machines.iter().filter(|&&o| o == Some(m)).count());
            (sharing, m)
        })
        .collect()
}

/// A plan's frame estimate (µs) from its nodes' estimates, and what the CPU sharing did to it.
pub(crate) fn plan_estimate(
    nodes: &[NodePlan],
    cluster: &[DaemonSpec],
) -> (u64, Option<CpuShared>) {
    let slowest = nodes.iter().map(|n| n.est_cost_us).max().unwrap_or(0);
    let sharing = plan_sharing(nodes, cluster);
    let mut machines: Vec<f64> = Vec::new();
    let mut shared: Vec<usize> = Vec::new();
    for (n, &(count, m)) in nodes.iter().zip(&sharing) {
        if let (Some(m), true) = (m, count >= 2) {
            if machines.len() <= m {
                machines.resize(m + 1, 0.0);
            }
            machines[m] += n.est_cost_us as f64;
            shared.push(m);
        }
    }
    let est = machines.into_iter().fold(slowest as f64, f64::max).round() as u64;
    let nodes_sharing = shared.len();
    shared.sort_unstable();
    shared.dedup();
    let cpu = (nodes_sharing >= 2).then_some(CpuShared {
        machines: shared.len(),
        nodes: nodes_sharing,
        est_slowest_node_us: slowest,
    });
    (est.max(slowest), cpu)
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightfold_protocol::{Capabilities, Role};

    fn node(id: &str, host: &str) -> DaemonSpec {
        DaemonSpec {
            id: id.into(),
            address: String::new(),
            capabilities: Some(Capabilities {
                cpu_host: host.into(),
                ..Capabilities::unmeasured(Role::Node, id)
            }),
        }
    }

    #[test]
    fn nodes_on_one_machines_cpu_add_up_and_others_do_not() {
        let nodes = [
            node("a", "m1"),
            node("b", "m1"),
            node("c", "m2"),
            node("d", ""),
            node("e", "m3"),
            node("f", "m3"),
            node("g", "m1"),
        ];
        assert_eq!(
            cpu_hosts(&nodes),
            [Some(0), Some(0), None, None, Some(1), Some(1), Some(0)]
        );
        let hosts = cpu_hosts(&nodes);
        // m1: 10 + 20 + 5; m3: 30 + 1; alone: 40, 25.
        let costs = [
            (0, 10.0),
            (1, 20.0),
            (2, 40.0),
            (3, 25.0),
            (4, 30.0),
            (5, 1.0),
        ];
        assert_eq!(frame_estimate(costs, &hosts), 40.0);
        let costs = [(0, 10.0), (1, 20.0), (6, 15.0), (2, 40.0)];
        assert_eq!(frame_estimate(costs, &hosts), 45.0);
        // Negative control: without the machines, the slowest node.
        assert_eq!(frame_estimate(costs, &[None; 7]), 40.0);
    }
}
