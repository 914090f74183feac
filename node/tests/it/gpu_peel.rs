//! Peeled eye layers (`NodeConfig::peel`, `Renderer::set_peel`, `docs/translucency.md`) on the
//! device against truths built from the CPU reference of the same light samples.
//!
//! The scene: a red glass pane (a filter with its own diffuse colour and a specular highlight)
//! over a checker floor, and a blue film (coverage, α = 0.5) under one side of it. Each layer's
//! truth is a classic reference render (`render_point_sum`) of a variant of the scene whose
//! shadows are the same (a translucent caster's transmittance does not depend on what the eye
//! sees of it):
//!
//! - `classic`: the scene as it is, the film's cutoff above its alpha, so eye rays skip the film
//!   and see through the pane: the opaque surface, its materials times the pane's transmittance;
//! - `surfaces`: the pane as a coverage surface of α = 1 (its shadow transmittance unchanged),
//!   the film's cutoff at its alpha: the nearest surface, pane, film or floor;
//! - `film`: the film visible, the pane a filter: the film behind the pane, tinted by it.
//!
//! Peel 0 is `classic` with the pane's tint divided out, peel 1 the nearest of `surfaces`
//! where it is translucent, peel 2 the film of `film` where the pane is in front of it; the
//! material layers of a translucent layer times its coverage (1 for the pane, 0.5 for the film).
//! Compared as in `gpu_translucent.rs`: shadow edges and silhouettes of every variant left out,
//! ≥ 99 % of the rest within 1e-3 relative + 1e-4, energy within 1 %.

use crate::gpu_support;

use gpu_support::*;
use lightfold_node::gpu::{Gpu, LayerSet, NodeFrame, RenderOptions, Renderer};
use lightfold_reference::{Layers, render_point_sum};
use lightfold_scene::primitives::plane;
use lightfold_scene::{
    AlphaMode, Camera, Image, LightSample, Material, Scene, Texture, Transmission,
};
use std::sync::OnceLock;

const W: u32 = 160;
const H: u32 = 120;
const RED_GLASS: [f32; 3] = [0.9, 0.1, 0.1];
const FILM_ALPHA: f32 = 0.5;
const AMBIENT: [f32; 3] = [0.05; 3];

fn checker_texture() -> Texture {
    let n = 8;
    let mut rgba8 = Vec::with_capacity(n * n * 4);
    for y in 0..n {
        for x in 0..n {
            let v = if (x + y) % 2 == 0 { 220 } else { 90 };
            rgba8.extend_from_slice(&[v, v, v, 255]);
        }
    }
    Texture {
        name: "checker".into(),
        width: n as u32,
        height: n as u32,
        srgb: false,
        rgba8,
    }
}

/// The test scene; `film_cutoff` decides whether classic eye rays see the film (at or below its
/// alpha) or skip it.
fn peel_scene(film_cutoff: f32) -> Scene {
    let mut s = Scene::new("peeled panes");
    s.textures.push(checker_texture());
    let floor = s.add_material(Material {
        diffuse_texture: Some(0),
        ambient: [0.6; 3],
        ..Material::diffuse("checker floor", [0.9, 0.9, 0.9])
    });
    let red = s.add_material(Material {
        transmission: Some(Transmission {
            color: RED_GLASS,
            coverage: false,
        }),
        specular: [0.5; 3],
        shininess: 40.0,
        ambient: [0.2, 0.02, 0.02],
        ..Material::diffuse("red glass", [0.3, 0.03, 0.03])
    });
    let film = s.add_material(Material {
        alpha: FILM_ALPHA,
        alpha_mode: AlphaMode::Mask {
            cutoff: film_cutoff,
        },
        transmission: Some(Transmission {
            color: [0.2, 0.3, 1.0],
            coverage: true,
        }),
        ambient: [0.1, 0.15, 0.5],
        ..Material::diffuse("blue film", [0.2, 0.3, 1.0])
    });
    let (x, y) = ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
    s.add_mesh(plane("floor", [0.0; 3], y, x, [8.0, 8.0], 4, floor));
    s.add_mesh(plane(
        "red pane",
        [-0.4, 1.2, -0.1],
        y,
        x,
        [1.4, 1.4],
        1,
        red,
    ));
    s.add_mesh(plane(
        "blue film",
        [-0.1, 0.6, -0.3],
        y,
        x,
        [1.2, 1.2],
        1,
        film,
    ));
    s.lights = vec![lightfold_scene::Light {
        name: "lamp".into(),
        shape: lightfold_scene::LightShape::Rect {
            center: [4.0, 3.2, -0.3],
            normal: [0.0, -1.0, 0.0],
            u_axis: x,
            size: [0.5, 0.5],
        },
        color: [1.0, 1.0, 1.0],
        power: 20.0,
        range: None,
        samples: 4,
    }];
    s.camera = Camera {
        position: [0.0, 3.6, 3.8],
        target: [0.0, 0.5, 0.0],
        up: y,
        fov_y_deg: 40.0,
        width: W,
        height: H,
    };
    s
}

/// The scene under test: classic eye rays skip the film.
fn scene() -> Scene {
    peel_scene(0.75)
}

/// Which translucent surfaces a pixel's eye ray passes in front of the opaque one, nearest
/// first, by the references' depths.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Pane,
    Film,
}

struct Truth {
    samples: Vec<LightSample>,
    classic: Layers,
    surfaces: Layers,
    film: Layers,
    /// Per pixel, the translucent layers in front of the opaque surface, nearest first.
    order: Vec<Vec<Kind>>,
    mask: Vec<bool>,
}

fn truth() -> &'static Truth {
    static T: OnceLock<Truth> = OnceLock::new();
    T.get_or_init(|| {
        let scene = scene();
        let samples = samples(&scene);
        let mut surfaces_scene = peel_scene(FILM_ALPHA);
        for m in &mut surfaces_scene.materials {
            if let Some(t) = &mut m.transmission
                && !t.coverage
            {
                // α = 1 coverage: the same shadow transmittance, but a surface to the eye.
                t.coverage = true;
            }
        }
        let film_scene = peel_scene(FILM_ALPHA);
        let variants = [&scene, &surfaces_scene, &film_scene];
        let [classic, surfaces, film] = variants.map(|s| render_point_sum(s, &samples, [1.0; 3]));
        let mut mask = vec![true; (W * H) as usize];
        for (s, r) in variants.iter().zip([&classic, &surfaces, &film]) {
            for (m, c) in mask.iter_mut().zip(edge_free(s, &samples, r)) {
                *m &= c;
            }
        }
        let nearer = |a: f32, b: f32| a > 0.0 && a < b * (1.0 - 1e-4);
        let order = (0..(W * H) as usize)
            .map(|i| {
                let (z_floor, z_film, z_near) = (
                    classic.depth.data[i],
                    film.depth.data[i],
                    surfaces.depth.data[i],
                );
                let mut o = Vec::new();
                if nearer(z_near, z_film) {
                    o.push(Kind::Pane);
                }
                if nearer(z_film, z_floor) {
                    o.push(Kind::Film);
                }
                o
            })
            .collect();
        Truth {
            samples,
            classic,
            surfaces,
            film,
            order,
            mask,
        }
    })
}

/// A frame of the reference's layers (`None` for what the truth does not hold).
fn frame_of(layers: [Image; 6]) -> NodeFrame {
    let [illumination, diffuse, specular, ambient, emissive, depth] = layers;
    NodeFrame {
        illumination: Some(illumination),
        diffuse: Some(diffuse),
        specular: Some(specular),
        ambient: Some(ambient),
        emissive: Some(emissive),
        depth: Some(depth),
        ambient_mask: None,
        transmittance: None,
        stats: Default::default(),
    }
}

fn materials(l: &Layers) -> [&Image; 4] {
    [&l.diffuse, &l.specular, &l.ambient, &l.emissive]
}

/// The truth of peel `d` (0: the opaque layer), with its transmittance (d ≥ 1).
fn expected(t: &Truth, d: usize) -> (NodeFrame, Image) {
    let n = (W * H) as usize;
    let mut illumination = Image::new(W, H, 6);
    let mut m = [0; 4].map(|_| Image::new(W, H, 3));
    let mut depth = Image::new(W, H, 1);
    let mut tr = Image::new(W, H, 3);
    tr.data.fill(1.0);
    for i in 0..n {
        // (source layers, per-channel factor on its materials, its transmittance)
        let (src, factor, transmit): (&Layers, [f32; 3], [f32; 3]) = if d == 0 {
            let tint = if t.order[i].first() == Some(&Kind::Pane) {
                RED_GLASS
            } else {
                [1.0; 3]
            };
            (&t.classic, tint.map(|c| 1.0 / c), [1.0; 3])
        } else {
            match (t.order[i].get(d - 1), d) {
                (None, _) => continue,
                (Some(Kind::Pane), _) => (&t.surfaces, [1.0; 3], RED_GLASS),
                (Some(Kind::Film), 1) => (&t.surfaces, [FILM_ALPHA; 3], [1.0 - FILM_ALPHA; 3]),
                // The film behind the pane: the `film` reference tints it by the pane.
                (Some(Kind::Film), _) => (
                    &t.film,
                    RED_GLASS.map(|c| FILM_ALPHA / c),
                    [1.0 - FILM_ALPHA; 3],
                ),
            }
        };
        illumination.data[i * 6..i * 6 + 6]
            .copy_from_slice(&src.illumination.data[i * 6..i * 6 + 6]);
        depth.data[i] = src.depth.data[i];
        for (out, from) in m.iter_mut().zip(materials(src)) {
            for (k, f) in factor.iter().enumerate() {
                out.data[i * 3 + k] = from.data[i * 3 + k] * f;
            }
        }
        tr.data[i * 3..i * 3 + 3].copy_from_slice(&transmit);
    }
    let [md, ms, ma, e] = m;
    (frame_of([illumination, md, ms, ma, e, depth]), tr)
}

fn renderer(gpu: &Gpu) -> Renderer {
    let s = scene();
    Renderer::new(gpu, &s, RenderOptions::from_quality(&s.quality)).expect("renderer")
}

fn layers(peel: Option<u32>) -> LayerSet {
    LayerSet {
        transmittance: peel.is_some_and(|d| d >= 1),
        ..LayerSet::all()
    }
}

fn render_peel(gpu: &Gpu, r: &mut Renderer, peel: Option<u32>) -> NodeFrame {
    r.set_peel(peel);
    r.render(gpu, &truth().samples, None, [1.0; 3], layers(peel))
        .expect("render")
}

/// Radiance of a frame (eq. 2 with its own illumination): premultiplied for a peeled layer.
fn radiance(f: &NodeFrame) -> Image {
    f.radiance(f.illumination.as_ref().expect("illumination"), AMBIENT)
        .expect("layers")
}

/// The compositor's `blend`: `out = R_0`, then `out = R_i + T_i ⊙ out` for each layer in
/// front, back to front.
fn blend(back: &Image, front: &[(Image, &Image)]) -> Image {
    let mut out = back.clone();
    for (r, t) in front {
        for (k, o) in out.data.iter_mut().enumerate() {
            *o = r.data[k] + t.data[k] * *o;
        }
    }
    out
}

#[test]
fn each_peeled_layer_matches_its_reference() {
    let gpu = gpu();
    let t = truth();
    let mut r = renderer(&gpu);
    let mut pane_pixels = 0;
    for d in 0..=2u32 {
        let frame = render_peel(&gpu, &mut r, Some(d));
        let (want, want_t) = expected(t, d as usize);
        // Pixels this layer holds a surface of (peel 0: all; the others: where the truth has
        // one), and the rest, which must be empty.
        let here: Vec<bool> = (0..(W * H) as usize)
            .map(|i| d == 0 || t.order[i].len() >= d as usize)
            .collect();
        let mask: Vec<bool> = t.mask.iter().zip(&here).map(|(m, h)| *m && *h).collect();
        let compared = mask.iter().filter(|m| **m).count();
        eprintln!("peel {d}: {compared} pixels with a layer compared");
        // The film under the pane is the smallest region (about 400 pixels before the mask).
        let least = if d == 2 { 150 } else { 300 };
        assert!(compared > least, "peel {d}: {compared} pixels");
        for (name, got, want) in [
            ("illumination", &frame.illumination, &want.illumination),
            ("m^d", &frame.diffuse, &want.diffuse),
            ("m^s", &frame.specular, &want.specular),
            ("m^a", &frame.ambient, &want.ambient),
            ("depth", &frame.depth, &want.depth),
        ] {
            let (got, want) = (got.as_ref().expect(name), want.as_ref().expect(name));
            let c = compare(got, want, &mask);
            eprintln!("peel {d} {name}: {c:?}");
            if c.agree < 0.99 {
                let ch = got.channels;
                for i in (0..(W * H) as usize)
                    .filter(|&i| mask[i])
                    .filter(|&i| {
                        (0..ch).any(|k| {
                            let (a, b) = (got.data[i * ch + k], want.data[i * ch + k]);
                            (a - b).abs() > 1e-3 * b.abs() + 1e-4
                        })
                    })
                    .take(12)
                {
                    eprintln!(
                        "  {i} ({}, {}) {:?}: got {:?} want {:?}",
                        i % W as usize,
                        i / W as usize,
                        t.order[i],
                        &got.data[i * ch..i * ch + ch],
                        &want.data[i * ch..i * ch + ch]
                    );
                }
            }
            assert!(
                c.agree >= 0.99,
                "peel {d} {name}: {c:?} (energy over every pixel: {})",
                c.energy_ratio
            );
        }
        let c = compare(&radiance(&frame), &radiance(&want), &t.mask);
        eprintln!("peel {d} radiance: {c:?}");
        assert!(c.passes(), "peel {d} radiance: {c:?}");
        // Where the layer has no surface: nothing, and T = 1, exactly.
        let empty = (0..(W * H) as usize).filter(|&i| t.mask[i] && !here[i]);
        for i in empty {
            let f = &frame;
            assert_eq!(f.depth.as_ref().unwrap().data[i], 0.0, "peel {d} pixel {i}");
            assert!(
                f.diffuse.as_ref().unwrap().data[i * 3..i * 3 + 3] == [0.0; 3]
                    && f.illumination.as_ref().unwrap().data[i * 6..i * 6 + 6] == [0.0; 6],
                "peel {d} pixel {i} is not empty"
            );
        }
        let tr = frame.transmittance.as_ref();
        assert_eq!(tr.is_some(), d >= 1, "peel {d}");
        if let Some(tr) = tr {
            // T directly: the pane's colour (to f16 rounding), 0.5 on the film, 1 elsewhere.
            for i in (0..(W * H) as usize).filter(|&i| t.mask[i]) {
                let got = &tr.data[i * 3..i * 3 + 3];
                let want = &want_t.data[i * 3..i * 3 + 3];
                let kind = t.order[i].get(d as usize - 1);
                if kind == Some(&Kind::Pane) {
                    pane_pixels += 1;
                    assert!(
                        got.iter().zip(want).all(|(g, w)| (g - w).abs() <= 2.5e-4),
                        "peel {d} pixel {i}: T {got:?}, the pane's {want:?}"
                    );
                } else {
                    assert_eq!(got, want, "peel {d} pixel {i} ({kind:?})");
                }
            }
        }
    }
    assert!(pane_pixels > 300, "{pane_pixels} pane pixels");
    // Some pixels see both the pane and the film (peel 2 is not empty).
    let both = t.order.iter().filter(|o| o.len() == 2).count();
    assert!(both > 300, "{both} pixels see two translucent layers");
}

/// The composite of peels 0, 2, 1 by the blend rule against the composite of their truths;
/// with the classic frame (filters already multiplied in) as the back, the pane's tint counts
/// twice and the comparison fails (the negative control).
#[test]
fn the_blend_of_the_peels_matches_and_the_classic_back_double_tints() {
    let gpu = gpu();
    let t = truth();
    let mut r = renderer(&gpu);
    let peels: Vec<NodeFrame> = (0..=2)
        .map(|d| render_peel(&gpu, &mut r, Some(d)))
        .collect();
    let classic = render_peel(&gpu, &mut r, None);
    let front = |frames: &[NodeFrame]| -> Vec<(Image, Image)> {
        [2, 1]
            .map(|d| {
                (
                    radiance(&frames[d]),
                    frames[d].transmittance.clone().expect("T"),
                )
            })
            .into()
    };
    let layers: Vec<(NodeFrame, Image)> = (0..=2).map(|d| expected(t, d)).collect();
    let want = blend(
        &radiance(&layers[0].0),
        &[2, 1].map(|d| (radiance(&layers[d].0), &layers[d].1)),
    );
    let got_front = front(&peels);
    let pairs: Vec<(Image, &Image)> = got_front.iter().map(|(r, t)| (r.clone(), t)).collect();
    let got = blend(&radiance(&peels[0]), &pairs);
    let c = compare(&got, &want, &t.mask);
    eprintln!("blend of peels 0, 2, 1: {c:?}");
    assert!(c.passes(), "{c:?}");
    let doubled = blend(&radiance(&classic), &pairs);
    let n = compare(&doubled, &want, &t.mask);
    eprintln!("classic back under the peels (double tint): {n:?}");
    assert!(!n.passes(), "the classic back passed: {n:?}");
    // Only one peel over the opaque layer: the film under the pane is lost, so it differs too.
    let one = blend(&radiance(&peels[0]), &pairs[1..]);
    let o = compare(&one, &want, &t.mask);
    eprintln!("peel 1 alone over peel 0: {o:?}");
    assert!(o.agree < c.agree, "{o:?} against {c:?}");
}

/// `peel: None` is the classic eye pass bit for bit, before and after peeled frames on the same
/// renderer; peel 0 differs from it exactly where glass is seen (the control).
#[test]
fn no_peel_is_the_classic_pass_bit_for_bit() {
    let gpu = gpu();
    let t = truth();
    let bits = |f: &NodeFrame| -> Vec<u32> {
        [
            &f.illumination,
            &f.diffuse,
            &f.specular,
            &f.ambient,
            &f.emissive,
            &f.depth,
        ]
        .into_iter()
        .flatten()
        .flat_map(|i| i.data.iter().map(|v| v.to_bits()))
        .collect()
    };
    // A renderer never told about peeling (the API before peels existed).
    let mut fresh = renderer(&gpu);
    let before = fresh
        .render(&gpu, &t.samples, None, [1.0; 3], LayerSet::all())
        .expect("render");
    assert_eq!(fresh.peel(), None);
    let mut r = renderer(&gpu);
    let a = render_peel(&gpu, &mut r, None);
    let peeled = render_peel(&gpu, &mut r, Some(2));
    let opaque = render_peel(&gpu, &mut r, Some(0));
    let b = render_peel(&gpu, &mut r, None);
    assert!(a.transmittance.is_none() && b.transmittance.is_none());
    assert!(
        bits(&before) == bits(&a),
        "peel None differs from the classic frame"
    );
    assert!(bits(&before) == bits(&b), "peel None after peels differs");
    assert!(bits(&peeled) != bits(&a));
    // Peel 0 is the classic frame but where glass is seen: there its materials are untinted.
    let (cd, od) = (
        a.diffuse.as_ref().unwrap(),
        opaque.diffuse.as_ref().unwrap(),
    );
    let differing = (0..(W * H) as usize)
        .filter(|&i| cd.data[i * 3..i * 3 + 3] != od.data[i * 3..i * 3 + 3])
        .count();
    let glass = t.order.iter().filter(|o| !o.is_empty()).count();
    eprintln!("peel 0 against classic m^d: {differing} pixels differ, {glass} see glass");
    assert!(differing > 300 && differing <= glass + 2 * (W + H) as usize);
}

/// A sort-first tile of a peeled layer: the same rows as the whole frame, nothing elsewhere.
#[test]
fn a_tile_of_a_peeled_layer_is_the_same_rows() {
    let gpu = gpu();
    let t = truth();
    let mut r = renderer(&gpu);
    let whole = render_peel(&gpu, &mut r, Some(1));
    let [y0, y1] = [30u32, 70];
    r.set_rows(Some([y0, y1]));
    let tile = render_peel(&gpu, &mut r, Some(1));
    for (name, a, b) in [
        ("illumination", &whole.illumination, &tile.illumination),
        ("m^d", &whole.diffuse, &tile.diffuse),
        ("depth", &whole.depth, &tile.depth),
        ("transmittance", &whole.transmittance, &tile.transmittance),
    ] {
        let (a, b) = (a.as_ref().unwrap(), b.as_ref().unwrap());
        let row = W as usize * a.channels;
        let (lo, hi) = (y0 as usize * row, y1 as usize * row);
        assert!(
            a.data[lo..hi] == b.data[lo..hi],
            "{name}: the tile's rows differ"
        );
        assert!(
            b.data[..lo].iter().chain(&b.data[hi..]).all(|v| *v == 0.0),
            "{name}: rows outside the tile are not empty"
        );
    }
    let _ = t;
}

/// Bands in protocol order, from a channel big enough for the frame.
fn bands(
    f: impl FnOnce(&tokio::sync::mpsc::Sender<lightfold_node::daemon::bands::PackedBand>),
) -> Vec<lightfold_node::daemon::bands::PackedBand> {
    let (tx, mut rx) = tokio::sync::mpsc::channel(1024);
    f(&tx);
    drop(tx);
    let mut out = Vec::new();
    while let Ok(b) = rx.try_recv() {
        out.push(b);
    }
    out
}

/// The transmittance layer packed on the device equals the CPU's pack of the read-back image, in
/// both of its formats; a frame asking for it without a translucent peel is an error.
#[test]
fn transmittance_packs_on_the_device_as_on_the_cpu() {
    use lightfold_node::daemon::bands::{BandLayout, LayerImages, assemble_frame, pack_frame};
    use lightfold_protocol::{Layer, PixelFormat};
    use std::sync::Arc;
    let gpu = gpu();
    let t = truth();
    let mut r = renderer(&gpu);
    let band_height = 16;
    for format in [PixelFormat::F16x4, PixelFormat::Rgba8Linear] {
        let layers = [
            (Layer::Illumination, PixelFormat::F16x6),
            (Layer::Diffuse, PixelFormat::F16x4),
            (Layer::Depth, PixelFormat::DepthF32),
            (Layer::Transmittance, format),
        ];
        r.set_peel(Some(1));
        let (packed, _) = r
            .render_packed(&gpu, &t.samples, None, [1.0; 3], &layers, band_height, 1.0)
            .expect("frame")
            .expect("this device packs");
        let set = LayerSet::of(layers.iter().map(|(l, _)| *l));
        let mut frame = r
            .render(&gpu, &t.samples, None, [1.0; 3], set)
            .expect("frame");
        let images: LayerImages = layers
            .iter()
            .map(|&(layer, format)| {
                let img = lightfold_node::daemon::render_thread::take_layer(&mut frame, layer)
                    .expect("layer");
                (layer, format, Arc::new(img))
            })
            .collect();
        let layout = BandLayout {
            epoch: 1,
            frame: 1,
            width: W,
            height: H,
            band_height,
            scale: 1.0,
        };
        let device = bands(|tx| {
            assemble_frame(&layout, &layers, &packed, tx).expect("device bands");
        });
        let cpu = bands(|tx| {
            pack_frame(&layout, &images, None, tx).expect("CPU bands");
        });
        assert_eq!(device.len(), cpu.len(), "{format:?}");
        for (d, c) in device.iter().zip(&cpu) {
            assert_eq!(d.header, c.header, "{format:?}");
            assert_eq!(d.payload, c.payload, "{format:?}");
        }
        // T is 1 where no glass is seen: no band of it is empty.
        assert!(
            cpu.iter()
                .filter(|b| b.header.layer == Layer::Transmittance)
                .all(|b| !b.header.empty),
            "{format:?}"
        );
        // A peel beyond the cap is refused, and the renderer still serves.
        r.set_peel(Some(lightfold_node::gpu::MAX_PEEL + 1));
        let e = r
            .render(&gpu, &t.samples, None, [1.0; 3], set)
            .expect_err("too deep");
        assert!(
            matches!(e, lightfold_node::gpu::RenderError::PeelTooDeep { .. }),
            "{e}"
        );
        // Without a translucent peel there is no transmittance, on either path.
        for peel in [None, Some(0)] {
            r.set_peel(peel);
            let e = r
                .render(&gpu, &t.samples, None, [1.0; 3], set)
                .expect_err("no transmittance");
            assert!(e.to_string().contains("peel >= 1"), "{e}");
            let e = r
                .render_packed(&gpu, &t.samples, None, [1.0; 3], &layers, band_height, 1.0)
                .expect_err("no transmittance");
            assert!(e.to_string().contains("peel >= 1"), "{e}");
        }
    }
}

/// A node configured with `peel: Some(1)` streams the peeled layer and its transmittance, equal
/// to a direct peeled render within each link format's bound; transmittance without a
/// translucent peel is refused with `BadConfig`, and the node keeps serving.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_peeling_node_streams_the_peeled_layer() {
    use crate::daemon_support::{
        assemble, band_count, node_config, start_compositor, start_node, worst_excess,
    };
    use lightfold_node::daemon::render_thread::{shadow_filter, take_layer};
    use lightfold_protocol::{ErrorCode, Layer, Message, PixelFormat};
    use lightfold_scene::wire::camera_to_wire;
    let mut node = start_node("node-peel", None).await;
    let mut comp = start_compositor().await;
    let mut coord = node.coordinator().await;
    let scene = scene();
    let hash = coord.send_scene(&scene).await;
    let lights = samples(&scene);
    let layers = vec![
        (Layer::Illumination, PixelFormat::F32x6),
        (Layer::Diffuse, PixelFormat::F16x4),
        (Layer::Depth, PixelFormat::DepthF32),
        (Layer::Transmittance, PixelFormat::F16x4),
    ];
    let mut config = node_config(3, hash, &lights, layers.clone(), &comp.addr);
    config.camera = camera_to_wire(&scene.camera);
    config.depth_bias = scene.quality.depth_bias;
    config.slope_bias = scene.quality.slope_bias;
    // Refused: transmittance of the opaque layer, and a peel deeper than the cap.
    for (peel, needle) in [(Some(0), "needs peel >= 1"), (Some(99), "deeper than")] {
        let bad = lightfold_protocol::NodeConfig {
            peel,
            ..config.clone()
        };
        match coord.request(Message::ConfigureNode(bad)).await {
            Message::Error { code, message, .. }
                if code == ErrorCode::BadConfig && message.contains(needle) => {}
            other => panic!("peel {peel:?}: expected BadConfig ({needle}), got {other:?}"),
        }
    }
    config.peel = Some(1);
    assert_eq!(
        coord.request(Message::ConfigureNode(config.clone())).await,
        Message::Configured { epoch: 3 }
    );
    match coord.frame(3, 1).await {
        Message::FrameDone(_) => {}
        other => panic!("expected FrameDone, got {other:?}"),
    }
    let bands = comp.take(band_count(&config)).await;
    assert!(comp.idle(), "exactly the configured bands arrive");
    let gpu = gpu();
    let options = RenderOptions {
        shadow_map_size: scene.quality.shadow_map_size,
        map_sizing: scene.quality.map_sizing,
        filter: shadow_filter(config.filter),
        depth_bias: config.depth_bias,
        slope_bias: config.slope_bias,
        ..RenderOptions::default()
    };
    let mut r = Renderer::new(&gpu, &scene, options).expect("renderer");
    r.set_peel(Some(1));
    let mut direct = r
        .render(
            &gpu,
            &lights,
            None,
            config.color,
            LayerSet::of(layers.iter().map(|(l, _)| *l)),
        )
        .expect("direct render");
    for (layer, format) in &layers {
        let want = take_layer(&mut direct, *layer).expect("direct layer");
        let got = assemble(&bands, *layer, W, H);
        let excess = worst_excess(*format, &got, &want, config.scale);
        eprintln!("{layer:?} in {format:?}: worst excess over the bound {excess:e}");
        assert!(excess <= 0.0, "{layer:?} in {format:?}: {excess}");
    }
    // The glass is in the streamed layer: T below 1 somewhere, 1 elsewhere.
    let t = assemble(&bands, Layer::Transmittance, W, H);
    let lo = t.data.iter().copied().fold(f32::INFINITY, f32::min);
    let ones = t.data.iter().filter(|v| **v == 1.0).count();
    eprintln!(
        "T: least {lo}, {ones} channels exactly 1 of {}",
        t.data.len()
    );
    assert!(t.data.iter().any(|v| *v < 0.6) && t.data.contains(&1.0));
    drop(coord);
    node.stop().await;
}

/// Khronos AlphaBlendModeTest (metallic-roughness, textured BLEND labels with an alpha gradient):
/// its peel 1 is the labels, each texel's eye transmittance grey (`1 − α · texture alpha` in every
/// channel) and spread over (0, 1) by the gradient, its material layers premultiplied (none
/// brighter than the classic frame's cut-out where both see the label).
#[test]
fn textured_coverage_peels_with_its_texture_alpha() {
    let gpu = gpu();
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../assets/AlphaBlendModeTest/AlphaBlendModeTest.gltf"
    );
    let mut scene =
        lightfold_scene::load_gltf(std::path::Path::new(path)).expect("AlphaBlendModeTest loads");
    assert!(scene.materials.iter().any(|m| m.pbr.is_some()));
    scene.lights = vec![lightfold_scene::Light {
        name: "sun-ish".into(),
        shape: lightfold_scene::LightShape::Point {
            position: [0.0, 3.0, 3.0],
        },
        color: [1.0; 3],
        power: 20.0,
        range: None,
        samples: 1,
    }];
    scene.camera = Camera {
        position: [0.0, 1.2, 4.5],
        target: [0.0, 0.6, 0.0],
        up: [0.0, 1.0, 0.0],
        fov_y_deg: 45.0,
        width: W,
        height: H,
    };
    let samples = samples(&scene);
    let mut r =
        Renderer::new(&gpu, &scene, RenderOptions::from_quality(&scene.quality)).expect("renderer");
    r.set_peel(Some(1));
    let f = r
        .render(&gpu, &samples, None, [1.0; 3], layers(Some(1)))
        .expect("peel 1");
    let tr = f.transmittance.as_ref().expect("T");
    let depth = f.depth.as_ref().expect("depth");
    let md = f.diffuse.as_ref().expect("m^d");
    let mut partial = 0;
    for i in 0..(W * H) as usize {
        let t = &tr.data[i * 3..i * 3 + 3];
        assert!(
            t.iter().all(|v| (0.0..=1.0).contains(v)),
            "pixel {i}: {t:?}"
        );
        assert!(
            t[0] == t[1] && t[1] == t[2],
            "pixel {i}: coverage T is grey, {t:?}"
        );
        if depth.data[i] == 0.0 {
            assert_eq!(t, [1.0; 3], "pixel {i} has no layer");
            assert_eq!(
                &md.data[i * 3..i * 3 + 3],
                [0.0; 3],
                "pixel {i} has no layer"
            );
        } else if t[0] > 0.05 && t[0] < 0.95 {
            partial += 1;
        }
    }
    eprintln!("{partial} pixels partly covered");
    assert!(partial > 200, "{partial} pixels partly covered");
    // The classic frame sees a label texel as a cut-out at α ≥ 0.5: there its m^d is the
    // uncovered colour, which the peeled layer scales by a = 1 − T ≤ 1.
    r.set_peel(None);
    let classic = r
        .render(&gpu, &samples, None, [1.0; 3], LayerSet::all())
        .expect("classic");
    let (cd, cz) = (classic.diffuse.unwrap(), classic.depth.unwrap());
    let mut checked = 0;
    for i in 0..(W * H) as usize {
        let (z, zc) = (depth.data[i], cz.data[i]);
        if z > 0.0 && (z - zc).abs() <= 1e-5 * zc {
            checked += 1;
            let a = 1.0 - tr.data[i * 3];
            for k in 0..3 {
                let (p, c) = (md.data[i * 3 + k], cd.data[i * 3 + k]);
                assert!(
                    (p - a * c).abs() <= 2e-3 * c + 1e-4,
                    "pixel {i} channel {k}: peeled {p}, a {a} × classic {c}"
                );
            }
        }
    }
    eprintln!("{checked} pixels where both see the label");
    assert!(checked > 100, "{checked}");
}

/// The CPU reference of peeled layers (`reference::render_peeled`, `Tracer::eye_layers`): each
/// GPU peel against its layer, T against its T, and the blend of the GPU peels against the
/// reference's composite; the classic frame as the back (its filters already multiplied in)
/// fails the same comparison (negative control).
#[test]
fn peels_match_the_peeled_reference() {
    let gpu = gpu();
    let t = truth();
    let scene = scene();
    let reference = lightfold_reference::render_peeled(&scene, &t.samples, [1.0; 3], 2);
    let mut r = renderer(&gpu);
    let peels: Vec<NodeFrame> = (0..=2)
        .map(|d| render_peel(&gpu, &mut r, Some(d)))
        .collect();
    for (d, frame) in peels.iter().enumerate() {
        let want = if d == 0 {
            &reference.opaque
        } else {
            &reference.layers[d - 1]
        };
        for (name, got, want) in [
            ("illumination", &frame.illumination, &want.illumination),
            ("m^d", &frame.diffuse, &want.diffuse),
            ("m^s", &frame.specular, &want.specular),
            ("m^a", &frame.ambient, &want.ambient),
            ("depth", &frame.depth, &want.depth),
        ] {
            let c = compare(got.as_ref().expect(name), want, &t.mask);
            eprintln!("peel {d} {name} against render_peeled: {c:?}");
            assert!(c.passes(), "peel {d} {name}: {c:?}");
        }
        if d >= 1 {
            let got = frame.transmittance.as_ref().expect("T");
            let want = &reference.transmittance[d - 1];
            // f16 targets: within 2.5e-4 of the reference everywhere compared.
            let off = (0..(W * H) as usize)
                .filter(|&i| t.mask[i])
                .filter(|&i| {
                    (0..3).any(|k| (got.data[i * 3 + k] - want.data[i * 3 + k]).abs() > 2.5e-4)
                })
                .count();
            assert_eq!(off, 0, "peel {d}: {off} pixels' T differ");
        }
    }
    // Peel 0 in both eye variants (the renderer's default, deferred, above); the translucent
    // peels are forward whatever the variant.
    r.set_variant(lightfold_node::gpu::EyeVariant::Forward);
    let forward = render_peel(&gpu, &mut r, Some(0));
    r.set_variant(lightfold_node::gpu::EyeVariant::Deferred);
    for (name, got, want) in [
        (
            "illumination",
            &forward.illumination,
            &reference.opaque.illumination,
        ),
        ("m^d", &forward.diffuse, &reference.opaque.diffuse),
        ("depth", &forward.depth, &reference.opaque.depth),
    ] {
        let c = compare(got.as_ref().expect(name), want, &t.mask);
        eprintln!("forward peel 0 {name} against render_peeled: {c:?}");
        assert!(c.passes(), "forward peel 0 {name}: {c:?}");
    }
    let (a, b) = (
        forward.illumination.as_ref().unwrap(),
        peels[0].illumination.as_ref().unwrap(),
    );
    let worst = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| (x - y).abs() / y.abs().max(1e-3))
        .fold(0.0f32, f32::max);
    eprintln!("peel 0 forward against deferred: worst relative difference {worst:e}");
    assert!(worst < 1e-4, "{worst}");
    assert!(forward.diffuse == peels[0].diffuse && forward.depth == peels[0].depth);
    let want = reference.radiance([1.0; 3], AMBIENT);
    let front: Vec<(Image, Image)> = [2, 1]
        .map(|d| {
            (
                radiance(&peels[d]),
                peels[d].transmittance.clone().expect("T"),
            )
        })
        .into();
    let pairs: Vec<(Image, &Image)> = front.iter().map(|(r, t)| (r.clone(), t)).collect();
    let got = blend(&radiance(&peels[0]), &pairs);
    let c = compare(&got, &want, &t.mask);
    eprintln!("blend of the GPU peels against render_peeled's composite: {c:?}");
    assert!(c.passes(), "{c:?}");
    let classic = render_peel(&gpu, &mut r, None);
    let n = compare(&blend(&radiance(&classic), &pairs), &want, &t.mask);
    eprintln!("classic back (double tint) against render_peeled: {n:?}");
    assert!(!n.passes(), "the classic back passed: {n:?}");
}
