//! "balls": diffuse and glossy spheres on a ground plane under two coloured rectangular lights
//! (2 × 16 samples), the default scene.

use super::{camera, rect_light, shiny};
use crate::model::{Material, Scene};
use crate::primitives;

pub(super) fn build() -> Scene {
    let mut s = Scene::new("balls");
    let ground = s.add_material(Material::diffuse("ground", [0.75, 0.75, 0.72]));
    s.add_mesh(primitives::plane(
        "ground",
        [0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [16.0, 16.0],
        1,
        ground,
    ));
    // (centre x, z, radius, colour, specular)
    let balls: [(f32, f32, f32, [f32; 3], f32); 7] = [
        (-1.6, 0.2, 0.6, [0.75, 0.18, 0.12], 0.25),
        (0.1, -0.9, 0.8, [0.18, 0.32, 0.75], 0.0),
        (1.5, 0.5, 0.5, [0.8, 0.62, 0.18], 0.3),
        (0.35, 1.3, 0.35, [0.22, 0.62, 0.28], 0.0),
        (-0.6, 1.7, 0.28, [0.85, 0.85, 0.85], 0.5),
        (2.5, -1.4, 0.7, [0.55, 0.25, 0.65], 0.2),
        (-2.5, -1.3, 0.45, [0.85, 0.45, 0.12], 0.0),
    ];
    for (i, (x, z, r, colour, spec)) in balls.into_iter().enumerate() {
        let name = format!("ball{i}");
        let m = if spec > 0.0 {
            shiny(&name, colour, spec, 60.0)
        } else {
            Material::diffuse(&name, colour)
        };
        let m = s.add_material(m);
        s.add_mesh(primitives::sphere(&name, [x, r, z], r, 48, 24, m));
    }
    s.lights = vec![
        rect_light(
            "warm",
            [-3.6, 2.5, 0.8],
            [0.0, 0.0, -0.5],
            1.2,
            30.0,
            [1.0, 0.92, 0.8],
        ),
        rect_light(
            "cool",
            [3.8, 2.9, -0.2],
            [0.0, 0.0, -0.5],
            1.2,
            30.0,
            [0.8, 0.9, 1.0],
        ),
    ];
    s.camera = camera([0.0, 3.0, 7.0], [0.0, 0.5, 0.0], 40.0);
    s
}
