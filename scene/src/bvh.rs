//! A small bounding-volume hierarchy for the CPU reference: binned-SAH build over triangles,
//! flattened depth-first nodes, and closest-hit / any-hit traversal with a caller filter (so alpha
//! masks and back-face rules stay out of the tree). It shares nothing with any GPU path.
//!
//! Node boxes are f32 with a conservatively widened slab test; the ray–triangle test is
//! Möller–Trumbore in f64 on edges taken exactly from the f32 vertices, with a tiny barycentric
//! slack, so a ray through a shared edge or vertex hits at least one of the triangles there.

/// Triangles of a leaf at most this many when SAH says splitting is not worth it.
const MAX_LEAF: usize = 4;
/// Number of SAH bins per axis.
const BINS: usize = 16;
/// Past this depth the build splits at the object median, bounding the depth by 64 + log2(n).
const SAH_DEPTH: usize = 64;
/// Traversal stack size; the build never exceeds it (64 + 32 < 128).
const STACK: usize = 128;
/// Barycentric slack: neighbours computing a shared edge from different vertices round
/// differently (a ray through the midpoint of a shared diagonal otherwise slips between both at
/// f64 precision); 1e-9 of a triangle's size is far above that rounding and far below a pixel.
const EDGE_TOLERANCE: f64 = 1e-9;
/// Relative widening of the slab-test exit distance (PBRT's `1 + 2·γ(3)`), so rounding never
/// culls a box the ray actually touches.
const SLAB_GROW: f32 = 1.0 + 2.0 * 3.0 * f32::EPSILON;

#[derive(Debug, Clone, Copy)]
struct Node {
    min: [f32; 3],
    max: [f32; 3],
    /// Leaf: index of the first triangle. Interior: index of the right child (left is `self + 1`).
    offset: u32,
    /// Number of triangles; 0 for an interior node.
    count: u32,
}

#[derive(Debug, Clone, Copy)]
struct Tri {
    v0: [f64; 3],
    e1: [f64; 3],
    e2: [f64; 3],
}

/// A ray hit: distance along the (not necessarily unit) direction, barycentrics of `v1` and `v2`,
/// and the caller's triangle id.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    pub t: f64,
    pub u: f64,
    pub v: f64,
    pub id: u32,
}

/// The hierarchy over the non-degenerate triangles it was built from.
#[derive(Debug, Clone)]
pub struct Bvh {
    nodes: Vec<Node>,
    tris: Vec<Tri>,
    ids: Vec<u32>,
}

#[derive(Clone, Copy)]
struct Aabb {
    min: [f32; 3],
    max: [f32; 3],
}

impl Aabb {
    const EMPTY: Aabb = Aabb {
        min: [f32::INFINITY; 3],
        max: [f32::NEG_INFINITY; 3],
    };
    fn grow(&mut self, p: [f32; 3]) {
        self.min = [0, 1, 2].map(|k| self.min[k].min(p[k]));
        self.max = [0, 1, 2].map(|k| self.max[k].max(p[k]));
    }
    fn merge(&mut self, b: &Aabb) {
        self.grow(b.min);
        self.grow(b.max);
    }
    fn area(&self) -> f32 {
        let d = [
            self.max[0] - self.min[0],
            self.max[1] - self.min[1],
            self.max[2] - self.min[2],
        ];
        if d[0] < 0.0 {
            return 0.0;
        }
        2.0 * (d[0] * d[1] + d[1] * d[2] + d[2] * d[0])
    }
}

struct Prim {
    bounds: Aabb,
    centroid: [f32; 3],
    index: u32,
}

/// True when the triangle has finite vertices and a non-zero area (in f64).
pub fn is_valid_triangle(t: &[[f32; 3]; 3]) -> bool {
    if !t.iter().flatten().all(|c| c.is_finite()) {
        return false;
    }
    let e1 = sub64(t[1], t[0]);
    let e2 = sub64(t[2], t[0]);
    let n = cross64(e1, e2);
    dot64(n, n) > 0.0
}

impl Bvh {
    /// Builds over `triangles`; triangle `i` is reported as id `i`. Degenerate triangles (zero
    /// area or non-finite vertices) are left out: they can never be hit.
    pub fn build(triangles: &[[[f32; 3]; 3]]) -> Bvh {
        let mut prims: Vec<Prim> = triangles
            .iter()
            .enumerate()
            .filter(|(_, t)| is_valid_triangle(t))
            .map(|(i, t)| {
                let mut b = Aabb::EMPTY;
                t.iter().for_each(|&p| b.grow(p));
                let centroid = [0, 1, 2].map(|k| 0.5 * (b.min[k] + b.max[k]));
                Prim {
                    bounds: b,
                    centroid,
                    index: i as u32,
                }
            })
            .collect();
        let mut nodes = Vec::with_capacity(2 * prims.len() / MAX_LEAF + 1);
        if !prims.is_empty() {
            build_node(&mut nodes, &mut prims, 0, 0);
        }
        let tris = prims
            .iter()
            .map(|p| {
                let t = &triangles[p.index as usize];
                Tri {
                    v0: t[0].map(f64::from),
                    e1: sub64(t[1], t[0]),
                    e2: sub64(t[2], t[0]),
                }
            })
            .collect();
        let ids = prims.iter().map(|p| p.index).collect();
        Bvh { nodes, tris, ids }
    }

    /// Number of triangles in the tree (degenerate ones excluded).
    pub fn triangle_count(&self) -> usize {
        self.tris.len()
    }

    /// Bounds of everything in the tree, or `None` when it is empty.
    pub fn bounds(&self) -> Option<([f32; 3], [f32; 3])> {
        self.nodes.first().map(|n| (n.min, n.max))
    }

    /// The nearest hit with `t` in `(tmin, tmax)` whose triangle `accept(id, u, v)` allows.
    pub fn closest(
        &self,
        o: [f64; 3],
        d: [f64; 3],
        tmin: f64,
        tmax: f64,
        mut accept: impl FnMut(u32, f64, f64) -> bool,
    ) -> Option<Hit> {
        let mut best: Option<Hit> = None;
        let mut tmax = tmax;
        self.traverse(o, d, tmin, &mut tmax, true, |tri, id, tmax| {
            if let Some((t, u, v)) = intersect(tri, o, d, tmin, *tmax)
                && accept(id, u, v)
            {
                *tmax = t;
                best = Some(Hit { t, u, v, id });
            }
            false
        });
        best
    }

    /// Whether any accepted triangle is hit with `t` in `(tmin, tmax)`.
    pub fn occluded(
        &self,
        o: [f64; 3],
        d: [f64; 3],
        tmin: f64,
        tmax: f64,
        mut accept: impl FnMut(u32, f64, f64) -> bool,
    ) -> bool {
        let mut tmax = tmax;
        self.traverse(o, d, tmin, &mut tmax, false, |tri, id, tmax| {
            matches!(intersect(tri, o, d, tmin, *tmax), Some((_, u, v)) if accept(id, u, v))
        })
    }

    /// Visits the leaves the ray reaches; `visit` returns true to stop. Returns whether stopped.
    fn traverse(
        &self,
        o: [f64; 3],
        d: [f64; 3],
        tmin: f64,
        tmax: &mut f64,
        ordered: bool,
        mut visit: impl FnMut(&Tri, u32, &mut f64) -> bool,
    ) -> bool {
        if self.nodes.is_empty() {
            return false;
        }
        let ray = BoxRay::new(o, d);
        let mut stack = [0u32; STACK];
        let mut sp = 1usize;
        while sp > 0 {
            sp -= 1;
            let node = &self.nodes[stack[sp] as usize];
            if ray.hit(node, tmin as f32, *tmax as f32).is_none() {
                continue;
            }
            if node.count > 0 {
                let first = node.offset as usize;
                for i in first..first + node.count as usize {
                    if visit(&self.tris[i], self.ids[i], tmax) {
                        return true;
                    }
                }
                continue;
            }
            let left = stack[sp] + 1;
            let right = node.offset;
            let (near, far) = if ordered {
                let tl = ray.hit(&self.nodes[left as usize], tmin as f32, *tmax as f32);
                let tr = ray.hit(&self.nodes[right as usize], tmin as f32, *tmax as f32);
                match (tl, tr) {
                    (None, None) => continue,
                    (Some(_), None) => (left, None),
                    (None, Some(_)) => (right, None),
                    (Some(a), Some(b)) if a <= b => (left, Some(right)),
                    _ => (right, Some(left)),
                }
            } else {
                (left, Some(right))
            };
            if let Some(far) = far {
                stack[sp] = far;
                sp += 1;
            }
            stack[sp] = near;
            sp += 1;
        }
        false
    }
}

/// A ray prepared for slab tests: f32 origin, reciprocal direction (±∞ for zero components) and
/// which slab plane is entered first per axis. The comparisons below keep the running bound when
/// the candidate is NaN (`0·∞`: the origin lies on a slab plane of an axis the ray is parallel
/// to), which makes such boxes inclusive, as they should be.
#[derive(Clone, Copy)]
struct BoxRay {
    o: [f32; 3],
    inv: [f32; 3],
    neg: [bool; 3],
}

impl BoxRay {
    fn new(o: [f64; 3], d: [f64; 3]) -> BoxRay {
        let inv = d.map(|c| 1.0 / c as f32);
        BoxRay {
            o: o.map(|c| c as f32),
            inv,
            neg: inv.map(|c| c < 0.0),
        }
    }

    /// Entry distance into the node's box within `[tmin, tmax]`, or `None`.
    #[inline(always)]
    fn hit(&self, n: &Node, tmin: f32, tmax: f32) -> Option<f32> {
        let mut t0 = tmin;
        let mut t1 = tmax;
        for k in 0..3 {
            let (near, far) = if self.neg[k] {
                (n.max[k], n.min[k])
            } else {
                (n.min[k], n.max[k])
            };
            let a = (near - self.o[k]) * self.inv[k];
            let b = (far - self.o[k]) * self.inv[k] * SLAB_GROW;
            t0 = if a > t0 { a } else { t0 };
            t1 = if b < t1 { b } else { t1 };
        }
        (t0 <= t1).then_some(t0)
    }
}

/// Möller–Trumbore in f64 with edges widened by `EDGE_TOLERANCE`: `(t, u, v)` for `t` in
/// `(tmin, tmax)`.
#[inline]
fn intersect(tri: &Tri, o: [f64; 3], d: [f64; 3], tmin: f64, tmax: f64) -> Option<(f64, f64, f64)> {
    let p = cross64(d, tri.e2);
    let det = dot64(tri.e1, p);
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let inv = 1.0 / det;
    let s = [o[0] - tri.v0[0], o[1] - tri.v0[1], o[2] - tri.v0[2]];
    let u = dot64(s, p) * inv;
    if !(-EDGE_TOLERANCE..=1.0 + EDGE_TOLERANCE).contains(&u) {
        return None;
    }
    let q = cross64(s, tri.e1);
    let v = dot64(d, q) * inv;
    if v < -EDGE_TOLERANCE || u + v > 1.0 + EDGE_TOLERANCE {
        return None;
    }
    let t = dot64(tri.e2, q) * inv;
    (t > tmin && t < tmax).then_some((t, u, v))
}

/// Builds the subtree over `prims`, which sit at `start..` in the final triangle order.
/// Recursion depth is bounded by `SAH_DEPTH + log2(n)` (median splits past `SAH_DEPTH`).
fn build_node(nodes: &mut Vec<Node>, prims: &mut [Prim], start: usize, depth: usize) {
    let mut bounds = Aabb::EMPTY;
    let mut cb = Aabb::EMPTY;
    for p in prims.iter() {
        bounds.merge(&p.bounds);
        cb.grow(p.centroid);
    }
    let index = nodes.len();
    nodes.push(Node {
        min: bounds.min,
        max: bounds.max,
        offset: start as u32,
        count: prims.len() as u32,
    });
    let n = prims.len();
    let extent = [0, 1, 2].map(|k| cb.max[k] - cb.min[k]);
    let axis = (0..3)
        .max_by(|&a, &b| extent[a].total_cmp(&extent[b]))
        .unwrap_or(0);
    if n <= 1 || extent[axis] <= 0.0 {
        // All centroids coincide: no split can separate them.
        return;
    }
    let mid = if depth >= SAH_DEPTH {
        median_split(prims, axis)
    } else {
        match sah_split(prims, &cb, bounds.area()) {
            Some((ax, pos)) => {
                let m = partition(prims, |p| p.centroid[ax] < pos);
                if m == 0 || m == n {
                    median_split(prims, axis)
                } else {
                    m
                }
            }
            None => return,
        }
    };
    nodes[index].count = 0;
    let (l, r) = prims.split_at_mut(mid);
    build_node(nodes, l, start, depth + 1);
    nodes[index].offset = nodes.len() as u32;
    build_node(nodes, r, start + mid, depth + 1);
}

fn median_split(prims: &mut [Prim], axis: usize) -> usize {
    let mid = prims.len() / 2;
    prims.select_nth_unstable_by(mid, |a, b| a.centroid[axis].total_cmp(&b.centroid[axis]));
    mid
}

fn partition(prims: &mut [Prim], pred: impl Fn(&Prim) -> bool) -> usize {
    let mut i = 0;
    for j in 0..prims.len() {
        if pred(&prims[j]) {
            prims.swap(i, j);
            i += 1;
        }
    }
    i
}

/// Best binned-SAH split `(axis, position)`, or `None` when no split beats a leaf.
fn sah_split(prims: &[Prim], cb: &Aabb, parent_area: f32) -> Option<(usize, f32)> {
    let n = prims.len();
    let leaf_cost = n as f32;
    let mut best: Option<(f32, usize, f32)> = None;
    for axis in 0..3 {
        let lo = cb.min[axis];
        let ext = cb.max[axis] - lo;
        if ext <= 0.0 {
            continue;
        }
        let mut bins = [(Aabb::EMPTY, 0u32); BINS];
        let scale = BINS as f32 / ext;
        for p in prims {
            let b = (((p.centroid[axis] - lo) * scale) as usize).min(BINS - 1);
            bins[b].0.merge(&p.bounds);
            bins[b].1 += 1;
        }
        let mut right_area = [0f32; BINS];
        let mut right_count = [0u32; BINS];
        let mut acc = Aabb::EMPTY;
        let mut cnt = 0;
        for i in (1..BINS).rev() {
            acc.merge(&bins[i].0);
            cnt += bins[i].1;
            right_area[i] = acc.area();
            right_count[i] = cnt;
        }
        let mut acc = Aabb::EMPTY;
        let mut cnt = 0;
        for i in 0..BINS - 1 {
            acc.merge(&bins[i].0);
            cnt += bins[i].1;
            if cnt == 0 || right_count[i + 1] == 0 {
                continue;
            }
            // Traversal cost 1 relative to one triangle test.
            let cost = 1.0
                + (acc.area() * cnt as f32 + right_area[i + 1] * right_count[i + 1] as f32)
                    / parent_area.max(f32::MIN_POSITIVE);
            if best.is_none_or(|(c, _, _)| cost < c) {
                best = Some((cost, axis, lo + ext * (i + 1) as f32 / BINS as f32));
            }
        }
    }
    best.filter(|&(c, _, _)| c < leaf_cost || n > MAX_LEAF)
        .map(|(_, a, p)| (a, p))
}

#[inline]
fn sub64(a: [f32; 3], b: [f32; 3]) -> [f64; 3] {
    [0, 1, 2].map(|k| f64::from(a[k]) - f64::from(b[k]))
}
#[inline]
fn dot64(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline]
fn cross64(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
