//! The GPU renderer against the CPU reference (same samples, same triangles) on a scene built so
//! that ≥ 20 % of pixels are shadowed and a caster sits outside a 90° cone of a sample, for both
//! eye-pass variants; and the negative controls: a wrong bias, a missing cube face and a
//! mis-applied colour must each fail the same comparison. The edge mask is documented in
//! `gpu_support`.

use crate::gpu_support;

use gpu_support::*;
use lightfold_node::gpu::{EyeVariant, Fault, Gpu, LayerSet, NodeFrame, RenderOptions, Renderer};
use lightfold_reference::{Layers, render_point_sum};
use lightfold_scene::{LightSample, Scene};
use std::sync::OnceLock;

const W: u32 = 192;
const H: u32 = 144;

/// Reference layers, shadow-state mask and samples, computed once for every test in this file.
struct Expected {
    scene: Scene,
    samples: Vec<LightSample>,
    reference: Layers,
    mask: Vec<bool>,
    shadowed_fraction: f64,
}

fn expected() -> &'static Expected {
    static E: OnceLock<Expected> = OnceLock::new();
    E.get_or_init(|| {
        let scene = shadow_scene(W, H);
        let samples = samples(&scene);
        let reference = render_point_sum(&scene, &samples, C_N);
        let states = shadow_states(&scene, &samples);
        let mask = comparable(&reference, &states.visible);
        Expected {
            shadowed_fraction: states.shadowed_fraction(),
            scene,
            samples,
            reference,
            mask,
        }
    })
}

/// Renders with the default eye variant.
fn render(gpu: &Gpu, opts: RenderOptions, layers: LayerSet) -> NodeFrame {
    render_variant(gpu, opts, layers, EyeVariant::default())
}

fn render_variant(
    gpu: &Gpu,
    opts: RenderOptions,
    layers: LayerSet,
    variant: EyeVariant,
) -> NodeFrame {
    let e = expected();
    let mut r = Renderer::new(gpu, &e.scene, opts).expect("renderer");
    r.set_variant(variant);
    r.render(gpu, &e.samples, None, C_N, layers)
        .expect("render")
}

fn illumination_comparison(name: &str, opts: RenderOptions) -> Comparison {
    let gpu = gpu();
    let e = expected();
    let frame = render(&gpu, opts, LayerSet::illumination());
    dump(name, &frame, &e.reference);
    let c = compare(
        frame.illumination.as_ref().expect("illumination"),
        &e.reference.illumination,
        &e.mask,
    );
    eprintln!("{name}: {c:?}");
    c
}

fn default_options() -> RenderOptions {
    RenderOptions::from_quality(&expected().scene.quality)
}

#[test]
fn the_scene_stresses_shadows() {
    let e = expected();
    assert!(
        e.shadowed_fraction >= 0.2,
        "only {:.1} % of pixels shadowed",
        e.shadowed_fraction * 100.0
    );
    let compared = e.mask.iter().filter(|&&m| m).count() as f64 / e.mask.len() as f64;
    assert!(
        compared > 0.6,
        "edge mask leaves only {:.1} %",
        compared * 100.0
    );
    // The pillar lies wholly outside the 90° cone around the axis of every sample of the low light.
    let pillar = e
        .scene
        .meshes
        .iter()
        .find(|m| m.name == "pillar")
        .expect("pillar");
    let (lo, hi) = pillar.bounds().expect("pillar bounds");
    for s in e.samples.iter().filter(|s| s.light == 0) {
        for i in 0..8 {
            let c = [0, 1, 2].map(|k| if i >> k & 1 == 0 { lo[k] } else { hi[k] });
            let d =
                lightfold_scene::shading::normalize(lightfold_scene::shading::sub(c, s.position));
            let angle = lightfold_scene::shading::dot(d, s.direction)
                .acos()
                .to_degrees();
            assert!(
                angle > 45.0,
                "pillar corner {c:?} at {angle}° from a sample's axis"
            );
        }
    }
    // So such samples need more than one fitted frustum.
    let gpu = gpu();
    let frame = render(&gpu, default_options(), LayerSet::illumination());
    assert!(
        frame.stats.passes_per_light.iter().any(|&p| p > 1),
        "{:?}",
        frame.stats.passes_per_light
    );
    assert_eq!(
        frame.stats.shadow_passes,
        frame.stats.passes_per_light.iter().sum::<u32>()
    );
}

#[test]
fn illumination_matches_the_reference() {
    let c = illumination_comparison("correct", default_options());
    assert!(c.passes(), "{c:?}");
}

#[test]
fn forward_illumination_matches_the_reference() {
    let gpu = gpu();
    let e = expected();
    let frame = render_variant(
        &gpu,
        default_options(),
        LayerSet::illumination(),
        EyeVariant::Forward,
    );
    dump("forward", &frame, &e.reference);
    let c = compare(
        frame.illumination.as_ref().expect("illumination"),
        &e.reference.illumination,
        &e.mask,
    );
    eprintln!("forward: {c:?}");
    assert!(c.passes(), "{c:?}");
}

#[test]
fn material_layers_and_depth_match_the_reference() {
    for variant in [EyeVariant::Forward, EyeVariant::Deferred] {
        layers_match(variant);
    }
}

fn layers_match(variant: EyeVariant) {
    let gpu = gpu();
    let e = expected();
    let frame = render_variant(&gpu, default_options(), LayerSet::all(), variant);
    // Material layers do not depend on shadows: only silhouettes are masked.
    let sil = lightfold_reference::masks::silhouettes(&e.reference.depth, &e.reference.coverage, 1);
    let mask: Vec<bool> = sil.iter().map(|&s| !s).collect();
    for (name, got, want) in [
        ("m^d", &frame.diffuse, &e.reference.diffuse),
        ("m^s", &frame.specular, &e.reference.specular),
        ("m^a", &frame.ambient, &e.reference.ambient),
        ("e", &frame.emissive, &e.reference.emissive),
        ("depth", &frame.depth, &e.reference.depth),
    ] {
        let got = got.as_ref().unwrap_or_else(|| panic!("{name} missing"));
        let c = compare(got, want, &mask);
        eprintln!("{variant:?} {name}: {c:?}");
        assert!(c.passes(), "{variant:?} {name}: {c:?}");
    }
    let il = compare(
        frame.illumination.as_ref().expect("illumination"),
        &e.reference.illumination,
        &e.mask,
    );
    assert!(il.passes(), "{variant:?} with layers: {il:?}");
}

#[test]
fn negative_control_zero_bias_fails() {
    let c = illumination_comparison(
        "no-bias",
        RenderOptions {
            fault: Some(Fault::NoBias),
            ..default_options()
        },
    );
    assert!(!c.passes(), "{c:?}");
}

#[test]
fn negative_control_huge_bias_fails() {
    let c = illumination_comparison(
        "huge-bias",
        RenderOptions {
            fault: Some(Fault::HugeBias),
            ..default_options()
        },
    );
    assert!(!c.passes(), "{c:?}");
}

#[test]
fn negative_control_missing_face_fails() {
    let c = illumination_comparison(
        "missing-face",
        RenderOptions {
            fault: Some(Fault::MissingFace),
            ..default_options()
        },
    );
    assert!(!c.passes(), "{c:?}");
}

#[test]
fn negative_control_colour_applied_twice_fails() {
    let c = illumination_comparison(
        "colour",
        RenderOptions {
            fault: Some(Fault::ColourNotDivided),
            ..default_options()
        },
    );
    assert!(!c.passes(), "{c:?}");
}
