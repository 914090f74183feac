//! Eq. 7's ambient mask (`Layer::AmbientMask`, `gpu::ambient_mask`) on the device, against the
//! scene's materials: per channel exactly 1 where the material has `m^a = m^d`, exactly 0 where
//! `m^a = 0` (untextured or not), for Blinn-Phong materials mixing both per channel and a
//! metallic-roughness material without an occlusion texture (whose `m^a` is its `m^d`). A glass
//! filter in front tints m^d and m^a alike and leaves the mask as it is. Negative controls: the
//! eq. 6 rule (`I^a = 1` everywhere) fails the same check, and the pane does change m^d.

use crate::gpu_support;

use gpu_support::gpu;
use lightfold_node::gpu::{EyeVariant, Gpu, LayerSet, NodeFrame, RenderOptions, Renderer};
use lightfold_scene::primitives::{cuboid, plane, sphere};
use lightfold_scene::{Camera, Material, MetallicRoughness, Scene, Texture, Transmission};

const W: u32 = 96;
const H: u32 = 72;

/// Floor (`m^a = m^d`), box (`m^a = 0`), ball (`m^a = m^d` in red and blue, 0 in green), a
/// metallic-roughness block, and a checker-textured slab with `m^a = 0`.
fn scene() -> Scene {
    let mut s = Scene::new("ambient-mask");
    s.ambient = [0.3, 0.3, 0.3];
    let mut floor = Material::diffuse("floor", [0.7, 0.55, 0.35]);
    floor.ambient = floor.diffuse;
    let boxed = Material::diffuse("box", [0.2, 0.6, 0.4]);
    let mut ball = Material::diffuse("ball", [0.9, 0.3, 0.5]);
    ball.ambient = [0.9, 0.0, 0.5];
    let pbr =
        Material::metallic_roughness("pbr", MetallicRoughness::new([0.3, 0.4, 0.8], 0.0, 0.5));
    s.textures.push(Texture {
        name: "checker".into(),
        width: 2,
        height: 2,
        srgb: true,
        rgba8: vec![
            255, 255, 255, 255, 40, 90, 160, 255, 40, 90, 160, 255, 255, 255, 255, 255,
        ],
    });
    let mut slab = Material::diffuse("slab", [0.8, 0.8, 0.8]);
    slab.diffuse_texture = Some(0);
    let [floor, boxed, ball, pbr, slab] =
        [floor, boxed, ball, pbr, slab].map(|m| s.add_material(m));
    s.add_mesh(plane(
        "floor",
        [0.0; 3],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [8.0, 8.0],
        1,
        floor,
    ));
    s.add_mesh(cuboid("box", [-1.3, 0.5, 0.0], [0.45, 0.5, 0.45], boxed));
    s.add_mesh(sphere("ball", [0.0, 0.6, 0.2], 0.6, 24, 12, ball));
    s.add_mesh(cuboid("pbr", [1.3, 0.4, 0.0], [0.4, 0.4, 0.4], pbr));
    s.add_mesh(cuboid("slab", [0.0, 0.1, 1.6], [1.2, 0.1, 0.3], slab));
    s.camera = Camera {
        position: [0.0, 2.2, 5.5],
        target: [0.0, 0.4, 0.0],
        up: [0.0, 1.0, 0.0],
        fov_y_deg: 45.0,
        width: W,
        height: H,
    };
    s
}

/// `scene` with a green glass pane (a filter) in front of the ball and the block.
fn behind_glass() -> Scene {
    let mut s = scene();
    let mut glass = Material::diffuse("glass", [0.0; 3]);
    glass.transmission = Some(Transmission {
        color: [0.6, 0.9, 0.7],
        coverage: false,
    });
    let glass = s.add_material(glass);
    s.add_mesh(plane(
        "pane",
        [0.7, 0.8, 2.6],
        [0.0, 0.0, 1.0],
        [1.0, 0.0, 0.0],
        [1.6, 1.6],
        1,
        glass,
    ));
    s
}

fn render(gpu: &Gpu, scene: &Scene, variant: EyeVariant) -> NodeFrame {
    let mut r =
        Renderer::new(gpu, scene, RenderOptions::from_quality(&scene.quality)).expect("renderer");
    r.set_variant(variant);
    let layers = LayerSet {
        diffuse: true,
        ambient: true,
        depth: true,
        ambient_mask: true,
        ..Default::default()
    };
    r.render(gpu, &[], None, [1.0; 3], layers).expect("render")
}

/// Per covered pixel, the expected mask under `rule` (per material: its m^d and m^a as the
/// scene has them, the slab's m^d varying under its texture) for the material whose untextured
/// m^d the pixel shows (the slab where none does); mismatched channels and pixels per material.
fn check(
    scene: &Scene,
    frame: &NodeFrame,
    rule: impl Fn(&Material, usize) -> f32,
) -> (usize, Vec<usize>) {
    let md = frame.diffuse.as_ref().expect("m^d");
    let mask = frame.ambient_mask.as_ref().expect("I^a");
    let depth = frame.depth.as_ref().expect("depth");
    let mut seen = vec![0; scene.materials.len()];
    let mut wrong = 0;
    let slab = scene
        .materials
        .iter()
        .position(|m| m.diffuse_texture.is_some())
        .expect("a textured material");
    for i in 0..md.pixel_count() {
        if depth.data[i] <= 0.0 {
            continue;
        }
        let d = &md.data[i * 3..i * 3 + 3];
        let near = |m: &Material| (0..3).all(|c| (m.diffuse[c] - d[c]).abs() < 4e-3);
        let k = scene
            .materials
            .iter()
            .position(|m| m.diffuse_texture.is_none() && !m.is_filter() && near(m))
            .unwrap_or(slab);
        seen[k] += 1;
        for c in 0..3 {
            if mask.data[i * 3 + c].to_bits() != rule(&scene.materials[k], c).to_bits() {
                wrong += 1;
            }
        }
    }
    (wrong, seen)
}

/// The mask eq. 7 renders for material `m`'s channel `c`.
fn eq7(m: &Material, c: usize) -> f32 {
    if m.ambient[c] == 0.0 || m.diffuse[c] == 0.0 {
        0.0
    } else {
        1.0
    }
}

#[test]
fn the_ambient_mask_is_one_where_ma_is_md_and_zero_where_ma_is_zero() {
    let gpu = gpu();
    let s = scene();
    for variant in [EyeVariant::Deferred, EyeVariant::Forward] {
        let frame = render(&gpu, &s, variant);
        let (wrong, seen) = check(&s, &frame, eq7);
        eprintln!("{variant:?}: pixels per material {seen:?}, {wrong} channels off the mask");
        assert!(
            seen.iter().all(|&n| n > 40),
            "every material seen: {seen:?}"
        );
        assert_eq!(wrong, 0, "{variant:?}");
        // The control: eq. 6's I^a = 1 is wrong wherever m^a = 0.
        let (wrong, _) = check(&s, &frame, |_, _| 1.0);
        assert!(wrong > 500, "eq. 6's rule is off in only {wrong} channels");
        // The mask is not the m^a layer itself.
        let (ma, mask) = (
            frame.ambient.as_ref().unwrap(),
            frame.ambient_mask.as_ref().unwrap(),
        );
        assert_ne!(ma.data, mask.data);
    }
    // Behind a glass filter m^d and m^a are tinted alike; the mask stays.
    let glass = behind_glass();
    let (plain, tinted) = (
        render(&gpu, &s, EyeVariant::Deferred),
        render(&gpu, &glass, EyeVariant::Deferred),
    );
    let (a, b) = (plain.diffuse.unwrap(), tinted.diffuse.unwrap());
    let changed = a
        .data
        .iter()
        .zip(&b.data)
        .filter(|(x, y)| (*x - *y).abs() > 0.01)
        .count();
    assert!(
        changed > 300,
        "the pane tints only {changed} channels of m^d"
    );
    assert_eq!(
        plain.ambient_mask.unwrap().data,
        tinted.ambient_mask.unwrap().data,
        "the mask behind glass"
    );
}
