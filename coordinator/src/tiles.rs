//! Sort-first tiles (`PlanOptions::tiles`, `docs/planner.md` § Tiles): the image rows each tile's
//! nodes render, and the balancer that moves rows between tiles from what the nodes measured, so
//! that a tile whose rows are heavier gets fewer of them next frame (Equalizer's 2D load
//! balancer, in one dimension: rows, band-aligned).

use std::collections::{BTreeMap, HashMap};

/// The most tiles a plan may ask for.
pub const MAX_TILES: u32 = 64;

/// How far one step moves a boundary towards where the last measurement puts it (1: all the
/// way). Below 1 a noisy frame moves the rows less, and a boundary between two tiles of about
/// equal cost settles instead of swinging.
pub const DAMPING: f64 = 0.5;

/// `tiles` tiles of about equal rows over `height` rows, each boundary on a band boundary
/// (`band_height`), top to bottom, covering every row once. `None` where there are fewer bands
/// than tiles (a tile would be empty) or no tile.
pub fn even_rows(height: u32, band_height: u32, tiles: u32) -> Option<Vec<[u32; 2]>> {
    let bands = height.div_ceil(band_height.max(1));
    if tiles == 0 || bands < tiles {
        return None;
    }
    let edge = |i: u32| {
        let band = (u64::from(i) * u64::from(bands) / u64::from(tiles)) as u32;
        (band * band_height).min(height)
    };
    Some((0..tiles).map(|i| [edge(i), edge(i + 1)]).collect())
}

/// The rows of the next frame, from the rows a frame was rendered with and what each tile cost
/// (its slowest node's row-dependent time: eye pass, readback and packing). Each tile's cost is
/// taken as spread evenly over its rows; the new boundaries split the total cost evenly
/// (moved `damping` of the way from the old ones), are put on band boundaries and keep every
/// tile at least one band. Costs that are not all finite and positive leave the rows as they are.
pub fn rebalance(
    rows: &[[u32; 2]],
    costs: &[f64],
    height: u32,
    band_height: u32,
    damping: f64,
) -> Vec<[u32; 2]> {
    let n = rows.len();
    let bh = band_height.max(1);
    let bands = height.div_ceil(bh);
    if n < 2
        || costs.len() != n
        || bands < n as u32
        || costs.iter().any(|c| !c.is_finite() || *c <= 0.0)
        || rows.iter().any(|r| r[0] >= r[1])
    {
        return rows.to_vec();
    }
    let total: f64 = costs.iter().sum();
    // Where the cumulative cost reaches `target`, in rows (piecewise linear over the tiles).
    let row_at = |target: f64| -> f64 {
        let mut before = 0.0;
        for (r, c) in rows.iter().zip(costs) {
            if before + c >= target {
                let within = (target - before) / c;
                return f64::from(r[0]) + within * f64::from(r[1] - r[0]);
            }
            before += c;
        }
        f64::from(height)
    };
    let mut edges: Vec<u32> = Vec::with_capacity(n + 1);
    edges.push(0);
    for k in 1..n {
        let old = f64::from(rows[k][0]);
        let want = row_at(total * k as f64 / n as f64);
        let moved = old + damping.clamp(0.0, 1.0) * (want - old);
        let to_band = |row: f64| (row / f64::from(bh)).round() as i64;
        let (from, goal) = (to_band(old), to_band(want));
        // Damped, but at least a band towards where it should be: a boundary does not stall
        // half-way because the damped step rounds back to where it was.
        let band = match to_band(moved) {
            b if b == from && goal != from => from + (goal - from).signum(),
            b => b,
        };
        // At least one band for this tile and for every tile after it.
        let lo = i64::from(edges[k - 1] / bh) + 1;
        let hi = i64::from(bands) - (n - k) as i64;
        edges.push((band.clamp(lo, hi) as u32 * bh).min(height));
    }
    edges.push(height);
    edges.windows(2).map(|w| [w[0], w[1]]).collect()
}

/// One frame's tiles: the rows it was requested with and, per tile, the costs its nodes reported.
#[derive(Debug, Clone)]
struct Measured {
    rows: Vec<[u32; 2]>,
    costs: Vec<Vec<f64>>,
}

/// A plan's tiles over the frames of its epoch: which tile each node renders, the rows every
/// frame was requested with, and each frame's measurements until every tiled node has reported.
#[derive(Debug, Clone)]
pub struct TileBalancer {
    height: u32,
    band_height: u32,
    rows: Vec<[u32; 2]>,
    tile_of: HashMap<String, usize>,
    /// Per wire frame, the rows it was requested with and the costs reported so far.
    frames: BTreeMap<u64, Measured>,
    /// The rows each node was last sent.
    given: HashMap<String, [u32; 2]>,
}

impl TileBalancer {
    /// The balancer of a plan, `None` where it has no tiles.
    pub fn of(plan: &crate::plan::Plan) -> Option<TileBalancer> {
        if plan.tiles.len() < 2 {
            return None;
        }
        let tile_of: HashMap<String, usize> = plan
            .nodes
            .iter()
            .filter_map(|n| Some((n.node.clone(), n.tile?)))
            .collect();
        let given = plan
            .nodes
            .iter()
            .filter_map(|n| Some((n.node.clone(), *plan.tiles.get(n.tile?)?)))
            .collect();
        Some(TileBalancer {
            height: plan.height,
            band_height: plan.band_height,
            rows: plan.tiles.clone(),
            tile_of,
            frames: BTreeMap::new(),
            given,
        })
    }

    /// Starts from the rows `previous` (the last epoch's balancer) reached, where it had as many
    /// tiles of the same image and bands: a re-plan (a lost node, new colours) keeps the
    /// balance instead of starting even. The nodes, configured with the plan's rows, are sent
    /// these with their next frame.
    pub fn carry(&mut self, previous: &TileBalancer) {
        if previous.rows.len() == self.rows.len()
            && (previous.height, previous.band_height) == (self.height, self.band_height)
        {
            self.rows = previous.rows.clone();
        }
    }

    /// The rows of every tile now.
    pub fn rows(&self) -> &[[u32; 2]] {
        &self.rows
    }

    /// Frame `wire` is being requested: remembers its rows, and returns `node`'s rows where they
    /// differ from what it was last sent (what `FrameParams::rows` carries).
    pub fn requested(&mut self, wire: u64, node: &str) -> Option<[u32; 2]> {
        let tiles = self.rows.len();
        self.frames.entry(wire).or_insert_with(|| Measured {
            rows: self.rows.clone(),
            costs: vec![Vec::new(); tiles],
        });
        let tile = *self.tile_of.get(node)?;
        let now = self.rows[tile];
        (self.given.insert(node.to_string(), now) != Some(now)).then_some(now)
    }

    /// `node` reported frame `wire`, its row-dependent time `cost_us`. Once every tiled node has
    /// reported the frame, the rows are balanced from it (frames before it are forgotten):
    /// returns whether they were.
    pub fn reported(&mut self, wire: u64, node: &str, cost_us: f64) -> bool {
        let Some(&tile) = self.tile_of.get(node) else {
            return false;
        };
        let per_tile = self.per_tile();
        let Some(Measured { rows, costs }) = self.frames.get_mut(&wire) else {
            return false;
        };
        costs[tile].push(cost_us);
        if costs.iter().zip(&per_tile).any(|(c, &n)| c.len() < n) {
            return false;
        }
        let slowest: Vec<f64> = costs
            .iter()
            .map(|c| c.iter().copied().fold(0.0, f64::max))
            .collect();
        self.rows = rebalance(rows, &slowest, self.height, self.band_height, DAMPING);
        self.frames = self.frames.split_off(&(wire + 1));
        true
    }

    /// Nodes per tile.
    fn per_tile(&self) -> Vec<usize> {
        let mut n = vec![0; self.rows.len()];
        for &t in self.tile_of.values() {
            if let Some(c) = n.get_mut(t) {
                *c += 1;
            }
        }
        n
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn covers(rows: &[[u32; 2]], height: u32) -> bool {
        rows.first().is_some_and(|r| r[0] == 0)
            && rows.last().is_some_and(|r| r[1] == height)
            && rows.windows(2).all(|w| w[0][1] == w[1][0])
            && rows.iter().all(|r| r[0] < r[1])
    }

    #[test]
    fn even_rows_cover_the_image_on_band_edges() {
        let rows = even_rows(600, 64, 3).unwrap();
        assert_eq!(rows, vec![[0, 192], [192, 384], [384, 600]]);
        assert!(covers(&rows, 600));
        assert_eq!(even_rows(100, 64, 3), None, "two bands, three tiles");
        assert_eq!(even_rows(100, 64, 0), None);
        assert_eq!(even_rows(7, 1, 7).unwrap().len(), 7);
    }

    /// A heavy top: each row of the top quarter costs 9 times a row below. The top tile
    /// shrinks until both tiles cost about the same; the control (costs per tile equal to
    /// their rows, an even scene) leaves the rows where they are.
    #[test]
    fn the_heavy_tile_shrinks_until_the_costs_meet() {
        let (height, band) = (480, 16);
        let cost = |r: [u32; 2]| -> f64 {
            (r[0]..r[1])
                .map(|y| if y < height / 4 { 9.0 } else { 1.0 })
                .sum()
        };
        let mut rows = even_rows(height, band, 2).unwrap();
        for _ in 0..20 {
            let costs: Vec<f64> = rows.iter().map(|&r| cost(r)).collect();
            rows = rebalance(&rows, &costs, height, band, DAMPING);
            assert!(covers(&rows, height));
        }
        let (a, b) = (cost(rows[0]), cost(rows[1]));
        assert!(rows[0][1] < height / 2, "the heavy tile shrank: {rows:?}");
        assert!(
            (a - b).abs() <= 2.0 * 9.0 * f64::from(band),
            "costs {a} and {b} within a boundary band of the heavy rows: {rows:?}"
        );
        let even = even_rows(height, band, 3).unwrap();
        let flat: Vec<f64> = even.iter().map(|r| f64::from(r[1] - r[0])).collect();
        assert_eq!(rebalance(&even, &flat, height, band, DAMPING), even);
    }

    #[test]
    fn every_tile_keeps_a_band_and_bad_costs_change_nothing() {
        let rows = even_rows(64, 8, 4).unwrap();
        let next = rebalance(&rows, &[1.0, 1e9, 1.0, 1.0], 64, 8, 1.0);
        assert!(covers(&next, 64), "{next:?}");
        assert!(next.iter().all(|r| r[1] - r[0] >= 8), "{next:?}");
        for bad in [f64::NAN, 0.0, -1.0, f64::INFINITY] {
            assert_eq!(rebalance(&rows, &[1.0, bad, 1.0, 1.0], 64, 8, 1.0), rows);
        }
        assert_eq!(rebalance(&rows, &[1.0], 64, 8, 1.0), rows, "costs per tile");
    }
}
