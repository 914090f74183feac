//! Re-plans after the cluster changed: the same planner, with light groups kept on the nodes
//! that rendered them (`group::sticky`), and how many lights a re-plan moved.

use super::{ClusterSpec, Plan, PlanError, PlanOptions, plan_with};
use lightfold_scene::Scene;

/// Plans `scene` again on a changed cluster (a daemon lost or joined), moving as few lights as
/// it can: the groups are those `plan` would make, but each goes to the node that rendered most of
/// its lights in `previous` unless that makes the slowest node slower (`group::sticky`). Pure,
/// like `plan`.
pub fn replan(
    scene: &Scene,
    cluster: &ClusterSpec,
    options: &PlanOptions,
    previous: &Plan,
) -> Result<Plan, PlanError> {
    plan_with(scene, cluster, options, Some(previous))
}

/// Lights of `previous` that `next` renders on another node (or not at all).
pub fn lights_moved(previous: &Plan, next: &Plan) -> usize {
    let owner = |p: &Plan, l: usize| {
        p.nodes
            .iter()
            .find(|n| n.lights.contains(&l))
            .map(|n| n.node.clone())
    };
    previous
        .active
        .iter()
        .filter(|&&l| owner(previous, l) != owner(next, l))
        .count()
}
