//! The BVH against brute force, degenerate input and shared edges.

use lightfold_scene::bvh::{Bvh, is_valid_triangle};
use proptest::prelude::*;

fn brute_closest(
    tris: &[[[f32; 3]; 3]],
    o: [f64; 3],
    d: [f64; 3],
    tmax: f64,
) -> Option<(f64, u32)> {
    let bvh_one = |i: usize| Bvh::build(&tris[i..=i]);
    let mut best: Option<(f64, u32)> = None;
    for i in 0..tris.len() {
        if let Some(h) = bvh_one(i).closest(o, d, 0.0, tmax, |_, _, _| true)
            && best.is_none_or(|(t, _)| h.t < t)
        {
            best = Some((h.t, i as u32));
        }
    }
    best
}

fn coord() -> impl Strategy<Value = f32> {
    -5.0f32..5.0
}

fn triangle() -> impl Strategy<Value = [[f32; 3]; 3]> {
    (
        [coord(), coord(), coord()],
        -1.0f32..1.0,
        -1.0f32..1.0,
        -1.0f32..1.0,
    )
        .prop_map(|(c, a, b, e)| {
            [
                c,
                [c[0] + a, c[1] + b, c[2] + e],
                [c[0] + b, c[1] - e, c[2] + a * 0.5],
            ]
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]
    #[test]
    fn closest_and_any_hit_match_brute_force(
        tris in prop::collection::vec(triangle(), 1..200),
        rays in prop::collection::vec(([coord(), coord(), coord()], [coord(), coord(), coord()]), 16),
        tmax in 0.5f64..20.0,
    ) {
        let bvh = Bvh::build(&tris);
        for (o, t) in rays {
            let o = o.map(f64::from);
            let d = [0, 1, 2].map(|k| f64::from(t[k]) - o[k]);
            let want = brute_closest(&tris, o, d, tmax);
            let got = bvh.closest(o, d, 0.0, tmax, |_, _, _| true);
            prop_assert_eq!(got.map(|h| h.t), want.map(|w| w.0));
            prop_assert_eq!(bvh.occluded(o, d, 0.0, tmax, |_, _, _| true), want.is_some());
        }
    }
}

#[test]
fn filter_rejects_hits_and_traversal_continues_behind() {
    let near = [[-1.0, -1.0, 1.0], [1.0, -1.0, 1.0], [0.0, 1.0, 1.0]];
    let far = [[-1.0, -1.0, 2.0], [1.0, -1.0, 2.0], [0.0, 1.0, 2.0]];
    let bvh = Bvh::build(&[near, far]);
    let (o, d) = ([0.0, 0.0, 0.0], [0.0, 0.0, 1.0]);
    assert_eq!(
        bvh.closest(o, d, 0.0, 10.0, |_, _, _| true).map(|h| h.id),
        Some(0)
    );
    assert_eq!(
        bvh.closest(o, d, 0.0, 10.0, |id, _, _| id != 0)
            .map(|h| h.id),
        Some(1)
    );
    assert!(!bvh.occluded(o, d, 0.0, 10.0, |_, _, _| false));
    assert!(
        !bvh.occluded(o, d, 0.0, 0.9, |_, _, _| true),
        "tmax excludes both"
    );
    assert!(
        bvh.occluded(o, d, 1.5, 10.0, |id, _, _| id == 1),
        "tmin excludes the near one"
    );
}

#[test]
fn degenerate_triangles_are_skipped() {
    let good = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let line = [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]];
    let point = [[3.0; 3]; 3];
    let nan = [[f32::NAN, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    let inf = [[f32::INFINITY, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    assert!(is_valid_triangle(&good));
    for t in [line, point, nan, inf] {
        assert!(!is_valid_triangle(&t));
    }
    let bvh = Bvh::build(&[line, good, point, nan, inf]);
    assert_eq!(bvh.triangle_count(), 1);
    let h = bvh.closest([0.2, 0.2, -1.0], [0.0, 0.0, 1.0], 0.0, 5.0, |_, _, _| true);
    assert_eq!(h.map(|h| h.id), Some(1), "ids are the caller's indices");
    assert!(
        Bvh::build(&[])
            .closest([0.0; 3], [1.0, 0.0, 0.0], 0.0, 1.0, |_, _, _| true)
            .is_none()
    );
}

/// Rays aimed exactly at the shared edges and vertices of a finely tessellated grid never slip
/// through.
#[test]
fn shared_edges_and_vertices_are_watertight() {
    let n = 40;
    let mut tris = Vec::new();
    let at = |i: usize, j: usize| [i as f32 * 0.1 - 2.0, 0.0, j as f32 * 0.1 - 2.0];
    for j in 0..n {
        for i in 0..n {
            tris.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            tris.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    let bvh = Bvh::build(&tris);
    let mut misses = 0;
    for j in 1..n {
        for i in 1..n {
            let v = at(i, j).map(f64::from);
            let mid = [0, 1, 2].map(|k| 0.5 * (v[k] + f64::from(at(i + 1, j + 1)[k])));
            let half = [0, 1, 2].map(|k| 0.5 * (v[k] + f64::from(at(i + 1, j)[k])));
            for target in [v, mid, half] {
                let o = [target[0] + 0.37, 3.0, target[2] - 0.21];
                let d = [0, 1, 2].map(|k| target[k] - o[k]);
                if bvh.closest(o, d, 0.0, 10.0, |_, _, _| true).is_none() {
                    misses += 1;
                }
            }
        }
    }
    assert_eq!(misses, 0);
}

#[test]
fn deep_degenerate_distributions_build_and_trace() {
    // Exponentially spaced triangles drive SAH towards one-sided splits.
    let tris: Vec<[[f32; 3]; 3]> = (0..2000)
        .map(|i| {
            let x = 1.0001f32.powi(i) - 1.0;
            [[x, 0.0, 0.0], [x, 1.0, 0.0], [x, 0.0, 1.0]]
        })
        .collect();
    let bvh = Bvh::build(&tris);
    let h = bvh.closest([-1.0, 0.25, 0.25], [1.0, 0.0, 0.0], 0.0, 1e9, |_, _, _| {
        true
    });
    assert_eq!(h.map(|h| h.id), Some(0));
    // Many triangles at one centroid: one leaf, still correct.
    let same = vec![[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]; 300];
    let bvh = Bvh::build(&same);
    assert!(bvh.occluded([0.2, 0.2, 1.0], [0.0, 0.0, -1.0], 0.0, 2.0, |_, _, _| true));
}

/// Axis-parallel rays (zero direction components) through vertices and edges of a flat grid,
/// whose boxes have zero thickness: the slab test must neither produce NaN nor miss.
#[test]
fn axis_parallel_rays_hit_flat_geometry() {
    let at = |i: usize, j: usize| [i as f32 * 0.25, 0.0, j as f32 * 0.25];
    let mut tris = Vec::new();
    for j in 0..8 {
        for i in 0..8 {
            tris.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            tris.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    let bvh = Bvh::build(&tris);
    for j in 0..=8 {
        for i in 0..=8 {
            let p = at(i, j).map(f64::from);
            for dy in [-1.0, 1.0] {
                let o = [p[0], -dy, p[2]];
                let h = bvh.closest(o, [0.0, dy, 0.0], 0.0, 10.0, |_, _, _| true);
                assert!(
                    h.is_some_and(|h| (h.t - 1.0).abs() < 1e-12),
                    "({i},{j}) dy {dy}: {h:?}"
                );
            }
        }
    }
    // A ray lying in the plane of the grid never reports a hit (and does not panic).
    assert!(!bvh.occluded([-1.0, 0.0, 0.5], [1.0, 0.0, 0.0], 0.0, 10.0, |_, _, _| true));
}
