//! Glossy specular of area lights in closed form: linearly transformed cosines (LTC; Heitz,
//! Dupuy, Hill & Neubelt, "Real-Time Polygonal-Light Shading with Linearly Transformed Cosines",
//! 2016).
//!
//! The GGX lobe `f·cos` of a view is fitted by a clamped cosine pushed through a 3×3 linear map
//! `M`; the lobe's integral over a light's polygon is then the cosine's integral over the polygon
//! pushed through `M⁻¹`, which has a closed form (a sum over edges). The fitted `M⁻¹`, the lobe's
//! norm `∫f·cos` and its Fresnel share `∫f·cos·(1 − |v·h|)⁵` come from `data/ltc_ggx.bin`, written
//! by `cargo run --release -p lightfold-scene --example fit_ltc -- scene/data/ltc_ggx.bin`.
//!
//! lightfold renders an area light as N point samples, each with its own shadow map, and composes
//! them linearly (a node sums any subset). A sample `λ` of a light whose shape is known
//! ([`crate::AreaShape`]) therefore keeps the point formula's diffuse and takes as specular its
//! share of the light's closed-form specular, in proportion to its irradiance:
//! `i^s_λ = E_λ · S/E`, with `S` the lobe integrated over the shape and `E` the shape's
//! unshadowed irradiance, both per unit radiance (which cancels). Unshadowed, the samples sum to
//! `S` (up to the point sampling's error of `E`, the diffuse's error); shadowed, each keeps its
//! own visibility, so a penumbra darkens the highlight where it darkens the diffuse.
//! `docs/shading.md` states the model; the lighting shader mirrors this module.

use crate::model::AreaShape;
use crate::sampling::basis;
use crate::shading::{V3, add, cross, dot, length, normalize, scale, sub};
use std::f32::consts::{PI, TAU};
use std::sync::OnceLock;

/// Rows (roughness `r = i/63`, `α = max(r², MIN_ALPHA)`) and columns (`t = j/63`,
/// `cos θ_v = 1 − t²`) of the table.
pub const LTC_SIZE: usize = 64;
/// Floats per cell: `M⁻¹`'s `(a, b, c, d)` (the map `(x, y, z) ↦ (a·x + b·z, y, c·x + d·z)` in
/// the frame whose x axis is the view's tangent direction and z the normal), the lobe's norm and
/// Fresnel integral, and two unused.
pub const LTC_CELL: usize = 8;

const BYTES: &[u8] = include_bytes!("../data/ltc_ggx.bin");
const _: () = assert!(BYTES.len() == LTC_SIZE * LTC_SIZE * LTC_CELL * 4);

/// The fitted table, row-major (`row · LTC_SIZE + column`).
pub fn table() -> &'static [[f32; LTC_CELL]] {
    static TABLE: OnceLock<Vec<[f32; LTC_CELL]>> = OnceLock::new();
    TABLE.get_or_init(|| parse_table(BYTES))
}

/// Cells of a table file (little-endian f32, [`LTC_CELL`] a cell; a trailing partial cell is
/// dropped).
pub fn parse_table(bytes: &[u8]) -> Vec<[f32; LTC_CELL]> {
    bytes
        .chunks_exact(4 * LTC_CELL)
        .map(|cell| {
            let mut out = [0.0; LTC_CELL];
            for (o, b) in out.iter_mut().zip(cell.chunks_exact(4)) {
                *o = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
            }
            out
        })
        .collect()
}

/// The table bilinearly interpolated at GGX `alpha` and view cosine `cos_v` (both clamped to
/// the table; the shader reads it the same way).
pub fn lookup(alpha: f32, cos_v: f32) -> [f32; LTC_CELL] {
    lookup_in(table(), alpha, cos_v)
}

/// [`lookup`] in table `t` (`LTC_SIZE²` cells).
pub fn lookup_in(t: &[[f32; LTC_CELL]], alpha: f32, cos_v: f32) -> [f32; LTC_CELL] {
    let last = (LTC_SIZE - 1) as f32;
    let alpha = if alpha.is_finite() { alpha } else { 1.0 };
    let cos_v = if cos_v.is_finite() { cos_v } else { 1.0 };
    let x = alpha.clamp(0.0, 1.0).sqrt() * last;
    let y = (1.0 - cos_v.clamp(0.0, 1.0)).sqrt() * last;
    let (i, fx) = split(x);
    let (j, fy) = split(y);
    let at = |r: usize, c: usize| &t[r * LTC_SIZE + c];
    let mut out = [0.0; LTC_CELL];
    for (k, o) in out.iter_mut().enumerate() {
        let top = at(i, j)[k] + (at(i, j + 1)[k] - at(i, j)[k]) * fy;
        let bottom = at(i + 1, j)[k] + (at(i + 1, j + 1)[k] - at(i + 1, j)[k]) * fy;
        *o = top + (bottom - top) * fx;
    }
    out
}

/// Cell index and fraction of a coordinate in `[0, LTC_SIZE − 1]`.
fn split(x: f32) -> (usize, f32) {
    let i = (x.floor() as usize).min(LTC_SIZE - 2);
    (i, x - i as f32)
}

/// Vertices in a polygon (an ellipse or a sphere's silhouette is a regular octagon of the same
/// area).
pub const MAX_VERTICES: usize = 8;
/// Circumradius of the regular octagon whose area is the unit disk's: `√(π / (2√2))`.
pub const OCTAGON_RADIUS: f32 = 1.053_907_4;

/// The polygon standing for `shape` as seen from `p` (world space), with its vertex count; `None`
/// from inside a sphere light.
pub fn polygon(shape: &AreaShape, p: V3) -> Option<([V3; MAX_VERTICES], usize)> {
    let mut out = [[0.0; 3]; MAX_VERTICES];
    let ellipse = |out: &mut [V3; MAX_VERTICES], c: V3, u: V3, v: V3| {
        for (k, o) in out.iter_mut().enumerate() {
            let phi = TAU * k as f32 / MAX_VERTICES as f32;
            let (s, co) = phi.sin_cos();
            *o = add(
                c,
                add(scale(u, co * OCTAGON_RADIUS), scale(v, s * OCTAGON_RADIUS)),
            );
        }
    };
    match *shape {
        AreaShape::Rect { center, u, v } => {
            let corners = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)];
            for (o, (a, b)) in out.iter_mut().zip(corners) {
                *o = add(center, add(scale(u, a), scale(v, b)));
            }
            Some((out, 4))
        }
        AreaShape::Disk { center, u, v } => {
            ellipse(&mut out, center, u, v);
            Some((out, MAX_VERTICES))
        }
        AreaShape::Sphere { center, radius } => {
            // The silhouette: the circle where the cone from p touches the sphere.
            let d = sub(center, p);
            let dist = length(d);
            // NaN (a non-finite centre) counts as inside.
            if dist.is_nan() || dist <= radius * 1.0001 {
                return None;
            }
            let k = (radius / dist) * (radius / dist);
            let c = add(p, scale(d, 1.0 - k));
            let r = radius * (1.0 - k).sqrt();
            let (u, v) = basis(scale(d, 1.0 / dist));
            ellipse(&mut out, c, scale(u, r), scale(v, r));
            Some((out, MAX_VERTICES))
        }
    }
}

/// `∫ max(z, 0)/π dω` over the spherical polygon of the directions `verts` (from the shading
/// point, any length, a convex planar polygon), as a non-negative number: the polygon clipped to
/// the upper hemisphere (z ≥ 0), then summed over its edges.
pub fn clipped_cosine_integral(verts: &[V3]) -> f32 {
    let n = verts.len();
    if n < 3 {
        return 0.0;
    }
    // Sutherland–Hodgman against z = 0: a convex polygon of n vertices keeps at most n + 1.
    let mut clipped = [[0.0f32; 3]; MAX_VERTICES + 1];
    let mut m = 0;
    for k in 0..n {
        let a = verts[k];
        let b = verts[(k + 1) % n];
        if a[2] >= 0.0 {
            clipped[m] = a;
            m += 1;
        }
        if (a[2] >= 0.0) != (b[2] >= 0.0) && m < clipped.len() {
            let t = a[2] / (a[2] - b[2]);
            let mut x = add(a, scale(sub(b, a), t));
            x[2] = 0.0;
            clipped[m] = x;
            m += 1;
        }
    }
    let sum: f32 = (0..m)
        .map(|k| edge(normalize(clipped[k]), normalize(clipped[(k + 1) % m])))
        .sum();
    (sum / TAU).abs()
}

/// `θ · (v1 × v2).z / |v1 × v2|` for unit `v1`, `v2` at angle θ: one edge's share of
/// `2π · ∫ cos/π` over a spherical polygon (zero for a zero vertex).
fn edge(v1: V3, v2: V3) -> f32 {
    let c = cross(v1, v2);
    let s = length(c);
    let theta = s.atan2(dot(v1, v2));
    let factor = if s > 1e-9 { theta / s } else { 1.0 };
    c[2] * factor
}

/// A view's tangent frame at a surface point: x the view's direction along the surface (any
/// tangent where the view is the normal), z the normal.
fn frame(n: V3, v: V3) -> (V3, V3) {
    let t = sub(v, scale(n, dot(n, v)));
    let l = length(t);
    let t1 = if l > 1e-6 {
        scale(t, 1.0 / l)
    } else {
        basis(n).0
    };
    (t1, cross(n, t1))
}

/// Roughness below which glossy specular is wholly the closed form, and above which wholly the
/// samples' own (between, a smoothstep blend): the fit is within a few per cent where the lobe is
/// narrow, while a rough lobe is what point samples integrate well and what the fit (a cosine's
/// shape) follows worst at grazing views (hard case 19, `docs/shading.md`).
pub const CLOSED_FORM_ROUGHNESS: (f32, f32) = (0.4, 0.6);

/// The closed form's share of a sample's glossy specular at GGX `alpha` (`α = roughness²`): 1 up
/// to roughness [`CLOSED_FORM_ROUGHNESS`]`.0`, 0 from `.1`, a smoothstep between.
pub fn closed_form_share(alpha: f32) -> f32 {
    let (lo, hi) = CLOSED_FORM_ROUGHNESS;
    let r = alpha.max(0.0).sqrt();
    let t = ((r - lo) / (hi - lo)).clamp(0.0, 1.0);
    if t.is_nan() {
        return 0.0;
    }
    1.0 - t * t * (3.0 - 2.0 * t)
}

/// Smallest unshadowed cosine integral (`E / (π·L)`) for which the closed form is used; below
/// it the light is edge-on or below the horizon and its samples' point formula stands.
const MIN_COSINE_INTEGRAL: f32 = 1e-7;

/// `(S₁/E, S_w/E)` at surface point `p` (unit normal `n`, unit view direction `v`) of GGX
/// roughness `alpha` under the area light `shape`: the lobe `f·cos` (Fresnel 1) and its Fresnel
/// share `f·cos·(1 − |v·h|)⁵` integrated over the shape, each over the shape's unshadowed
/// irradiance `∫ cos dω` (all per unit radiance). A sample of irradiance `E_λ` reflects
/// `E_λ·(F0·S₁/E + (1 − F0)·S_w/E)`. `None` where the closed form does not apply (inside a
/// sphere light, a light edge-on or below the horizon).
pub fn ggx_area_terms(shape: &AreaShape, p: V3, n: V3, v: V3, alpha: f32) -> Option<(f32, f32)> {
    let (verts, count) = polygon(shape, p)?;
    let (t1, t2) = frame(n, v);
    let cell = lookup(alpha, dot(n, v));
    let [a, b, c, d, norm, fresnel, ..] = cell;
    let mut local = [[0.0; 3]; MAX_VERTICES];
    let mut lobe = [[0.0; 3]; MAX_VERTICES];
    for k in 0..count {
        let w = sub(verts[k], p);
        let (x, y, z) = (dot(w, t1), dot(w, t2), dot(w, n));
        local[k] = [x, y, z];
        lobe[k] = [a * x + b * z, y, c * x + d * z];
    }
    let e = clipped_cosine_integral(&local[..count]);
    if e.is_nan() || e <= MIN_COSINE_INTEGRAL {
        return None;
    }
    let s = clipped_cosine_integral(&lobe[..count]) / (PI * e);
    let (s1, sw) = (norm * s, fresnel * s);
    (s1.is_finite() && sw.is_finite()).then_some((s1, sw))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table_is_whole_and_finite() {
        let t = table();
        assert_eq!(t.len(), LTC_SIZE * LTC_SIZE);
        assert!(t.iter().flatten().all(|x| x.is_finite()));
    }

    /// A polygon's cosine integral against its known form factor: a unit square at distance 1
    /// straight above the point, `(1/π)·(4·(1/√2)·atan(1/√2)·…)`, checked by the closed form of
    /// a rectangle's form factor to a parallel differential area.
    #[test]
    fn cosine_integral_is_the_form_factor() {
        // Form factor of a differential area to a parallel a×b rectangle at height c whose
        // corner is above it: (1/2π)(A/√(1+A²)·atan(B/√(1+A²)) + B/√(1+B²)·atan(A/√(1+B²))).
        let corner = |a: f32, b: f32, c: f32| {
            let (x, y) = (a / c, b / c);
            let (sx, sy) = ((1.0 + x * x).sqrt(), (1.0 + y * y).sqrt());
            (x / sx * (y / sx).atan() + y / sy * (x / sy).atan()) / TAU
        };
        let square = [
            [0.0, 0.0, 1.0],
            [0.7, 0.0, 1.0],
            [0.7, 1.3, 1.0],
            [0.0, 1.3, 1.0],
        ];
        let got = clipped_cosine_integral(&square);
        let want = corner(0.7, 1.3, 1.0);
        assert!((got - want).abs() < 1e-5, "{got} vs {want}");
        // Either winding; a polygon wholly below the horizon gives nothing; one across it is cut.
        let reversed: Vec<V3> = square.iter().rev().copied().collect();
        assert!((clipped_cosine_integral(&reversed) - want).abs() < 1e-5);
        let below: Vec<V3> = square.iter().map(|p| [p[0], p[1], -p[2]]).collect();
        assert_eq!(clipped_cosine_integral(&below), 0.0);
        let across = [
            [-1.0, -1.0, 1.0],
            [1.0, -1.0, 1.0],
            [1.0, 1.0, -1.0],
            [-1.0, 1.0, -1.0],
        ];
        let half = clipped_cosine_integral(&across);
        let upper = [
            [-1.0, -1.0, 1.0],
            [1.0, -1.0, 1.0],
            [1.0, 0.0, 0.0],
            [-1.0, 0.0, 0.0],
        ];
        assert!((half - clipped_cosine_integral(&upper)).abs() < 1e-6);
    }

    #[test]
    fn polygons_keep_the_shapes_area() {
        let area = |verts: &[V3]| {
            let mut s = [0.0; 3];
            for k in 0..verts.len() {
                s = add(s, cross(verts[k], verts[(k + 1) % verts.len()]));
            }
            0.5 * length(s)
        };
        let (v, n) = polygon(
            &AreaShape::Disk {
                center: [0.0, 2.0, 0.0],
                u: [0.5, 0.0, 0.0],
                v: [0.0, 0.0, 0.5],
            },
            [0.0; 3],
        )
        .unwrap();
        assert!((area(&v[..n]) - PI * 0.25).abs() < 1e-5);
        // A sphere from afar: its silhouette's area; from inside: none.
        let shape = AreaShape::Sphere {
            center: [0.0, 10.0, 0.0],
            radius: 1.0,
        };
        let (v, n) = polygon(&shape, [0.0; 3]).unwrap();
        assert!((area(&v[..n]) - PI * 0.99).abs() < 1e-4);
        assert!(polygon(&shape, [0.0, 10.5, 0.0]).is_none());
    }
}
