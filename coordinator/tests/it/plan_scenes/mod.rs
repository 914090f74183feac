//! Small scenes for the planner's tests: a fixed stage and random ones built from a seed.

use lightfold_scene::primitives::{cuboid, plane, sphere};
use lightfold_scene::sampling::SplitMix64;
use lightfold_scene::{Light, LightShape, Material, Scene};

pub(crate) const PALETTE: [[f32; 3]; 4] = [
    [1.0, 1.0, 1.0],
    [1.0, 0.8, 0.6],
    [0.6, 0.7, 1.0],
    [1.0, 0.2, 0.2],
];

pub(crate) fn rect(
    name: &str,
    center: [f32; 3],
    normal: [f32; 3],
    side: f32,
    color: [f32; 3],
    n: u32,
) -> Light {
    Light {
        name: name.to_string(),
        shape: LightShape::Rect {
            center,
            normal,
            u_axis: [1.0, 0.0, 0.0],
            size: [side, side],
        },
        color,
        power: 20.0,
        range: None,
        samples: n,
    }
}

/// A floor, a box and a ball under one downward rectangular light of 4 samples.
pub(crate) fn stage() -> Scene {
    let mut s = Scene::new("stage");
    let grey = s.add_material(Material::diffuse("grey", [0.7, 0.7, 0.7]));
    let red = s.add_material(Material::diffuse("red", [0.8, 0.2, 0.2]));
    s.add_mesh(plane(
        "floor",
        [0.0; 3],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [8.0, 8.0],
        1,
        grey,
    ));
    s.add_mesh(cuboid("box", [-0.8, 0.5, 0.0], [0.5, 0.5, 0.5], red));
    s.add_mesh(sphere("ball", [0.8, 0.6, 0.3], 0.6, 16, 8, grey));
    s.lights.push(rect(
        "key",
        [0.0, 3.0, 0.0],
        [0.0, -1.0, 0.0],
        1.0,
        [1.0; 3],
        4,
    ));
    s.camera.position = [0.0, 2.5, 6.0];
    s.camera.target = [0.0, 0.5, 0.0];
    s.camera.width = 64;
    s.camera.height = 48;
    s
}

fn pick<T: Copy>(rng: &mut SplitMix64, items: &[T]) -> T {
    items[(rng.next_u64() % items.len() as u64) as usize]
}

fn range(rng: &mut SplitMix64, lo: f32, hi: f32) -> f32 {
    lo + (hi - lo) * rng.next_f32()
}

/// A random small scene: a floor, 1–4 objects with random materials, 1–4 lights of every kind
/// (some aimed away, some with a short range, some black), optional ambient and emission.
pub(crate) fn random(seed: u64) -> Scene {
    let mut rng = SplitMix64(seed);
    let mut s = Scene::new(&format!("random-{seed}"));
    let spec = pick(&mut rng, &[[0.0; 3], [0.04; 3], [0.04; 3]]);
    let ambient_mode = rng.next_u64() % 3;
    let material = |rng: &mut SplitMix64, s: &mut Scene, i: usize| {
        let d = [
            range(rng, 0.1, 0.9),
            range(rng, 0.1, 0.9),
            range(rng, 0.1, 0.9),
        ];
        let mut m = Material::diffuse(&format!("m{i}"), d);
        m.specular = if rng.next_u64().is_multiple_of(4) {
            [0.5; 3]
        } else {
            spec
        };
        m.shininess = 32.0;
        m.ambient = match ambient_mode {
            0 => [0.0; 3],
            1 => d,
            _ => [0.2; 3],
        };
        if rng.next_u64().is_multiple_of(6) {
            m.emissive = [0.5, 0.4, 0.1];
        }
        s.add_material(m)
    };
    let floor = material(&mut rng, &mut s, 0);
    s.add_mesh(plane(
        "floor",
        [0.0; 3],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [10.0, 10.0],
        1,
        floor,
    ));
    let objects = 1 + rng.next_u64() % 4;
    for i in 0..objects {
        let m = material(&mut rng, &mut s, i as usize + 1);
        let c = [
            range(&mut rng, -3.0, 3.0),
            range(&mut rng, 0.3, 1.5),
            range(&mut rng, -3.0, 3.0),
        ];
        if rng.next_u64().is_multiple_of(2) {
            s.add_mesh(cuboid(&format!("box{i}"), c, [0.4, 0.4, 0.4], m));
        } else {
            s.add_mesh(sphere(&format!("ball{i}"), c, 0.5, 8, 6, m));
        }
    }
    // Far away behind the camera: never visible, still a possible caster.
    if rng.next_u64().is_multiple_of(2) {
        s.add_mesh(cuboid("hidden", [0.0, 1.0, 40.0], [1.0, 1.0, 1.0], floor));
    }
    let lights = 1 + rng.next_u64() % 4;
    for i in 0..lights {
        let color = if rng.next_u64().is_multiple_of(8) {
            [0.0; 3]
        } else {
            pick(&mut rng, &PALETTE)
        };
        let p = [
            range(&mut rng, -3.0, 3.0),
            range(&mut rng, 2.0, 5.0),
            range(&mut rng, -3.0, 3.0),
        ];
        let mut light = match rng.next_u64() % 5 {
            0 => {
                let up = rng.next_u64().is_multiple_of(4);
                let n = if up {
                    [0.0, 1.0, 0.0]
                } else {
                    [0.0, -1.0, 0.0]
                };
                rect(
                    &format!("rect{i}"),
                    p,
                    n,
                    1.0,
                    color,
                    1 + (rng.next_u64() % 6) as u32,
                )
            }
            1 => Light {
                name: format!("point{i}"),
                shape: LightShape::Point { position: p },
                color,
                power: 10.0,
                range: None,
                samples: 1,
            },
            2 => {
                let away = rng.next_u64().is_multiple_of(3);
                Light {
                    name: format!("spot{i}"),
                    shape: LightShape::Spot {
                        position: p,
                        direction: if away {
                            [0.0, 1.0, 0.0]
                        } else {
                            [0.0, -1.0, 0.0]
                        },
                        inner_angle: 0.3,
                        outer_angle: 0.5,
                    },
                    color,
                    power: 30.0,
                    range: None,
                    samples: 1,
                }
            }
            3 => Light {
                name: format!("sun{i}"),
                shape: LightShape::Directional {
                    direction: [range(&mut rng, -0.5, 0.5), -1.0, range(&mut rng, -0.5, 0.5)],
                    angle: 0.0,
                },
                color,
                power: 1.0,
                range: None,
                samples: 1,
            },
            _ => Light {
                name: format!("dim{i}"),
                shape: LightShape::Point {
                    position: [p[0], 8.0, p[2]],
                },
                color,
                power: 1e-4,
                range: None,
                samples: 1,
            },
        };
        if rng.next_u64().is_multiple_of(4) {
            light.range = Some(range(&mut rng, 0.5, 4.0));
        }
        s.lights.push(light);
    }
    if ambient_mode != 0 && rng.next_u64().is_multiple_of(2) {
        s.ambient = [0.05, 0.05, 0.05];
    }
    s.camera.position = [range(&mut rng, -2.0, 2.0), 3.0, 7.0];
    s.camera.target = [0.0, 0.5, 0.0];
    s.camera.width = 48;
    s.camera.height = 32;
    s.quality.samples_per_area_light = None;
    s
}
