//! Two translucent layers per light view (peeling renderers, `docs/translucency.md`): two
//! stacked horizontal glass panes, red over blue, under a point light over a floor. The lower
//! pane, seen as peel 2 through the upper one, is lit through the red pane only (the CPU
//! reference's exact ray products); the floor below both through both. Compared with
//! `lightfold_reference::render_peeled` of the same samples at `gpu_translucent.rs`'s tolerances
//! (1e-3 relative + 1e-4, ≥ 99 % of the compared pixels); the one-layer maps
//! (`Fault::OneTranslucentLayer`) tint the lower pane by itself too and fail.

use crate::gpu_support;

use gpu_support::*;
use lightfold_node::gpu::{Fault, Gpu, LayerSet, NodeFrame, RenderOptions, Renderer};
use lightfold_reference::{PeeledLayers, render_peeled};
use lightfold_scene::primitives::plane;
use lightfold_scene::trace::{SurfaceHit, Tracer};
use lightfold_scene::{Camera, LightSample, Material, Scene, Transmission};
use std::sync::OnceLock;

const W: u32 = 128;
const H: u32 = 96;
const RED: [f32; 3] = [0.9, 0.1, 0.1];
const BLUE: [f32; 3] = [0.1, 0.3, 0.9];

fn glass(name: &str, color: [f32; 3]) -> Material {
    Material {
        transmission: Some(Transmission {
            color,
            coverage: false,
        }),
        ..Material::diffuse(name, color.map(|c| 0.3 * c))
    }
}

fn scene() -> Scene {
    let mut s = Scene::new("stacked panes");
    let floor = s.add_material(Material::diffuse("floor", [0.8, 0.8, 0.8]));
    let red = s.add_material(glass("red glass", RED));
    let blue = s.add_material(glass("blue glass", BLUE));
    let (x, y) = ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
    s.add_mesh(plane("floor", [0.0; 3], y, x, [8.0, 8.0], 4, floor));
    s.add_mesh(plane("red pane", [0.0, 1.5, 0.0], y, x, [1.2, 1.2], 1, red));
    s.add_mesh(plane(
        "blue pane",
        [0.0, 0.8, 0.0],
        y,
        x,
        [2.0, 2.0],
        1,
        blue,
    ));
    s.lights = vec![lightfold_scene::Light {
        name: "lamp".into(),
        shape: lightfold_scene::LightShape::Point {
            position: [0.1, 3.5, -0.1],
        },
        color: [1.0; 3],
        power: 20.0,
        range: None,
        samples: 1,
    }];
    s.camera = Camera {
        position: [0.0, 4.0, 3.0],
        target: [0.0, 0.6, 0.0],
        up: y,
        fov_y_deg: 45.0,
        width: W,
        height: H,
    };
    s
}

struct Truth {
    samples: Vec<LightSample>,
    peeled: PeeledLayers,
    /// Per pixel, its peel-2 surface's (the lower pane's) and its opaque surface's per-sample
    /// transmittance, `None` where the ray meets none.
    lower: Vec<Option<Vec<[f32; 3]>>>,
    floor: Vec<Option<Vec<[f32; 3]>>>,
}

fn truth() -> &'static Truth {
    static T: OnceLock<Truth> = OnceLock::new();
    T.get_or_init(|| {
        let scene = scene();
        let samples = samples(&scene);
        let peeled = render_peeled(&scene, &samples, [1.0; 3], 2);
        let tracer = Tracer::new(&scene);
        let tints = |hit: &SurfaceHit| -> Vec<[f32; 3]> {
            samples
                .iter()
                .map(|s| tracer.transmittance(hit, s))
                .collect()
        };
        let (mut lower, mut floor) = (Vec::new(), Vec::new());
        for i in 0..W * H {
            let eye = tracer.eye_layers((i % W) as f32 + 0.5, (i / W) as f32 + 0.5, 2);
            lower.push(eye.translucent.get(1).map(|l| tints(&l.surface)));
            floor.push(eye.opaque.map(|h| tints(&h)));
        }
        Truth {
            samples,
            peeled,
            lower,
            floor,
        }
    })
}

/// Pixels whose 3×3 neighbourhood all has a surface in `per_pixel` with every sample's
/// transmittance within 1 % of the pixel's (no silhouette, no tinted shadow's edge), and whose
/// own transmittance satisfies `want`.
fn steady(per_pixel: &[Option<Vec<[f32; 3]>>], want: impl Fn(&[[f32; 3]]) -> bool) -> Vec<bool> {
    let (w, h) = (W as i64, H as i64);
    (0..w * h)
        .map(|i| {
            let Some(mine) = &per_pixel[i as usize] else {
                return false;
            };
            let (x, y) = (i % w, i / w);
            want(mine)
                && (-1..=1).all(|dy| {
                    (-1..=1).all(|dx| {
                        let (nx, ny) = (x + dx, y + dy);
                        if nx < 0 || ny < 0 || nx >= w || ny >= h {
                            return false;
                        }
                        per_pixel[(ny * w + nx) as usize].as_ref().is_some_and(|t| {
                            t.iter()
                                .zip(mine)
                                .all(|(p, q)| (0..3).all(|k| (p[k] - q[k]).abs() <= 0.01))
                        })
                    })
                })
        })
        .collect()
}

/// Whether every sample's transmittance is `t` (to 1e-4).
fn all_near(tints: &[[f32; 3]], t: [f32; 3]) -> bool {
    tints
        .iter()
        .all(|s| (0..3).all(|k| (s[k] - t[k]).abs() <= 1e-4))
}

fn render(gpu: &Gpu, peel: u32, fault: Option<Fault>) -> NodeFrame {
    let s = scene();
    let opts = RenderOptions {
        fault,
        ..RenderOptions::from_quality(&s.quality)
    };
    let mut r = Renderer::new(gpu, &s, opts).expect("renderer");
    r.set_peel(Some(peel));
    let layers = LayerSet {
        transmittance: peel >= 1,
        ..LayerSet::all()
    };
    r.render(gpu, &truth().samples, None, [1.0; 3], layers)
        .expect("render")
}

/// The lower pane lit through the red pane (peel 2) and the floor through both (peel 0).
fn comparisons(gpu: &Gpu, fault: Option<Fault>) -> (Comparison, Comparison) {
    let t = truth();
    let red_mul_blue = [0, 1, 2].map(|k| RED[k] * BLUE[k]);
    let lower_mask = steady(&t.lower, |s| all_near(s, RED));
    let floor_mask = steady(&t.floor, |s| all_near(s, red_mul_blue));
    let (n_lower, n_floor) = (
        lower_mask.iter().filter(|m| **m).count(),
        floor_mask.iter().filter(|m| **m).count(),
    );
    assert!(n_lower > 300, "{n_lower} lower-pane pixels lit through red");
    assert!(n_floor > 150, "{n_floor} floor pixels lit through both");
    let illumination = |f: &NodeFrame| f.illumination.clone().expect("illumination");
    let lower = compare(
        &illumination(&render(gpu, 2, fault)),
        &t.peeled.layers[1].illumination,
        &lower_mask,
    );
    let floor = compare(
        &illumination(&render(gpu, 0, fault)),
        &t.peeled.opaque.illumination,
        &floor_mask,
    );
    eprintln!("{fault:?}: lower pane {lower:?} ({n_lower} px), floor {floor:?} ({n_floor} px)");
    (lower, floor)
}

#[test]
fn the_lower_pane_is_lit_through_the_upper_one_only() {
    let gpu = gpu();
    let (lower, floor) = comparisons(&gpu, None);
    assert!(lower.agree >= 0.99, "lower pane: {lower:?}");
    assert!(floor.agree >= 0.99, "floor: {floor:?}");
}

#[test]
fn one_translucent_layer_over_tints_the_lower_pane() {
    let gpu = gpu();
    let (lower, floor) = comparisons(&gpu, Some(Fault::OneTranslucentLayer));
    // The lower pane tinted by itself too: blue × red where the truth is red.
    assert!(lower.agree < 0.5, "one layer still matches: {lower:?}");
    // Below both panes the product is the truth either way.
    assert!(floor.agree >= 0.99, "floor: {floor:?}");
}
