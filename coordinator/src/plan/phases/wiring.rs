//! The topology phase: the compositor stages that sum the nodes' illumination, with or
//! without sort-last parts, the node plans that feed them, and the frame they are estimated at.

use super::groups::{Assignment, Grouping, Materials};
use super::shadows::{Fit, Shadows};
use crate::plan::group::Group;
use crate::plan::types::*;
use crate::plan::{cpu_hosts, topology};
use lightfold_protocol::{Layer, PixelFormat};
use lightfold_scene::Scene;

/// The topology phase's output: the compositor stages, the render nodes that feed them and the
/// frame they are estimated at.
pub(super) struct Wired {
    pub(super) stages: Vec<StagePlan>,
    pub(super) nodes: Vec<NodePlan>,
    pub(super) placement: MaterialPlacement,
    /// The sort-last parts the nodes render (mesh indices), none without partitions.
    pub(super) parts: Vec<Vec<u32>>,
    /// The estimated frame (µs), and the render nodes that share a machine's CPU cores.
    pub(super) est_frame_us: u64,
    pub(super) cpu_shared: Option<CpuShared>,
}

/// The stages, nodes and material placement of one layout, before the estimate.
struct Layout {
    stages: Vec<StagePlan>,
    nodes: Vec<NodePlan>,
    placement: MaterialPlacement,
}

/// Wires the assigned nodes into compositor stages (per part with partitions) that sum the
/// illumination, apply the material layers and send the result to the sink, and estimates the
/// frame of those nodes.
pub(super) fn wire_stages(
    scene: &Scene,
    cluster: &ClusterSpec,
    fit: Fit,
    grouping: &Grouping,
    materials: &Materials,
    assignment: &Assignment,
    shadows: &Shadows,
) -> Wired {
    let layers = &materials.layers;
    let finish = topology::Finish {
        mode: materials.mode,
        ambient: scene.ambient,
        ambient_layer: layers.iter().any(|l| l.0 == Layer::Ambient),
        emissive: layers.iter().any(|l| l.0 == Layer::Emissive),
        material_layers: layers.clone(),
        material_node: assignment
            .material_node
            .map(|m| cluster.nodes[m].id.clone()),
        fold: materials.fold,
        ambient_mask: materials.ambient_mask,
        exposure: scene.exposure,
        penumbra: materials.penumbra.clone(),
    };
    let Layout {
        stages,
        nodes,
        placement,
    } = if fit.parts.is_empty() {
        unpartitioned(cluster, grouping, assignment, shadows, &finish)
    } else if fit.peels > 0 {
        peeled(&fit, cluster, grouping, assignment, shadows, &finish)
    } else {
        partitioned(&fit, cluster, grouping, assignment, shadows, &finish)
    };
    debug_assert!(
        {
            let mut ids: Vec<&str> = nodes.iter().map(|n| n.node.as_str()).collect();
            ids.sort_unstable();
            ids.dedup();
            ids.len() == nodes.len()
                && ids.len()
                    == assignment.units.len() + usize::from(assignment.material_node.is_some())
        },
        "one node plan per unit, and one for the material layers' own node, each on its own node"
    );
    let (est_frame_us, cpu_shared) = cpu_hosts::plan_estimate(&nodes, &cluster.nodes);
    Wired {
        stages,
        nodes,
        placement,
        parts: fit.sort_last,
        est_frame_us,
        cpu_shared,
    }
}

/// The nodes and stages without partitions: one node per group, and the material layers as
/// extra targets of the node the topology chooses, or on their own node.
fn unpartitioned(
    cluster: &ClusterSpec,
    grouping: &Grouping,
    assignment: &Assignment,
    shadows: &Shadows,
    finish: &topology::Finish,
) -> Layout {
    let Grouping { costs, groups, .. } = grouping;
    let Assignment {
        options,
        on_node,
        material_node,
        ..
    } = assignment;
    let material_layers = &finish.material_layers;
    let group_shadows = |g: &Group| shadows.of(None, &g.lights);
    // Eq. 7: the folding group's node also renders its ambient mask, an extra target.
    let mask_of = |i: usize| {
        finish
            .ambient_mask
            .filter(|_| finish.fold == Some(i))
            .map(|f| (Layer::AmbientMask, f))
    };
    let node_layers = |i: usize| {
        let mut layers = vec![(Layer::Illumination, options.formats.node)];
        layers.extend(mask_of(i));
        layers
    };
    let illum: Vec<topology::IllumInput> = groups
        .iter()
        .zip(on_node)
        .enumerate()
        .map(|(i, (g, &n))| topology::IllumInput {
            node: cluster.nodes[n].id.clone(),
            color: g.color,
            layers: node_layers(i),
            cost: costs[n].frame(&group_shadows(g), mask_of(i).iter().count()),
        })
        .collect();
    let (stages, node_dst, site) = topology::stages(
        &illum,
        finish,
        &cluster.compositors,
        options.topology,
        &options.formats,
    );
    let mut nodes: Vec<NodePlan> = groups
        .iter()
        .zip(on_node)
        .zip(node_dst)
        .zip(&illum)
        .map(|(((g, &n), (stage, input)), ill)| NodePlan {
            node: cluster.nodes[n].id.clone(),
            lights: g.lights.clone(),
            color: g.color,
            shadows: g
                .lights
                .iter()
                .filter_map(|&i| shadows.whole[i].clone())
                .collect(),
            layers: ill.layers.clone(),
            downstream: stage,
            input_index: input,
            est_cost_us: ill.cost.round() as u64,
            part: None,
            tile: None,
            peel: None,
            scene: None,
        })
        .collect();
    let placement = match (&site, *material_node) {
        (topology::MaterialSite::Host(h), _) => {
            // Extra targets: the host's eye pass writes the material layers too.
            let host = &mut nodes[*h];
            host.layers.extend(material_layers.iter().copied());
            let g = &groups[*h];
            host.est_cost_us = costs[on_node[*h]]
                .frame(
                    &group_shadows(g),
                    material_layers.len() + mask_of(*h).iter().count(),
                )
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
                tile: None,
                peel: None,
                scene: None,
            });
            MaterialPlacement::OwnNode {
                node: cluster.nodes[m].id.clone(),
            }
        }
        (topology::MaterialSite::OwnNode(_), None) => {
            unreachable!("the topology hosts the material layers whenever no own node is chosen")
        }
    };
    Layout {
        stages,
        nodes,
        placement,
    }
}

/// The nodes and stages of a grid of cells (sort-last parts, sort-first tiles or both, or the
/// eye layers of peeled translucency: `Fit`): unit `u = (cell, group)` on node `on_node[u]`;
/// each cell's cheapest node (costed with its extra targets) also renders `host_layers(cell)`
/// (its illumination first), the others their illumination. `stages` wires the cells' nodes
/// into stages and says where each streams.
fn grid(
    fit: &Fit,
    cluster: &ClusterSpec,
    grouping: &Grouping,
    assignment: &Assignment,
    shadows: &Shadows,
    host_layers: impl Fn(usize) -> Vec<(Layer, PixelFormat)>,
    stages: impl FnOnce(&[Vec<topology::IllumInput>]) -> (Vec<StagePlan>, Vec<Vec<topology::Dest>>),
) -> Layout {
    let Grouping { costs, groups, .. } = grouping;
    let Assignment {
        options,
        units,
        on_node,
        ..
    } = assignment;
    let unit_shadows = |u: usize| {
        let (c, g) = units[u];
        shadows.of(c, &groups[g].lights)
    };
    let cost_of = |u: usize, layers: usize| costs[on_node[u]].frame(&unit_shadows(u), layers);
    // Per cell, its units with the cheapest first (it hosts the cell's extra layers).
    let cells = fit.parts.len();
    let mut cell_units: Vec<Vec<usize>> = vec![Vec::new(); cells];
    for (u, &(c, _)) in units.iter().enumerate() {
        cell_units[c.expect("grid units name their cell")].push(u);
    }
    for (c, list) in cell_units.iter_mut().enumerate() {
        let extra = host_layers(c).len() - 1;
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
    let inputs: Vec<Vec<topology::IllumInput>> = cell_units
        .iter()
        .enumerate()
        .map(|(c, list)| {
            list.iter()
                .enumerate()
                .map(|(j, &u)| topology::IllumInput {
                    node: cluster.nodes[on_node[u]].id.clone(),
                    color: groups[units[u].1].color,
                    layers: if j == 0 {
                        host_layers(c)
                    } else {
                        vec![(Layer::Illumination, options.formats.node)]
                    },
                    cost: cost_of(u, 0),
                })
                .collect()
        })
        .collect();
    let (stages, dst) = stages(&inputs);
    let mut nodes = Vec::with_capacity(units.len());
    for (c, list) in cell_units.iter().enumerate() {
        let (part, tile) = fit.cell(c);
        for (j, &u) in list.iter().enumerate() {
            let g = &groups[units[u].1];
            let (stage, input) = dst[c][j].clone();
            let layers = inputs[c][j].layers.clone();
            nodes.push(NodePlan {
                node: inputs[c][j].node.clone(),
                lights: g.lights.clone(),
                color: g.color,
                shadows: unit_shadows(u).into_iter().cloned().collect(),
                est_cost_us: cost_of(u, layers.len() - 1).round() as u64,
                layers,
                downstream: stage,
                input_index: input,
                part,
                tile,
                peel: fit.peel(c),
                scene: None,
            });
        }
    }
    let placement = MaterialPlacement::PerPart {
        nodes: inputs.iter().map(|p| p[0].node.clone()).collect(),
    };
    Layout {
        stages,
        nodes,
        placement,
    }
}

/// The nodes and stages of a peeled plan (`docs/translucency.md` § Peeled layers): one cell of
/// light groups per eye layer, back to front (`Fit::peel`); each cell's cheapest node also
/// renders its layer's material layers and, for a translucent layer, its transmittance.
fn peeled(
    fit: &Fit,
    cluster: &ClusterSpec,
    grouping: &Grouping,
    assignment: &Assignment,
    shadows: &Shadows,
    finish: &topology::Finish,
) -> Layout {
    let options = &assignment.options;
    let translucent: Vec<bool> = (0..fit.parts.len())
        .map(|c| fit.peel(c) != Some(0))
        .collect();
    let host_layers = |c: usize| {
        let mut layers = vec![(Layer::Illumination, options.formats.node)];
        layers.extend(
            finish
                .material_layers
                .iter()
                .copied()
                .filter(|l| l.0 != Layer::Depth),
        );
        if translucent[c] {
            // Transmittance in [0, 1] as half floats, as the node's target holds it.
            layers.push((Layer::Transmittance, PixelFormat::F16x4));
        }
        layers
    };
    grid(
        fit,
        cluster,
        grouping,
        assignment,
        shadows,
        host_layers,
        |inputs| {
            topology::peeled_stages(
                inputs,
                &translucent,
                finish,
                &cluster.compositors,
                &options.formats,
            )
        },
    )
}

/// The nodes and stages of a grid of sort-last parts, sort-first tiles or both: each cell's
/// cheapest node also renders its cell's eye depth and material layers, and the stages
/// depth-compose the cells.
fn partitioned(
    fit: &Fit,
    cluster: &ClusterSpec,
    grouping: &Grouping,
    assignment: &Assignment,
    shadows: &Shadows,
    finish: &topology::Finish,
) -> Layout {
    let options = &assignment.options;
    // The eye depth (which the penumbra filter's material layers may already name) and the
    // material layers.
    let mut host = vec![
        (Layer::Illumination, options.formats.node),
        (Layer::Depth, PixelFormat::DepthF32),
    ];
    host.extend(
        finish
            .material_layers
            .iter()
            .copied()
            .filter(|l| l.0 != Layer::Depth),
    );
    grid(
        fit,
        cluster,
        grouping,
        assignment,
        shadows,
        |_| host.clone(),
        |inputs| {
            topology::partition_stages(
                inputs,
                finish,
                &cluster.compositors,
                options.topology,
                &options.formats,
            )
        },
    )
}
