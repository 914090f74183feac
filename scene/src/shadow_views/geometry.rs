//! Box and convex-polygon helpers of the shadow-view fitting: receiver boxes as face polygons,
//! clipped against planes through the light (Sutherland–Hodgman).

use crate::shading::{V3, cross, dot, length, normalize, scale};

/// A convex polygon of points relative to the sample position.
pub(super) type Poly = Vec<V3>;

pub(super) fn add3(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// Euclidean distance from `p` to the box (0 inside).
pub(super) fn box_distance(p: V3, lo: V3, hi: V3) -> f32 {
    let d = [0, 1, 2].map(|k| (lo[k] - p[k]).max(0.0).max(p[k] - hi[k]));
    length(d)
}

pub(super) fn box_corners(lo: V3, hi: V3) -> [V3; 8] {
    std::array::from_fn(|i| {
        [
            if i & 1 == 0 { lo[0] } else { hi[0] },
            if i & 2 == 0 { lo[1] } else { hi[1] },
            if i & 4 == 0 { lo[2] } else { hi[2] },
        ]
    })
}

/// The six faces of a box as quads (a flat box gives coincident faces, which is harmless).
pub(super) fn box_faces(lo: V3, hi: V3) -> [[V3; 4]; 6] {
    let c = box_corners(lo, hi);
    [
        [c[0], c[2], c[6], c[4]], // x = lo
        [c[1], c[3], c[7], c[5]], // x = hi
        [c[0], c[1], c[5], c[4]], // y = lo
        [c[2], c[3], c[7], c[6]], // y = hi
        [c[0], c[1], c[3], c[2]], // z = lo
        [c[4], c[5], c[7], c[6]], // z = hi
    ]
}

/// Clips a convex polygon to every half-space `dot(n, p) ≥ 0` (Sutherland–Hodgman).
pub(super) fn clip_all(mut poly: Poly, planes: &[V3]) -> Poly {
    for n in planes {
        if poly.is_empty() {
            break;
        }
        poly = clip(&poly, *n);
    }
    poly
}

pub(super) fn clip(poly: &[V3], n: V3) -> Poly {
    let mut out = Vec::with_capacity(poly.len() + 2);
    for i in 0..poly.len() {
        let a = poly[i];
        let b = poly[(i + 1) % poly.len()];
        let (da, db) = (dot(n, a), dot(n, b));
        if da >= 0.0 {
            out.push(a);
        }
        if (da >= 0.0) != (db >= 0.0) {
            let t = da / (da - db);
            out.push([
                a[0] + (b[0] - a[0]) * t,
                a[1] + (b[1] - a[1]) * t,
                a[2] + (b[2] - a[2]) * t,
            ]);
        }
    }
    out
}

/// Column-major view matrix with rows `right`, `up`, `−fwd`, eye at `origin`.
pub(super) fn look_view(origin: V3, fwd: V3, right: V3, up: V3) -> [[f32; 4]; 4] {
    let back = scale(fwd, -1.0);
    [
        [right[0], up[0], back[0], 0.0],
        [right[1], up[1], back[1], 0.0],
        [right[2], up[2], back[2], 0.0],
        [
            -dot(right, origin),
            -dot(up, origin),
            -dot(back, origin),
            1.0,
        ],
    ]
}

/// Two unit vectors completing `axis` to a right-handed frame (`right × up = −axis` as for a view
/// looking down `axis`), preferring world +Y as up.
pub fn perpendicular_frame(axis: V3) -> (V3, V3) {
    let hint = if axis[1].abs() < 0.99 {
        [0.0, 1.0, 0.0]
    } else {
        [1.0, 0.0, 0.0]
    };
    let right = normalize(cross(axis, hint));
    let up = cross(right, axis);
    (right, up)
}
