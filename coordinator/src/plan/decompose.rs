//! Sort-first, sort-last, both or neither, chosen (`PlanOptions::tiles` 0; `docs/planner.md` §
//! Choosing tiles). Sort-last partitions are chosen first, by memory and the eye pass's share of
//! a frame budget (`partitions_for`). Then the planner plans the image whole and with each
//! candidate tile count the render nodes allow (with those partitions: a grid of tiles × parts),
//! and takes the tile count whose plan gives up the fewest accuracy steps to its frame budget
//! and, among those, estimates the shortest frame, if that frame is at least
//! [`TILES_MIN_GAIN`] shorter than the untiled plan's. The cost model decides what tiles buy: a
//! node's fixed cost and the eye-pass half of each light scale with its pixels, its shadow passes
//! do not, and tiles multiply the shadow passes (each tile's nodes render every light group);
//! nodes on one machine's CPU or one GPU run one after another, so there tiles mostly add shadow
//! passes.

use super::display::ms;
use super::types::{Decomposition, PlanOptions, TILES_MIN_GAIN, TileCandidate};
use super::{Plan, PlanError, partitions_for, plan_with};
use crate::plan::ClusterSpec;
use crate::tiles::MAX_TILES;
use lightfold_scene::Scene;

/// Tile counts an automatic plan weighs beside the untiled image (those the nodes and the
/// image's bands allow): enough to find the knee without planning every count.
const CANDIDATES: [u32; 11] = [2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64];

/// Plans `scene` with the tile count chosen as the module documentation says, `options.tiles`
/// being 0. The plan records the choice (`Plan::decomposition`).
pub(super) fn choose(
    scene: &Scene,
    cluster: &ClusterSpec,
    options: &PlanOptions,
    previous: Option<&Plan>,
) -> Result<Plan, PlanError> {
    let decided = |plan: Result<Plan, PlanError>, candidates: Vec<TileCandidate>, why: String| {
        plan.map(|mut p| {
            p.decomposition = Some(Decomposition { candidates, why });
            p
        })
    };
    let asked = options.partitions;
    let parts = partitions_for(scene, cluster, options).max(1);
    // The candidates keep the partitions resolved, so the grid is tiles × those parts.
    let options = &PlanOptions {
        partitions: parts,
        ..options.clone()
    };
    let with = |tiles: u32| {
        let options = PlanOptions {
            tiles,
            ..options.clone()
        };
        plan_with(scene, cluster, &options, previous)
    };
    // What the partitions say before the tiles' reason.
    let sort_last = if parts > 1 {
        let cause = if asked > 1 {
            "asked for"
        } else {
            "the scene's geometry or eye pass needs them"
        };
        format!("sort-last, {parts} partitions ({cause}); ")
    } else {
        String::new()
    };
    if options.material_own_node {
        return decided(
            with(1),
            Vec::new(),
            format!(
                "{sort_last}untiled: the material layers have a node of their own (a tile's first node renders its own)"
            ),
        );
    }
    let nodes = cluster.nodes.len() as u32;
    let bands = scene
        .camera
        .height
        .div_ceil(options.band_height.max(1))
        .max(1);
    let most = (nodes / parts).min(bands).min(MAX_TILES);
    if most < 2 {
        let why = if nodes < 2 {
            "untiled: one render node".to_string()
        } else if parts > 1 {
            format!("{sort_last}untiled: too few render nodes for two tiles of every part")
        } else {
            "untiled: the image has one band of rows".to_string()
        };
        return decided(with(1), Vec::new(), why);
    }
    let whole = with(1)?;
    // Nodes sharing a GPU run one after another: tiles stacked on one device buy nothing.
    let est = |p: &Plan| super::shared::serial_est_us(p, cluster);
    let weigh = |tiles: u32, p: &Plan| TileCandidate {
        tiles,
        est_frame_us: est(p),
        concessions: p.concessions.len(),
        nodes: p.nodes.len(),
    };
    let mut candidates = vec![weigh(1, &whole)];
    let mut best: Option<Plan> = None;
    for tiles in CANDIDATES.into_iter().filter(|&t| t <= most) {
        // Too few nodes for T tiles × the light groups plans fewer tiles: a smaller candidate.
        let Ok(plan) = with(tiles) else { continue };
        if plan.tiles.len() != tiles as usize {
            continue;
        }
        candidates.push(weigh(tiles, &plan));
        let better =
            |b: &Plan| (plan.concessions.len(), est(&plan)) < (b.concessions.len(), est(b));
        if best.as_ref().is_none_or(better) {
            best = Some(plan);
        }
    }
    let listed = candidates
        .iter()
        .map(|c| format!("{} → {}", c.tiles, ms(c.est_frame_us)))
        .collect::<Vec<_>>()
        .join(", ");
    let gain = |p: &Plan| 1.0 - est(p) as f64 / est(&whole).max(1) as f64;
    match best {
        Some(tiled)
            if tiled.concessions.len() < whole.concessions.len()
                || (tiled.concessions.len() == whole.concessions.len()
                    && gain(&tiled) >= TILES_MIN_GAIN) =>
        {
            let why = if tiled.concessions.len() < whole.concessions.len() {
                format!(
                    "{sort_last}sort-first, {} tiles: {} accuracy step(s) given up to the frame budget \
                     against {} untiled (estimates {listed})",
                    tiled.tiles.len(),
                    tiled.concessions.len(),
                    whole.concessions.len()
                )
            } else {
                format!(
                    "{sort_last}sort-first, {} tiles: est. frame {} against {} untiled, {:.0} % shorter \
                     (estimates {listed})",
                    tiled.tiles.len(),
                    ms(est(&tiled)),
                    ms(est(&whole)),
                    100.0 * gain(&tiled)
                )
            };
            decided(Ok(tiled), candidates, why)
        }
        Some(_) => {
            let one_cpu = super::cpu_hosts::cpu_hosts(&cluster.nodes)
                .iter()
                .any(Option::is_some);
            let cpu = if one_cpu {
                "; nodes on one machine's CPU run one after another, so tiles mostly add shadow passes"
            } else {
                ""
            };
            let why = format!(
                "{sort_last}untiled: no tile count is {:.0} % faster by the cost model (estimates {listed}){cpu}",
                100.0 * TILES_MIN_GAIN
            );
            decided(Ok(whole), candidates, why)
        }
        None => decided(
            Ok(whole),
            candidates,
            format!("{sort_last}untiled: too few render nodes for two tiles of every light group"),
        ),
    }
}
