//! One plan of a scene at the quality it asks for, in phases: cull the light samples, fit shadow
//! views to the scene (and to each sort-last part), plan every active sample's shadow maps, form
//! groups of K, choose the material layers, assign work to nodes, wire the compositor stages,
//! then name the links and assemble the `Plan`. Each phase takes what the phases before it made
//! and returns what the next ones read; debug builds check what each promises the next.

mod groups;
mod shadows;
mod wiring;

use crate::plan::types::*;
use crate::plan::{PlanError, scene_hash, topology};
use groups::{Materials, assign_nodes, choose_materials, group_samples};
use lightfold_scene::Scene;
use shadows::{Culled, cull_samples, fit_views, plan_shadows};
use wiring::{Wired, wire_stages};

/// One plan of `scene` at the quality it asks for (a frame budget only picks K here).
pub(super) fn plan_once(
    scene: &Scene,
    cluster: &ClusterSpec,
    options: &PlanOptions,
    previous: Option<&Plan>,
) -> Result<Plan, PlanError> {
    let culled = cull_samples(scene, options);
    let fit = fit_views(scene, &culled.bounds, options)?;
    let shadows = plan_shadows(scene, options, &culled, &fit);
    let mut grouping = group_samples(scene, cluster, options, &culled, fit.parts.len(), &shadows)?;
    let materials = choose_materials(
        scene,
        options,
        &culled.receivers,
        fit.parts.is_empty(),
        &mut grouping.groups,
    );
    let assignment = assign_nodes(
        cluster,
        options,
        previous,
        culled.samples.len(),
        fit.parts.len(),
        &grouping,
        &shadows,
    );
    let wired = wire_stages(
        scene,
        cluster,
        fit,
        &grouping,
        &materials,
        &assignment,
        &shadows,
    );
    let links = link(scene, cluster, materials.band_height, &wired);
    Ok(assemble(
        scene,
        culled,
        grouping.k_used,
        materials,
        &assignment.options,
        wired,
        links,
    ))
}

/// The links phase's output: who is idle, where every daemon listens and the links between them.
struct Links {
    idle_nodes: Vec<String>,
    /// Every node and stage's daemon, with its data address.
    addresses: Vec<(String, String)>,
    links: Vec<LinkPlan>,
    /// The coordinator's data address, where the last stage sends its bands.
    sink: String,
}

/// Names the idle render nodes, the data address of every daemon the plan uses and the links
/// (with their bytes per frame) from the nodes through the stages to the sink.
fn link(scene: &Scene, cluster: &ClusterSpec, band_height: u32, wired: &Wired) -> Links {
    let cam = &scene.camera;
    let used: Vec<&str> = wired.nodes.iter().map(|n| n.node.as_str()).collect();
    let idle_nodes: Vec<String> = cluster
        .nodes
        .iter()
        .filter(|n| !used.contains(&n.id.as_str()))
        .map(|n| n.id.clone())
        .collect();
    debug_assert_eq!(
        used.len() + idle_nodes.len(),
        cluster.nodes.len(),
        "every render node is used or idle"
    );
    let daemons: Vec<&DaemonSpec> = cluster.nodes.iter().chain(&cluster.compositors).collect();
    let address_of = |id: &str| {
        daemons
            .iter()
            .find(|d| d.id == id)
            .map_or_else(String::new, |d| d.data_address())
    };
    let mut addresses: Vec<(String, String)> = used
        .iter()
        .map(|&id| (id.to_string(), address_of(id)))
        .collect();
    addresses.extend(
        wired
            .stages
            .iter()
            .map(|s| (s.compositor.clone(), address_of(&s.compositor))),
    );
    let links = topology::links(
        &wired.stages,
        address_of,
        &cluster.sink,
        (cam.width, cam.height, band_height),
    );
    Links {
        idle_nodes,
        addresses,
        links,
        sink: cluster.sink.clone(),
    }
}

/// The last step: the plan, from what the phases made.
fn assemble(
    scene: &Scene,
    culled: Culled,
    k_used: u32,
    materials: Materials,
    options: &PlanOptions,
    wired: Wired,
    links: Links,
) -> Plan {
    let cam = &scene.camera;
    let Wired {
        stages,
        nodes,
        placement,
        parts,
        est_frame_us,
        cpu_shared,
    } = wired;
    let Materials {
        needs,
        fold,
        wants_fold,
        ambient_mask,
        mode,
        layers,
        radius,
        band_height,
        ..
    } = materials;
    let mut notes = needs.notes;
    if wants_fold && fold.is_none() {
        notes.push(if options.tiles > 1 {
            "ambient: each tile sums its own groups, so no one node carries c_n = c^a → ambient layer instead".to_string()
        } else if !parts.is_empty() {
            "ambient: each part sums its own groups, so no one node carries c_n = c^a → ambient layer instead".to_string()
        } else {
            "ambient: no node can carry c_n = c^a → ambient layer instead".to_string()
        });
    }
    let material = MaterialPlan {
        mode,
        layers,
        ambient: scene.ambient,
        fold_ambient: fold.is_some(),
        ambient_mask,
        placement,
        notes,
    };
    Plan {
        penumbra_radius: radius,
        epoch: options.epoch,
        scene_hash: scene_hash(scene),
        scene_name: scene.name.clone(),
        width: cam.width,
        height: cam.height,
        band_height,
        camera: *cam,
        exposure: scene.exposure,
        topology: options.topology,
        k: k_used,
        samples: culled.samples,
        active: culled.culling.active,
        dropped: culled.culling.dropped,
        epsilon: options.epsilon,
        epsilon_used: culled.culling.epsilon_used,
        nodes,
        idle_nodes: links.idle_nodes,
        shared_devices: None,
        cpu_shared,
        stages,
        material,
        links: links.links,
        sink: links.sink,
        walkthrough: options.walkthrough,
        frames_in_flight: options.frames_in_flight,
        filter: scene.quality.filter,
        depth_bias: scene.quality.depth_bias,
        slope_bias: scene.quality.slope_bias,
        est_frame_us,
        frame_budget_us: options.frame_budget_us,
        concessions: Vec::new(),
        target: None,
        addresses: links.addresses,
        tiles: if options.tiles > 1 {
            crate::tiles::even_rows(cam.height, band_height, options.tiles)
                .or_else(|| crate::tiles::even_rows(cam.height, 1, options.tiles))
                .unwrap_or_default()
        } else {
            Vec::new()
        },
        partitions: parts,
        decomposition: None,
        peels: None,
    }
}
