//! "cornell": the Cornell box (2 m room, red left wall, green right wall, two rotated boxes) lit by
//! one ceiling area light of 32 samples. An emissive panel just above the light's plane makes the
//! light visible without occluding it (it lies behind the one-sided lobes).

use super::camera;
use crate::model::{Light, LightShape, Material, Scene};
use crate::primitives;
use glam::{Affine3A, Quat, Vec3};

/// Radiance of the ceiling light (W/(sr·m²)).
const RADIANCE: f32 = 40.0;
const LIGHT_COLOR: [f32; 3] = [1.0, 0.85, 0.6];

pub(super) fn build() -> Scene {
    let mut s = Scene::new("cornell");
    let white = s.add_material(Material::diffuse("white", [0.73, 0.73, 0.73]));
    let red = s.add_material(Material::diffuse("red", [0.63, 0.065, 0.05]));
    let green = s.add_material(Material::diffuse("green", [0.14, 0.45, 0.09]));
    // (name, centre, inward normal, u axis, material)
    let walls = [
        (
            "floor",
            [0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
            white,
        ),
        (
            "ceiling",
            [0.0, 2.0, 0.0],
            [0.0, -1.0, 0.0],
            [1.0, 0.0, 0.0],
            white,
        ),
        (
            "back",
            [0.0, 1.0, -1.0],
            [0.0, 0.0, 1.0],
            [1.0, 0.0, 0.0],
            white,
        ),
        (
            "left",
            [-1.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0],
            red,
        ),
        (
            "right",
            [1.0, 1.0, 0.0],
            [-1.0, 0.0, 0.0],
            [0.0, 0.0, -1.0],
            green,
        ),
    ];
    for (name, c, n, u, m) in walls {
        s.add_mesh(primitives::plane(name, c, n, u, [2.0, 2.0], 1, m));
    }
    for (name, centre, half, angle) in [
        ("short box", [0.33, 0.3, 0.28], [0.3, 0.3, 0.3], -17.0f32),
        ("tall box", [-0.34, 0.6, -0.3], [0.3, 0.6, 0.3], 17.0),
    ] {
        let mut m = primitives::cuboid(name, [0.0; 3], half, white);
        m.transform(&Affine3A::from_rotation_translation(
            Quat::from_rotation_y(angle.to_radians()),
            Vec3::from(centre),
        ));
        s.add_mesh(m);
    }
    let size = [0.5, 0.4];
    let panel = s.add_material(Material {
        emissive: [
            RADIANCE * LIGHT_COLOR[0],
            RADIANCE * LIGHT_COLOR[1],
            RADIANCE * LIGHT_COLOR[2],
        ],
        double_sided: false,
        transmission: None,
        ..Material::diffuse("light panel", [0.0; 3])
    });
    s.add_mesh(primitives::plane(
        "light panel",
        [0.0, 1.998, 0.0],
        [0.0, -1.0, 0.0],
        [1.0, 0.0, 0.0],
        size,
        1,
        panel,
    ));
    s.lights = vec![Light {
        name: "ceiling".into(),
        shape: LightShape::Rect {
            center: [0.0, 1.995, 0.0],
            normal: [0.0, -1.0, 0.0],
            u_axis: [1.0, 0.0, 0.0],
            size,
        },
        color: LIGHT_COLOR,
        power: RADIANCE,
        range: None,
        samples: 32,
    }];
    s.camera = camera([0.0, 1.0, 3.9], [0.0, 1.0, 0.0], 38.0);
    s
}
