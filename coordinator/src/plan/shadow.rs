//! Per active sample: the casters its shadow map needs (meshes in its reach that overlap the region
//! between it and a visible receiver it lights), the views `scene::shadow_views` fits (as the node
//! does), and the map size from the eye/light resolution mismatch factor of Govindaraju et al.
//! (seed 002) by the rule the renderer applies (`scene::shadow_views::sizing`).

use super::cull::Receiver;
use super::geom::{Aabb, reach};
use super::types::{MAX_MAP_SIZE, MapSizing, ShadowPlan, ShadowViews};
use lightfold_scene::shading::V3;
use lightfold_scene::shadow_views::{
    Mismatch, Probe, ShadowView, ShadowViewKind, fitted_views, mismatch_size,
};
use lightfold_scene::{Camera, LightSample, SampleKind};

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

/// Map side by `sizing` (`Scene` resolved by `plan()` first): the rule `lightfold render` and
/// the node apply (`scene::shadow_views::mismatch_size`), with `fallback` where no probe is lit.
pub(crate) fn map_size(
    s: &LightSample,
    views: &[ShadowView],
    probes: &[Probe],
    receivers: &[(V3, V3)],
    cam: &Camera,
    sizing: MapSizing,
    fallback: u32,
) -> u32 {
    match sizing {
        MapSizing::Fixed(n) => n.clamp(1, MAX_MAP_SIZE),
        MapSizing::Scene => fallback.clamp(1, MAX_MAP_SIZE),
        MapSizing::Mismatch { min, max, target } => mismatch_size(
            s,
            views,
            probes,
            receivers,
            cam,
            Mismatch { min, max, target },
            fallback,
        ),
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
    fallback: u32,
    force_all: bool,
) -> ShadowPlan {
    let casters = if force_all {
        (0..bounds.len() as u32).collect()
    } else {
        casters(s, lit, bounds)
    };
    let views = fitted_views(s, scene_receivers, fit_camera);
    let map_size = map_size(s, &views, probes, scene_receivers, cam, sizing, fallback);
    ShadowPlan {
        views: summarize(&views),
        map_size,
        casters,
        transmittance: false,
    }
}
