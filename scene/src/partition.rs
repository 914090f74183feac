//! Sort-last partitions of a scene's meshes (issue 24, seed 000 §6): `parts` spatially coherent
//! groups balanced by triangle count, by recursive bisection of the mesh centres. Each step sorts
//! the group's meshes along the longest axis of their centres' bounds (ties by mesh index) and
//! cuts where the triangles before the cut come nearest the share of the parts on that side, so
//! every part holds about `total / parts` triangles: off by at most about the largest mesh per
//! level of bisection, since meshes are not split. Deterministic: the same scene gives the same
//! parts. Pure CPU code.

use crate::model::Scene;

/// Partitions the meshes of `scene` into `parts` groups (mesh indices, ascending in each).
/// Every mesh is in exactly one group; meshes without a finite position go to the first group;
/// groups are empty only when there are fewer meshes than `parts`. `parts` 0 is taken as 1.
pub fn partition_meshes(scene: &Scene, parts: usize) -> Vec<Vec<u32>> {
    let parts = parts.max(1);
    let mut out = vec![Vec::new(); parts];
    // (index, centre, triangles) of the meshes with a position; the others join part 0.
    let mut items: Vec<(u32, [f32; 3], u64)> = Vec::with_capacity(scene.meshes.len());
    for (i, m) in scene.meshes.iter().enumerate() {
        match m.bounds() {
            Some((lo, hi)) => items.push((
                i as u32,
                [0, 1, 2].map(|k| 0.5 * lo[k] + 0.5 * hi[k]),
                m.triangle_count() as u64,
            )),
            None => out[0].push(i as u32),
        }
    }
    bisect(&mut items, 0, parts, &mut out);
    for p in &mut out {
        p.sort_unstable();
    }
    out
}

/// Splits `items` into parts `first .. first + count` of `out`.
fn bisect(items: &mut [(u32, [f32; 3], u64)], first: usize, count: usize, out: &mut [Vec<u32>]) {
    if count == 1 || items.len() <= 1 {
        out[first].extend(items.iter().map(|it| it.0));
        return;
    }
    let axis = longest_axis(items);
    items.sort_by(|a, b| a.1[axis].total_cmp(&b.1[axis]).then(a.0.cmp(&b.0)));
    let left_parts = count / 2;
    let total: u64 = items.iter().map(|it| it.2.max(1)).sum();
    // The cut whose left triangles come nearest the left parts' share; each side keeps at least
    // as many meshes as it has parts where it can.
    let want = total as f64 * left_parts as f64 / count as f64;
    let lo = left_parts.min(items.len() - 1).max(1);
    let hi = items.len().saturating_sub(count - left_parts).max(lo);
    let mut acc = 0u64;
    let mut best = (f64::INFINITY, lo);
    for (cut, it) in items.iter().enumerate().take(hi) {
        acc += it.2.max(1);
        let at = cut + 1;
        if at < lo {
            continue;
        }
        let miss = (acc as f64 - want).abs();
        if miss < best.0 {
            best = (miss, at);
        }
    }
    let (left, right) = items.split_at_mut(best.1);
    bisect(left, first, left_parts, out);
    bisect(right, first + left_parts, count - left_parts, out);
}

fn longest_axis(items: &[(u32, [f32; 3], u64)]) -> usize {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for it in items {
        for k in 0..3 {
            lo[k] = lo[k].min(it.1[k]);
            hi[k] = hi[k].max(it.1[k]);
        }
    }
    (0..3)
        .max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b])).then(b.cmp(&a)))
        .unwrap_or(0)
}
