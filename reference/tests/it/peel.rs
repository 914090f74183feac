//! Peeled translucency (`render_peeled`): each translucent layer shaded as a surface, times its
//! eye coverage, with its eye transmittance, composited back to front over the opaque layer;
//! checked against eq. 2 worked out by hand per surface, against the classic (unpeeled) render,
//! and `Tracer::translucent_count` against the panes a ray crosses.

use crate::common;

use common::*;
use lightfold_reference::{
    Tracer, radiance_peeled, radiance_point_sum, render_peeled, render_point_sum,
};
use lightfold_scene::primitives::plane;
use lightfold_scene::sampling::direct_samples;
use lightfold_scene::shading::{self, V3};
use lightfold_scene::{AlphaMode, Camera, LightSample, Material, Mesh, Texture, Transmission};

const W: u32 = 40;
const H: u32 = 30;
/// Pixels whose rays (eye or shadow) pass within this of a pane's edge are left out (the hand
/// computation cannot tell which side the tracer's triangles put them on).
const MARGIN: f32 = 0.03;
/// Relative tolerance of a hand-computed value (f32 rounding of a few operations).
const REL: f32 = 1e-5;

fn cam() -> Camera {
    top_camera(5.0, 60.0, W, H)
}

/// A horizontal rectangle at height `y`, centred at `(c[0], c[1])` in x and z, half sizes `half`.
#[derive(Debug, Clone, Copy)]
struct Rect {
    y: f32,
    c: [f32; 2],
    half: [f32; 2],
}

impl Rect {
    /// The rectangle as a mesh facing up (`up`) or down.
    fn mesh(&self, material: usize, up: bool) -> Mesh {
        plane(
            "rect",
            [self.c[0], self.y, self.c[1]],
            [0.0, if up { 1.0 } else { -1.0 }, 0.0],
            [1.0, 0.0, 0.0],
            [2.0 * self.half[0], 2.0 * self.half[1]],
            1,
            material,
        )
    }

    /// Where the line from `o` along `d` meets the rectangle's plane, and whether inside it;
    /// `None` for the inside where the point lies within `MARGIN` of its edge.
    fn meets(&self, o: V3, d: V3) -> (V3, Option<bool>) {
        let (o, d) = (o.map(f64::from), d.map(f64::from));
        let t = (f64::from(self.y) - o[1]) / d[1];
        let p = [o[0] + t * d[0], f64::from(self.y), o[2] + t * d[2]].map(|c| c as f32);
        let e =
            ((p[0] - self.c[0]).abs() - self.half[0]).max((p[2] - self.c[1]).abs() - self.half[1]);
        (p, (e.abs() >= MARGIN).then_some(e < 0.0))
    }
}

fn filter(name: &str, diffuse: V3, color: V3) -> Material {
    Material {
        specular: [0.4; 3],
        shininess: 30.0,
        ambient: [0.1, 0.2, 0.3],
        emissive: [0.01, 0.0, 0.02],
        transmission: Some(Transmission {
            color,
            coverage: false,
        }),
        ..Material::diffuse(name, diffuse)
    }
}

fn film(alpha: f32) -> Material {
    Material {
        alpha,
        // glTF BLEND is loaded with a 0.5 mask for the classic cut-out.
        alpha_mode: AlphaMode::Mask { cutoff: 0.5 },
        specular: [0.2; 3],
        shininess: 12.0,
        ambient: [0.1; 3],
        emissive: [0.02, 0.0, 0.01],
        transmission: Some(Transmission {
            color: [0.2, 0.4, 1.0],
            coverage: true,
        }),
        ..Material::diffuse("film", [0.2, 0.4, 1.0])
    }
}

/// What a translucent material lets through where it covers, by hand: the colour for a filter,
/// `(1 − α) + α·c` for coverage (shadow rays).
fn shadow_t(m: &Material) -> V3 {
    let tr = m.transmission.unwrap();
    if tr.coverage {
        tr.color.map(|c| (1.0 - m.alpha) + m.alpha * c)
    } else {
        tr.color
    }
}

/// What the eye sees of a translucent material by hand: `(a, T)`.
fn eye_t(m: &Material) -> (f32, V3) {
    let tr = m.transmission.unwrap();
    if tr.coverage {
        (m.alpha, [1.0 - m.alpha; 3])
    } else {
        (1.0, tr.color)
    }
}

/// Paper eq. 2 of an up-facing Blinn-Phong surface of `m` at `p` seen along `d`, lit by `s`
/// through shadow transmittance `shadow`, times coverage `a`.
fn eq2(m: &Material, p: V3, d: V3, s: &LightSample, shadow: V3, ambient: V3, a: f32) -> V3 {
    let v = shading::scale(d, -1.0);
    let (id, is) = shading::coefficients(s, p, [0.0, 1.0, 0.0], v, m.shininess, m.has_specular());
    [0, 1, 2].map(|k| {
        let c = s.color[k] * shadow[k];
        a * (m.emissive[k]
            + m.ambient[k] * ambient[k]
            + m.diffuse[k] * c * id
            + m.specular[k] * c * is)
    })
}

/// A top-down world by hand: a floor of `floor` at y = 0 under up-facing translucent `panes`
/// (no textures), one point-light sample above them all.
struct Hand<'a> {
    floor: &'a Material,
    panes: &'a [(Rect, Material)],
    sample: &'a LightSample,
    ambient: V3,
}

impl Hand<'_> {
    /// The shadow transmittance at `p` towards the light: the product over the panes above it
    /// the shadow ray crosses; `None` where it passes near an edge.
    fn shadow(&self, p: V3) -> Option<V3> {
        let d = shading::sub(self.sample.position, p);
        let mut t = [1.0; 3];
        for (r, m) in self.panes.iter().filter(|(r, _)| r.y > p[1] + 1e-3) {
            if r.meets(p, d).1? {
                t = shading::mul(t, shadow_t(m));
            }
        }
        Some(t)
    }

    /// The pixel `(x, y)` peeled into `peels` layers and composited; `None` near an edge.
    fn pixel(&self, cam: &Camera, x: u32, y: u32, peels: usize) -> Option<V3> {
        let o = cam.position;
        let d = cam.ray_dir(x as f32 + 0.5, y as f32 + 0.5);
        let mut panes: Vec<&(Rect, Material)> = self.panes.iter().collect();
        panes.sort_by(|a, b| b.0.y.total_cmp(&a.0.y));
        let mut front = Vec::new();
        for (r, m) in panes {
            let (p, inside) = r.meets(o, d);
            if inside? {
                front.push((p, m));
            }
        }
        let floor_p = Rect {
            y: 0.0,
            c: [0.0; 2],
            half: [100.0; 2],
        }
        .meets(o, d)
        .0;
        let mut out = eq2(
            self.floor,
            floor_p,
            d,
            self.sample,
            self.shadow(floor_p)?,
            self.ambient,
            1.0,
        );
        for &(p, m) in front.iter().take(peels).rev() {
            let (a, t) = eye_t(m);
            let l = eq2(m, p, d, self.sample, self.shadow(p)?, self.ambient, a);
            out = [0, 1, 2].map(|k| l[k] + t[k] * out[k]);
        }
        Some(out)
    }
}

fn close(got: V3, want: V3, what: &str) {
    for k in 0..3 {
        let tol = REL * want[k].abs().max(1e-3);
        assert!(
            (got[k] - want[k]).abs() <= tol,
            "{what} ch {k}: got {got:?}, want {want:?}"
        );
    }
}

fn is_close(got: V3, want: V3) -> bool {
    (0..3).all(|k| (got[k] - want[k]).abs() <= REL * want[k].abs().max(1e-3))
}

/// A 64 × 64 linear checker of 4-texel squares, white and dark grey.
fn checker() -> Texture {
    let mut rgba8 = Vec::new();
    for y in 0..64 {
        for x in 0..64 {
            let v = if (x / 4 + y / 4) % 2 == 0 { 255 } else { 50 };
            rgba8.extend_from_slice(&[v, v, v, 255]);
        }
    }
    Texture {
        name: "checker".into(),
        width: 64,
        height: 64,
        srgb: false,
        rgba8,
    }
}

#[test]
fn a_glass_pane_adds_its_reflection_to_the_classic_tinted_view() {
    let pane = Rect {
        y: 2.0,
        c: [0.3, -0.2],
        half: [1.0, 0.8],
    };
    let glass = filter("glass", [0.1; 3], [0.9, 0.2, 0.1]);
    let floor = Material {
        diffuse_texture: Some(0),
        ..Material::diffuse("floor", [0.8; 3])
    };
    let mut s = scene(
        vec![ground(0), pane.mesh(1, true)],
        vec![floor, glass.clone()],
        vec![point_light([0.5, 4.0, 0.3], 20.0)],
        cam(),
    );
    s.textures = vec![checker()];
    s.ambient = [0.05; 3];
    let samples = direct_samples(&s);
    assert_eq!(samples.len(), 1);
    let classic = radiance_point_sum(&s, &samples);
    let peeled = render_peeled(&s, &samples, [1.0; 3], 1);
    let composite = peeled.radiance([1.0; 3], s.ambient);
    assert_eq!(composite, radiance_peeled(&s, &samples, 1));
    let bare = radiance_peeled(&s, &samples, 0);
    let cam = cam();
    let (mut through, mut beside, mut highlight) = (0, 0, 0.0f32);
    for y in 0..H {
        for x in 0..W {
            let d = cam.ray_dir(x as f32 + 0.5, y as f32 + 0.5);
            let (p, inside) = pane.meets(cam.position, d);
            let (c, got) = (classic.rgb(x, y), composite.rgb(x, y));
            let what = format!("pixel ({x},{y})");
            match inside {
                Some(true) => {
                    through += 1;
                    // Nothing above the pane: its own light is unshadowed.
                    let l_pane = eq2(&glass, p, d, &samples[0], [1.0; 3], s.ambient, 1.0);
                    let spec = eq2(
                        &Material {
                            specular: [0.0; 3],
                            ..glass.clone()
                        },
                        p,
                        d,
                        &samples[0],
                        [1.0; 3],
                        s.ambient,
                        1.0,
                    );
                    highlight = highlight.max(l_pane[0] - spec[0]);
                    // Classic shows T ⊙ L_floor: the peeled composite adds the pane's own light.
                    let diff = [0, 1, 2].map(|k| got[k] - c[k]);
                    for k in 0..3 {
                        let tol = REL * (l_pane[k].abs() + c[k].abs()).max(1e-3);
                        assert!(
                            (diff[k] - l_pane[k]).abs() <= tol,
                            "{what} ch {k}: peeled − classic {diff:?}, L_pane {l_pane:?}"
                        );
                    }
                    // Peeled 0 leaves the glass out: the floor untinted, which classic tints.
                    let t = [0.9, 0.2, 0.1];
                    close(c, shading::mul(t, bare.rgb(x, y)), &what);
                    assert!(!is_close(c, bare.rgb(x, y)), "{what}: untinted");
                    // The layer: the glass's material at coverage 1, its colour as T, its depth.
                    let i = (y * W + x) as usize;
                    let layer = &peeled.layers[0];
                    assert!(layer.coverage[i]);
                    assert_eq!(layer.diffuse.rgb(x, y), [0.1; 3]);
                    assert_eq!(layer.specular.rgb(x, y), [0.4; 3]);
                    assert_eq!(peeled.transmittance[0].rgb(x, y), t);
                    assert!((layer.depth.data[i] - 3.0).abs() < 1e-4, "{what} depth");
                    assert!((peeled.opaque.depth.data[i] - 5.0).abs() < 1e-4);
                }
                Some(false) => {
                    beside += 1;
                    assert_eq!(got, c, "{what}: no glass, as classic");
                    let i = (y * W + x) as usize;
                    assert!(!peeled.layers[0].coverage[i]);
                    assert_eq!(peeled.layers[0].diffuse.rgb(x, y), [0.0; 3]);
                    assert_eq!(peeled.transmittance[0].rgb(x, y), [1.0; 3]);
                }
                None => {}
            }
        }
    }
    assert!(
        through > 150 && beside > 300,
        "{through} through, {beside} beside"
    );
    // The highlight is part of what was checked.
    assert!(highlight > 0.05, "highlight {highlight}");
}

/// Two stacked filter panes over a plain floor: a large red one over a smaller green one.
fn two_panes() -> [(Rect, Material); 2] {
    [
        (
            Rect {
                y: 2.0,
                c: [0.0, 0.0],
                half: [1.5, 1.5],
            },
            filter("red", [0.1; 3], [0.9, 0.3, 0.2]),
        ),
        (
            Rect {
                y: 1.0,
                c: [0.5, 0.3],
                half: [0.75, 0.75],
            },
            Material {
                specular: [0.5; 3],
                shininess: 50.0,
                ..filter("green", [0.05, 0.1, 0.2], [0.2, 0.8, 0.6])
            },
        ),
    ]
}

#[test]
fn two_stacked_panes_composite_back_to_front_and_one_peel_drops_the_far_pane() {
    let panes = two_panes();
    let floor = Material::diffuse("floor", [0.7; 3]);
    let mut materials = vec![floor.clone()];
    let mut meshes = vec![ground(0)];
    for (k, (r, m)) in panes.iter().enumerate() {
        materials.push(m.clone());
        meshes.push(r.mesh(k + 1, true));
    }
    let mut s = scene(
        meshes,
        materials,
        vec![point_light([0.2, 4.0, -0.1], 30.0)],
        cam(),
    );
    s.ambient = [0.05, 0.04, 0.03];
    let samples = direct_samples(&s);
    let hand = Hand {
        floor: &floor,
        panes: &panes,
        sample: &samples[0],
        ambient: s.ambient,
    };
    let two = render_peeled(&s, &samples, [1.0; 3], 2);
    let three = render_peeled(&s, &samples, [1.0; 3], 3);
    let (one, two_img) = (
        radiance_peeled(&s, &samples, 1),
        two.radiance([1.0; 3], s.ambient),
    );
    // A third peel finds nothing: it is absent everywhere and changes no bit.
    assert_eq!((two.layers.len(), three.layers.len()), (2, 3));
    assert!(three.layers[2].coverage.iter().all(|c| !c));
    assert!(three.transmittance[2].data.iter().all(|&t| t == 1.0));
    assert_eq!(three.radiance([1.0; 3], s.ambient), two_img);
    let cam = cam();
    let (mut both, mut red_only) = (0, 0);
    for y in 0..H {
        for x in 0..W {
            let what = format!("pixel ({x},{y})");
            let (Some(want2), Some(want1)) = (hand.pixel(&cam, x, y, 2), hand.pixel(&cam, x, y, 1))
            else {
                continue;
            };
            let d = cam.ray_dir(x as f32 + 0.5, y as f32 + 0.5);
            let inside = panes
                .each_ref()
                .map(|(r, _)| r.meets(cam.position, d).1 == Some(true));
            close(two_img.rgb(x, y), want2, &what);
            close(one.rgb(x, y), want1, &what);
            let i = (y * W + x) as usize;
            match inside {
                [true, true] => {
                    both += 1;
                    // Negative control: one peel drops the green pane's light and tint.
                    assert!(!is_close(one.rgb(x, y), want2), "{what}: one peel");
                    assert!((two.layers[0].depth.data[i] - 3.0).abs() < 1e-4);
                    assert!((two.layers[1].depth.data[i] - 4.0).abs() < 1e-4);
                    assert_eq!(two.transmittance[1].rgb(x, y), [0.2, 0.8, 0.6]);
                }
                [true, false] => {
                    red_only += 1;
                    assert_eq!(one.rgb(x, y), two_img.rgb(x, y), "{what}");
                    assert!(!two.layers[1].coverage[i]);
                }
                _ => {}
            }
        }
    }
    assert!(
        both > 50 && red_only > 100,
        "{both} both, {red_only} red only"
    );
}

#[test]
fn a_coverage_film_blends_by_its_alpha_and_is_never_cut_out_when_peeled() {
    let floor = Material::diffuse("floor", [0.7; 3]);
    let rect = Rect {
        y: 2.0,
        c: [0.0, 0.0],
        half: [1.2, 1.0],
    };
    for alpha in [0.5, 0.25] {
        let panes = [(rect, film(alpha))];
        let mut s = scene(
            vec![ground(0), rect.mesh(1, true)],
            vec![floor.clone(), panes[0].1.clone()],
            vec![point_light([0.2, 4.0, -0.1], 30.0)],
            cam(),
        );
        s.ambient = [0.05; 3];
        let samples = direct_samples(&s);
        let hand = Hand {
            floor: &floor,
            panes: &panes,
            sample: &samples[0],
            ambient: s.ambient,
        };
        let peeled = render_peeled(&s, &samples, [1.0; 3], 1);
        let img = peeled.radiance([1.0; 3], s.ambient);
        let classic = render_point_sum(&s, &samples, [1.0; 3]);
        let classic_img = classic.radiance([1.0; 3], s.ambient);
        let cam = cam();
        let mut through = 0;
        for y in 0..H {
            for x in 0..W {
                let what = format!("alpha {alpha} pixel ({x},{y})");
                let d = cam.ray_dir(x as f32 + 0.5, y as f32 + 0.5);
                if rect.meets(cam.position, d).1 != Some(true) {
                    continue;
                }
                let Some(want) = hand.pixel(&cam, x, y, 1) else {
                    continue;
                };
                through += 1;
                close(img.rgb(x, y), want, &what);
                // Material layers times the coverage, T = 1 − α in every channel.
                let layer = &peeled.layers[0];
                let half = |v: V3| v.map(|c| alpha * c);
                assert_eq!(layer.diffuse.rgb(x, y), half([0.2, 0.4, 1.0]), "{what}");
                assert_eq!(layer.specular.rgb(x, y), half([0.2; 3]), "{what}");
                assert_eq!(layer.ambient.rgb(x, y), half([0.1; 3]), "{what}");
                assert_eq!(layer.emissive.rgb(x, y), half([0.02, 0.0, 0.01]), "{what}");
                assert_eq!(peeled.transmittance[0].rgb(x, y), [1.0 - alpha; 3]);
                // Classic: a cut-out at α ≥ 0.5 (the film, whole), else the floor, untinted.
                if alpha >= 0.5 {
                    assert_eq!(classic.diffuse.rgb(x, y), [0.2, 0.4, 1.0], "{what}");
                } else {
                    assert_eq!(classic.diffuse.rgb(x, y), [0.7; 3], "{what}");
                    assert_eq!(
                        classic_img.rgb(x, y),
                        peeled.opaque.radiance([1.0; 3], s.ambient).rgb(x, y)
                    );
                }
                assert!(!is_close(classic_img.rgb(x, y), want), "{what}: classic");
            }
        }
        assert!(through > 200, "alpha {alpha}: {through} pixels");
    }
}

#[test]
fn translucent_count_counts_the_panes_in_front_of_the_opaque_hit() {
    let [(a, red), (b, green)] = two_panes();
    // An opaque sheet between the panes hides part of the green one.
    let sheet = Rect {
        y: 1.5,
        c: [1.0, 0.9],
        half: [0.4, 0.4],
    };
    // Not layers: the back of a single-sided filter, a filter masked out by its alpha.
    let back = Rect {
        y: 2.5,
        c: [-1.0, 0.0],
        half: [0.5, 0.5],
    };
    let masked = Rect {
        y: 3.0,
        c: [-0.8, -0.8],
        half: [0.4, 0.4],
    };
    // A layer: coverage under the same mask (peeling never cuts coverage out).
    let blend = Rect {
        y: 3.0,
        c: [0.8, -0.8],
        half: [0.4, 0.4],
    };
    let single = Material {
        double_sided: false,
        ..red.clone()
    };
    let masked_filter = Material {
        alpha: 0.3,
        alpha_mode: AlphaMode::Mask { cutoff: 0.5 },
        ..red.clone()
    };
    let s = scene(
        vec![
            ground(0),
            a.mesh(1, true),
            b.mesh(2, true),
            sheet.mesh(0, true),
            back.mesh(3, false),
            masked.mesh(4, true),
            blend.mesh(5, true),
        ],
        vec![
            Material::diffuse("floor", [0.7; 3]),
            red,
            green,
            single,
            masked_filter,
            film(0.3),
        ],
        vec![point_light([0.2, 4.0, -0.1], 30.0)],
        cam(),
    );
    let tracer = Tracer::new(&s);
    let cam = cam();
    let mut seen = [0; 3];
    for y in 0..H {
        for x in 0..W {
            let d = cam.ray_dir(x as f32 + 0.5, y as f32 + 0.5);
            let hits = [a, b, sheet, back, masked, blend].map(|r| r.meets(cam.position, d).1);
            let Some([a_in, b_in, sheet_in, _, _, blend_in]) = hits
                .iter()
                .all(Option::is_some)
                .then(|| hits.map(Option::unwrap))
            else {
                continue;
            };
            let want = usize::from(a_in) + usize::from(b_in && !sheet_in) + usize::from(blend_in);
            let (fx, fy) = (x as f32 + 0.5, y as f32 + 0.5);
            let what = format!("pixel ({x},{y})");
            assert_eq!(tracer.translucent_count(fx, fy, 8), want, "{what}");
            assert_eq!(tracer.translucent_count(fx, fy, 1), want.min(1), "{what}");
            assert_eq!(tracer.translucent_count(fx, fy, 0), 0, "{what}");
            let layers = tracer.eye_layers(fx, fy, 8);
            assert_eq!(layers.translucent.len(), want, "{what}");
            assert_eq!(tracer.eye_layers(fx, fy, 1).translucent.len(), want.min(1));
            // Nearest first; the opaque hit is the sheet where it covers, else the floor.
            let depths: Vec<f32> = layers.translucent.iter().map(|l| l.surface.depth).collect();
            assert!(depths.windows(2).all(|w| w[0] < w[1]), "{what}: {depths:?}");
            let opaque = layers.opaque.expect("the floor").depth;
            let want_opaque = if sheet_in { 3.5 } else { 5.0 };
            assert!((opaque - want_opaque).abs() < 1e-4, "{what}: {opaque}");
            seen[want] += 1;
        }
    }
    assert!(seen.iter().all(|&n| n > 10), "pixels per count {seen:?}");
}

#[test]
fn zero_peels_of_an_opaque_scene_is_the_point_sum_bit_for_bit() {
    let mut s = lightfold_scene::builtin::builtin("cornell").unwrap();
    assert!(s.materials.iter().all(|m| !m.is_translucent()));
    s.camera.width = 48;
    s.camera.height = 36;
    s.ambient = [0.02, 0.03, 0.04];
    let samples: Vec<LightSample> = direct_samples(&s).into_iter().take(8).collect();
    let c_n = [0.9, 1.0, 0.8];
    let peeled = render_peeled(&s, &samples, c_n, 0);
    assert!(peeled.layers.is_empty() && peeled.transmittance.is_empty());
    let classic = render_point_sum(&s, &samples, c_n);
    assert_eq!(peeled.opaque, classic);
    assert_eq!(
        peeled.radiance(c_n, s.ambient),
        classic.radiance(c_n, s.ambient)
    );
    assert_eq!(
        radiance_peeled(&s, &samples, 0),
        radiance_point_sum(&s, &samples)
    );
    // Peels of a scene without translucent layers are absent and change nothing.
    let more = render_peeled(&s, &samples, c_n, 2);
    assert_eq!(
        more.radiance(c_n, s.ambient),
        classic.radiance(c_n, s.ambient)
    );
}
