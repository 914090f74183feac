//! Views fitted to what a camera sees, split into cascades by eye depth (issue 22). One frustum
//! fitted to every visible receiver spreads its texels over all of them: a ground seen to
//! hundreds of metres gets metre-wide texels under the camera, where a small box's shadow is a
//! few decimetres. When the visible receivers span more than [`CASCADE_RATIO`] in eye depth,
//! the light gets up to [`MAX_CASCADES`] frusta instead, each fitted to the receivers within
//! one geometric slice of that range (the camera's pyramid cut by two planes across its forward
//! axis), so a texel near the camera covers about as much of the image as one far away.
//!
//! Only a light whose receivers fit one frustum is split; a light that already needs two split
//! frusta or cube faces keeps them. Nodes and the planner call the same function, so their pass
//! counts agree.

use super::geometry::{Poly, add3, box_distance, box_faces, clip, clip_all};
use super::{ShadowView, ShadowViewKind, shadow_views};
use crate::model::{Camera, LightSample};
use crate::shading::{V3, cross, dot, normalize, scale, sub};

/// Largest far/near ratio of eye depth one cascade covers.
pub const CASCADE_RATIO: f32 = 8.0;
/// Most cascades per light, the base views' included (a cascade is one more shadow pass).
pub const MAX_CASCADES: usize = 4;
/// Most views of one light: a full cube.
const MAX_VIEWS: usize = 6;

/// A receiver box cut to the camera's view: its new bounds and the eye depths it spans.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Clipped {
    pub bounds: (V3, V3),
    pub depth: (f32, f32),
}

/// The four side planes of the camera's view pyramid (through the eye, normals inward).
fn pyramid(camera: &Camera) -> Vec<V3> {
    let (w, h) = (camera.width as f32, camera.height as f32);
    let corners = [
        camera.ray_dir(0.0, 0.0),
        camera.ray_dir(w, 0.0),
        camera.ray_dir(w, h),
        camera.ray_dir(0.0, h),
    ];
    let forward = camera.frame().forward;
    (0..4)
        .map(|i| {
            let n = normalize(cross(corners[i], corners[(i + 1) % 4]));
            if dot(n, forward) < 0.0 {
                scale(n, -1.0)
            } else {
                n
            }
        })
        .collect()
}

/// Keeps the part of `poly` (relative to the eye) with eye depth `d·forward ≥ at` (`keep_far`)
/// or `≤ at`.
fn clip_depth(poly: Poly, forward: V3, at: f32, keep_far: bool) -> Poly {
    let shift = scale(forward, at);
    let rel: Poly = poly.iter().map(|p| sub(*p, shift)).collect();
    let n = if keep_far {
        forward
    } else {
        scale(forward, -1.0)
    };
    clip(&rel, n).iter().map(|p| add3(*p, shift)).collect()
}

/// Each of `receivers` cut to the camera's view pyramid and, with `slab = (a, b)`, to eye depths
/// within `[a, b]`; boxes with nothing left are dropped.
pub(crate) fn clip_to_view(
    camera: &Camera,
    receivers: &[(V3, V3)],
    slab: Option<(f32, f32)>,
) -> Vec<Clipped> {
    let planes = pyramid(camera);
    let forward = camera.frame().forward;
    let eye = camera.position;
    let mut out = Vec::new();
    let valid = |(lo, hi): &&(V3, V3)| {
        lo.iter().chain(hi.iter()).all(|c| c.is_finite()) && (0..3).all(|k| lo[k] <= hi[k])
    };
    for &(lo, hi) in receivers.iter().filter(valid) {
        let mut b = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        let mut depth = (f32::INFINITY, f32::NEG_INFINITY);
        let mut grow = |p: V3| {
            b.0 = std::array::from_fn(|k| b.0[k].min(p[k]));
            b.1 = std::array::from_fn(|k| b.1[k].max(p[k]));
            let z = dot(sub(p, eye), forward);
            depth = (depth.0.min(z), depth.1.max(z));
        };
        if box_distance(eye, lo, hi) <= 0.0 && slab.is_none_or(|(a, _)| a <= 0.0) {
            grow(eye);
        }
        for face in box_faces(lo, hi) {
            let rel: Poly = face.iter().map(|p| sub(*p, eye)).collect();
            let mut poly = clip_all(rel, &planes);
            if let Some((a, z)) = slab {
                poly = clip_depth(poly, forward, a, true);
                poly = clip_depth(poly, forward, z, false);
            }
            for p in poly {
                grow(add3(p, eye));
            }
        }
        if b.0[0] <= b.1[0] {
            // Clipping never leaves the box; rounding must not either.
            let clamp = |v: V3| std::array::from_fn(|k| v[k].clamp(lo[k], hi[k]));
            out.push(Clipped {
                bounds: (clamp(b.0), clamp(b.1)),
                depth: (depth.0.max(0.0), depth.1.max(0.0)),
            });
        }
    }
    out
}

/// [`camera_views`] with a camera, [`shadow_views`] of every receiver without one (walkthrough
/// maps, which must outlive camera moves).
pub fn fitted_views(
    sample: &LightSample,
    receivers: &[(V3, V3)],
    camera: Option<&Camera>,
) -> Vec<ShadowView> {
    match camera {
        Some(c) => camera_views(sample, receivers, c),
        None => shadow_views(sample, receivers),
    }
}

/// The views of `sample` fitted to what `camera` sees of `receivers` (every mesh's box): the
/// [`shadow_views`] of the visible receivers, preceded — where those receivers span more than
/// [`CASCADE_RATIO`] in eye depth — by up to `MAX_CASCADES − 1` near cascades, one fitted frustum
/// per geometric slice of the depth range, each marked with the eye depths it serves
/// (`eye_depth`). The views fitted to everything serve what lies beyond the last cascade.
pub fn camera_views(
    sample: &LightSample,
    receivers: &[(V3, V3)],
    camera: &Camera,
) -> Vec<ShadowView> {
    let clipped = clip_to_view(camera, receivers, None);
    let visible: Vec<(V3, V3)> = clipped.iter().map(|c| c.bounds).collect();
    let base = shadow_views(sample, &visible);
    if base.is_empty() || base[0].kind == ShadowViewKind::Ortho {
        return base;
    }
    let far = clipped.iter().map(|c| c.depth.1).fold(0.0f32, f32::max);
    let near = clipped
        .iter()
        .map(|c| c.depth.0)
        .fold(f32::INFINITY, f32::min)
        .max(far / CASCADE_RATIO.powi(MAX_CASCADES as i32))
        .max(1e-4);
    if !(far.is_finite() && far > near * CASCADE_RATIO) {
        return base;
    }
    let n = ((far / near).ln() / CASCADE_RATIO.ln()).ceil() as usize;
    let n = n.clamp(2, MAX_CASCADES);
    let at = |k: usize| near * (far / near).powf(k as f32 / n as f32);
    let mut out: Vec<ShadowView> = Vec::with_capacity(n - 1 + base.len());
    // Slices before the last, nearest first; the base views serve the last slice and anything a
    // slice could not take. A light never has more views than a full cube (nodes size their
    // texture arrays and light chunks by that).
    let slices = (n - 1).min(MAX_VIEWS.saturating_sub(base.len()));
    for k in 0..slices {
        let a = if k == 0 { 0.0 } else { at(k) };
        let b = at(k + 1);
        let boxes: Vec<(V3, V3)> = clip_to_view(camera, receivers, Some((a, b)))
            .into_iter()
            .map(|c| c.bounds)
            .collect();
        if boxes.is_empty() {
            continue;
        }
        match shadow_views(sample, &boxes).as_slice() {
            [one] if one.kind == ShadowViewKind::Fitted => {
                let mut v = *one;
                v.eye_depth = Some([a, b]);
                out.push(v);
            }
            // The lobe reaches nothing in this slice: no view needed there.
            [] => {}
            // Too wide for one frustum: the base views take it and everything beyond.
            _ => break,
        }
    }
    if out.is_empty() {
        return base;
    }
    out.extend(base);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::SampleKind;
    use crate::shadow_views::project;

    fn lobe(position: V3, direction: V3) -> LightSample {
        LightSample {
            position,
            direction: normalize(direction),
            kind: SampleKind::CosineLobe,
            intensity: 1.0,
            color: [1.0; 3],
            range: None,
            light: 0,
            area: None,
            cell: 0.0,
        }
    }

    fn camera(position: V3, target: V3) -> Camera {
        Camera {
            position,
            target,
            up: [0.0, 1.0, 0.0],
            fov_y_deg: 50.0,
            width: 64,
            height: 48,
        }
    }

    /// A ground 800 m deep seen from 1.6 m up, lit from above and behind.
    fn deep() -> (LightSample, Vec<(V3, V3)>, Camera) {
        let ground = ([-200.0, 0.0, -798.0], [200.0, 0.0, 2.0]);
        let boxes = vec![ground, ([-1.0, 0.0, -3.0], [-0.75, 0.25, -2.75])];
        let s = lobe([30.0, 45.0, 15.0], [-30.0, -45.0, -35.0]);
        (s, boxes, camera([0.0, 1.6, 2.0], [0.0, 0.4, -12.0]))
    }

    #[test]
    fn a_deep_view_splits_into_ordered_cascades_that_hold_what_the_camera_sees() {
        let (s, boxes, cam) = deep();
        let views = camera_views(&s, &boxes, &cam);
        let cascades = views.iter().take_while(|v| v.eye_depth.is_some()).count();
        assert!((1..MAX_CASCADES).contains(&cascades), "{cascades}");
        assert!(views[cascades..].iter().all(|v| v.eye_depth.is_none()));
        let ranges: Vec<[f32; 2]> = views[..cascades]
            .iter()
            .map(|v| v.eye_depth.unwrap())
            .collect();
        assert_eq!(ranges[0][0], 0.0);
        for w in ranges.windows(2) {
            assert_eq!(w[0][1], w[1][0], "{ranges:?}");
        }
        for r in &ranges[1..] {
            assert!(r[1] / r[0] <= CASCADE_RATIO * 1.01, "{ranges:?}");
        }
        // Every visible ground point lands inside the cascade its eye depth picks.
        let fwd = cam.frame().forward;
        let mut judged = 0;
        for i in 0..cam.width {
            for j in 0..cam.height {
                let d = cam.ray_dir(i as f32 + 0.5, j as f32 + 0.5);
                if d[1] >= -1e-3 {
                    continue;
                }
                let t = -cam.position[1] / d[1];
                let p = add3(cam.position, scale(d, t));
                if p[2] < -798.0 {
                    continue;
                }
                let z = dot(sub(p, cam.position), fwd);
                // The first cascade reaching z, else the base view (one frustum here).
                let v = views
                    .iter()
                    .find(|v| v.eye_depth.is_none_or(|d| z < d[1]))
                    .unwrap();
                let (uv, depth) = project(v, p).expect("in front of the view");
                assert!(
                    uv.iter().all(|c| (0.0..=1.0).contains(c)) && (0.0..=1.0).contains(&depth),
                    "{p:?} at eye depth {z}: uv {uv:?} depth {depth}"
                );
                judged += 1;
            }
        }
        assert!(judged > 1000, "{judged}");
        // The nearest cascade's texels are far finer than one frustum's over everything.
        let one = shadow_views(&s, &super::super::visible_receivers(&cam, &boxes));
        let span = |v: &ShadowView| (v.extent[1] - v.extent[0]).max(v.extent[3] - v.extent[2]);
        assert!(
            span(&views[0]) < 0.25 * span(&one[0]),
            "{} vs {}",
            span(&views[0]),
            span(&one[0])
        );
    }

    #[test]
    fn a_shallow_view_keeps_one_frustum_and_no_camera_fits_everything() {
        let (s, _, _) = deep();
        let boxes = vec![([-2.0, 0.0, -2.0], [2.0, 0.5, 2.0])];
        let cam = camera([0.0, 3.0, 4.0], [0.0, 0.0, 0.0]);
        let views = camera_views(&s, &boxes, &cam);
        assert_eq!(views.len(), 1);
        assert_eq!(views[0].eye_depth, None);
        let (s, boxes, _) = deep();
        assert_eq!(fitted_views(&s, &boxes, None), shadow_views(&s, &boxes));
    }

    #[test]
    fn cascades_come_first_and_empty_input_gives_no_view() {
        let (_, boxes, cam) = deep();
        let point = LightSample {
            kind: SampleKind::Isotropic,
            ..lobe([0.0, 0.5, -1.0], [0.0, -1.0, 0.0])
        };
        let views = camera_views(&point, &boxes, &cam);
        // Cascades (if any) come first, each one fitted frustum; the base views follow.
        let cascades = views.iter().take_while(|v| v.eye_depth.is_some()).count();
        assert!(
            views[..cascades]
                .iter()
                .all(|v| v.kind == ShadowViewKind::Fitted)
        );
        assert!(views[cascades..].iter().all(|v| v.eye_depth.is_none()));
        assert!(camera_views(&point, &[], &cam).is_empty());
        let nan = ([f32::NAN; 3], [f32::NAN; 3]);
        let s = lobe([0.0, 5.0, 0.0], [0.0, -1.0, 0.0]);
        assert!(
            camera_views(&s, &[nan], &cam)
                .iter()
                .all(|v| v.eye_depth.is_none())
        );
    }
}
