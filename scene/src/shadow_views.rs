//! Shadow-map geometry of one light sample, as pure maths so the planner can count shadow passes
//! without a GPU (ARCHITECTURE §9). A sample's lit region (a cosine lobe's hemisphere, a spot's
//! cone, a point light's sphere) is covered only **where receivers are**: one off-centre
//! perspective frustum fitted to the receivers when their directions fit within
//! [`MAX_FITTED_FOV_DEG`], otherwise the faces of a cube around the sample that see a receiver,
//! each fitted to what it sees. A directional light gets one orthographic view. Near and far are
//! fitted to the receivers; casters closer than near are kept by depth clamping on the GPU.
//!
//! Matrices are column-major (like [`crate::Camera::view_matrix`]); views look down −Z; the
//! projection is reversed-Z (depth 1 at `near`, 0 at `far`) with wgpu clip conventions.

mod cascades;
mod geometry;
pub mod sizing;

use crate::model::{Camera, LightSample, SampleKind};
use crate::shading::{V3, cross, dot, length, normalize, scale, sub};
pub use cascades::{CASCADE_RATIO, MAX_CASCADES, camera_views, fitted_views};
pub use geometry::perpendicular_frame;
use geometry::{Poly, add3, box_corners, box_distance, box_faces, clip, clip_all, look_view};
pub use sizing::{Mismatch, Probe, mismatch_size, probes};

/// Widest field of view (per axis) of a single fitted frustum before cube faces are used: wider
/// frusta waste resolution at their edges (texels grow as `1/cos²`).
pub const MAX_FITTED_FOV_DEG: f32 = 120.0;
/// Extra border around fitted extents, as a fraction of their width, so PCF kernels at the edge of
/// the receivers' footprint still read rendered texels.
pub const EXTENT_MARGIN: f32 = 0.02;

/// Which of a cube's six faces, in the cube's own frame (`+Z` is the sample's axis).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CubeFace {
    PosX,
    NegX,
    PosY,
    NegY,
    PosZ,
    NegZ,
}

/// How a view was chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShadowViewKind {
    /// One perspective frustum fitted to every receiver.
    Fitted,
    /// One face of a cube around the sample, fitted to the receivers inside it.
    CubeFace(CubeFace),
    /// Orthographic view of a directional light.
    Ortho,
}

/// One shadow map's view of a light sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShadowView {
    pub kind: ShadowViewKind,
    /// World → light view (looks down −Z), column-major.
    pub view: [[f32; 4]; 4],
    /// Reversed-Z projection, column-major.
    pub proj: [[f32; 4]; 4],
    /// Distances along the view axis covered by the map.
    pub near: f32,
    pub far: f32,
    /// Image-plane bounds `[left, right, bottom, top]`: tangents (`x/z`) for perspective views,
    /// metres for orthographic ones. A texel spans `(right − left)/size` of them.
    pub extent: [f32; 4],
    /// For one of two fitted frusta that split the receivers by a plane through the sample: the
    /// plane's normal, pointing to this view's side (a point `p` belongs to the view whose
    /// `half_space·(p − sample)` is ≥ 0).
    pub half_space: Option<V3>,
    /// For one of the cascades [`camera_views`] splits a light's frustum into: the eye depths
    /// (distance along the camera's forward axis) of the receivers it holds, `[from, to)`; the
    /// last cascade's `to` is infinite. A point takes the first cascade whose `to` exceeds its
    /// eye depth.
    pub eye_depth: Option<[f32; 2]>,
}

impl ShadowView {
    pub fn is_ortho(&self) -> bool {
        self.kind == ShadowViewKind::Ortho
    }
}

/// The views needed to shadow `sample` on receivers given as axis-aligned boxes `(min, max)`.
/// Empty when the sample reaches no receiver (outside its range, behind its lobe or cone).
pub fn shadow_views(sample: &LightSample, receivers: &[(V3, V3)]) -> Vec<ShadowView> {
    let boxes: Vec<(V3, V3)> = receivers
        .iter()
        .copied()
        .filter(|(lo, hi)| {
            lo.iter().chain(hi.iter()).all(|c| c.is_finite()) && (0..3).all(|k| lo[k] <= hi[k])
        })
        .collect();
    if boxes.is_empty() {
        return Vec::new();
    }
    if sample.kind == SampleKind::Directional {
        return ortho_view(normalize(sample.direction), &boxes)
            .into_iter()
            .collect();
    }
    perspective_views(sample, &boxes)
}

/// Axis-aligned bounds of each mesh, the receivers [`shadow_views`] expects for a whole scene.
pub fn mesh_receivers(scene: &crate::Scene) -> Vec<(V3, V3)> {
    scene.meshes.iter().filter_map(|m| m.bounds()).collect()
}

/// The parts of `receivers` the camera can see: each box cut to the camera's view pyramid (no far
/// plane) and re-boxed; boxes out of view are dropped. Shadow maps only need to cover these, so
/// with a fixed camera fewer lights need more than one fitted frustum.
pub fn visible_receivers(camera: &Camera, receivers: &[(V3, V3)]) -> Vec<(V3, V3)> {
    cascades::clip_to_view(camera, receivers, None)
        .into_iter()
        .map(|c| c.bounds)
        .collect()
}

/// The frame of a sample's cube faces, `[x, y, z]` with `z` the sample's axis (−Y without one):
/// a direction `d` from the sample falls in the face of the largest `|d·axis|`, its sign picking
/// `Pos`/`Neg` (ties go to x before y before z).
pub fn cube_frame(sample: &LightSample) -> [V3; 3] {
    let axis = normalize(sample.direction);
    let axis = if axis == [0.0; 3] {
        [0.0, -1.0, 0.0]
    } else {
        axis
    };
    let (r, u) = perpendicular_frame(axis);
    [r, u, axis]
}

impl CubeFace {
    /// Position in `[PosX, NegX, PosY, NegY, PosZ, NegZ]`.
    pub fn index(self) -> usize {
        self as usize
    }
}

fn perspective_views(sample: &LightSample, boxes: &[(V3, V3)]) -> Vec<ShadowView> {
    let origin = sample.position;
    let frame = cube_frame(sample);
    let axis = frame[2];
    // Half-spaces through the sample bounding its lit region.
    let mut region: Vec<V3> = Vec::new();
    match sample.kind {
        SampleKind::CosineLobe | SampleKind::Bounce { .. } => region.push(axis),
        SampleKind::Spot { cos_outer, .. } if cos_outer > 0.0 => {
            region.push(axis);
            // The square pyramid around the cone, when the cone is narrow enough to have one.
            let t = (1.0 - cos_outer * cos_outer).sqrt() / cos_outer;
            if t < 50.0 {
                let (r, u) = perpendicular_frame(axis);
                for side in [r, scale(r, -1.0), u, scale(u, -1.0)] {
                    region.push(sub(scale(axis, t), side));
                }
            }
        }
        _ => {}
    }
    let mut polys: Vec<Poly> = Vec::new();
    let mut contains_light = false;
    for &(lo, hi) in boxes {
        let d = box_distance(origin, lo, hi);
        if let Some(range) = sample.range.filter(|r| *r > 0.0)
            && d >= range
        {
            continue;
        }
        if d <= 0.0 {
            contains_light = true;
        }
        for face in box_faces(lo, hi) {
            let rel: Poly = face.iter().map(|p| sub(*p, origin)).collect();
            let clipped = clip_all(rel, &region);
            if clipped.len() >= 3 {
                polys.push(clipped);
            }
        }
    }
    if polys.is_empty() {
        return Vec::new();
    }
    let own_axis = (sample.kind != SampleKind::Isotropic).then_some(axis);
    if !contains_light {
        if let Some(v) = fitted_view(origin, own_axis, &polys) {
            return vec![v];
        }
        if let Some(views) = split_views(origin, frame, &polys) {
            return views;
        }
    }
    cube_views(origin, frame, &polys, &region, contains_light)
}

/// Two fitted frusta, one each side of a plane through the sample containing its axis, when
/// both halves of the receivers fit; of the planes tried the tightest pair wins. Cheaper than
/// three to five cube faces for receivers spread wide in one direction only.
fn split_views(origin: V3, [r, u, _]: [V3; 3], polys: &[Poly]) -> Option<Vec<ShadowView>> {
    let normals = [r, u, normalize(add3(r, u)), normalize(sub(r, u))];
    let mut best: Option<(f32, Vec<ShadowView>)> = None;
    'planes: for n in normals {
        let mut views = Vec::with_capacity(2);
        for side in [n, scale(n, -1.0)] {
            let half: Vec<Poly> = polys
                .iter()
                .map(|p| clip(p, side))
                .filter(|p| p.len() >= 3)
                .collect();
            if half.is_empty() {
                continue;
            }
            let Some(mut v) = fitted_view(origin, None, &half) else {
                continue 'planes;
            };
            v.half_space = Some(side);
            views.push(v);
        }
        // One empty half means a single frustum would have fitted: not this function's case.
        if views.len() == 2 {
            let area: f32 = views
                .iter()
                .map(|v| (v.extent[1] - v.extent[0]) * (v.extent[3] - v.extent[2]))
                .sum();
            if best.as_ref().is_none_or(|b| area < b.0) {
                best = Some((area, views));
            }
        }
    }
    best.map(|b| b.1)
}

/// One frustum around the receivers, if they all fit inside [`MAX_FITTED_FOV_DEG`]. Axes tried:
/// the mean receiver direction and the sample's own axis, each re-centred on the receivers'
/// angular bounds a few times; the tightest frustum wins.
fn fitted_view(origin: V3, sample_axis: Option<V3>, polys: &[Poly]) -> Option<ShadowView> {
    let mut sum = [0.0f32; 3];
    for p in polys.iter().flatten() {
        sum = add3(sum, normalize(*p));
    }
    let limit = (MAX_FITTED_FOV_DEG.to_radians() * 0.5).tan();
    let mut best: Option<(f32, V3, V3, V3, Fit)> = None;
    for start in [Some(normalize(sum)), sample_axis].into_iter().flatten() {
        let mut axis = start;
        for _ in 0..4 {
            if axis == [0.0; 3] {
                break;
            }
            let (right, up) = perpendicular_frame(axis);
            // Loose bounds (no limit) to re-centre on; the limit applies to the final frame.
            let Some(loose) = fit_points(polys.iter().flatten().copied(), axis, right, up, 1e6)
            else {
                break;
            };
            if let Some(fit) = fit_points(polys.iter().flatten().copied(), axis, right, up, limit) {
                let e = fit.extent;
                let area = (e[1] - e[0]) * (e[3] - e[2]);
                if best.as_ref().is_none_or(|b| area < b.0) {
                    best = Some((area, axis, right, up, fit));
                }
            }
            let e = loose.extent;
            let (cx, cy) = (0.5 * (e[0] + e[1]), 0.5 * (e[2] + e[3]));
            axis = normalize(add3(axis, add3(scale(right, cx), scale(up, cy))));
        }
    }
    let (_, axis, right, up, fit) = best?;
    Some(perspective_view(
        ShadowViewKind::Fitted,
        origin,
        axis,
        right,
        up,
        fit,
        false,
    ))
}

/// The cube faces that see a receiver, each fitted to the receivers inside it.
fn cube_views(
    origin: V3,
    [r, u, axis]: [V3; 3],
    polys: &[Poly],
    region: &[V3],
    contains_light: bool,
) -> Vec<ShadowView> {
    let faces = [
        (CubeFace::PosX, r, u),
        (CubeFace::NegX, scale(r, -1.0), u),
        (CubeFace::PosY, u, scale(r, -1.0)),
        (CubeFace::NegY, scale(u, -1.0), r),
        (CubeFace::PosZ, axis, u),
        (CubeFace::NegZ, scale(axis, -1.0), u),
    ];
    let mut out = Vec::new();
    for (face, fwd, up_hint) in faces {
        // A face entirely behind the lit half-space sees nothing lit.
        if region.first().is_some_and(|h| dot(*h, fwd) < -0.99) {
            continue;
        }
        let right = normalize(cross(fwd, up_hint));
        let up = cross(right, fwd);
        let pyramid = [
            sub(fwd, right),
            add3(fwd, right),
            sub(fwd, up),
            add3(fwd, up),
        ];
        let mut pts: Vec<V3> = Vec::new();
        for poly in polys {
            let c = clip_all(poly.clone(), &pyramid);
            if c.len() >= 3 {
                pts.extend(c);
            }
        }
        if pts.is_empty() {
            continue;
        }
        // Points on the pyramid's edges have tangents of exactly ±1; allow rounding.
        let Some(mut fit) = fit_points(pts.into_iter(), fwd, right, up, 1.0 + 1e-3) else {
            continue;
        };
        if contains_light {
            fit.near = 0.0;
        }
        out.push(perspective_view(
            ShadowViewKind::CubeFace(face),
            origin,
            fwd,
            right,
            up,
            fit,
            true,
        ));
    }
    out
}

#[derive(Debug, Clone, Copy)]
struct Fit {
    extent: [f32; 4],
    near: f32,
    far: f32,
}

/// Bounds of the points' tangents and depths in a frame; `None` if any point is behind the image
/// plane or outside `±limit`.
fn fit_points(
    pts: impl Iterator<Item = V3>,
    fwd: V3,
    right: V3,
    up: V3,
    limit: f32,
) -> Option<Fit> {
    let mut e = [
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::INFINITY,
        f32::NEG_INFINITY,
    ];
    let (mut near, mut far) = (f32::INFINITY, 0.0f32);
    let mut any = false;
    for p in pts {
        let z = dot(p, fwd);
        let len = length(p);
        if len <= 1e-6 {
            continue; // the sample itself: every direction is already bounded by the others
        }
        if z <= 1e-6 * len {
            return None;
        }
        let (x, y) = (dot(p, right) / z, dot(p, up) / z);
        if x.abs() > limit || y.abs() > limit {
            return None;
        }
        e = [e[0].min(x), e[1].max(x), e[2].min(y), e[3].max(y)];
        near = near.min(z);
        far = far.max(z);
        any = true;
    }
    if !any {
        return None;
    }
    Some(Fit {
        extent: e,
        near,
        far,
    })
}

fn perspective_view(
    kind: ShadowViewKind,
    origin: V3,
    fwd: V3,
    right: V3,
    up: V3,
    fit: Fit,
    clamp_unit: bool,
) -> ShadowView {
    let mut e = widen(fit.extent);
    if clamp_unit {
        // Cube faces stay near their 90° pyramid (plus the margin) so neighbours overlap a little.
        let m = 1.0 + EXTENT_MARGIN * 2.0;
        e = [e[0].max(-m), e[1].min(m), e[2].max(-m), e[3].min(m)];
    }
    let far = fit.far * 1.02 + 1e-4;
    let near = (fit.near * 0.98).max(far * 1e-5);
    let (l, r, b, t) = (e[0], e[1], e[2], e[3]);
    let a = near / (far - near);
    let proj = [
        [2.0 / (r - l), 0.0, 0.0, 0.0],
        [0.0, 2.0 / (t - b), 0.0, 0.0],
        [(r + l) / (r - l), (t + b) / (t - b), a, -1.0],
        [0.0, 0.0, a * far, 0.0],
    ];
    ShadowView {
        kind,
        view: look_view(origin, fwd, right, up),
        proj,
        near,
        far,
        extent: e,
        half_space: None,
        eye_depth: None,
    }
}

fn ortho_view(dir: V3, boxes: &[(V3, V3)]) -> Option<ShadowView> {
    let fwd = if dir == [0.0; 3] {
        [0.0, -1.0, 0.0]
    } else {
        dir
    };
    let (right, up) = perpendicular_frame(fwd);
    let mut e = [
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::INFINITY,
        f32::NEG_INFINITY,
    ];
    let (mut zmin, mut zmax) = (f32::INFINITY, f32::NEG_INFINITY);
    for &(lo, hi) in boxes {
        for p in box_corners(lo, hi) {
            let (x, y, z) = (dot(p, right), dot(p, up), dot(p, fwd));
            e = [e[0].min(x), e[1].max(x), e[2].min(y), e[3].max(y)];
            zmin = zmin.min(z);
            zmax = zmax.max(z);
        }
    }
    let [l, r, b, t] = widen(e);
    let depth = (zmax - zmin).max(1e-3);
    // The eye sits before the nearest receiver (on the axis through the world origin, so view
    // x/y equal the world projections above); casters further up-light are depth-clamped. The
    // room left up-light of the receivers holds their bias (metres along the ray: the depth bias
    // and up to ten texels of slope): a flat receiver facing the light has no depth range of its
    // own, and a biased depth past the near plane would pass every clamped caster.
    let lateral = (r - l).max(t - b);
    let start = zmin - 0.02 * depth - 0.25 * lateral - 1e-3;
    let origin = scale(fwd, start);
    let near = 1e-3f32;
    let far = zmax - start + 0.02 * depth;
    // Reversed-Z orthographic: depth = (far − z)/(far − near).
    let k = 1.0 / (far - near);
    let proj = [
        [2.0 / (r - l), 0.0, 0.0, 0.0],
        [0.0, 2.0 / (t - b), 0.0, 0.0],
        [0.0, 0.0, k, 0.0],
        [-(r + l) / (r - l), -(t + b) / (t - b), far * k, 1.0],
    ];
    Some(ShadowView {
        kind: ShadowViewKind::Ortho,
        view: look_view(origin, fwd, right, up),
        proj,
        near,
        far,
        extent: [l, r, b, t],
        half_space: None,
        eye_depth: None,
    })
}

/// Widens image-plane bounds by [`EXTENT_MARGIN`] and to a minimum size.
fn widen(e: [f32; 4]) -> [f32; 4] {
    let grow = |lo: f32, hi: f32| {
        let c = 0.5 * (lo + hi);
        let half = (0.5 * (hi - lo) * (1.0 + 2.0 * EXTENT_MARGIN)).max(1e-3);
        (c - half, c + half)
    };
    let (l, r) = grow(e[0], e[1]);
    let (b, t) = grow(e[2], e[3]);
    [l, r, b, t]
}

/// Where `p` lands in `view`: texture coordinates (row 0 at the top) and reversed-Z depth, or
/// `None` behind the view. The shader does the same sum.
pub fn project(view: &ShadowView, p: V3) -> Option<([f32; 2], f32)> {
    let m = |m: &[[f32; 4]; 4], v: [f32; 4]| -> [f32; 4] {
        std::array::from_fn(|r| (0..4).map(|c| m[c][r] * v[c]).sum())
    };
    let clip = m(&view.proj, m(&view.view, [p[0], p[1], p[2], 1.0]));
    if clip[3] <= 0.0 {
        return None;
    }
    let (x, y, z) = (clip[0] / clip[3], clip[1] / clip[3], clip[2] / clip[3]);
    Some(([(x + 1.0) * 0.5, (1.0 - y) * 0.5], z))
}
