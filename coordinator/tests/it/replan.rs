//! Re-plans after a lost daemon (issue 18): every active light is still rendered exactly once,
//! by daemons that are left, and the re-plan moves as few lights as it can — with a spare node
//! only the lost node's lights move, which a fresh plan of the same cluster does not achieve.

use lightfold_coordinator::plan::{ClusterSpec, Plan, PlanOptions, lights_moved, plan, replan};
use lightfold_protocol::{Capabilities, Role};

/// `ClusterSpec::local` with registered nodes whose devices take up to 16 lights.
fn registered(nodes: usize, compositors: usize) -> ClusterSpec {
    let mut c = ClusterSpec::local(nodes, compositors);
    for n in &mut c.nodes {
        n.capabilities = Some(Capabilities {
            advertise: n.address.clone(),
            adapter: "test".into(),
            backend: "test".into(),
            max_lights: 16,
            max_texture_size: 4096,
            threads: 1,
            ..Capabilities::unmeasured(Role::Node, &n.id)
        });
    }
    c
}

fn without(cluster: &ClusterSpec, id: &str) -> ClusterSpec {
    let mut c = cluster.clone();
    c.nodes.retain(|d| d.id != id);
    c.compositors.retain(|d| d.id != id);
    c
}

fn assert_covers(p: &Plan, lost: &str) {
    let mut lights: Vec<usize> = p.nodes.iter().flat_map(|n| n.lights.clone()).collect();
    lights.sort_unstable();
    let mut active = p.active.clone();
    active.sort_unstable();
    assert_eq!(lights, active, "every active light once");
    assert!(p.nodes.iter().all(|n| n.node != lost), "{lost} is not used");
    assert!(
        p.stages.iter().all(|s| s.compositor != lost),
        "{lost} is not used"
    );
}

#[test]
fn a_spare_node_takes_exactly_the_lost_nodes_lights() {
    let scene = lightfold_scene::builtin("balls").unwrap();
    let opts = PlanOptions::default();
    let cluster = registered(9, 9);
    let before = plan(&scene, &cluster, &opts).unwrap();
    assert_eq!(before.idle_nodes.len(), 1, "one spare node");
    let left = without(&cluster, "node-3");
    let sticky = replan(&scene, &left, &opts, &before).unwrap();
    assert_covers(&sticky, "node-3");
    let lost_lights = before
        .nodes
        .iter()
        .find(|n| n.node == "node-3")
        .unwrap()
        .lights
        .len();
    assert_eq!(lights_moved(&before, &sticky), lost_lights);
    // The negative control: planning afresh shifts every group after the lost node.
    let fresh = plan(&scene, &left, &opts).unwrap();
    assert_covers(&fresh, "node-3");
    assert!(
        lights_moved(&before, &fresh) > 2 * lost_lights,
        "fresh plan moved only {}",
        lights_moved(&before, &fresh)
    );
}

#[test]
fn a_short_cluster_raises_k_and_keeps_what_it_can() {
    let scene = lightfold_scene::builtin("balls").unwrap();
    let opts = PlanOptions::default();
    let cluster = registered(8, 8);
    let before = plan(&scene, &cluster, &opts).unwrap();
    for lost in ["node-0", "node-5", "comp-2", "comp-7"] {
        let left = without(&cluster, lost);
        let after = replan(&scene, &left, &opts, &before).unwrap();
        assert_covers(&after, lost);
        let fresh = plan(&scene, &left, &opts).unwrap();
        assert!(
            lights_moved(&before, &after) <= lights_moved(&before, &fresh),
            "{lost}: sticky moved {} > fresh {}",
            lights_moved(&before, &after),
            lights_moved(&before, &fresh)
        );
        if lost.starts_with("comp") {
            assert_eq!(lights_moved(&before, &after), 0, "{lost}: no light moves");
        } else {
            assert!(after.k > before.k, "{lost}: K rises on 7 nodes");
        }
    }
}
