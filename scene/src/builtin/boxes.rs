//! "box": boxes, a table and a tall pillar in front of a wall, under a high light and a low lamp
//! hanging beside the pillar (2 × 16 samples). The lamp's samples see the pillar at grazing angles,
//! outside a 90° cone about their axis, where it still shadows the far floor.

use super::{camera, rect_light, shiny};
use crate::model::{Material, Scene};
use crate::primitives;

/// Centre and half extents of the pillar beside the low lamp (tests look for it).
pub(crate) const PILLAR: ([f32; 3], [f32; 3]) = ([1.4, 1.3, -0.6], [0.25, 1.3, 0.25]);

pub(super) fn build() -> Scene {
    let mut s = Scene::new("box");
    let floor = s.add_material(Material::diffuse("floor", [0.72, 0.72, 0.7]));
    let wall = s.add_material(Material::diffuse("wall", [0.78, 0.76, 0.7]));
    s.add_mesh(primitives::plane(
        "floor",
        [0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [16.0, 16.0],
        1,
        floor,
    ));
    s.add_mesh(primitives::plane(
        "wall",
        [0.0, 2.5, -2.6],
        [0.0, 0.0, 1.0],
        [1.0, 0.0, 0.0],
        [16.0, 5.0],
        1,
        wall,
    ));
    let crate_mat = s.add_material(Material::diffuse("crate", [0.7, 0.5, 0.3]));
    let blue = s.add_material(shiny("blue", [0.2, 0.3, 0.7], 0.2, 40.0));
    let red = s.add_material(Material::diffuse("red", [0.75, 0.2, 0.15]));
    let grey = s.add_material(shiny("grey", [0.5, 0.5, 0.52], 0.3, 80.0));
    let boxes: [(&str, [f32; 3], [f32; 3], usize); 6] = [
        ("pillar", PILLAR.0, PILLAR.1, grey),
        ("crate", [-1.3, 0.4, -0.3], [0.6, 0.4, 0.5], crate_mat),
        ("crate top", [-1.2, 1.05, -0.2], [0.3, 0.25, 0.3], red),
        ("cube", [0.2, 0.35, 0.9], [0.35, 0.35, 0.35], blue),
        ("slab", [-2.6, 0.1, 1.2], [0.5, 0.1, 0.7], red),
        ("block", [2.6, 0.3, 1.3], [0.3, 0.3, 0.6], crate_mat),
    ];
    for (name, c, h, m) in boxes {
        s.add_mesh(primitives::cuboid(name, c, h, m));
    }
    // A table: top and four legs.
    let table = s.add_material(Material::diffuse("table", [0.55, 0.4, 0.28]));
    let (tx, tz) = (-0.2, -1.4);
    s.add_mesh(primitives::cuboid(
        "table top",
        [tx, 0.78, tz],
        [0.8, 0.04, 0.45],
        table,
    ));
    for (dx, dz) in [(-0.72, -0.38), (0.72, -0.38), (-0.72, 0.38), (0.72, 0.38)] {
        s.add_mesh(primitives::cuboid(
            "table leg",
            [tx + dx, 0.37, tz + dz],
            [0.04, 0.37, 0.04],
            table,
        ));
    }
    let mut lamp = rect_light(
        "lamp",
        [2.3, 1.5, -0.6],
        [2.3, 0.0, -0.6],
        0.5,
        40.0,
        [1.0, 0.85, 0.65],
    );
    lamp.name = "low lamp".into();
    s.lights = vec![
        rect_light(
            "sky",
            [-2.5, 4.5, 3.0],
            [0.0, 0.0, -0.6],
            1.4,
            30.0,
            [0.9, 0.95, 1.0],
        ),
        lamp,
    ];
    s.camera = camera([0.6, 3.2, 7.2], [0.0, 0.6, -0.4], 42.0);
    s
}
