//! The planner: a pure function from a scene, the cluster and options to a `Plan` — which light
//! samples are active, the casters, views and map size of each shadow map, groups of K with their
//! colour `c_n` on nodes balanced by cost, which material layers exist, the compositor stages and
//! the bytes of every link (ARCHITECTURE §9). No I/O, no clock, no randomness: the same inputs give
//! the same plan, so the control loop can diff plans and tests can state properties of them.

pub mod adapt;
mod budget;
mod config;
mod cpu_hosts;
mod cull;
mod display;
mod error_model;
mod geom;
mod group;
mod material;
mod replan;
mod shadow;
mod shared;
mod topology;
mod types;
pub mod wire;

pub use budget::{MAX_EPSILON, expected_penumbra_db, filter_cost_us, filter_radius, targeted};
pub use error_model::{Choice, Curve, ErrorModel};
pub use group::{DEFAULT_FIXED_US, DEFAULT_LIGHT_US};
pub use replan::{lights_moved, replan};
pub use topology::BAND_OVERHEAD_BYTES;
pub use types::*;

use group::{Group, NodeCost};
use lightfold_compositor::ops::penumbra::MAX_RADIUS as PENUMBRA_MAX_RADIUS;
use lightfold_protocol::{Layer, PixelFormat};
use lightfold_scene::shading::V3;
use lightfold_scene::{LightSample, Scene};
use sha2::{Digest, Sha256};

/// The most sort-last partitions a plan may ask for.
pub const MAX_PARTITIONS: u32 = 64;

/// Why no plan could be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlanError {
    #[error("the cluster has no render node")]
    NoNodes,
    #[error("the cluster has no compositor")]
    NoCompositors,
    #[error("daemon id {id:?} appears twice in the cluster")]
    DuplicateDaemon { id: String },
    #[error(
        "{active} active light samples need {needed} render nodes at K = {k} (one per group of K lights and sort-last part, plus the material layers' node when they have one of their own) and the devices take at most K = {limit}; the cluster has {available}"
    )]
    NotEnoughNodes {
        active: usize,
        k: u32,
        limit: u32,
        needed: usize,
        available: usize,
    },
    #[error("invalid scene: {reason}")]
    InvalidScene { reason: String },
    #[error("invalid plan options: {reason}")]
    InvalidOptions { reason: String },
}

/// SHA-256 of the scene's canonical encoding (bincode 2, standard configuration): the content hash
/// nodes cache scenes by when the coordinator ships this encoding.
pub fn scene_hash(scene: &Scene) -> [u8; 32] {
    let bytes =
        bincode::serde::encode_to_vec(scene, bincode::config::standard()).unwrap_or_default();
    Sha256::digest(&bytes).into()
}

/// Node `spec`'s cost model for `plan`'s image, without `PlanOptions::cost_scale`: `(fixed µs
/// per frame, µs per light before its weight)`; [`light_weight`] gives each light's weight. The
/// live loop fits measured frames to it.
pub fn node_cost(spec: &DaemonSpec, plan: &Plan) -> (f64, f64) {
    let pixels = u64::from(plan.width) * u64::from(plan.height);
    let c = NodeCost::of(spec, pixels);
    (c.fixed_us, c.light_us)
}

/// A light with transmittance maps against the same light without, measured on one node
/// (`docs/translucency.md`): its shadow passes and its eye-pass lookups.
pub const TRANSMIT_SHADOW_FACTOR: f64 = 2.3;
pub const TRANSMIT_EYE_FACTOR: f64 = 1.4;

/// The cost model's weight of one light's maps: `(whole light, its shadow passes)`.
pub fn light_weight(shadow: &ShadowPlan) -> (f64, f64) {
    let views = shadow.views.count() as f64 * shadow.map_size as f64 / 512.0;
    let (eye, maps) = if shadow.transmittance {
        (
            0.5 * TRANSMIT_EYE_FACTOR,
            0.5 * views * TRANSMIT_SHADOW_FACTOR,
        )
    } else {
        (0.5, 0.5 * views)
    };
    (eye + maps, maps)
}

/// A part's meshes (by index), their boxes and the points the mismatch rule measures on them.
type PartFit = (
    Vec<bool>,
    Vec<(V3, V3)>,
    Vec<lightfold_scene::shadow_views::Probe>,
);

/// Bytes a render node holds per triangle it is sent: peak RSS of one node at 4 M triangles
/// (scene, uploaded buffers, the driver's copy; `docs/scaling.md`), 430 bytes.
pub const NODE_BYTES_PER_TRIANGLE: u64 = 430;
/// The share of a node's reported memory a scene's geometry may take before automatic
/// partitioning splits it (the rest: shadow maps, targets, frames in flight).
pub const SCENE_MEMORY_SHARE: f64 = 0.5;

/// The share of a frame budget one node's eye pass may take before automatic partitioning
/// splits the scene (the rest: its shadow passes, readback, packing).
pub const EYE_BUDGET_SHARE: f64 = 0.5;

/// The partitions `options` asks for, resolved: as given, or for 0 (automatic) the fewest parts
/// such that
/// - a part's share of the scene's triangles fits the smallest memory a render node reported
///   (`Capabilities::memory_bytes`, [`NODE_BYTES_PER_TRIANGLE`] each, within
///   [`SCENE_MEMORY_SHARE`]), and
/// - under a frame budget, a part's eye pass fits [`EYE_BUDGET_SHARE`] of the budget on the
///   fastest node (`Capabilities::eye_ns_per_triangle`, measured at start-up),
///
/// at most the nodes there are and [`MAX_PARTITIONS`]. The eye pass decides nothing where the
/// fastest node's fixed cost per frame alone is over the budget (no split meets it). What no
/// node reports does not count:
/// automatic partitioning is 1 without reports, and where a material node of its own is asked
/// for (partitions exclude it).
pub fn partitions_for(scene: &Scene, cluster: &ClusterSpec, options: &PlanOptions) -> u32 {
    if options.partitions > 0 {
        return options.partitions;
    }
    if options.material_own_node {
        return 1;
    }
    let reported = |f: fn(&lightfold_protocol::Capabilities) -> u64| {
        cluster
            .nodes
            .iter()
            .filter_map(|n| n.capabilities.as_ref().map(f))
            .filter(|&v| v > 0)
            .min()
    };
    let triangles = scene.triangle_count() as f64;
    let by_memory = reported(|c| c.memory_bytes).map_or(1.0, |memory| {
        triangles * NODE_BYTES_PER_TRIANGLE as f64 / (memory as f64 * SCENE_MEMORY_SHARE)
    });
    // (Where even the fastest node's fixed cost per frame is over the budget, no split meets it:
    // the budget's own concessions decide.)
    let pixels = u64::from(scene.camera.width) * u64::from(scene.camera.height);
    let fixed = reported(|c| c.fixed_cost_us).map(|f| group::measured_fixed_us(f, pixels));
    let by_cost = match (options.frame_budget_us, reported(|c| c.eye_ns_per_triangle)) {
        (Some(budget), Some(ns)) if fixed.is_none_or(|f| f < budget as f64) => {
            triangles * ns as f64 / 1000.0 / (budget.max(1) as f64 * EYE_BUDGET_SHARE)
        }
        _ => 1.0,
    };
    let parts = by_memory
        .max(by_cost)
        .ceil()
        .clamp(1.0, f64::from(MAX_PARTITIONS)) as u32;
    parts.min(cluster.nodes.len().max(1) as u32)
}

/// The scene a plan with `options` on `cluster` renders: with partitions (as
/// [`partitions_for`] resolves them), meshes too large for a part split into chunks
/// (`scene::partition::chunk_for_parts`); otherwise `scene` itself. The control loop plans and
/// ships this scene, and `lightfold plan` prints its plan.
pub fn scene_for<'s>(
    scene: &'s Scene,
    cluster: &ClusterSpec,
    options: &PlanOptions,
) -> std::borrow::Cow<'s, Scene> {
    let parts = partitions_for(scene, cluster, options) as usize;
    match lightfold_scene::partition::chunk_for_parts(scene, parts) {
        Some(chunked) => std::borrow::Cow::Owned(chunked),
        None => std::borrow::Cow::Borrowed(scene),
    }
}

/// Per part and sample, the meshes that can shadow the part (mesh indices, ascending, as
/// `scene::partition` gives them) of a still `scene`: the casters a sort-last node of that part
/// draws for the sample, by the planner's rule (meshes in the sample's reach between it and a
/// visible receiver of the part it reaches). What `lightfold render --partitions` gives each
/// part's shadow passes, as the cluster does.
pub fn part_casters(
    scene: &Scene,
    samples: &[LightSample],
    parts: &[Vec<u32>],
) -> Vec<Vec<Vec<u32>>> {
    let bounds = geom::mesh_bounds(scene);
    let receivers = cull::receivers(scene, &bounds);
    parts
        .iter()
        .map(|part| {
            let in_part: Vec<&cull::Receiver> = receivers
                .iter()
                .filter(|r| part.binary_search(&(r.mesh as u32)).is_ok())
                .collect();
            samples
                .iter()
                .map(|s| {
                    let lit: Vec<&cull::Receiver> = in_part
                        .iter()
                        .copied()
                        .filter(|r| geom::reach(s, &r.bounds).is_ok())
                        .collect();
                    shadow::casters(s, &lit, &bounds)
                })
                .collect()
        })
        .collect()
}

/// Plans `scene` on `cluster` (see the module documentation and `docs/planner.md`).
pub fn plan(
    scene: &Scene,
    cluster: &ClusterSpec,
    options: &PlanOptions,
) -> Result<Plan, PlanError> {
    plan_with(scene, cluster, options, None)
}

pub(crate) fn plan_with(
    scene: &Scene,
    cluster: &ClusterSpec,
    options: &PlanOptions,
    previous: Option<&Plan>,
) -> Result<Plan, PlanError> {
    validate(scene, cluster, options)?;
    if options.partitions == 0 {
        let options = PlanOptions {
            partitions: partitions_for(scene, cluster, options),
            ..options.clone()
        };
        return plan_with(scene, cluster, &options, previous);
    }
    let separate = budget::within_budget(scene, cluster, options, previous, plan_once);
    shared::prefer_merged(cluster, options, separate, |one| {
        budget::within_budget(scene, one, options, previous, plan_once)
    })
}

/// One plan of `scene` at the quality it asks for (a frame budget only picks K here).
fn plan_once(
    scene: &Scene,
    cluster: &ClusterSpec,
    options: &PlanOptions,
    previous: Option<&Plan>,
) -> Result<Plan, PlanError> {
    let cam = &scene.camera;
    // Direct samples, then the virtual point lights of indirect light (planned like the rest).
    let samples = lightfold_reference::indirect::frame_samples(scene);
    let bounds = geom::mesh_bounds(scene);
    let receivers = cull::receivers(scene, &bounds);
    let mut culling = cull::cull(
        &samples,
        &receivers,
        scene.exposure,
        options.epsilon,
        options.force_all,
    );
    // A moving light's samples reach other receivers at other times: none is culled for what
    // it misses at rest, and every mesh may cast into its maps.
    let moving_sample: Vec<bool> = match &scene.animation {
        None => vec![false; samples.len()],
        Some(a) => {
            let moving = a.moving_lights(scene.lights.len());
            samples
                .iter()
                .map(|s| moving.get(s.light as usize).copied().unwrap_or(false))
                .collect()
        }
    };
    if moving_sample.contains(&true) {
        cull::keep_moving(&mut culling, &moving_sample, receivers.len());
    }
    // The boxes nodes fit shadow views to: every mesh with triangles (node/src/gpu/scene_data.rs),
    // or a sort-last node's part of them.
    let boxes_where = |keep: &dyn Fn(usize) -> bool| -> Vec<(V3, V3)> {
        bounds
            .iter()
            .zip(&scene.meshes)
            .enumerate()
            .filter(|(m, (_, mesh))| keep(*m) && mesh.indices.len() >= 3)
            .filter_map(|(_, (b, _))| b.map(|b| (b.lo, b.hi)))
            .collect()
    };
    let scene_receivers = boxes_where(&|_| true);
    // Where the mismatch rule measures, as the renderer does (`shadow_views::sizing`).
    let probes = lightfold_scene::shadow_views::probes(cam, &scene_receivers);
    // Sort-last parts: every group is rendered once per part.
    let parts = if options.partitions > 1 {
        let parts =
            lightfold_scene::partition::partition_meshes(scene, options.partitions as usize);
        if parts.iter().any(Vec::is_empty) {
            return Err(PlanError::InvalidOptions {
                reason: format!(
                    "{} partitions of a scene with {} meshes leave a part empty (`scene_for` \
                     splits meshes too large for a part, but not an animated scene's, nor one an \
                     emissive-mesh light samples): ask for at most {} partitions",
                    options.partitions,
                    scene.meshes.len(),
                    parts.iter().filter(|p| !p.is_empty()).count()
                ),
            });
        }
        parts
    } else {
        Vec::new()
    };
    // A part's nodes fit their maps to the part's own receivers (`Renderer::
    // set_fit_to_eye_meshes`): per part, its meshes, their boxes and where the mismatch rule
    // measures on them.
    let part_fit: Vec<PartFit> = parts
        .iter()
        .map(|part| {
            let mut mask = vec![false; scene.meshes.len()];
            for &m in part {
                mask[m as usize] = true;
            }
            let boxes = boxes_where(&|m| mask[m]);
            let probes = lightfold_scene::shadow_views::probes(cam, &boxes);
            (mask, boxes, probes)
        })
        .collect();
    // Like the node's renderer: moving-light maps are fitted to what the camera sees (cascades
    // where that spans a deep range); walkthrough maps outlive camera moves, so they cover every
    // receiver.
    let fit_camera = (!options.walkthrough).then_some(cam);
    // Sample i's shadow plan for the whole scene, or for part `p`'s receivers only.
    let shadow_in = |i: usize, p: Option<usize>| {
        let in_part = |m: usize| p.is_none_or(|p| part_fit[p].0[m]);
        let lit: Vec<&cull::Receiver> = culling.lit[i]
            .iter()
            .map(|&r| &receivers[r])
            .filter(|r| in_part(r.mesh))
            .collect();
        let (fit_boxes, fit_probes) = match p {
            Some(p) => (&part_fit[p].1, &part_fit[p].2),
            None => (&scene_receivers, &probes),
        };
        let mut plan = shadow::shadow_plan(
            &samples[i],
            &lit,
            &bounds,
            fit_boxes,
            fit_camera,
            fit_probes,
            cam,
            options.map_sizing.resolve(&scene.quality),
            scene.quality.shadow_map_size,
            options.force_all || moving_sample[i],
        );
        // Model only what the scene needs: transmittance maps where a caster lets light through.
        plan.transmittance = plan
            .casters
            .iter()
            .any(|&m| scene.is_translucent_mesh(m as usize));
        plan
    };
    let shadows_of = |p: Option<usize>| -> Vec<Option<ShadowPlan>> {
        let mut v = vec![None; samples.len()];
        for &i in &culling.active {
            v[i] = Some(shadow_in(i, p));
        }
        v
    };
    let shadows = shadows_of(None);
    let part_shadows: Vec<Vec<Option<ShadowPlan>>> =
        (0..parts.len()).map(|p| shadows_of(Some(p))).collect();

    // Groups: K per node (or as a frame budget allows), raised towards the device limit when
    // nodes are short.
    let available = cluster.nodes.len();
    let pixels = u64::from(cam.width) * u64::from(cam.height);
    let costs: Vec<NodeCost> = cluster
        .nodes
        .iter()
        .map(|n| NodeCost::of(n, pixels).scaled(options.cost_scale))
        .collect();
    // Nodes report their limit at 512² maps: larger maps take fewer lights per node.
    let largest_map = shadows.iter().flatten().map(|s| s.map_size).max();
    // Maps the mismatch rule sizes above the scene's base size share a node's shadow budget (it
    // halves the largest to fit, as `render` does: docs/gpu.md), so its limit counts them at that
    // size; fixed sizes count as they are.
    let limit_map = match options.map_sizing.resolve(&scene.quality) {
        MapSizing::Mismatch { .. } => largest_map.map(|m| m.min(scene.quality.shadow_map_size)),
        _ => largest_map,
    };
    let at_map = limit_map.and_then(|m| group::device_limit_at(&cluster.nodes, m));
    let (k, limit) = match options.frame_budget_us {
        None => {
            let k = options.lights_per_node;
            match at_map {
                Some(l) => (k.min(l), l),
                None => (k, group::device_limit(&cluster.nodes, k)),
            }
        }
        Some(_) => {
            let limit =
                at_map.unwrap_or_else(|| group::device_limit(&cluster.nodes, group::BUDGET_MAX_K));
            (limit, limit)
        }
    };
    let groups_for = |k: u32| {
        let mut g = group::form_groups(&culling.active, &samples, k);
        if g.is_empty() {
            // Nothing lit: one node with no light keeps the pipeline whole (it sends empty bands).
            g.push(Group {
                lights: Vec::new(),
                color: [1.0; 3],
            });
        }
        g
    };
    let per_group = parts.len().max(1);
    // Nodes a plan of `g` groups needs: one per group and part, and one more when the material
    // layers have a node of their own (on request; otherwise they are extra targets of a node
    // the last stage reads).
    let own_node = options.material_own_node;
    let needed = |g: usize| g * per_group + usize::from(own_node);
    let k = match options.frame_budget_us {
        None => k,
        Some(budget) => {
            let views = |g: &Group| -> Vec<&ShadowPlan> {
                g.lights
                    .iter()
                    .filter_map(|&i| shadows[i].as_ref())
                    .collect()
            };
            let fits = |g: &[Group]| needed(g.len()) <= available;
            let hosts = cpu_hosts::cpu_hosts(&cluster.nodes);
            group::budget_k(
                budget as f64,
                limit,
                &costs,
                &hosts,
                groups_for,
                fits,
                views,
            )
        }
    };
    let mut k_used = k;
    let mut groups = groups_for(k);
    while needed(groups.len()) > available && k_used < limit {
        k_used += 1;
        groups = groups_for(k_used);
    }
    if needed(groups.len()) > available {
        return Err(PlanError::NotEnoughNodes {
            active: culling.active.len(),
            k,
            limit,
            needed: needed(groups_for(k).len()),
            available,
        });
    }

    // K as rendered: a budget or a short cluster may raise K past the largest group there is.
    let k_used = groups
        .iter()
        .map(|g| g.lights.len() as u32)
        .max()
        .map_or(k_used, |most| k_used.min(most.max(1)));

    // Materials, and the eq. 6–7 folding when a node can carry c_n = c^a.
    let needs = material::needs(scene, &receivers, options.force_all);
    let mut fold = None;
    // Parts each sum their own light groups, so no one input of theirs can carry c^a for all.
    if needs.foldable && parts.is_empty() {
        let ca = scene.ambient;
        let positive = ca.iter().all(|&c| c > 0.0);
        // A group of colour c^a folds as is; otherwise any group can take c_n = c^a (the node
        // emits c_λ ⊘ c_n, so c_n is free) when no channel of c^a is zero.
        fold = groups
            .iter()
            .position(|g| g.color.map(f32::to_bits) == ca.map(f32::to_bits))
            .or_else(|| groups.iter().position(|g| g.lights.is_empty()))
            .or_else(|| positive.then_some(0));
        if let Some(f) = fold {
            groups[f].color = ca;
        }
    }
    let (mode, mut material_layers) = material::layers(&needs, fold.is_some(), &options.formats);
    // The penumbra filter reads the eye depth beside the material layers. `within_budget` has
    // resolved `Budget` and `Auto` to a radius (or `Off`) before this.
    let radius = match options.penumbra_filter {
        PenumbraFilter::Radius(r) => r,
        _ => 0,
    };
    let penumbra = (radius > 0).then(|| {
        material_layers.push((Layer::Depth, PixelFormat::DepthF32));
        lightfold_compositor::ops::penumbra::planned_params(
            cam.width,
            cam.height,
            radius,
            cam.fov_y_deg,
        )
    });
    let band_height = if penumbra.is_some() {
        options
            .band_height
            .max(lightfold_compositor::ops::penumbra::halo_rows(radius, true))
    } else {
        options.band_height
    };

    // Assignment: group → node by cost; the material node is the cheapest node left.
    let group_shadows = |g: &Group| -> Vec<&ShadowPlan> {
        g.lights
            .iter()
            .filter_map(|&i| shadows[i].as_ref())
            .collect()
    };
    // Work units: one per group, or per part and group (part-major) with partitions.
    let units: Vec<(Option<usize>, usize)> = if parts.is_empty() {
        (0..groups.len()).map(|g| (None, g)).collect()
    } else {
        (0..parts.len())
            .flat_map(|p| (0..groups.len()).map(move |g| (Some(p), g)))
            .collect()
    };
    // `Auto` chooses by the number of stages a chain would have.
    let options = &PlanOptions {
        topology: options.topology.resolve(
            units.len() + usize::from(own_node),
            cluster.compositors.len(),
        ),
        ..options.clone()
    };
    // A part's nodes render the part's maps (fitted to its receivers).
    let unit_maps = |(p, g): (Option<usize>, usize)| -> Vec<&ShadowPlan> {
        let maps = p.map_or(&shadows, |p| &part_shadows[p]);
        groups[g]
            .lights
            .iter()
            .filter_map(|&i| maps[i].as_ref())
            .collect()
    };
    let unit_costs: Vec<Vec<f64>> = units
        .iter()
        .map(|&u| {
            let maps = unit_maps(u);
            costs.iter().map(|c| c.frame(&maps, 0)).collect()
        })
        .collect();
    let mut on_node = group::assign(&unit_costs);
    if let Some(prev) = previous {
        // A light keeps its node when the node keeps its part.
        let key = |part: Option<usize>, l: usize| part.map_or(l, |p| (p + 1) * samples.len() + l);
        let had: Vec<Vec<usize>> = cluster
            .nodes
            .iter()
            .map(|n| {
                prev.nodes
                    .iter()
                    .find(|p| p.node == n.id)
                    .map_or_else(Vec::new, |p| {
                        p.lights.iter().map(|&l| key(p.part, l)).collect()
                    })
            })
            .collect();
        let lights: Vec<Vec<usize>> = units
            .iter()
            .map(|&(p, g)| groups[g].lights.iter().map(|&l| key(p, l)).collect())
            .collect();
        let lights: Vec<&[usize]> = lights.iter().map(Vec::as_slice).collect();
        on_node = group::sticky(&unit_costs, &on_node, &lights, &had);
    }
    let material_node = own_node.then(|| {
        (0..available)
            .filter(|n| !on_node.contains(n))
            .min_by(|&a, &b| {
                costs[a]
                    .fixed_us
                    .total_cmp(&costs[b].fixed_us)
                    .then(a.cmp(&b))
            })
            .expect("checked: one node more than groups")
    });

    let finish = topology::Finish {
        mode,
        ambient: scene.ambient,
        ambient_layer: material_layers.iter().any(|l| l.0 == Layer::Ambient),
        emissive: material_layers.iter().any(|l| l.0 == Layer::Emissive),
        material_layers: material_layers.clone(),
        material_node: material_node.map(|m| cluster.nodes[m].id.clone()),
        fold,
        exposure: scene.exposure,
        penumbra,
    };
    let (stages, nodes, placement) = if parts.is_empty() {
        let illum: Vec<topology::IllumInput> = groups
            .iter()
            .zip(&on_node)
            .map(|(g, &n)| topology::IllumInput {
                node: cluster.nodes[n].id.clone(),
                color: g.color,
                layers: vec![(Layer::Illumination, options.formats.node)],
                cost: costs[n].frame(&group_shadows(g), 0),
            })
            .collect();
        let (stages, node_dst, site) = topology::stages(
            &illum,
            &finish,
            &cluster.compositors,
            options.topology,
            &options.formats,
        );

        let mut nodes: Vec<NodePlan> = groups
            .iter()
            .zip(&on_node)
            .zip(node_dst)
            .map(|((g, &n), (stage, input))| NodePlan {
                node: cluster.nodes[n].id.clone(),
                lights: g.lights.clone(),
                color: g.color,
                shadows: g
                    .lights
                    .iter()
                    .filter_map(|&i| shadows[i].clone())
                    .collect(),
                layers: vec![(Layer::Illumination, options.formats.node)],
                downstream: stage,
                input_index: input,
                est_cost_us: costs[n].frame(&group_shadows(g), 0).round() as u64,
                part: None,
                scene: None,
            })
            .collect();
        let placement = match (&site, material_node) {
            (topology::MaterialSite::Host(h), _) => {
                // Extra targets: the host's eye pass writes the material layers too.
                let host = &mut nodes[*h];
                host.layers.extend(material_layers.iter().copied());
                let g = &groups[*h];
                host.est_cost_us = costs[on_node[*h]]
                    .frame(&group_shadows(g), material_layers.len())
                    .round() as u64;
                MaterialPlacement::ExtraTargets {
                    node: host.node.clone(),
                }
            }
            (topology::MaterialSite::OwnNode((stage, input)), Some(m)) => {
                nodes.push(NodePlan {
                    node: cluster.nodes[m].id.clone(),
                    lights: Vec::new(),
                    color: [1.0; 3],
                    shadows: Vec::new(),
                    layers: material_layers.clone(),
                    downstream: stage.clone(),
                    input_index: *input,
                    est_cost_us: costs[m].frame(&[], material_layers.len()).round() as u64,
                    part: None,
                    scene: None,
                });
                MaterialPlacement::OwnNode {
                    node: cluster.nodes[m].id.clone(),
                }
            }
            (topology::MaterialSite::OwnNode(_), None) => {
                unreachable!(
                    "the topology hosts the material layers whenever no own node is chosen"
                )
            }
        };
        (stages, nodes, placement)
    } else {
        partitioned(
            &parts, &units, &on_node, &groups, &unit_maps, &costs, cluster, &finish, options,
        )
    };
    let plan_parts = parts.len();
    let used: Vec<&str> = nodes.iter().map(|n| n.node.as_str()).collect();
    let idle_nodes = cluster
        .nodes
        .iter()
        .filter(|n| !used.contains(&n.id.as_str()))
        .map(|n| n.id.clone())
        .collect();

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
        stages
            .iter()
            .map(|s| (s.compositor.clone(), address_of(&s.compositor))),
    );
    let links = topology::links(
        &stages,
        address_of,
        &cluster.sink,
        (cam.width, cam.height, band_height),
    );
    let (est_frame_us, cpu_shared) = cpu_hosts::plan_estimate(&nodes, &cluster.nodes);
    let mut notes = needs.notes;
    if needs.foldable && fold.is_none() {
        notes.push(if plan_parts > 0 {
            "ambient: each part sums its own groups, so no one node carries c_n = c^a → ambient layer instead".to_string()
        } else {
            "ambient: no node can carry c_n = c^a → ambient layer instead".to_string()
        });
    }
    let material = MaterialPlan {
        mode,
        layers: material_layers,
        ambient: scene.ambient,
        fold_ambient: fold.is_some(),
        placement,
        notes,
    };
    Ok(Plan {
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
        samples,
        active: culling.active,
        dropped: culling.dropped,
        epsilon: options.epsilon,
        epsilon_used: culling.epsilon_used,
        nodes,
        idle_nodes,
        shared_devices: None,
        cpu_shared,
        stages,
        material,
        links,
        sink: cluster.sink.clone(),
        walkthrough: options.walkthrough,
        frames_in_flight: options.frames_in_flight,
        filter: scene.quality.filter,
        depth_bias: scene.quality.depth_bias,
        slope_bias: scene.quality.slope_bias,
        est_frame_us,
        frame_budget_us: options.frame_budget_us,
        concessions: Vec::new(),
        target: None,
        addresses,
        partitions: parts,
    })
}

/// The nodes and stages of a sort-last grid: `units[u] = (part, group)` on node `on_node[u]`;
/// each part's cheapest node also renders its part's eye depth and material layers.
#[allow(clippy::too_many_arguments)]
fn partitioned<'a>(
    parts: &[Vec<u32>],
    units: &[(Option<usize>, usize)],
    on_node: &[usize],
    groups: &[Group],
    unit_maps: &dyn Fn((Option<usize>, usize)) -> Vec<&'a ShadowPlan>,
    costs: &[NodeCost],
    cluster: &ClusterSpec,
    finish: &topology::Finish,
    options: &PlanOptions,
) -> (Vec<StagePlan>, Vec<NodePlan>, MaterialPlacement) {
    let unit_shadows = |u: usize| unit_maps(units[u]);
    // The eye depth (which the penumbra filter's material layers may already name) and the
    // material layers.
    let mut host_layers = vec![
        (Layer::Illumination, options.formats.node),
        (Layer::Depth, PixelFormat::DepthF32),
    ];
    host_layers.extend(
        finish
            .material_layers
            .iter()
            .copied()
            .filter(|l| l.0 != Layer::Depth),
    );
    let extra = host_layers.len() - 1;
    // Per part, its units with the cheapest first (it hosts the part's depth and materials).
    let mut part_units: Vec<Vec<usize>> = vec![Vec::new(); parts.len()];
    for (u, &(p, _)) in units.iter().enumerate() {
        part_units[p.expect("partitioned units name their part")].push(u);
    }
    let cost_of = |u: usize, layers: usize| costs[on_node[u]].frame(&unit_shadows(u), layers);
    for list in &mut part_units {
        if let Some(first) = list
            .iter()
            .enumerate()
            .min_by(|a, b| {
                cost_of(*a.1, extra)
                    .total_cmp(&cost_of(*b.1, extra))
                    .then(a.0.cmp(&b.0))
            })
            .map(|(i, _)| i)
        {
            let host = list.remove(first);
            list.insert(0, host);
        }
    }
    let inputs: Vec<Vec<topology::IllumInput>> = part_units
        .iter()
        .map(|list| {
            list.iter()
                .enumerate()
                .map(|(j, &u)| topology::IllumInput {
                    node: cluster.nodes[on_node[u]].id.clone(),
                    color: groups[units[u].1].color,
                    layers: if j == 0 {
                        host_layers.clone()
                    } else {
                        vec![(Layer::Illumination, options.formats.node)]
                    },
                    cost: cost_of(u, 0),
                })
                .collect()
        })
        .collect();
    let (stages, dst) = topology::partition_stages(
        &inputs,
        finish,
        &cluster.compositors,
        options.topology,
        &options.formats,
    );
    let mut nodes = Vec::with_capacity(units.len());
    for (p, list) in part_units.iter().enumerate() {
        for (j, &u) in list.iter().enumerate() {
            let g = &groups[units[u].1];
            let (stage, input) = dst[p][j].clone();
            nodes.push(NodePlan {
                node: inputs[p][j].node.clone(),
                lights: g.lights.clone(),
                color: g.color,
                shadows: unit_shadows(u).into_iter().cloned().collect(),
                layers: inputs[p][j].layers.clone(),
                downstream: stage,
                input_index: input,
                est_cost_us: cost_of(u, if j == 0 { extra } else { 0 }).round() as u64,
                part: Some(p),
                scene: None,
            });
        }
    }
    let placement = MaterialPlacement::PerPart {
        nodes: inputs.iter().map(|p| p[0].node.clone()).collect(),
    };
    (stages, nodes, placement)
}

fn validate(scene: &Scene, cluster: &ClusterSpec, o: &PlanOptions) -> Result<(), PlanError> {
    let bad_options = |reason: &str| {
        Err(PlanError::InvalidOptions {
            reason: reason.to_string(),
        })
    };
    let bad_scene = |reason: String| Err(PlanError::InvalidScene { reason });
    if o.lights_per_node == 0 {
        return bad_options("lights per node (K) must be at least 1");
    }
    if o.band_height == 0 {
        return bad_options("band height must be at least 1");
    }
    if let PenumbraFilter::Radius(r) = o.penumbra_filter
        && !(1..=PENUMBRA_MAX_RADIUS).contains(&r)
    {
        return bad_options("the penumbra filter's radius must be 1 to 8 (a 3×3 to 17×17 window)");
    }
    if o.partitions > MAX_PARTITIONS {
        return bad_options(&format!(
            "partitions must be 0 (automatic) or 1 to {MAX_PARTITIONS}, got {}",
            o.partitions
        ));
    }
    if o.partitions > 1 && o.material_own_node {
        return bad_options(
            "with partitions each part's first node renders its material layers: drop the material node of its own",
        );
    }
    if o.frames_in_flight == 0 {
        return bad_options("frames in flight must be at least 1");
    }
    if let Some(t) = o.target_penumbra_db
        && !(t > 0.0 && t < 200.0)
    {
        return bad_options("the error target must be a penumbra PSNR between 0 and 200 dB");
    }
    let scale_ok = |k: f64| k > 0.0 && k <= 1e6;
    if !(scale_ok(o.cost_scale.fixed) && scale_ok(o.cost_scale.light)) {
        return bad_options("cost scale must be positive and at most 1e6");
    }
    if !(o.epsilon >= 0.0 && o.epsilon.is_finite()) {
        return bad_options("epsilon must be finite and non-negative");
    }
    if let MapSizing::Fixed(0) = o.map_sizing {
        return bad_options("a fixed shadow-map size must be at least 1");
    }
    if scene.quality.indirect > 0 && scene.animation.is_some() {
        return bad_scene(
            "indirect light (virtual point lights) is traced for still scenes, and this one is \
             animated: render it without indirect light, or a still pose of it"
                .to_string(),
        );
    }
    if cluster.nodes.is_empty() {
        return Err(PlanError::NoNodes);
    }
    if cluster.compositors.is_empty() {
        return Err(PlanError::NoCompositors);
    }
    let mut ids: Vec<&str> = cluster
        .nodes
        .iter()
        .chain(&cluster.compositors)
        .map(|d| d.id.as_str())
        .collect();
    ids.sort_unstable();
    if let Some(w) = ids.windows(2).find(|w| w[0] == w[1]) {
        return Err(PlanError::DuplicateDaemon {
            id: w[0].to_string(),
        });
    }
    if let Err(e) = lightfold_scene::wire::camera_from_wire(&lightfold_scene::wire::camera_to_wire(
        &scene.camera,
    )) {
        return bad_scene(e.to_string());
    }
    if !(scene.exposure.is_finite() && scene.exposure >= 0.0) {
        return bad_scene(format!(
            "exposure {} must be finite and non-negative",
            scene.exposure
        ));
    }
    if !scene.ambient.iter().all(|c| c.is_finite() && *c >= 0.0) {
        return bad_scene(format!(
            "ambient colour {:?} must be finite and non-negative",
            scene.ambient
        ));
    }
    if let Some((i, m)) = scene
        .meshes
        .iter()
        .enumerate()
        .find(|(_, m)| m.material >= scene.materials.len())
    {
        return bad_scene(format!(
            "mesh {i} ({}) names material {} of {}",
            m.name,
            m.material,
            scene.materials.len()
        ));
    }
    for (i, m) in scene.materials.iter().enumerate() {
        let ok = [m.diffuse, m.specular, m.ambient, m.emissive]
            .iter()
            .all(|c| c.iter().all(|v| v.is_finite() && *v >= 0.0));
        if !ok {
            return bad_scene(format!(
                "material {i} ({}) has a negative or non-finite colour",
                m.name
            ));
        }
    }
    Ok(())
}
