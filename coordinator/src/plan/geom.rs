//! Conservative geometry for planning: mesh bounds, the view frustum, which meshes are visible
//! receivers, and whether a light sample's emission can reach a box. Every test here may say
//! "reaches" when it does not, never the reverse: culling built on it cannot change the picture.

use lightfold_scene::shading::{V3, cross, dot, length, normalize, scale, sub};
use lightfold_scene::{Camera, LightSample, SampleKind, Scene};

/// An axis-aligned box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Aabb {
    pub lo: V3,
    pub hi: V3,
}

impl Aabb {
    pub(crate) fn corners(&self) -> [V3; 8] {
        let (l, h) = (self.lo, self.hi);
        std::array::from_fn(|i| {
            [
                if i & 1 == 0 { l[0] } else { h[0] },
                if i & 2 == 0 { l[1] } else { h[1] },
                if i & 4 == 0 { l[2] } else { h[2] },
            ]
        })
    }

    pub(crate) fn center(&self) -> V3 {
        std::array::from_fn(|k| 0.5 * (self.lo[k] + self.hi[k]))
    }

    /// Radius of the bounding sphere about `center`.
    pub(crate) fn radius(&self) -> f32 {
        0.5 * length(sub(self.hi, self.lo))
    }

    /// Distance from `p` to the nearest point of the box (0 inside).
    pub(crate) fn distance(&self, p: V3) -> f32 {
        let d: V3 = std::array::from_fn(|k| (self.lo[k] - p[k]).max(p[k] - self.hi[k]).max(0.0));
        length(d)
    }

    pub(crate) fn union_point(&self, p: V3) -> Aabb {
        Aabb {
            lo: std::array::from_fn(|k| self.lo[k].min(p[k])),
            hi: std::array::from_fn(|k| self.hi[k].max(p[k])),
        }
    }

    pub(crate) fn intersects(&self, o: &Aabb) -> bool {
        (0..3).all(|k| self.lo[k] <= o.hi[k] && o.lo[k] <= self.hi[k])
    }

    /// Whether moving this box along `d` by some `t ≥ 0` makes it overlap `o` (a box swept to
    /// infinity, for directional lights). Exact for boxes: the overlap in all three axes at once.
    pub(crate) fn sweep_hits(&self, d: V3, o: &Aabb) -> bool {
        let (mut t0, mut t1) = (0.0f32, f32::INFINITY);
        for (k, &dk) in d.iter().enumerate() {
            // Overlap on axis k: lo + t·d ≤ o.hi and o.lo ≤ hi + t·d.
            if dk.abs() < 1e-12 {
                if self.lo[k] > o.hi[k] || o.lo[k] > self.hi[k] {
                    return false;
                }
                continue;
            }
            let a = (o.lo[k] - self.hi[k]) / dk;
            let b = (o.hi[k] - self.lo[k]) / dk;
            t0 = t0.max(a.min(b));
            t1 = t1.min(a.max(b));
        }
        t0 <= t1
    }
}

/// Bounds of every mesh (`None` for meshes without finite positions).
pub(crate) fn mesh_bounds(scene: &Scene) -> Vec<Option<Aabb>> {
    // Over an animation: boxes that hold each mesh at every time (`Scene::swept_bounds`).
    scene
        .swept_bounds()
        .into_iter()
        .map(|b| b.map(|(lo, hi)| Aabb { lo, hi }))
        .collect()
}

/// The view frustum as inward half-spaces `n·p + d ≥ 0` through the eye (no far plane).
#[derive(Debug, Clone)]
pub(crate) struct Frustum {
    planes: Vec<(V3, f32)>,
}

impl Frustum {
    pub(super) fn new(cam: &Camera) -> Frustum {
        let f = cam.frame();
        let ty = (cam.fov_y_deg.to_radians() * 0.5).tan();
        let tx = ty * cam.aspect();
        let corner = |sx: f32, sy: f32| -> V3 {
            std::array::from_fn(|k| f.forward[k] + sx * tx * f.right[k] + sy * ty * f.up[k])
        };
        let mut planes = vec![(f.forward, -dot(f.forward, cam.position))];
        for (a, b) in [
            (corner(1.0, 1.0), corner(1.0, -1.0)),
            (corner(-1.0, -1.0), corner(-1.0, 1.0)),
            (corner(1.0, 1.0), corner(-1.0, 1.0)),
            (corner(-1.0, -1.0), corner(1.0, -1.0)),
        ] {
            let mut n = normalize(cross(a, b));
            if dot(n, f.forward) < 0.0 {
                n = scale(n, -1.0);
            }
            planes.push((n, -dot(n, cam.position)));
        }
        Frustum { planes }
    }

    /// False only when the box is entirely outside one plane (with a small margin).
    pub(super) fn may_contain(&self, b: &Aabb) -> bool {
        let margin = 1e-4 * (1.0 + b.radius());
        self.planes.iter().all(|&(n, d)| {
            let p: V3 = std::array::from_fn(|k| if n[k] >= 0.0 { b.hi[k] } else { b.lo[k] });
            dot(n, p) + d >= -margin
        })
    }
}

/// Why a sample cannot reach a box.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Miss {
    Range,
    Cone,
    Behind,
}

/// Whether the sample's emission can reach the box; on success, an upper bound of the sample's
/// irradiance on any surface in the box (`f32::INFINITY` when the light is inside or touching it).
pub(crate) fn reach(s: &LightSample, b: &Aabb) -> Result<f32, Miss> {
    if let SampleKind::Directional = s.kind {
        return Ok(s.intensity.abs());
    }
    let dmin = b.distance(s.position);
    let window = match s.range {
        Some(r) if r > 0.0 => {
            if dmin >= r {
                return Err(Miss::Range);
            }
            lightfold_scene::shading::range_window(dmin, s.range)
        }
        _ => 1.0,
    };
    // A non-unit axis changes what the shading's cosine means: bound it without cone tests.
    let len = length(s.direction);
    let unit = (len - 1.0).abs() <= 1e-3;
    let axis = normalize(s.direction);
    let to_c = sub(b.center(), s.position);
    let dc = length(to_c);
    let inside = dc <= b.radius() * (1.0 + 1e-5);
    // Largest cosine between the axis and any direction into the box (via its bounding sphere).
    let max_cos = if inside || !unit {
        1.0
    } else {
        let phi = (dot(axis, to_c) / dc).clamp(-1.0, 1.0).acos();
        let rho = (b.radius() / dc).clamp(0.0, 1.0).asin();
        (phi - rho).max(0.0).cos()
    };
    let peak = match s.kind {
        SampleKind::CosineLobe | SampleKind::Bounce { .. } => {
            if unit
                && b.corners()
                    .iter()
                    .all(|&p| dot(s.direction, sub(p, s.position)) <= 0.0)
            {
                return Err(Miss::Behind);
            }
            s.intensity.abs() * max_cos * len.max(1.0)
        }
        SampleKind::TwoSidedLobe => s.intensity.abs() * len.max(1.0),
        SampleKind::Spot { cos_outer, .. } => {
            let outer = cos_outer.clamp(-1.0, 1.0).acos();
            // Outside the cone's bounding sphere test, or (for cones narrower than a half-space)
            // entirely behind the plane through the apex.
            let behind_apex = cos_outer >= 0.0
                && b.corners()
                    .iter()
                    .all(|&p| dot(s.direction, sub(p, s.position)) <= 0.0);
            if unit
                && (behind_apex
                    || (!inside && max_cos < (outer + 1e-4).min(std::f32::consts::PI).cos()))
            {
                return Err(Miss::Cone);
            }
            s.intensity.abs()
        }
        _ => s.intensity.abs(),
    };
    let falloff = lightfold_scene::shading::falloff(s, dmin);
    if falloff <= 1e-12 {
        return Ok(f32::INFINITY);
    }
    Ok(peak * window / falloff)
}
