//! Primitive meshes in world space: planes, boxes and spheres (scene files and built-in scenes
//! build from these).

use crate::model::Mesh;
use crate::shading::{V3, add, cross, normalize, scale};

/// A rectangle centred at `center` with unit `normal`, spanning `size[0]` along `u_axis` and
/// `size[1]` along `normal × u_axis`, split into `div×div` quads. Faces +normal (CCW seen from it).
pub fn plane(
    name: &str,
    center: V3,
    normal: V3,
    u_axis: V3,
    size: [f32; 2],
    div: u32,
    material: usize,
) -> Mesh {
    let n = normalize(normal);
    let u = normalize(u_axis);
    let v = cross(n, u);
    let div = div.max(1);
    let mut m = empty(name, material);
    for j in 0..=div {
        for i in 0..=div {
            let a = i as f32 / div as f32 - 0.5;
            let b = j as f32 / div as f32 - 0.5;
            m.positions.push(add(
                center,
                add(scale(u, a * size[0]), scale(v, b * size[1])),
            ));
            m.normals.push(n);
            m.uvs.push([a + 0.5, b + 0.5]);
        }
    }
    let row = div + 1;
    for j in 0..div {
        for i in 0..div {
            let k = j * row + i;
            // u × v = n, so (k, k+1, k+row) is counter-clockwise seen from +n.
            m.indices
                .extend_from_slice(&[k, k + 1, k + row + 1, k, k + row + 1, k + row]);
        }
    }
    m
}

/// An axis-aligned box with outward normals (24 vertices, flat faces).
pub fn cuboid(name: &str, center: V3, half: V3, material: usize) -> Mesh {
    let mut m = empty(name, material);
    let axes = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for (a, axis) in axes.iter().enumerate() {
        for sign in [1.0f32, -1.0] {
            let n = scale(*axis, sign);
            let u = scale(axes[(a + 1) % 3], sign);
            let v = cross(n, u);
            let hn = half[a];
            let hu = half[(a + 1) % 3];
            let hv = half[(a + 2) % 3];
            let c = add(center, scale(n, hn));
            let base = m.positions.len() as u32;
            for (su, sv) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                m.positions
                    .push(add(c, add(scale(u, su * hu), scale(v, sv * hv))));
                m.normals.push(n);
                m.uvs.push([(su + 1.0) * 0.5, (sv + 1.0) * 0.5]);
            }
            m.indices
                .extend_from_slice(&[base, base + 1, base + 2, base, base + 2, base + 3]);
        }
    }
    m
}

/// A UV sphere with smooth normals, `segments` around and `rings` from pole to pole.
pub fn sphere(
    name: &str,
    center: V3,
    radius: f32,
    segments: u32,
    rings: u32,
    material: usize,
) -> Mesh {
    let (segments, rings) = (segments.max(3), rings.max(2));
    let mut m = empty(name, material);
    for r in 0..=rings {
        let theta = std::f32::consts::PI * r as f32 / rings as f32;
        for s in 0..=segments {
            let phi = std::f32::consts::TAU * s as f32 / segments as f32;
            let n = [
                theta.sin() * phi.cos(),
                theta.cos(),
                -theta.sin() * phi.sin(),
            ];
            m.positions.push(add(center, scale(n, radius)));
            m.normals.push(n);
            m.uvs
                .push([s as f32 / segments as f32, r as f32 / rings as f32]);
        }
    }
    let row = segments + 1;
    for r in 0..rings {
        for s in 0..segments {
            let k = r * row + s;
            if r != 0 {
                m.indices.extend_from_slice(&[k, k + row, k + 1]);
            }
            if r != rings - 1 {
                m.indices.extend_from_slice(&[k + 1, k + row, k + row + 1]);
            }
        }
    }
    m
}

fn empty(name: &str, material: usize) -> Mesh {
    Mesh {
        name: name.to_string(),
        positions: Vec::new(),
        normals: Vec::new(),
        uvs: Vec::new(),
        indices: Vec::new(),
        material,
    }
}

impl Mesh {
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// Axis-aligned bounds `(min, max)` of the finite positions, or `None` for an empty mesh.
    pub fn bounds(&self) -> Option<(V3, V3)> {
        let mut it = self
            .positions
            .iter()
            .filter(|p| p.iter().all(|c| c.is_finite()));
        let first = *it.next()?;
        Some(it.fold((first, first), |(lo, hi), p| {
            (
                [lo[0].min(p[0]), lo[1].min(p[1]), lo[2].min(p[2])],
                [hi[0].max(p[0]), hi[1].max(p[1]), hi[2].max(p[2])],
            )
        }))
    }
}
