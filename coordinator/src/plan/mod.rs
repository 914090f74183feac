//! The planner: a pure function from a scene, the cluster and options to a `Plan` — which light
//! samples are active, the casters, views and map size of each shadow map, groups of K with their
//! colour `c_n` on nodes balanced by cost, which material layers exist, the compositor stages and
//! the bytes of every link (ARCHITECTURE §9). No I/O, no clock, no randomness: the same inputs give
//! the same plan, so the control loop can diff plans and tests can state properties of them.

pub mod adapt;
mod budget;
mod cpu_hosts;
mod cull;
mod daemon_configs;
mod decompose;
mod display;
mod error_model;
mod geom;
pub mod gloss;
mod group;
mod material;
mod peel;
mod phases;
mod replan;
mod shadow;
mod shared;
mod topology;
mod types;
pub mod wire;

pub use budget::{MAX_EPSILON, expected_penumbra_db, filter_cost_us, filter_radius, targeted};
pub use error_model::{Choice, Curve, ErrorModel};
pub use group::{DEFAULT_FIXED_US, DEFAULT_LIGHT_US};
pub use peel::depth_complexity;
pub use replan::{lights_moved, replan};
pub use topology::BAND_OVERHEAD_BYTES;
pub use types::*;

use group::NodeCost;
use lightfold_protocol::pipeline::PENUMBRA_MAX_RADIUS;
use lightfold_scene::{LightSample, Scene};
use phases::plan_once;
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
    if let Some((resolved, choice)) = peel::resolve(scene, cluster, options)? {
        let mut plan = plan_grid(scene, cluster, &resolved, previous)?;
        plan.peels = Some(choice);
        return Ok(plan);
    }
    plan_grid(scene, cluster, options, previous)
}

/// [`plan_with`] after peeling is resolved: the tiles and partitions chosen where automatic,
/// then the plan within its budget.
fn plan_grid(
    scene: &Scene,
    cluster: &ClusterSpec,
    options: &PlanOptions,
    previous: Option<&Plan>,
) -> Result<Plan, PlanError> {
    if options.tiles == 0 {
        return decompose::choose(scene, cluster, options, previous);
    }
    // Tiles take the nodes there are (a lost node leaves fewer; where T × the parts × the groups
    // do not fit them, fewer tiles).
    let nodes = cluster.nodes.len().max(1) as u32;
    if options.tiles > nodes {
        let options = PlanOptions {
            tiles: nodes,
            ..options.clone()
        };
        return plan_with(scene, cluster, &options, previous);
    }
    if options.partitions == 0 {
        let options = PlanOptions {
            partitions: partitions_for(scene, cluster, options),
            ..options.clone()
        };
        return plan_with(scene, cluster, &options, previous);
    }
    let separate = budget::within_budget(scene, cluster, options, previous, plan_once);
    let planned = shared::prefer_merged(cluster, options, separate, |one| {
        budget::within_budget(scene, one, options, previous, plan_once)
    });
    match planned {
        Err(PlanError::NotEnoughNodes { .. }) if options.tiles > 1 => {
            let fewer = PlanOptions {
                tiles: options.tiles - 1,
                ..options.clone()
            };
            plan_with(scene, cluster, &fewer, previous)
        }
        other => other,
    }
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
    if o.tiles > crate::tiles::MAX_TILES {
        return bad_options(&format!(
            "tiles must be 0 (automatic), 1 (none) or 2 to {}, got {}",
            crate::tiles::MAX_TILES,
            o.tiles
        ));
    }
    if o.tiles > 1 {
        if o.material_own_node {
            return bad_options(
                "with tiles each tile's first node renders its material layers: drop the material node of its own",
            );
        }
        let bands = scene.camera.height.div_ceil(o.band_height);
        if bands < o.tiles {
            return bad_options(&format!(
                "{} tiles need at least as many bands of rows: the image has {bands} ({} rows, \
                 bands of {})",
                o.tiles, scene.camera.height, o.band_height
            ));
        }
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
    if !(scale_ok(o.learned.cost_scale.fixed) && scale_ok(o.learned.cost_scale.light)) {
        return bad_options("cost scale must be positive and at most 1e6");
    }
    if !(o.epsilon >= 0.0 && o.epsilon.is_finite()) {
        return bad_options("epsilon must be finite and non-negative");
    }
    if let MapSizing::Fixed(0) = o.map_sizing {
        return bad_options("a fixed shadow-map size must be at least 1");
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
