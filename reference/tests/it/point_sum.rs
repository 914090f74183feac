//! The exact point-sum evaluator against closed forms, and its visibility conventions.

use crate::common;

use common::*;
use lightfold_reference::{
    PointSumOptions, radiance_point_sum, render_point_sum, render_point_sum_with,
};
use lightfold_scene::sampling::direct_samples;
use lightfold_scene::{AlphaMode, Material, Texture};

#[test]
fn single_point_light_over_plane_is_exact() {
    let light = [0.7, 2.5, -0.4];
    let cam = top_camera(5.0, 60.0, 40, 30);
    let s = scene(
        vec![ground(0)],
        vec![Material::diffuse("grey", [0.5, 0.25, 0.8])],
        vec![point_light(light, 12.0)],
        cam,
    );
    let img = radiance_point_sum(&s, &direct_samples(&s));
    for y in 0..30 {
        for x in 0..40 {
            let p = ground_point(&cam, x, y);
            let px = img.rgb(x, y);
            for (k, albedo) in [0.5, 0.25, 0.8].into_iter().enumerate() {
                let want = point_on_ground(light, p, 12.0, albedo);
                assert_close(
                    f64::from(px[k]),
                    want,
                    1e-5,
                    &format!("pixel ({x},{y}) ch {k}"),
                );
            }
        }
    }
}

#[test]
fn dense_rect_light_matches_polygon_formula_within_one_percent() {
    let (center, size) = ([0.2, 1.5, 0.1], [1.2, 0.8]);
    let cam = top_camera(5.0, 50.0, 24, 18);
    let mut s = scene(
        vec![ground(0)],
        vec![Material::diffuse("white", [1.0; 3])],
        vec![rect_light(center, size, 3.0, 16)],
        cam,
    );
    s.quality.samples_per_area_light = Some(1024);
    let img = radiance_point_sum(&s, &direct_samples(&s));
    let corners = rect_corners(center, [0.0, -1.0, 0.0], [1.0, 0.0, 0.0], size);
    for y in 0..18 {
        for x in 0..24 {
            let p = ground_point(&cam, x, y);
            let e = polygon_irradiance(p, [0.0, 1.0, 0.0], &corners, 3.0);
            let want = e / std::f64::consts::PI;
            assert_close(
                f64::from(img.rgb(x, y)[1]),
                want,
                0.01,
                &format!("pixel ({x},{y})"),
            );
        }
    }
}

/// A box between a point light and the ground: the ground under it is dark, the ground well
/// outside its shadow gets the closed form.
#[test]
fn box_shadows_the_ground() {
    let light = [0.0, 3.0, 0.0];
    let cam = top_camera(6.0, 40.0, 64, 64);
    let s = scene(
        vec![ground(0), occluder([0.0, 1.0, 0.0], [0.5, 0.1, 0.5], 0)],
        vec![Material::diffuse("white", [1.0; 3])],
        vec![point_light(light, 5.0)],
        cam,
    );
    let layers = render_point_sum(&s, &direct_samples(&s), [1.0; 3]);
    let img = layers.radiance([1.0; 3], [0.0; 3]);
    let (mut shadowed, mut lit) = (0, 0);
    for y in 0..64 {
        for x in 0..64 {
            let p = ground_point(&cam, x, y);
            let m = p[0].abs().max(p[2].abs());
            // Shadow square half-width 0.5·3/1.9 ≈ 0.789; the box top hides |x| < 0.612.
            if m > 0.64 && m < 0.77 {
                assert_eq!(
                    img.rgb(x, y),
                    [0.0; 3],
                    "pixel ({x},{y}) at {p:?} should be in shadow"
                );
                shadowed += 1;
            } else if m > 0.81 {
                let want = point_on_ground(light, p, 5.0, 1.0);
                assert_close(
                    f64::from(img.rgb(x, y)[0]),
                    want,
                    1e-5,
                    &format!("pixel ({x},{y})"),
                );
                lit += 1;
            }
        }
    }
    assert!(
        shadowed > 20 && lit > 1000,
        "shadowed {shadowed}, lit {lit}"
    );
    let unoccluded = render_point_sum_with(
        &s,
        &direct_samples(&s),
        [1.0; 3],
        PointSumOptions { shadows: false },
    )
    .radiance([1.0; 3], [0.0; 3]);
    let (x, y) = (0..64)
        .flat_map(|y| (0..64).map(move |x| (x, y)))
        .find(|&(x, y)| {
            let p = ground_point(&cam, x, y);
            let m = p[0].abs().max(p[2].abs());
            m > 0.64 && m < 0.77
        })
        .expect("a shadowed pixel");
    assert!(
        unoccluded.rgb(x, y)[0] > 0.0,
        "without shadows the pixel is lit"
    );
}

#[test]
fn node_colour_divides_light_colour_and_radiance_restores_it() {
    let cam = top_camera(4.0, 60.0, 8, 6);
    let mut light = point_light([0.0, 2.0, 0.0], 4.0);
    light.color = [1.0, 0.5, 0.25];
    let s = scene(
        vec![ground(0)],
        vec![Material::diffuse("white", [1.0; 3])],
        vec![light],
        cam,
    );
    let samples = direct_samples(&s);
    let white = render_point_sum(&s, &samples, [1.0; 3]);
    let tinted = render_point_sum(&s, &samples, [2.0, 0.5, 0.0]);
    for i in 0..48 {
        let w = &white.illumination.data[i * 6..i * 6 + 3];
        let t = &tinted.illumination.data[i * 6..i * 6 + 3];
        assert!((t[0] - w[0] / 2.0).abs() <= 1e-6 * w[0]);
        assert!((t[1] - w[1] * 2.0).abs() <= 1e-6 * w[1]);
        assert_eq!(t[2], 0.0, "a channel with c_n = 0 contributes nothing");
    }
    let a = white.radiance([1.0; 3], [0.0; 3]);
    let b = tinted.radiance([2.0, 0.5, 0.0], [0.0; 3]);
    for (x, y) in a.data.chunks(3).zip(b.data.chunks(3)) {
        assert!((x[0] - y[0]).abs() <= 1e-6 * x[0] && (x[1] - y[1]).abs() <= 1e-6 * x[1]);
    }
}

/// A single-sided ceiling between camera and ground, facing up (away from the camera above it
/// is towards the camera): seen from below it is invisible yet still casts shadows.
#[test]
fn single_sided_back_faces_are_invisible_but_cast_shadows() {
    let light = [0.0, 3.0, 0.0];
    let cam = top_camera(6.0, 30.0, 16, 16);
    // Facing down: the camera above sees its back.
    let sheet = lightfold_scene::primitives::plane(
        "sheet",
        [0.0, 1.5, 0.0],
        [0.0, -1.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.6, 0.6],
        1,
        1,
    );
    let mut one_sided = Material::diffuse("one-sided", [1.0, 0.0, 0.0]);
    one_sided.double_sided = false;
    let s = scene(
        vec![ground(0), sheet.clone()],
        vec![Material::diffuse("white", [1.0; 3]), one_sided],
        vec![point_light(light, 5.0)],
        cam,
    );
    let layers = render_point_sum(&s, &direct_samples(&s), [1.0; 3]);
    // Centre pixel: the ground (white) is seen through the sheet, and it is in shadow.
    assert_eq!(
        layers.diffuse.rgb(8, 8),
        [1.0; 3],
        "back face of a single-sided sheet is invisible"
    );
    assert_eq!(
        layers.illumination.pixel(8, 8)[0],
        0.0,
        "the sheet still casts a shadow"
    );
    // Double-sided: visible from the back with its normal flipped towards the viewer, lit by the
    // light above it (the light is on the viewer's side).
    let mut s2 = s.clone();
    s2.materials[1].double_sided = true;
    let layers = render_point_sum(&s2, &direct_samples(&s2), [1.0; 3]);
    assert_eq!(layers.diffuse.rgb(8, 8), [1.0, 0.0, 0.0]);
    // The light is 1.5 m above the sheet; the pixel centre is a few cm off-axis (< 1 %).
    let want = point_on_ground([0.0, 1.5, 0.0], [0.0; 3], 5.0, 1.0);
    assert_close(
        f64::from(layers.illumination.pixel(8, 8)[0]),
        want,
        0.02,
        "flipped normal",
    );
}

/// Alpha-masked geometry below the cutoff is transparent to eye rays and to shadow rays.
#[test]
fn alpha_mask_is_transparent_to_eye_and_shadow_rays() {
    let light = [0.0, 3.0, 0.0];
    let cam = top_camera(6.0, 30.0, 16, 16);
    let sheet = lightfold_scene::primitives::plane(
        "leaf",
        [0.0, 1.5, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.6, 0.6],
        1,
        1,
    );
    let mut leaf = Material::diffuse("leaf", [0.0, 1.0, 0.0]);
    leaf.alpha_mode = AlphaMode::Mask { cutoff: 0.5 };
    leaf.diffuse_texture = Some(0);
    let texture = |alpha: u8| Texture {
        name: "alpha".into(),
        width: 2,
        height: 2,
        srgb: false,
        rgba8: [255, 255, 255, alpha].repeat(4),
    };
    let mut s = scene(
        vec![ground(0), sheet],
        vec![Material::diffuse("white", [1.0; 3]), leaf],
        vec![point_light(light, 5.0)],
        cam,
    );
    s.textures.push(texture(40));
    let clear = render_point_sum(&s, &direct_samples(&s), [1.0; 3]);
    assert_eq!(
        clear.diffuse.rgb(8, 8),
        [1.0; 3],
        "masked texels are invisible"
    );
    assert!(
        clear.illumination.pixel(8, 8)[0] > 0.0,
        "masked texels cast no shadow"
    );
    s.textures[0] = texture(200);
    let solid = render_point_sum(&s, &direct_samples(&s), [1.0; 3]);
    assert_eq!(solid.diffuse.rgb(8, 8), [0.0, 1.0, 0.0]);
    // Seen from the side, below the leaf: the ground under it is shadowed only when opaque.
    let mut s3 = s.clone();
    s3.camera = camera([3.0, 0.5, 0.0], [0.0; 3], [0.0, 1.0, 0.0], 20.0, 16, 16);
    let side = render_point_sum(&s3, &direct_samples(&s3), [1.0; 3]);
    assert_eq!(
        side.diffuse.rgb(8, 8),
        [1.0; 3],
        "the centre ray hits the ground"
    );
    assert_eq!(
        side.illumination.pixel(8, 8)[0],
        0.0,
        "under an opaque leaf"
    );
    s3.textures[0] = texture(40);
    let side = render_point_sum(&s3, &direct_samples(&s3), [1.0; 3]);
    assert!(
        side.illumination.pixel(8, 8)[0] > 0.0,
        "under a masked-out leaf"
    );
}

#[test]
fn depth_is_distance_along_view_axis_and_zero_for_background() {
    let cam = camera(
        [0.0, 1.0, 5.0],
        [0.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
        60.0,
        20,
        20,
    );
    let s = scene(
        vec![ground(0)],
        vec![Material::diffuse("white", [1.0; 3])],
        vec![point_light([0.0, 2.0, 0.0], 1.0)],
        cam,
    );
    let layers = render_point_sum(&s, &[], [1.0; 3]);
    // Top rows look above the horizon: background.
    assert!(!layers.coverage[0] && layers.depth.data[0] == 0.0);
    let (x, y) = (10, 19);
    assert!(layers.coverage[(y * 20 + x) as usize]);
    let p = ground_point(&cam, x, y);
    let want = 5.0 - p[2];
    assert_close(
        f64::from(layers.depth.data[(y * 20 + x) as usize]),
        f64::from(want),
        1e-5,
        "depth",
    );
}

/// A pane at height `y` over the ground, of `material`, covering the whole view.
fn pane(y: f32, material: usize) -> lightfold_scene::Mesh {
    lightfold_scene::primitives::plane(
        "pane",
        [0.0, y, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [40.0, 40.0],
        1,
        material,
    )
}

#[test]
fn translucent_casters_tint_shadows_by_the_product_of_their_transmittance() {
    use lightfold_scene::Transmission;
    // The camera sits under the panes looking down at the ground: it sees only the ground,
    // whose every point the panes (40 m wide) stand between it and the light.
    let light = [0.3, 5.0, -0.2];
    let cam = camera(
        [0.0, 0.5, 0.0],
        [0.0, 0.0, 0.0],
        [0.0, 0.0, -1.0],
        60.0,
        12,
        10,
    );
    let glass = |color: [f32; 3], coverage: bool, alpha: f32| Material {
        alpha,
        transmission: Some(Transmission { color, coverage }),
        ..Material::diffuse("glass", [0.3; 3])
    };
    let materials = vec![
        Material::diffuse("white", [1.0; 3]),
        glass([0.9, 0.1, 0.2], false, 1.0),
        glass([0.2, 0.4, 1.0], true, 0.25),
        Material::diffuse("opaque", [0.5; 3]),
    ];
    let lit = |meshes: Vec<lightfold_scene::Mesh>| {
        let s = scene(
            meshes,
            materials.clone(),
            vec![point_light(light, 12.0)],
            cam,
        );
        render_point_sum(&s, &direct_samples(&s), [1.0; 3]).illumination
    };
    let open = lit(vec![ground(0)]);
    let red = lit(vec![ground(0), pane(2.0, 1)]);
    let both = lit(vec![ground(0), pane(2.0, 1), pane(3.0, 2)]);
    let blocked = lit(vec![ground(0), pane(2.0, 1), pane(1.0, 3)]);
    // Coverage 0.25 of a [0.2, 0.4, 1.0] filter: (1 − a) + a·c.
    let blue = [0.75 + 0.25 * 0.2, 0.75 + 0.25 * 0.4, 1.0];
    let red_t = [0.9, 0.1, 0.2];
    for y in 0..10 {
        for x in 0..12 {
            let (o, r, b, k) = (
                open.pixel(x, y),
                red.pixel(x, y),
                both.pixel(x, y),
                blocked.pixel(x, y),
            );
            assert!(o[0] > 0.0);
            for c in 0..3 {
                let what = format!("pixel ({x},{y}) ch {c}");
                assert_close(f64::from(r[c]), f64::from(o[c] * red_t[c]), 1e-6, &what);
                assert_close(
                    f64::from(b[c]),
                    f64::from(o[c] * red_t[c] * blue[c]),
                    1e-6,
                    &what,
                );
                // An opaque caster behind the pane (nearer the receiver) still blocks it all.
                assert_eq!(k[c], 0.0, "{what}");
            }
        }
    }
}

#[test]
fn glass_is_seen_and_lit_through_tinted() {
    use lightfold_reference::Tracer;
    use lightfold_scene::Transmission;
    let cam = camera(
        [0.0, 5.0, 0.0],
        [0.0, 0.0, 0.0],
        [0.0, 0.0, -1.0],
        40.0,
        8,
        8,
    );
    let glass = Material {
        transmission: Some(Transmission {
            color: [0.9, 0.1, 0.2],
            coverage: false,
        }),
        ..Material::diffuse("glass", [0.3; 3])
    };
    let film = Material {
        alpha: 0.5,
        transmission: Some(Transmission {
            color: [0.2, 0.4, 1.0],
            coverage: true,
        }),
        ..Material::diffuse("film", [0.2, 0.4, 1.0])
    };
    let materials = vec![Material::diffuse("white", [1.0; 3]), glass, film];
    let s = scene(
        vec![ground(0), pane(2.0, 1)],
        materials.clone(),
        vec![point_light([0.0, 4.0, 0.0], 10.0)],
        cam,
    );
    let t = Tracer::new(&s);
    // A light path down through the glass reaches the ground, tinted.
    let (hit, back, tint) = t
        .light_ray_tinted([0.0, 3.0, 0.0], [0.0, -1.0, 0.0])
        .unwrap();
    assert!(!back);
    assert!(hit.position[1].abs() < 1e-6, "{:?}", hit.position);
    assert_eq!(tint, [0.9, 0.1, 0.2]);
    // The eye sees the ground through it: its layers tinted, its depth the ground's.
    let layers = render_point_sum(&s, &direct_samples(&s), [1.0; 3]);
    for k in 0..3 {
        assert!((layers.diffuse.rgb(4, 4)[k] - [0.9, 0.1, 0.2][k]).abs() < 1e-6);
    }
    assert!((layers.depth.pixel(4, 4)[0] - 5.0).abs() < 1e-4);
    // A coverage film (glTF BLEND) is a surface to rays: the path stops on it.
    let s = scene(
        vec![ground(0), pane(2.0, 2)],
        materials,
        vec![point_light([0.0, 4.0, 0.0], 10.0)],
        cam,
    );
    let t = Tracer::new(&s);
    let (hit, _, tint) = t
        .light_ray_tinted([0.0, 3.0, 0.0], [0.0, -1.0, 0.0])
        .unwrap();
    assert!((hit.position[1] - 2.0).abs() < 1e-6);
    assert_eq!(tint, [1.0; 3]);
}
