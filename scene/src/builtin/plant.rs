//! "plant": a potted plant of a few hundred small alpha-masked leaves (one textured quad each)
//! on thin branches, in front of a wall, under two rectangular lights (2 × 16 samples). The leaf
//! shape lives only in the texture's alpha, so shadows must honour the mask.

use super::{camera, rect_light};
use crate::model::{AlphaMode, Material, Mesh, Scene, Texture};
use crate::primitives;
use crate::sampling::SplitMix64;
use crate::shading::{V3, add, cross, normalize, scale};
use glam::{Affine3A, Quat, Vec3};
use lightfold_protocol::srgb::srgb8;
use std::f32::consts::{PI, TAU};

const BRANCHES: u32 = 12;
const LEAVES_PER_BRANCH: u32 = 30;
const CROWN_LEAVES: u32 = 24;

pub(super) fn build() -> Scene {
    let mut s = Scene::new("plant");
    let floor = s.add_material(Material::diffuse("floor", [0.7, 0.68, 0.64]));
    let wall = s.add_material(Material::diffuse("wall", [0.8, 0.8, 0.78]));
    s.add_mesh(primitives::plane(
        "floor",
        [0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [12.0, 12.0],
        1,
        floor,
    ));
    s.add_mesh(primitives::plane(
        "wall",
        [0.0, 2.0, -1.2],
        [0.0, 0.0, 1.0],
        [1.0, 0.0, 0.0],
        [12.0, 4.0],
        1,
        wall,
    ));
    let pot = s.add_material(Material::diffuse("pot", [0.6, 0.28, 0.16]));
    let soil = s.add_material(Material::diffuse("soil", [0.18, 0.12, 0.08]));
    let wood = s.add_material(Material::diffuse("stem", [0.3, 0.42, 0.15]));
    s.add_mesh(primitives::cylinder("pot", [0.0; 3], 0.3, 0.42, 32, pot));
    s.add_mesh(primitives::cylinder("soil", [0.0; 3], 0.27, 0.43, 32, soil));

    s.textures.push(leaf_texture(64, 128));
    let leaf = s.add_material(Material {
        diffuse_texture: Some(s.textures.len() - 1),
        specular: [0.08; 3],
        shininess: 20.0,
        alpha_mode: AlphaMode::Mask { cutoff: 0.5 },
        double_sided: true,
        transmission: None,
        ..Material::diffuse("leaf", [1.0, 1.0, 1.0])
    });

    let mut rng = SplitMix64(0x1eaf);
    let base = [0.0, 0.43, 0.0];
    let top = [0.0, 1.75, 0.0];
    let mut stems = vec![branch_mesh(
        "stem",
        base,
        [0.0, 1.0, 0.0],
        1.32,
        0.018,
        wood,
    )];
    let mut leaves = empty_mesh("leaves", leaf);
    for b in 0..BRANCHES {
        let t = b as f32 / (BRANCHES - 1) as f32;
        let start = [0.0, 0.65 + 0.95 * t, 0.0];
        let azimuth = b as f32 * 2.399_963; // golden angle
        let elevation = (30.0 + 25.0 * t + 10.0 * rng.next_f32()).to_radians();
        let dir = [
            elevation.cos() * azimuth.cos(),
            elevation.sin(),
            elevation.cos() * azimuth.sin(),
        ];
        let length = 0.75 - 0.4 * t;
        stems.push(branch_mesh("branch", start, dir, length, 0.009, wood));
        for k in 0..LEAVES_PER_BRANCH {
            let f = 0.12 + 0.88 * (k as f32 + 0.5) / LEAVES_PER_BRANCH as f32;
            let at = add(start, scale(dir, f * length));
            let side = normalize(cross(dir, [0.0, 1.0, 0.0]));
            let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
            add_leaf(&mut leaves, at, dir, scale(side, sign), &mut rng);
        }
    }
    for k in 0..CROWN_LEAVES {
        let a = k as f32 * 2.399_963;
        let out = [a.cos(), 0.0, a.sin()];
        add_leaf(&mut leaves, top, [0.0, 1.0, 0.0], out, &mut rng);
    }
    for m in stems {
        s.add_mesh(m);
    }
    s.add_mesh(leaves);

    s.lights = vec![
        rect_light(
            "key",
            [-2.0, 3.4, 2.2],
            [0.0, 0.9, -0.3],
            1.0,
            40.0,
            [1.0, 0.95, 0.85],
        ),
        rect_light(
            "fill",
            [2.6, 2.8, 1.2],
            [0.0, 0.9, -0.3],
            1.0,
            20.0,
            [0.85, 0.9, 1.0],
        ),
    ];
    s.camera = camera([0.3, 1.5, 3.8], [0.0, 1.05, 0.0], 38.0);
    s
}

/// One leaf: a textured quad growing from `at`, pointing between the branch direction `along`
/// and the sideways direction `out`, with some random tilt and size.
fn add_leaf(m: &mut Mesh, at: V3, along: V3, out: V3, rng: &mut SplitMix64) {
    let mix = 0.45 + 0.3 * rng.next_f32();
    let droop = -0.25 + 0.5 * rng.next_f32();
    let axis = normalize(add(
        add(scale(along, 1.0 - mix), scale(out, mix)),
        [0.0, droop, 0.0],
    ));
    let length = 0.14 + 0.08 * rng.next_f32();
    let width = 0.5 * length;
    // The blade's width direction: perpendicular to the axis, rolled by a random angle.
    let side0 = normalize(cross(axis, [0.0, 1.0, 0.0]));
    let side0 = if side0 == [0.0; 3] {
        [1.0, 0.0, 0.0]
    } else {
        side0
    };
    let roll = (rng.next_f32() - 0.5) * PI * 0.6;
    let q = Quat::from_axis_angle(Vec3::from(axis), roll);
    let w = (q * Vec3::from(side0)).to_array();
    let normal = normalize(cross(w, axis));
    let half = scale(w, 0.5 * width);
    let tip = add(at, scale(axis, length));
    let first = m.positions.len() as u32;
    for (p, uv) in [
        (add(at, scale(half, -1.0)), [0.0, 0.0]),
        (add(at, half), [1.0, 0.0]),
        (add(tip, half), [1.0, 1.0]),
        (add(tip, scale(half, -1.0)), [0.0, 1.0]),
    ] {
        m.positions.push(p);
        m.normals.push(normal);
        m.uvs.push(uv);
    }
    m.indices
        .extend_from_slice(&[first, first + 1, first + 2, first, first + 2, first + 3]);
}

/// A thin cylinder from `start` along unit `dir`.
fn branch_mesh(name: &str, start: V3, dir: V3, length: f32, radius: f32, material: usize) -> Mesh {
    let mut m = primitives::cylinder(name, [0.0; 3], radius, length, 6, material);
    let rot = Quat::from_rotation_arc(Vec3::Y, Vec3::from(dir));
    m.transform(&Affine3A::from_rotation_translation(rot, Vec3::from(start)));
    m
}

fn empty_mesh(name: &str, material: usize) -> Mesh {
    Mesh {
        name: name.to_string(),
        positions: Vec::new(),
        normals: Vec::new(),
        uvs: Vec::new(),
        tangents: Vec::new(),
        indices: Vec::new(),
        material,
    }
}

/// A leaf blade in sRGB RGBA8: opaque inside a pointed outline with a light midrib, transparent
/// outside. `v` runs from the stalk (0) to the tip (1).
fn leaf_texture(width: u32, height: u32) -> Texture {
    let mut rgba8 = Vec::with_capacity((width * height * 4) as usize);
    for y in 0..height {
        let v = (y as f32 + 0.5) / height as f32;
        for x in 0..width {
            let u = (x as f32 + 0.5) / width as f32;
            let d = (u - 0.5).abs();
            let blade = 0.48 * ((v - 0.08).max(0.0) / 0.92 * PI).sin().powf(0.7);
            let stalk = v < 0.1 && d < 0.04;
            let inside = stalk || d < blade;
            let vein = d < 0.018 || ((v * 9.0 + d * 6.0) % 1.0 < 0.06 && d < blade * 0.8);
            let shade = 0.75 + 0.25 * (v * TAU).sin().abs();
            let lin: V3 = if vein {
                [0.35, 0.55, 0.18]
            } else {
                [0.1 * shade, 0.4 * shade, 0.08 * shade]
            };
            for c in lin {
                rgba8.push(srgb8(c));
            }
            rgba8.push(if inside { 255 } else { 0 });
        }
    }
    Texture {
        name: "leaf".to_string(),
        width,
        height,
        srgb: true,
        rgba8,
    }
}
