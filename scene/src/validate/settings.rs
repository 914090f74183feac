//! Sanitising lights, the camera and quality options.

use super::{Issue, finite3};
use crate::defaults;
use crate::limits::MAX_SUN_ANGLE;
use crate::model::{Camera, Light, LightShape, Scene};
use crate::shading::{V3, add, dot, length, normalize, scale, sub};

/// Returns false when the light must be dropped.
pub(super) fn sanitize_light(
    l: &mut Light,
    mesh_index: &[Option<usize>],
    issues: &mut Vec<Issue>,
) -> bool {
    let mut drop = |problem: &'static str| {
        issues.push(Issue::BadLight {
            light: l.name.clone(),
            problem,
        });
        false
    };
    if !(l.power.is_finite() && l.power >= 0.0) {
        return drop("power is not finite and non-negative");
    }
    if !l.color.iter().all(|c| c.is_finite() && *c >= 0.0) {
        return drop("colour is not finite and non-negative");
    }
    let unit = |v: &V3| finite3(v) && length(*v) > 1e-6;
    let positive = |x: f32| x.is_finite() && x > 0.0;
    let mut fixes: Vec<&'static str> = Vec::new();
    match &mut l.shape {
        LightShape::Point { position } => {
            if !finite3(position) {
                return drop("position is not finite");
            }
        }
        LightShape::Spot {
            position,
            direction,
            inner_angle,
            outer_angle,
        } => {
            if !finite3(position) || !unit(direction) {
                return drop("position or direction is unusable");
            }
            let half_pi = std::f32::consts::FRAC_PI_2;
            let o = if outer_angle.is_finite() {
                outer_angle.clamp(0.0, half_pi)
            } else {
                half_pi
            };
            let i = if inner_angle.is_finite() {
                inner_angle.clamp(0.0, o)
            } else {
                0.0
            };
            if (o, i) != (*outer_angle, *inner_angle) {
                fixes.push("cone angles clamped to 0 ≤ inner ≤ outer ≤ π/2");
                (*outer_angle, *inner_angle) = (o, i);
            }
        }
        LightShape::Directional { direction, angle } => {
            if !unit(direction) {
                return drop("direction is unusable");
            }
            let a = if angle.is_finite() {
                angle.clamp(0.0, MAX_SUN_ANGLE)
            } else {
                0.0
            };
            if a != *angle {
                fixes.push("angle clamped to 0 ≤ angle ≤ 90°");
                *angle = a;
            }
        }
        LightShape::Rect {
            center,
            normal,
            u_axis,
            size,
        } => {
            if !finite3(center) || !unit(normal) || !positive(size[0]) || !positive(size[1]) {
                return drop("rectangle centre, normal or size is unusable");
            }
            let n = normalize(*normal);
            let u = normalize(sub(*u_axis, scale(n, dot(*u_axis, n))));
            let u = if u == [0.0; 3] {
                crate::sampling_shapes::basis(n).0
            } else {
                u
            };
            if !finite3(u_axis) || dot(normalize(*u_axis), n).abs() > 1e-3 {
                fixes.push("u axis made perpendicular to the normal");
                *u_axis = u;
            }
        }
        LightShape::Disk {
            center,
            normal,
            radius,
        } => {
            if !finite3(center) || !unit(normal) || !positive(*radius) {
                return drop("disk centre, normal or radius is unusable");
            }
        }
        LightShape::Sphere { center, radius } => {
            if !finite3(center) || !positive(*radius) {
                return drop("sphere centre or radius is unusable");
            }
        }
        LightShape::Cylinder {
            center,
            axis,
            length,
            radius,
        } => {
            if !finite3(center) || !unit(axis) || !positive(*length) || !positive(*radius) {
                return drop("cylinder centre, axis, length or radius is unusable");
            }
        }
        LightShape::EmissiveMesh { mesh } => match mesh_index.get(*mesh).copied().flatten() {
            Some(k) => *mesh = k,
            None => return drop("emissive mesh is missing or empty"),
        },
    }
    if l.range.is_some_and(|r| !positive(r)) {
        fixes.push("range must be positive (removed)");
        l.range = None;
    }
    if l.is_area() && l.samples == 0 {
        fixes.push("zero samples (set to 1)");
        l.samples = 1;
    }
    for problem in fixes {
        issues.push(Issue::BadLight {
            light: l.name.clone(),
            problem,
        });
    }
    true
}

pub(super) fn sanitize_camera(c: &mut Camera, issues: &mut Vec<Issue>) {
    let bad = |problem, issues: &mut Vec<Issue>| issues.push(Issue::BadCamera { problem });
    if !(finite3(&c.position) && finite3(&c.target) && finite3(&c.up)) {
        bad("non-finite position, target or up", issues);
        let d = Scene::new("").camera;
        (c.position, c.target, c.up) = (d.position, d.target, d.up);
    }
    if length(sub(c.target, c.position)) < 1e-9 {
        bad("target equals position", issues);
        c.target = add(c.position, [0.0, 0.0, -1.0]);
    }
    if length(c.up) < 1e-9 {
        bad("zero up vector", issues);
        c.up = [0.0, 1.0, 0.0];
    }
    if !(c.fov_y_deg.is_finite() && c.fov_y_deg > 0.0 && c.fov_y_deg < 180.0) {
        bad("vertical field of view outside (0°, 180°)", issues);
        c.fov_y_deg = 45.0;
    }
    if c.width == 0 || c.height == 0 {
        bad("zero image size", issues);
        (c.width, c.height) = (defaults::WIDTH, defaults::HEIGHT);
    }
}

pub(super) fn sanitize_quality(s: &mut Scene, issues: &mut Vec<Issue>) {
    let d = defaults::quality();
    let q = &mut s.quality;
    let mut bad = |problem| issues.push(Issue::BadQuality { problem });
    if q.samples_per_area_light == Some(0) {
        bad("zero samples per area light (set to 1)");
        q.samples_per_area_light = Some(1);
    }
    if q.shadow_map_size == 0 {
        bad("zero shadow-map size (default used)");
        q.shadow_map_size = d.shadow_map_size;
    }
    if let crate::model::MapSizing::Mismatch(m) = q.map_sizing {
        let bounds = crate::limits::MAX_SHADOW_MAP_SIZE;
        if !(m.target.is_finite() && m.target > 0.0)
            || m.min == 0
            || m.min > m.max
            || m.max > bounds
        {
            bad(
                "shadow-map sizing needs a finite target > 0 and 1 ≤ min ≤ max ≤ 4096 (default used)",
            );
            q.map_sizing = d.map_sizing;
        }
    }
    if q.lights_per_node == 0 {
        bad("zero lights per node (default used)");
        q.lights_per_node = d.lights_per_node;
    }
    if !(q.depth_bias.is_finite() && q.slope_bias.is_finite()) {
        bad("non-finite depth bias (defaults used)");
        (q.depth_bias, q.slope_bias) = (d.depth_bias, d.slope_bias);
    }
    if q.indirect_clamp
        .is_some_and(|c| !(c.is_finite() && c >= 0.0))
    {
        bad("indirect clamp is not a finite distance ≥ 0 (default used)");
        q.indirect_clamp = d.indirect_clamp;
    }
}
