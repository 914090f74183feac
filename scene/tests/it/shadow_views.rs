//! Shadow-view coverage: every receiver point a sample lights must land inside some view, at a
//! depth inside the map; faces that see nothing are skipped.

use lightfold_scene::shading::V3;
use lightfold_scene::shadow_views::{
    ShadowViewKind, cube_frame, project, shadow_views, visible_receivers,
};
use lightfold_scene::{Camera, LightSample, SampleKind};

fn sample(position: V3, direction: V3, kind: SampleKind) -> LightSample {
    LightSample {
        position,
        direction,
        kind,
        intensity: 1.0,
        color: [1.0; 3],
        range: None,
        light: 0,
        area: None,
        cell: 0.0,
    }
}

/// Deterministic points spread over a box (corners, face centres and a lattice).
fn box_points(lo: V3, hi: V3) -> Vec<V3> {
    let mut out = Vec::new();
    let n = 6;
    for i in 0..=n {
        for j in 0..=n {
            for k in 0..=n {
                let t = |a: f32, b: f32, q: u32| a + (b - a) * q as f32 / n as f32;
                out.push([t(lo[0], hi[0], i), t(lo[1], hi[1], j), t(lo[2], hi[2], k)]);
            }
        }
    }
    out
}

/// Asserts every lit point of every box is inside some view (uv in [0,1], depth in [0,1]).
fn assert_covered(s: &LightSample, boxes: &[(V3, V3)]) -> usize {
    let views = shadow_views(s, boxes);
    let mut lit = 0;
    for &(lo, hi) in boxes {
        for p in box_points(lo, hi) {
            let d = [
                p[0] - s.position[0],
                p[1] - s.position[1],
                p[2] - s.position[2],
            ];
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            let cos = (d[0] * s.direction[0] + d[1] * s.direction[1] + d[2] * s.direction[2]) / len;
            let lit_here = match s.kind {
                SampleKind::CosineLobe => cos > 1e-3,
                SampleKind::Directional => true,
                _ => len > 1e-3,
            };
            if !lit_here {
                continue;
            }
            lit += 1;
            let holds = |v: &&lightfold_scene::shadow_views::ShadowView| {
                project(v, p).is_some_and(|(uv, z)| {
                    (0.0..=1.0).contains(&uv[0])
                        && (0.0..=1.0).contains(&uv[1])
                        && (-1e-4..=1.0001).contains(&z)
                })
            };
            // Cube faces are picked by the dominant axis of the direction, as the shader does.
            let inside = if matches!(
                views.first().map(|v| v.kind),
                Some(ShadowViewKind::CubeFace(_))
            ) {
                let f = cube_frame(s);
                let c = [0, 1, 2].map(|k| d[0] * f[k][0] + d[1] * f[k][1] + d[2] * f[k][2]);
                let a = c.map(f32::abs);
                let face = if a[0] >= a[1] && a[0] >= a[2] {
                    if c[0] >= 0.0 { 0 } else { 1 }
                } else if a[1] >= a[2] {
                    if c[1] >= 0.0 { 2 } else { 3 }
                } else if c[2] >= 0.0 {
                    4
                } else {
                    5
                };
                views
                    .iter()
                    .filter(
                        |v| matches!(v.kind, ShadowViewKind::CubeFace(cf) if cf.index() == face),
                    )
                    .any(|v| holds(&v))
            } else if let Some(v) = views.iter().find(|v| {
                v.half_space
                    .is_some_and(|n| n[0] * d[0] + n[1] * d[1] + n[2] * d[2] >= 0.0)
            }) {
                // Split frusta: the side of the plane picks the view, as the shader does.
                holds(&v)
            } else {
                views.iter().any(|v| holds(&v))
            };
            assert!(inside, "lit point {p:?} outside all {} views", views.len());
        }
    }
    lit
}

const FLOOR: (V3, V3) = ([-2.0, -0.01, -2.0], [2.0, 0.0, 2.0]);

#[test]
fn a_lobe_over_a_small_floor_gets_one_fitted_frustum() {
    let s = sample([0.0, 3.0, 0.0], [0.0, -1.0, 0.0], SampleKind::CosineLobe);
    let boxes = [FLOOR, ([-0.5, 0.0, -0.5], [0.5, 1.0, 0.5])];
    let views = shadow_views(&s, &boxes);
    assert_eq!(views.len(), 1);
    assert_eq!(views[0].kind, ShadowViewKind::Fitted);
    assert!(views[0].near > 1.5 && views[0].far < 3.2, "{views:?}");
    assert!(assert_covered(&s, &boxes) > 100);
}

#[test]
fn a_lobe_in_a_room_needs_five_faces_and_covers_grazing_walls() {
    // Light on the ceiling of a closed room: the walls reach 90° off the lobe axis.
    let s = sample([0.0, 2.99, 0.0], [0.0, -1.0, 0.0], SampleKind::CosineLobe);
    let boxes = [
        FLOOR,
        ([-2.0, 0.0, -2.01], [2.0, 3.0, -2.0]),
        ([-2.0, 0.0, 2.0], [2.0, 3.0, 2.01]),
        ([-2.01, 0.0, -2.0], [-2.0, 3.0, 2.0]),
        ([2.0, 0.0, -2.0], [2.01, 3.0, 2.0]),
    ];
    let views = shadow_views(&s, &boxes);
    assert_eq!(views.len(), 5, "{views:#?}");
    assert!(
        views
            .iter()
            .all(|v| matches!(v.kind, ShadowViewKind::CubeFace(_)))
    );
    assert!(assert_covered(&s, &boxes) > 500);
}

#[test]
fn an_occluder_beyond_a_90_degree_cone_is_covered() {
    // A wall 80° off the lobe axis.
    let s = sample([0.0, 1.0, 0.0], [0.0, -1.0, 0.0], SampleKind::CosineLobe);
    let boxes = [FLOOR, ([3.0, 0.0, -1.0], [3.2, 0.8, 1.0])];
    let views = shadow_views(&s, &boxes);
    assert!(views.len() >= 2, "{views:#?}");
    assert!(assert_covered(&s, &boxes) > 100);
}

#[test]
fn faces_without_receivers_are_skipped() {
    // An isotropic light above a floor sees it through the bottom face and four sides only.
    let s = sample([0.0, 0.2, 0.0], [0.0, -1.0, 0.0], SampleKind::Isotropic);
    let views = shadow_views(&s, &[FLOOR]);
    assert_eq!(views.len(), 5, "{views:#?}");
    assert_covered(&s, &[FLOOR]);
    // Inside a box every face is needed.
    let room = [([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0])];
    let s = sample([0.1, 0.2, 0.3], [0.0, -1.0, 0.0], SampleKind::Isotropic);
    assert_eq!(shadow_views(&s, &room).len(), 6);
    assert_covered(&s, &room);
}

#[test]
fn out_of_range_and_behind_the_lobe_give_no_views() {
    let mut s = sample([0.0, 10.0, 0.0], [0.0, -1.0, 0.0], SampleKind::CosineLobe);
    s.range = Some(5.0);
    assert!(shadow_views(&s, &[FLOOR]).is_empty());
    let s = sample([0.0, 3.0, 0.0], [0.0, 1.0, 0.0], SampleKind::CosineLobe);
    assert!(shadow_views(&s, &[FLOOR]).is_empty());
    assert!(shadow_views(&s, &[]).is_empty());
}

#[test]
fn directional_light_gets_one_orthographic_view() {
    let s = sample([0.0; 3], [0.3, -1.0, 0.2], SampleKind::Directional);
    let s = LightSample {
        direction: lightfold_scene::shading::normalize(s.direction),
        ..s
    };
    let boxes = [FLOOR, ([-0.5, 0.0, -0.5], [0.5, 1.0, 0.5])];
    let views = shadow_views(&s, &boxes);
    assert_eq!(views.len(), 1);
    assert!(views[0].is_ortho());
    assert_covered(&s, &boxes);
}

/// A flat receiver facing a parallel light has no depth range of its own: the map must still
/// leave room up-light of it for the receiver's bias (the scene's depth bias and a slope
/// allowance of ten texels), or the biased reference depth passes the near plane, where every
/// clamped caster lies, and nothing is shadowed (a sun straight overhead once lit the floor under
/// a roof).
#[test]
fn a_flat_receiver_under_a_parallel_light_keeps_room_for_its_bias() {
    let floor = ([-2.0, 0.0, -2.0], [2.0, 0.0, 2.0]);
    for direction in [[0.0, -1.0, 0.0], [0.001, -1.0, 0.0]] {
        let s = sample(
            [0.0; 3],
            lightfold_scene::shading::normalize(direction),
            SampleKind::Directional,
        );
        let v = shadow_views(&s, &[floor])[0];
        let texel = 4.0 / 1024.0;
        let bias = lightfold_scene::defaults::quality().depth_bias + 1.5 * 2.0 * 10.0 * texel;
        let (_, at) = project(&v, [0.0, 0.0, 0.0]).unwrap();
        let (_, biased) = project(&v, [0.0, bias, 0.0]).unwrap();
        assert!(
            0.0 < at && at < biased && biased < 1.0,
            "{direction:?}: receiver at depth {at}, biased {biased}"
        );
    }
}

#[test]
fn depth_is_reversed_between_near_and_far() {
    let s = sample([0.0, 3.0, 0.0], [0.0, -1.0, 0.0], SampleKind::CosineLobe);
    let v = shadow_views(&s, &[FLOOR])[0];
    let (_, z_top) = project(&v, [0.0, 0.0, 0.0]).unwrap();
    let (_, z_bottom) = project(&v, [0.0, -0.01, 0.0]).unwrap();
    assert!(
        0.0 < z_bottom && z_bottom < z_top && z_top < 1.0,
        "{z_bottom} {z_top}"
    );
    // In front of near (a caster close to the light) the depth exceeds 1 and is clamped on the GPU.
    assert!(project(&v, [0.0, 1.5, 0.0]).unwrap().1 > 1.0);
    let (_, z_near) = project(&v, [0.0, 3.0 - v.near, 0.0]).unwrap();
    assert!((z_near - 1.0).abs() < 1e-4, "{z_near}");
}

#[test]
fn receivers_are_cut_to_what_the_camera_sees() {
    let camera = Camera {
        position: [0.0, 1.0, 3.0],
        target: [0.0, 0.0, 0.0],
        up: [0.0, 1.0, 0.0],
        fov_y_deg: 40.0,
        width: 40,
        height: 30,
    };
    let big_floor = ([-50.0, 0.0, -50.0], [50.0, 0.0, 50.0]);
    let behind = ([-1.0, 0.0, 5.0], [1.0, 1.0, 6.0]);
    let cut = visible_receivers(&camera, &[big_floor, behind]);
    assert_eq!(cut.len(), 1, "{cut:?}");
    let (lo, hi) = cut[0];
    // The floor is seen from the bottom edge of the view (z ≈ 1.7) to its far end, and narrows.
    assert!(hi[2] > 1.0 && hi[2] < 2.0 && lo[2] == -50.0, "{cut:?}");
    assert!(hi[0] < 30.0, "{cut:?}");
    assert!(lo[0] >= -50.0 && hi[0] <= 50.0 && lo[1] == 0.0 && hi[1] == 0.0);
    // Every floor point the camera sees through a pixel lies inside the cut box.
    for (x, y) in [(0.5, 29.5), (39.5, 29.5), (20.0, 20.0), (5.0, 16.0)] {
        let d = camera.ray_dir(x, y);
        if d[1] < 0.0 {
            let t = -camera.position[1] / d[1];
            let p = [
                camera.position[0] + t * d[0],
                0.0,
                camera.position[2] + t * d[2],
            ];
            if p[0].abs() <= 50.0 && p[2].abs() <= 50.0 {
                assert!(
                    (0..3).all(|k| p[k] >= lo[k] - 1e-3 && p[k] <= hi[k] + 1e-3),
                    "{p:?}"
                );
            }
        }
    }
    // A camera inside a box keeps the part of the box in front of it.
    let room = ([-2.0, 0.0, -2.0], [2.0, 3.0, 4.0]);
    assert_eq!(visible_receivers(&camera, &[room]).len(), 1);
}

#[test]
fn receivers_spread_one_way_get_two_fitted_frusta() {
    // A long strip under a low light: ±84° along x, ±45° along z.
    let strip = ([-10.0, 0.0, -1.0], [10.0, 0.0, 1.0]);
    let s = sample([0.0, 1.0, 0.0], [0.0, -1.0, 0.0], SampleKind::CosineLobe);
    let views = shadow_views(&s, &[strip]);
    assert_eq!(views.len(), 2, "{views:#?}");
    assert!(
        views
            .iter()
            .all(|v| v.kind == ShadowViewKind::Fitted && v.half_space.is_some())
    );
    assert!(assert_covered(&s, &[strip]) > 100);
}

/// Issue 22's per-light map sizes (`shadow_views::sizing`): larger images and thin casters the
/// maps hold ask for larger maps; the rule stays within its bounds and falls back when nothing
/// it probes is lit.
#[test]
fn map_sizes_follow_the_image_and_thin_casters() {
    use lightfold_scene::shadow_views::{Mismatch, camera_views, mismatch_size, probes};
    let yard = ([-20.0, 0.0, -20.0], [20.0, 0.0, 20.0]);
    let pole = ([-0.04, 0.0, -2.04], [0.04, 2.5, -1.96]);
    let lamp = sample([0.0, 4.0, 0.0], [0.0, -1.0, 0.0], SampleKind::CosineLobe);
    let rule = Mismatch {
        min: 16,
        max: 4096,
        target: 2.0,
    };
    let size = |w: u32, h: u32, boxes: &[(V3, V3)]| {
        let camera = Camera {
            position: [1.0, 1.5, 0.5],
            target: [1.5, 0.0, -3.0],
            up: [0.0, 1.0, 0.0],
            fov_y_deg: 45.0,
            width: w,
            height: h,
        };
        let views = camera_views(&lamp, boxes, &camera);
        let p = probes(&camera, boxes);
        assert!(!p.is_empty());
        mismatch_size(&lamp, &views, &p, boxes, &camera, rule, 512)
    };
    let small = size(160, 120, &[yard]);
    let large = size(640, 480, &[yard]);
    assert!(
        large >= 4 * small,
        "four times the pixels per side asks for about four times the texels: {small} → {large}"
    );
    // An 8 cm pole asks for more than the yard alone: its width must span texels.
    let with_pole = size(640, 480, &[yard, pole]);
    assert!(with_pole > large, "{large} → {with_pole}");
    for s in [small, large, with_pole] {
        assert!(s.is_power_of_two() && (16..=4096).contains(&s), "{s}");
    }
    // A light that reaches nothing the camera sees gets the fallback within the bounds.
    let away = sample([0.0, 4.0, 0.0], [0.0, 1.0, 0.0], SampleKind::CosineLobe);
    let camera = Camera {
        position: [1.0, 1.5, 0.5],
        target: [1.5, 0.0, -3.0],
        up: [0.0, 1.0, 0.0],
        fov_y_deg: 45.0,
        width: 640,
        height: 480,
    };
    let p = probes(&camera, &[yard]);
    assert_eq!(
        mismatch_size(&away, &[], &p, &[yard], &camera, rule, 100),
        100
    );
    let floor = Mismatch { min: 256, ..rule };
    assert_eq!(
        mismatch_size(&away, &[], &p, &[yard], &camera, floor, 100),
        256
    );
}
