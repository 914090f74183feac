//! What the eye sees of a translucent texel when translucency is peeled (`shading::eye_cover`),
//! and the tracer's peeled eye layers counting a pane's shared edge once.

use lightfold_scene::primitives::plane;
use lightfold_scene::shading::{EyeCover, eye_cover, transmittance};
use lightfold_scene::trace::Tracer;
use lightfold_scene::{AlphaMode, Camera, Material, Quality, Scene, Texture, Transmission};

const RED: [f32; 3] = [0.9, 0.2, 0.1];

fn coverage() -> Transmission {
    Transmission {
        color: RED,
        coverage: true,
    }
}

fn filter() -> Transmission {
    Transmission {
        color: RED,
        coverage: false,
    }
}

#[test]
fn coverage_is_alpha_times_texel_alpha_and_lets_the_rest_through_untinted() {
    let c = eye_cover(&coverage(), 0.5, [0.3, 0.6, 0.9, 0.5]);
    assert_eq!(
        c,
        EyeCover {
            coverage: 0.25,
            transmittance: [0.75; 3],
        }
    );
    // Not the shadow's transmittance, which tints the covered share: (1 − a) + a·c ⊙ x.
    let shadow = transmittance(&coverage(), 0.25, [0.3, 0.6, 0.9]);
    assert!((shadow[0] - (0.75 + 0.25 * 0.9 * 0.3)).abs() < 1e-6);
    assert_ne!(c.transmittance, shadow);
    // Clamped to [0, 1]; non-finite covers nothing.
    let at =
        |alpha: f32, texel_alpha: f32| eye_cover(&coverage(), alpha, [1.0, 1.0, 1.0, texel_alpha]);
    assert_eq!(at(3.0, 1.0).coverage, 1.0);
    assert_eq!(at(3.0, 1.0).transmittance, [0.0; 3]);
    assert_eq!(at(-0.5, 1.0).coverage, 0.0);
    assert_eq!(at(-0.5, 1.0).transmittance, [1.0; 3]);
    for bad in [f32::NAN, f32::INFINITY] {
        assert_eq!(at(bad, 1.0).coverage, 0.0, "{bad}");
        assert_eq!(at(bad, 1.0).transmittance, [1.0; 3], "{bad}");
        assert_eq!(at(1.0, bad).coverage, 0.0, "{bad}");
    }
}

#[test]
fn a_filter_covers_fully_and_lets_through_its_colour_times_the_texel() {
    let texel = [0.5, 1.0, 0.25, 0.1];
    let c = eye_cover(&filter(), 0.7, texel);
    assert_eq!(c.coverage, 1.0);
    assert_eq!(c.transmittance, [0.45, 0.2, 0.025]);
    // Exactly what shadow rays and the classic eye tint multiply in.
    assert_eq!(
        c.transmittance,
        transmittance(&filter(), 0.07, [0.5, 1.0, 0.25])
    );
    // Clamped: a transmittance never brightens; NaN is opaque.
    let wild = Transmission {
        color: [2.0, f32::NAN, -1.0],
        coverage: false,
    };
    assert_eq!(
        eye_cover(&wild, 1.0, [1.0; 4]).transmittance,
        [1.0, 0.0, 0.0]
    );
}

/// Camera at `(0, 5, 0)` looking straight down, 9 × 9 pixels (the centre pixel's ray is the axis).
fn top_down(panes: &[f32]) -> Scene {
    let glass = Material {
        transmission: Some(filter()),
        ..Material::diffuse("glass", [0.1; 3])
    };
    let mut meshes = vec![plane(
        "floor",
        [0.0; 3],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [10.0, 10.0],
        1,
        0,
    )];
    // Each pane is two triangles whose shared diagonal passes through the centre.
    for &y in panes {
        meshes.push(plane(
            "pane",
            [0.0, y, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
            [2.0, 2.0],
            1,
            1,
        ));
    }
    Scene {
        name: "panes".into(),
        meshes,
        materials: vec![Material::diffuse("floor", [0.5; 3]), glass],
        textures: Vec::new(),
        lights: Vec::new(),
        camera: Camera {
            position: [0.0, 5.0, 0.0],
            target: [0.0; 3],
            up: [0.0, 0.0, -1.0],
            fov_y_deg: 60.0,
            width: 9,
            height: 9,
        },
        ambient: [0.0; 3],
        exposure: 1.0,
        quality: Quality::default(),
        animation: None,
    }
}

#[test]
fn a_shared_edge_or_panes_within_epsilon_are_one_layer_panes_apart_two() {
    let one = top_down(&[2.0]);
    let t = Tracer::new(&one);
    // The centre ray crosses the pane on its diagonal, where both triangles are hit.
    assert_eq!(t.translucent_count(4.5, 4.5, 8), 1);
    let layers = t.eye_layers(4.5, 4.5, 8);
    assert_eq!(layers.translucent.len(), 1);
    assert!((layers.translucent[0].surface.depth - 3.0).abs() < 1e-5);
    assert_eq!(layers.translucent[0].cover.transmittance, RED);
    assert!((layers.opaque.unwrap().depth - 5.0).abs() < 1e-5);
    // Off the diagonal, and through no pane at the corner.
    assert_eq!(t.translucent_count(6.5, 3.5, 8), 1);
    assert_eq!(t.translucent_count(0.5, 0.5, 8), 0);
    // Two panes 1 cm apart (far beyond the tracer's epsilon) are two layers.
    let eps = t.epsilon() as f32;
    assert!(eps < 1e-3, "{eps}");
    let two = top_down(&[2.0, 2.01]);
    let t = Tracer::new(&two);
    assert_eq!(t.translucent_count(4.5, 4.5, 8), 2);
    assert_eq!(t.translucent_count(6.5, 3.5, 8), 2);
    assert_eq!(t.translucent_count(4.5, 4.5, 1), 1);
    let layers = t.eye_layers(4.5, 4.5, 8);
    assert_eq!(layers.translucent.len(), 2);
    assert!(layers.translucent[0].surface.depth < layers.translucent[1].surface.depth);
    // Within the epsilon of each other they are one (as a shared edge is).
    let twin = top_down(&[2.0, 2.0 + eps / 4.0]);
    let t = Tracer::new(&twin);
    assert_eq!(t.translucent_count(6.5, 3.5, 8), 1);
    assert_eq!(t.eye_layers(6.5, 3.5, 8).translucent.len(), 1);
}

#[test]
fn a_textured_coverage_film_covers_by_alpha_times_texel_alpha_even_below_the_mask_cutoff() {
    let mut s = top_down(&[2.0]);
    // Uniform linear texel (64, 128, 255) with alpha 128: below the 0.5 cutoff at α = 0.5.
    s.textures = vec![Texture {
        name: "film".into(),
        width: 2,
        height: 2,
        srgb: false,
        rgba8: [64, 128, 255, 128].repeat(4),
    }];
    s.materials[1] = Material {
        alpha: 0.5,
        alpha_mode: AlphaMode::Mask { cutoff: 0.5 },
        diffuse_texture: Some(0),
        transmission: Some(coverage()),
        ..Material::diffuse("film", [1.0; 3])
    };
    let t = Tracer::new(&s);
    // The classic eye cuts it out; peeling keeps it, covering a = α · texel alpha.
    assert!((t.primary(4, 4).unwrap().depth - 5.0).abs() < 1e-5);
    let layers = t.eye_layers(4.5, 4.5, 4);
    assert_eq!(layers.translucent.len(), 1);
    let a = 0.5 * 128.0 / 255.0;
    let cover = layers.translucent[0].cover;
    assert!((cover.coverage - a).abs() < 1e-6, "{cover:?}");
    for k in 0..3 {
        assert!(
            (cover.transmittance[k] - (1.0 - a)).abs() < 1e-6,
            "{cover:?}"
        );
    }
    // The same texel on a filter under the mask: masked out, no layer at all.
    s.materials[1].transmission = Some(filter());
    let t = Tracer::new(&s);
    assert_eq!(t.translucent_count(4.5, 4.5, 4), 0);
    assert!(t.eye_layers(4.5, 4.5, 4).translucent.is_empty());
}
