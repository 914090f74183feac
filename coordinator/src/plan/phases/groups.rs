//! The phases from samples to nodes: groups of K, the material layers (whose ambient fold may
//! recolour a group) and the assignment of every group, in every part, to a node of its own.

use super::shadows::{Culled, Shadows};
use crate::plan::group::{self, Group, NodeCost};
use crate::plan::types::*;
use crate::plan::{PlanError, cpu_hosts, cull, material};
use lightfold_protocol::{Layer, PixelFormat};
use lightfold_scene::Scene;

/// The group phase's output: the groups of K and what each node costs.
pub(super) struct Grouping {
    /// Per render node of the cluster, its cost model (scaled as the options ask).
    pub(super) costs: Vec<NodeCost>,
    pub(super) groups: Vec<Group>,
    /// K as rendered.
    pub(super) k_used: u32,
}

/// Forms the groups: K active samples per node (or as a frame budget allows), K raised towards
/// the device limit when nodes are short; an error where even that leaves too few nodes.
pub(super) fn group_samples(
    scene: &Scene,
    cluster: &ClusterSpec,
    options: &PlanOptions,
    culled: &Culled,
    parts: usize,
    shadows: &Shadows,
) -> Result<Grouping, PlanError> {
    let cam = &scene.camera;
    let culling = &culled.culling;
    let available = cluster.nodes.len();
    // A sort-first tile's node renders its share of the rows.
    let pixels = u64::from(cam.width) * u64::from(cam.height) / u64::from(options.tiles.max(1));
    let costs: Vec<NodeCost> = cluster
        .nodes
        .iter()
        .map(|n| NodeCost::of(n, pixels).scaled(options.learned.cost_scale))
        .collect();
    // Nodes report their limit at 512² maps: larger maps take fewer lights per node.
    let largest_map = shadows.whole.iter().flatten().map(|s| s.map_size).max();
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
    // An animated scene's virtual point lights change colour from frame to frame (each takes
    // the albedo where its path lands): their nodes' colour is white, so any colour passes.
    let animated_bounce = scene.is_animated();
    let groups_for = |k: u32| {
        let mut g = group::form_groups(&culling.active, &culled.samples, k);
        if animated_bounce {
            for group in &mut g {
                let bounce = |&i: &usize| {
                    matches!(
                        culled.samples[i].kind,
                        lightfold_scene::SampleKind::Bounce { .. }
                    )
                };
                if group.lights.iter().any(bounce) {
                    group.color = [1.0; 3];
                }
            }
        }
        if g.is_empty() {
            // Nothing lit: one node with no light keeps the pipeline whole (it sends empty bands).
            g.push(Group {
                lights: Vec::new(),
                color: [1.0; 3],
            });
        }
        g
    };
    let needed = |g: usize| nodes_needed(g, parts, options);
    let k = match options.frame_budget_us {
        None => k,
        Some(budget) => {
            let views = |g: &Group| shadows.of(None, &g.lights);
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
    debug_assert!(
        {
            let mut grouped: Vec<usize> = groups.iter().flat_map(|g| g.lights.clone()).collect();
            grouped.sort_unstable();
            grouped == culling.active
        },
        "the groups hold every active sample once, and nothing else"
    );
    Ok(Grouping {
        costs,
        groups,
        k_used,
    })
}

/// Nodes a plan of `groups` groups needs: one per group and part, and one more when the material
/// layers have a node of their own (on request; otherwise they are extra targets of a node the
/// last stage reads).
fn nodes_needed(groups: usize, parts: usize, options: &PlanOptions) -> usize {
    groups * parts.max(1) + usize::from(options.material_own_node)
}

/// The material phase's output: the material layers, the ambient fold and the penumbra filter.
pub(super) struct Materials {
    pub(super) needs: material::Needs,
    /// The group whose colour carries the ambient term (eq. 6–7), if one can.
    pub(super) fold: Option<usize>,
    /// Whether the visible materials ask for the fold (eq. 6, or eq. 7 where cheaper), whether
    /// or not a node can carry it.
    pub(super) wants_fold: bool,
    /// Eq. 7: the format the folding group's node sends its ambient mask `I^a` in (`None`: no
    /// fold, or eq. 6's `I^a = 1`).
    pub(super) ambient_mask: Option<PixelFormat>,
    pub(super) mode: MaterialMode,
    /// The material layers, with the eye depth last when the penumbra filter reads it.
    pub(super) layers: Vec<(Layer, PixelFormat)>,
    /// The penumbra filter's radius, 0 for none.
    pub(super) radius: u32,
    /// The `penumbra` operator's parameters, when it filters.
    pub(super) penumbra: Option<lightfold_protocol::pipeline::PenumbraParams>,
    /// Band height, raised to the filter's halo where it filters.
    pub(super) band_height: u32,
}

/// Chooses the material layers the scene needs, folds the ambient term into a group's colour
/// where a node can carry `c_n = c^a` (changing that group's colour), and adds the eye depth when
/// the penumbra filter runs.
pub(super) fn choose_materials(
    scene: &Scene,
    options: &PlanOptions,
    receivers: &[cull::Receiver],
    unpartitioned: bool,
    groups: &mut [Group],
) -> Materials {
    let cam = &scene.camera;
    let mut needs = material::needs(scene, receivers, options.force_all);
    let (mask, note) = material::eq7_mask(&needs, &options.formats);
    needs.notes.extend(note);
    let wants_fold = needs.foldable || mask.is_some();
    let mut fold = None;
    // Parts each sum their own light groups, so no one input of theirs can carry c^a for all.
    if wants_fold && unpartitioned {
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
    let (mode, mut layers) = material::layers(&needs, fold.is_some(), &options.formats);
    // The penumbra filter reads the eye depth beside the material layers. `within_budget` has
    // resolved `Budget` and `Auto` to a radius (or `Off`) before this.
    let radius = match options.penumbra_filter {
        PenumbraFilter::Radius(r) => r,
        _ => 0,
    };
    let penumbra = (radius > 0).then(|| {
        layers.push((Layer::Depth, PixelFormat::DepthF32));
        lightfold_protocol::pipeline::PenumbraParams::planned(
            cam.width,
            cam.height,
            radius,
            cam.fov_y_deg,
        )
    });
    let band_height = if penumbra.is_some() {
        options
            .band_height
            .max(lightfold_protocol::pipeline::halo_rows(radius, true))
    } else {
        options.band_height
    };
    debug_assert!(
        fold.is_none_or(|f| groups[f].color.map(f32::to_bits) == scene.ambient.map(f32::to_bits)),
        "the folding group's colour is the ambient colour"
    );
    debug_assert!(
        band_height >= options.band_height,
        "the filter's halo only ever raises the band height"
    );
    let ambient_mask = mask.filter(|_| fold.is_some());
    Materials {
        needs,
        fold,
        wants_fold,
        ambient_mask,
        mode,
        layers,
        radius,
        penumbra,
        band_height,
    }
}

/// The assignment phase's output: which node renders each unit of work.
pub(super) struct Assignment {
    /// The options with `Topology::Auto` resolved.
    pub(super) options: PlanOptions,
    /// Work units: one per group `(None, group)`, or per cell of the grid and group (cell-major)
    /// with partitions or tiles (`Fit::cell`).
    pub(super) units: Vec<(Option<usize>, usize)>,
    /// Per unit, the index of its render node in the cluster.
    pub(super) on_node: Vec<usize>,
    /// The render node of the material layers' own, when they have one.
    pub(super) material_node: Option<usize>,
}

/// Assigns every unit (a group, in each part) to a node of its own by cost, keeping lights
/// where `previous` had them within a slack; the material layers' own node, if asked for, is
/// the cheapest node left.
pub(super) fn assign_nodes(
    cluster: &ClusterSpec,
    options: &PlanOptions,
    previous: Option<&Plan>,
    samples: usize,
    parts: usize,
    grouping: &Grouping,
    shadows: &Shadows,
) -> Assignment {
    let Grouping { costs, groups, .. } = grouping;
    let own_node = options.material_own_node;
    let peels = options.peels.layers();
    let units: Vec<(Option<usize>, usize)> = if parts == 0 {
        (0..groups.len()).map(|g| (None, g)).collect()
    } else {
        (0..parts)
            .flat_map(|p| (0..groups.len()).map(move |g| (Some(p), g)))
            .collect()
    };
    // `Auto` chooses by the number of stages a chain would have.
    let options = PlanOptions {
        topology: options.topology.resolve(
            units.len() + usize::from(own_node),
            cluster.compositors.len(),
        ),
        ..options.clone()
    };
    // A part's nodes render the part's maps (fitted to its receivers).
    let unit_costs: Vec<Vec<f64>> = units
        .iter()
        .map(|&(p, g)| {
            let maps = shadows.of(p, &groups[g].lights);
            costs.iter().map(|c| c.frame(&maps, 0)).collect()
        })
        .collect();
    let mut on_node = group::assign(&unit_costs);
    if let Some(prev) = previous {
        // A light keeps its node when the node keeps its part, tile and eye layer.
        let key = |part: Option<usize>, tile: Option<usize>, peel: Option<u32>, l: usize| {
            let cell = (part.map_or(0, |p| p + 1) * (crate::tiles::MAX_TILES as usize + 1)
                + tile.map_or(0, |t| t + 1))
                * (MAX_PEELS as usize + 2)
                + peel.map_or(0, |d| d as usize + 1);
            cell * samples + l
        };
        let had: Vec<Vec<usize>> = cluster
            .nodes
            .iter()
            .map(|n| {
                prev.nodes
                    .iter()
                    .find(|p| p.node == n.id)
                    .map_or_else(Vec::new, |p| {
                        p.lights
                            .iter()
                            .map(|&l| key(p.part, p.tile, p.peel, l))
                            .collect()
                    })
            })
            .collect();
        let cell = |c: Option<usize>| match c {
            None => (None, None),
            Some(c) => {
                super::shadows::cell_of(c, options.partitions > 1, options.tiles.max(1) as usize)
            }
        };
        let lights: Vec<Vec<usize>> = units
            .iter()
            .map(|&(c, g)| {
                let (part, tile) = cell(c);
                let peel = c.and_then(|c| super::shadows::peel_of(c, peels));
                groups[g]
                    .lights
                    .iter()
                    .map(|&l| key(part, tile, peel, l))
                    .collect()
            })
            .collect();
        let lights: Vec<&[usize]> = lights.iter().map(Vec::as_slice).collect();
        on_node = group::sticky(&unit_costs, &on_node, &lights, &had);
    }
    let available = cluster.nodes.len();
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
    debug_assert!(
        {
            let mut used: Vec<usize> = on_node.iter().copied().chain(material_node).collect();
            used.sort_unstable();
            used.dedup();
            used.len() == on_node.len() + usize::from(own_node)
                && used.iter().all(|&n| n < available)
        },
        "every unit, and the material layers' own node, on a node of its own"
    );
    Assignment {
        options,
        units,
        on_node,
        material_node,
    }
}
