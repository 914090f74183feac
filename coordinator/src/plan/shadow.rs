//! Per active sample: the casters its shadow map needs (meshes in its reach that overlap the region
//! between it and a visible receiver it lights), the views `scene::shadow_views` fits (as the node
//! does), and the map size from the eye/light resolution mismatch factor of Govindaraju et al.
//! (seed 002): `m = (d_s·r_s/cos α)/(d_i·r_i/cos β)`, near the target `m` at the median lit visible
//! point found by a coarse grid of eye rays.

use super::cull::Receiver;
use super::geom::{Aabb, lights_point, reach};
use super::types::{DEFAULT_MAP_SIZE, MAX_MAP_SIZE, MapSizing, ShadowPlan, ShadowViews};
use lightfold_scene::shading::{V3, dot};
use lightfold_scene::shadow_views::{ShadowView, ShadowViewKind, fitted_views};
use lightfold_scene::{Camera, LightSample, SampleKind};

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

/// Summary of the views `scene::shadow_views` fits for this sample — the same call, with the same
/// receivers (every mesh with triangles), that the node makes, so the pass count is the node's.
pub(crate) fn summarize(views: &[ShadowView]) -> ShadowViews {
    let Some(first) = views.first() else {
        return ShadowViews::None;
    };
    let cascades = views.iter().take_while(|v| v.eye_depth.is_some()).count();
    if cascades > 0 {
        let byte = |n: usize| n.min(u8::MAX as usize) as u8;
        return ShadowViews::Cascaded {
            cascades: byte(cascades),
            base: byte(views.len() - cascades),
        };
    }
    match first.kind {
        ShadowViewKind::Ortho => ShadowViews::Ortho,
        ShadowViewKind::Fitted => {
            let fov = |lo: f32, hi: f32| (hi.atan() - lo.atan()).to_degrees();
            let fitted = views.iter().filter(|v| v.kind == ShadowViewKind::Fitted);
            ShadowViews::Frustum {
                count: fitted.clone().count().min(u8::MAX as usize) as u8,
                fov_deg: fitted
                    .map(|v| {
                        let e = v.extent;
                        fov(e[0], e[1]).max(fov(e[2], e[3]))
                    })
                    .fold(0.0, f32::max),
            }
        }
        ShadowViewKind::CubeFace(_) => {
            let mut faces = 0u8;
            for v in views {
                if let ShadowViewKind::CubeFace(f) = v.kind {
                    faces |= 1 << (f as u8);
                }
            }
            ShadowViews::Cube { faces }
        }
    }
}

/// World → view-space point (views look down −Z).
fn to_view(m: &[[f32; 4]; 4], p: V3) -> V3 {
    std::array::from_fn(|r| m[0][r] * p[0] + m[1][r] * p[1] + m[2][r] * p[2] + m[3][r])
}

/// Map size: the power of two nearest the size with mismatch `m = target` at the median lit
/// probe point.
pub(crate) fn map_size(
    s: &LightSample,
    views: &[ShadowView],
    probes: &[Probe],
    cam: &Camera,
    sizing: MapSizing,
) -> u32 {
    let (lo, hi, target) = match sizing {
        MapSizing::Fixed(n) => return n.clamp(1, super::types::MAX_MAP_SIZE),
        // `plan()` resolves `Scene` into the scene's size before sizing maps.
        MapSizing::Scene => return DEFAULT_MAP_SIZE,
        MapSizing::Mismatch { min, max, target } => (
            min.clamp(1, MAX_MAP_SIZE).next_power_of_two(),
            prev_power_of_two(max.clamp(1, MAX_MAP_SIZE)),
            if target.is_finite() && target > 0.0 {
                target
            } else {
                1.0
            },
        ),
    };
    let hi = hi.max(lo);
    // Angular size of an image pixel at the centre of the view (d_i per unit distance).
    let d_i = 2.0 * (cam.fov_y_deg.to_radians() * 0.5).tan() / cam.height.max(1) as f32;
    let forward = cam.frame().forward;
    let mut need: Vec<f32> = Vec::new();
    for p in probes {
        if !lights_point(s, p.point) {
            continue;
        }
        let (l, _) = lightfold_scene::shading::to_light(s, p.point);
        let cos_alpha = dot(p.normal, l).abs().max(MIN_COS_ALPHA);
        // The view holding the point; a texel there spans `span·depth / N` metres (`span / N`
        // for orthographic views).
        let eye_depth = dot(
            lightfold_scene::shading::sub(p.point, cam.position),
            forward,
        );
        let held = views.iter().find_map(|v| {
            // A cascade holds only the eye depths it serves.
            if v.eye_depth
                .is_some_and(|[a, b]| !(a..b).contains(&eye_depth))
            {
                return None;
            }
            let q = to_view(&v.view, p.point);
            let e = v.extent;
            let span = (e[1] - e[0]).max(e[3] - e[2]);
            if v.is_ortho() {
                let inside = (e[0]..=e[1]).contains(&q[0]) && (e[2]..=e[3]).contains(&q[1]);
                return inside.then_some(span);
            }
            let z = -q[2];
            if z <= 0.0 {
                return None;
            }
            let (x, y) = (q[0] / z, q[1] / z);
            let inside = (e[0]..=e[1]).contains(&x) && (e[2]..=e[3]).contains(&y);
            inside.then_some(span * z)
        });
        let Some(world) = held else { continue };
        let n = world * p.cos_beta / (d_i * p.eye_dist * cos_alpha * target);
        if n.is_finite() && n > 0.0 {
            need.push(n);
        }
    }
    if need.is_empty() {
        return DEFAULT_MAP_SIZE.clamp(lo, hi);
    }
    need.sort_by(f32::total_cmp);
    let median = need[need.len() / 2];
    let size = 2u32.pow(median.max(1.0).log2().round().clamp(0.0, 12.0) as u32);
    size.clamp(lo, hi)
}

fn prev_power_of_two(n: u32) -> u32 {
    if n.is_power_of_two() {
        n
    } else {
        n.next_power_of_two() / 2
    }
}

/// The whole shadow plan of one active sample. `scene_receivers` are the boxes the node fits
/// views to (every mesh with triangles), to what `fit_camera` sees of them when there is one.
#[allow(clippy::too_many_arguments)]
pub(crate) fn shadow_plan(
    s: &LightSample,
    lit: &[&Receiver],
    bounds: &[Option<Aabb>],
    scene_receivers: &[(V3, V3)],
    fit_camera: Option<&Camera>,
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
    let views = fitted_views(s, scene_receivers, fit_camera);
    let map_size = map_size(s, &views, probes, cam, sizing);
    ShadowPlan {
        views: summarize(&views),
        map_size,
        casters,
    }
}
