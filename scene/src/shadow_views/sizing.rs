//! Shadow-map sizes per light from the eye/light resolution mismatch factor of Govindaraju et al.
//! (seed 002): `m = (d_s·r_s/cos α)/(d_i·r_i/cos β)` — a shadow texel's footprint on a receiver
//! over an image pixel's there. A light's maps get the power of two that gives `m = target` at the
//! median lit visible point, found by a coarse grid of eye rays against the receivers' boxes —
//! or larger, where a caster the maps hold is so thin that it would fall between texels.
//! Pure maths, shared by the renderer (`lightfold render`, the node) and the planner, so both size
//! every light's maps alike.

use super::ShadowView;
use crate::model::{Camera, LightSample, SampleKind};
use crate::shading::{V3, dot, length, sub};
use lightfold_protocol::stats;

/// Grazing angles are capped so one nearly edge-on surface does not ask for a huge map.
const MIN_COS_ALPHA: f32 = 0.2;
/// The coarse grid of eye rays that finds representative visible points.
const PROBE_GRID: (u32, u32) = (16, 12);

pub use crate::model::Mismatch;

/// A visible point found by a probe ray: position, box-face normal, eye distance, `cos β`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Probe {
    pub point: V3,
    pub normal: V3,
    pub eye_dist: f32,
    pub cos_beta: f32,
}

/// Entry distance and face normal of the ray `o + t·d` into the box, `None` on a miss.
fn ray_box(lo: V3, hi: V3, o: V3, d: V3) -> Option<(f32, V3)> {
    let (mut t0, mut t1, mut axis) = (0.0f32, f32::INFINITY, None);
    for k in 0..3 {
        if d[k].abs() < 1e-12 {
            if o[k] < lo[k] || o[k] > hi[k] {
                return None;
            }
            continue;
        }
        let a = (lo[k] - o[k]) / d[k];
        let b = (hi[k] - o[k]) / d[k];
        let near = a.min(b);
        if near > t0 {
            t0 = near;
            axis = Some(k);
        }
        t1 = t1.min(a.max(b));
    }
    if t0 > t1 {
        return None;
    }
    let mut n = [0.0; 3];
    if let Some(k) = axis {
        n[k] = -d[k].signum();
    }
    Some((t0, n))
}

/// Probes the view with a coarse ray grid against the receivers' boxes (nearest box wins).
pub fn probes(cam: &Camera, receivers: &[(V3, V3)]) -> Vec<Probe> {
    let mut out = Vec::new();
    for j in 0..PROBE_GRID.1 {
        for i in 0..PROBE_GRID.0 {
            let x = (i as f32 + 0.5) / PROBE_GRID.0 as f32 * cam.width as f32;
            let y = (j as f32 + 0.5) / PROBE_GRID.1 as f32 * cam.height as f32;
            let d = cam.ray_dir(x, y);
            let hit = receivers
                .iter()
                .filter_map(|&(lo, hi)| ray_box(lo, hi, cam.position, d))
                .filter(|(t, _)| *t > 0.0 && t.is_finite())
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

/// Whether the sample sends any light to `p` (its lobe, cone and range).
fn lights_point(s: &LightSample, p: V3) -> bool {
    if s.kind == SampleKind::Directional {
        return s.intensity != 0.0;
    }
    let (l, r) = crate::shading::to_light(s, p);
    let to_point = [-l[0], -l[1], -l[2]];
    crate::shading::sample_intensity(s, to_point) != 0.0
        && crate::shading::range_window(r, s.range) > 0.0
}

/// World → view-space point (views look down −Z).
fn to_view(m: &[[f32; 4]; 4], p: V3) -> V3 {
    std::array::from_fn(|r| m[0][r] * p[0] + m[1][r] * p[1] + m[2][r] * p[2] + m[3][r])
}

/// Texels a caster's width must span in a map for its shadow to survive the lookup: a caster
/// narrower than a texel falls between texel centres and casts nothing (issue 22's thin poles).
pub const CASTER_TEXELS: f32 = 16.0;

/// A caster's width: the middle of its box's three extents (a pole's thickness, a leaf's or a
/// wall's smaller side; a flat plane is as wide as its smaller side, not zero).
fn caster_width(lo: V3, hi: V3) -> f32 {
    let mut e = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
    e.sort_by(f32::total_cmp);
    e[1]
}

/// Where a texel of the map holding `p` has a width of `span·depth / N` metres (`span / N` for
/// orthographic views) on an `N`² map: that `span·depth` (or `span`), from the first view that
/// holds `p` — a cascade only at the eye depths it serves.
fn held_span(views: &[ShadowView], p: V3, eye_depth: f32) -> Option<f32> {
    views.iter().find_map(|v| {
        if v.eye_depth
            .is_some_and(|[a, b]| !(a..b).contains(&eye_depth))
        {
            return None;
        }
        let q = to_view(&v.view, p);
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
    })
}

/// The side at which every caster in `casters` whose centre a view holds spans
/// [`CASTER_TEXELS`] texels of its width; 0 when none is held.
fn caster_need(views: &[ShadowView], casters: &[(V3, V3)], cam: &Camera, d_i: f32) -> f32 {
    let forward = cam.frame().forward;
    let mut need = 0f32;
    for &(lo, hi) in casters {
        let w = caster_width(lo, hi);
        if !(w.is_finite() && w > 0.0) {
            continue;
        }
        let centre: V3 = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
        let eye_depth = dot(sub(centre, cam.position), forward);
        if let Some(world) = held_span(views, centre, eye_depth) {
            // No more texels across it than the image has pixels: a caster the camera sees a
            // few pixels wide needs no finer map than that.
            let pixels = w / (d_i * length(sub(centre, cam.position)).max(1e-6));
            let n = CASTER_TEXELS.min(2.0 * pixels) * world / w;
            if n.is_finite() {
                need = need.max(n);
            }
        }
    }
    need
}

/// The map side of `s`, whose maps are `views`: the power of two in `[rule.min, rule.max]`
/// nearest (in log₂) to the larger of the side giving `m = rule.target` at the median lit probe a
/// view holds, and the side at which every caster box in `casters` that a view holds spans
/// [`CASTER_TEXELS`] texels of its width; `fallback` (clamped to the bounds) when no probe is
/// lit.
pub fn mismatch_size(
    s: &LightSample,
    views: &[ShadowView],
    probes: &[Probe],
    casters: &[(V3, V3)],
    cam: &Camera,
    rule: Mismatch,
    fallback: u32,
) -> u32 {
    let max_side = crate::limits::MAX_SHADOW_MAP_SIZE;
    let lo = rule
        .min
        .clamp(1, max_side)
        .next_power_of_two()
        .min(max_side);
    let hi = prev_power_of_two(rule.max.clamp(1, max_side)).max(lo);
    let target = if rule.target.is_finite() && rule.target > 0.0 {
        rule.target
    } else {
        1.0
    };
    // Angular size of an image pixel at the centre of the view (d_i per unit distance).
    let d_i = 2.0 * (cam.fov_y_deg.to_radians() * 0.5).tan() / cam.height.max(1) as f32;
    let forward = cam.frame().forward;
    let mut need: Vec<f32> = Vec::new();
    for p in probes {
        if !lights_point(s, p.point) {
            continue;
        }
        let (l, _) = crate::shading::to_light(s, p.point);
        let cos_alpha = dot(p.normal, l).abs().max(MIN_COS_ALPHA);
        // The view holding the point; a texel there spans `span·depth / N` metres (`span / N`
        // for orthographic views).
        let eye_depth = dot(sub(p.point, cam.position), forward);
        let held = held_span(views, p.point, eye_depth);
        let Some(world) = held else { continue };
        let n = world * p.cos_beta / (d_i * p.eye_dist * cos_alpha * target);
        if n.is_finite() && n > 0.0 {
            need.push(n);
        }
    }
    let Some(median) = stats::median(&need) else {
        return fallback.clamp(lo, hi);
    };
    let median = median.max(caster_need(views, casters, cam, d_i));
    let size = 2u32.pow(median.max(1.0).log2().round().clamp(0.0, 14.0) as u32);
    size.clamp(lo, hi)
}

fn prev_power_of_two(n: u32) -> u32 {
    if n.is_power_of_two() {
        n
    } else {
        n.next_power_of_two() / 2
    }
}
