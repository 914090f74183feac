//! The scene of case 7 (sub-texel occluders), generated in code: a 40 m yard, a crown of
//! `LEAVES` seeded 3×6 cm leaves, a 4 × 1.5 m fence of 3 mm wires on a 6 cm mesh, and a 0.5 m
//! lamp 25 m away at 55° elevation whose azimuth steps `LAMP_STEP` degrees a frame.

use lightfold_scene::primitives::{cuboid, plane};
use lightfold_scene::sampling::SplitMix64;
use lightfold_scene::shading::{add, cross, normalize, scale};
use lightfold_scene::{Camera, Light, LightShape, Material, Mesh, Scene};

/// Leaves in the crown.
pub(super) const LEAVES: usize = 4000;
/// Leaf size (m) and wire thickness and spacing (m).
const LEAF: [f32; 2] = [0.03, 0.06];
const WIRE: f32 = 0.003;
const WIRE_SPACING: f32 = 0.06;
/// The lamp: distance, elevation, first azimuth and step per frame (degrees).
const LAMP_DISTANCE: f32 = 25.0;
const LAMP_ELEVATION: f32 = 55.0;
const LAMP_AZIMUTH0: f32 = -2.0;
pub(super) const LAMP_STEP: f32 = 0.5;

/// The yard with leaves and fence, lamp at frame 0.
pub(super) fn scene(width: u32, height: u32) -> Scene {
    let mut s = Scene::new("hard-subtexel");
    let grey = s.add_material(Material::diffuse("ground", [0.8, 0.8, 0.8]));
    let leaf = s.add_material(Material::diffuse("leaf", [0.3, 0.55, 0.2]));
    let wire = s.add_material(Material::diffuse("wire", [0.6, 0.6, 0.6]));
    let (x, y) = ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
    s.add_mesh(plane("floor", [0.0; 3], y, x, [40.0, 40.0], 1, grey));
    s.add_mesh(leaves(leaf));
    s.add_mesh(fence(wire));
    s.lights = vec![lamp(0)];
    s.camera = Camera {
        position: [0.5, 8.0, -9.0],
        target: [0.3, 0.0, -1.8],
        up: y,
        fov_y_deg: 55.0,
        width,
        height,
    };
    s
}

/// The lamp at frame `t`: a 0.5 m square facing the yard's origin, 4 samples.
pub(super) fn lamp(t: usize) -> Light {
    let (az, el) = (
        (LAMP_AZIMUTH0 + LAMP_STEP * t as f32).to_radians(),
        LAMP_ELEVATION.to_radians(),
    );
    let dir = [az.sin() * el.cos(), el.sin(), az.cos() * el.cos()];
    Light {
        name: "lamp".into(),
        shape: LightShape::Rect {
            center: scale(dir, LAMP_DISTANCE),
            normal: scale(dir, -1.0),
            u_axis: [az.cos(), 0.0, -az.sin()],
            size: [0.5, 0.5],
        },
        color: [1.0; 3],
        power: 3000.0,
        range: None,
        samples: 4,
    }
}

/// `LEAVES` seeded 3×6 cm quads, uniform in an ellipsoid crown (centre (−2, 3.5, 0), radii
/// 1.5, 0.7, 1.5 m), each facing a random direction, in one double-sided mesh.
fn leaves(material: usize) -> Mesh {
    let mut rng = SplitMix64(7);
    let mut m = Mesh {
        name: "leaves".into(),
        positions: Vec::new(),
        normals: Vec::new(),
        uvs: Vec::new(),
        tangents: Vec::new(),
        indices: Vec::new(),
        material,
    };
    let mut unit = || 2.0 * rng.next_f32() - 1.0;
    while m.positions.len() < LEAVES * 4 {
        let p = [unit(), unit(), unit()];
        if p[0] * p[0] + p[1] * p[1] + p[2] * p[2] > 1.0 {
            continue;
        }
        let c = [-2.0 + 1.5 * p[0], 3.5 + 0.7 * p[1], 1.5 * p[2]];
        let n = normalize([unit(), unit(), unit()]);
        if n == [0.0; 3] || !n.iter().all(|v| v.is_finite()) {
            continue;
        }
        let helper = if n[1].abs() < 0.9 {
            [0.0, 1.0, 0.0]
        } else {
            [1.0, 0.0, 0.0]
        };
        let u = normalize(cross(helper, n));
        let v = cross(n, u);
        let base = m.positions.len() as u32;
        for (a, b) in [(-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)] {
            m.positions
                .push(add(c, add(scale(u, a * LEAF[0]), scale(v, b * LEAF[1]))));
            m.normals.push(n);
        }
        m.indices
            .extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
    }
    m
}

/// A 4 × 1.5 m fence of 3 mm square wires on a 6 cm mesh, in the plane z = 1 from x = 1.5 to 5.5
/// and y = 0.1 to 1.6, as one mesh.
fn fence(material: usize) -> Mesh {
    let (x0, x1, y0, y1, z) = (1.5f32, 5.5f32, 0.1f32, 1.6f32, 1.0f32);
    let h = 0.5 * WIRE;
    let mut parts = Vec::new();
    let columns = ((x1 - x0) / WIRE_SPACING).round() as usize;
    for k in 0..=columns {
        let x = x0 + k as f32 * WIRE_SPACING;
        parts.push(cuboid(
            "wire",
            [x, 0.5 * (y0 + y1), z],
            [h, 0.5 * (y1 - y0), h],
            material,
        ));
    }
    let rows = ((y1 - y0) / WIRE_SPACING).round() as usize;
    for k in 0..=rows {
        let y = y0 + k as f32 * WIRE_SPACING;
        parts.push(cuboid(
            "wire",
            [0.5 * (x0 + x1), y, z],
            [0.5 * (x1 - x0), h, h],
            material,
        ));
    }
    let mut m = Mesh {
        name: "fence".into(),
        positions: Vec::new(),
        normals: Vec::new(),
        uvs: Vec::new(),
        tangents: Vec::new(),
        indices: Vec::new(),
        material,
    };
    for p in parts {
        let base = m.positions.len() as u32;
        m.positions.extend(p.positions);
        m.normals.extend(p.normals);
        m.indices.extend(p.indices.iter().map(|i| i + base));
    }
    m
}
