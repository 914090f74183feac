//! Per active sample: the casters its shadow map needs, the views that cover its lit receivers,
//! and the map size from the eye/light resolution mismatch factor of Govindaraju et al. (seed 002):
//! `m = (d_s·r_s/cos α)/(d_i·r_i/cos β)`, chosen so that `m ≤ 1` on the median lit visible point.

use super::cull::Receiver;
use super::geom::{Aabb, lights_point, reach};
use super::types::{DEFAULT_MAP_SIZE, MapSizing, ShadowPlan, ShadowViews};
use lightfold_scene::shading::{V3, dot, normalize, sub};
use lightfold_scene::{Camera, LightSample, SampleKind};

/// Above this half-angle one frustum wastes too much resolution at its edges: use cube faces.
const MAX_FRUSTUM_HALF_ANGLE_DEG: f32 = 60.0;
/// Grazing angles are capped so one nearly edge-on surface does not ask for a huge map.
const MIN_COS_ALPHA: f32 = 0.2;
/// The coarse grid of eye rays that finds representative visible points.
const PROBE_GRID: (u32, u32) = (16, 12);

/// A visible point found by a probe ray: position, box-face normal, eye distance, `cos β`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Probe {
    pub point: V3,
    pub normal: V3,
    pub eye_dist: f32,
    pub cos_beta: f32,
}

/// Probe the view with a coarse ray grid against the receivers' boxes (nearest box wins).
pub(crate) fn probes(cam: &Camera, receivers: &[Receiver]) -> Vec<Probe> {
    let mut out = Vec::new();
    for j in 0..PROBE_GRID.1 {
        for i in 0..PROBE_GRID.0 {
            let x = (i as f32 + 0.5) / PROBE_GRID.0 as f32 * cam.width as f32;
            let y = (j as f32 + 0.5) / PROBE_GRID.1 as f32 * cam.height as f32;
            let d = cam.ray_dir(x, y);
            let hit = receivers
                .iter()
                .filter_map(|r| r.bounds.ray_hit(cam.position, d))
                .filter(|(t, _)| *t > 0.0)
                .min_by(|a, b| a.0.total_cmp(&b.0));
            if let Some((t, n)) = hit {
                out.push(Probe {
                    point: std::array::from_fn(|k| cam.position[k] + t * d[k]),
                    normal: n,
                    eye_dist: t,
                    cos_beta: dot(n, d).abs().max(MIN_COS_ALPHA),
                });
            }
        }
    }
    out
}

/// Meshes that can shadow a receiver this sample lights: inside its reach and overlapping the
/// region between the light and one of its lit receivers.
pub(crate) fn casters(s: &LightSample, lit: &[&Receiver], bounds: &[Option<Aabb>]) -> Vec<u32> {
    let directional = matches!(s.kind, SampleKind::Directional);
    let toward_light: V3 = std::array::from_fn(|k| -s.direction[k]);
    let between: Vec<Aabb> = lit
        .iter()
        .map(|r| r.bounds.union_point(s.position))
        .collect();
    bounds
        .iter()
        .enumerate()
        .filter_map(|(m, b)| {
            let b = (*b)?;
            if reach(s, &b).is_err() {
                return None;
            }
            let shadows = if directional {
                lit.iter().any(|r| r.bounds.sweep_hits(toward_light, &b))
            } else {
                between.iter().any(|h| h.intersects(&b))
            };
            shadows.then_some(m as u32)
        })
        .collect()
}

/// The shadow geometry covering the lit receivers.
pub(crate) fn views(
    s: &LightSample,
    lit: &[&Receiver],
    casters: &[u32],
    force_all: bool,
) -> ShadowViews {
    if matches!(s.kind, SampleKind::Directional) {
        return if casters.is_empty() && !force_all {
            ShadowViews::None
        } else {
            ShadowViews::Ortho
        };
    }
    if force_all {
        return ShadowViews::Cube { faces: 0b11_1111 };
    }
    if casters.is_empty() {
        return ShadowViews::None;
    }
    let p = s.position;
    let mut dirs = Vec::new();
    let mut surrounded = false;
    for r in lit {
        if r.bounds.distance(p) <= 1e-6 {
            surrounded = true;
            break;
        }
        dirs.extend(r.bounds.corners().iter().map(|&c| normalize(sub(c, p))));
    }
    if !surrounded && !dirs.is_empty() {
        let sum = dirs
            .iter()
            .fold([0.0; 3], |a: V3, d| std::array::from_fn(|k| a[k] + d[k]));
        let axis = normalize(sum);
        if axis != [0.0; 3] {
            let min_cos = dirs.iter().map(|&d| dot(axis, d)).fold(1.0f32, f32::min);
            let half = min_cos.clamp(-1.0, 1.0).acos().to_degrees();
            if half <= MAX_FRUSTUM_HALF_ANGLE_DEG {
                // A little margin so the PCF footprint at the edge stays inside the map.
                return ShadowViews::Frustum {
                    axis,
                    half_angle_deg: half * 1.02 + 0.1,
                };
            }
        }
    }
    ShadowViews::Cube {
        faces: cube_faces(s, lit),
    }
}

/// Cube faces whose pyramid may hold a lit receiver (and, for lobes, lies partly in front).
fn cube_faces(s: &LightSample, lit: &[&Receiver]) -> u8 {
    let mut mask = 0u8;
    for face in 0..6 {
        let (a, sign) = (face / 2, if face % 2 == 0 { 1.0f32 } else { -1.0 });
        let (b, c) = ((a + 1) % 3, (a + 2) % 3);
        if matches!(s.kind, SampleKind::CosineLobe) {
            // The face pyramid is spanned by its four edge rays: behind the lobe if all are.
            let behind = [(1.0f32, 1.0f32), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)]
                .iter()
                .all(|&(u, v)| {
                    let mut e = [0.0; 3];
                    e[a] = sign;
                    e[b] = u;
                    e[c] = v;
                    dot(s.direction, e) <= 0.0
                });
            if behind {
                continue;
            }
        }
        let holds = lit.iter().any(|r| {
            let q: Vec<V3> = r
                .bounds
                .corners()
                .iter()
                .map(|&p| sub(p, s.position))
                .collect();
            // Outside the pyramid `sign·x_a ≥ |x_b|, |x_c|` when all corners fail one plane.
            let planes = [(b, 1.0f32), (b, -1.0), (c, 1.0), (c, -1.0)];
            !planes
                .iter()
                .any(|&(k, t)| q.iter().all(|v| sign * v[a] - t * v[k] < 0.0))
        });
        if holds {
            mask |= 1 << face;
        }
    }
    mask
}

/// Map size: the smallest power of two with mismatch `m ≤ 1` at the median lit probe point.
pub(crate) fn map_size(
    s: &LightSample,
    views: &ShadowViews,
    lit: &[&Receiver],
    probes: &[Probe],
    cam: &Camera,
    sizing: MapSizing,
) -> u32 {
    let (lo, hi) = match sizing {
        MapSizing::Fixed(n) => return n.clamp(1, super::types::MAX_MAP_SIZE),
        MapSizing::Mismatch { min, max } => (min.min(max), max.max(min)),
    };
    // Angular size of an image pixel at the centre of the view (d_i per unit distance).
    let d_i = 2.0 * (cam.fov_y_deg.to_radians() * 0.5).tan() / cam.height.max(1) as f32;
    let mut need: Vec<f32> = Vec::new();
    for p in probes {
        if !lights_point(s, p.point) {
            continue;
        }
        let (l, r_s) = lightfold_scene::shading::to_light(s, p.point);
        let cos_alpha = dot(p.normal, l).abs().max(MIN_COS_ALPHA);
        // World size of a shadow texel at the point, per texel of an N-texel map: span / N.
        let span = match views {
            ShadowViews::None => return DEFAULT_MAP_SIZE.clamp(lo, hi),
            ShadowViews::Frustum { half_angle_deg, .. } => {
                2.0 * half_angle_deg.to_radians().tan() * r_s
            }
            ShadowViews::Cube { .. } => 2.0 * r_s,
            ShadowViews::Ortho => {
                let b = lit.iter().fold(None::<Aabb>, |a, r| {
                    Some(a.map_or(r.bounds, |a| a.union(&r.bounds)))
                });
                b.map_or(0.0, |b| 2.0 * b.radius())
            }
        };
        let n = span * p.cos_beta / (d_i * p.eye_dist * cos_alpha);
        if n.is_finite() && n > 0.0 {
            need.push(n);
        }
    }
    if need.is_empty() {
        return DEFAULT_MAP_SIZE.clamp(lo, hi);
    }
    need.sort_by(f32::total_cmp);
    let median = need[need.len() / 2];
    let size = (median.ceil() as u32).clamp(1, 1 << 16).next_power_of_two();
    size.clamp(lo, hi).next_power_of_two()
}

/// The whole shadow plan of one active sample.
pub(crate) fn shadow_plan(
    s: &LightSample,
    lit: &[&Receiver],
    bounds: &[Option<Aabb>],
    probes: &[Probe],
    cam: &Camera,
    sizing: MapSizing,
    force_all: bool,
) -> ShadowPlan {
    let casters = if force_all {
        (0..bounds.len() as u32).collect()
    } else {
        casters(s, lit, bounds)
    };
    let views = views(s, lit, &casters, force_all);
    let map_size = map_size(s, &views, lit, probes, cam, sizing);
    ShadowPlan {
        views,
        map_size,
        casters,
    }
}
