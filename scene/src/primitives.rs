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
        tangents: Vec::new(),
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

/// A closed cylinder standing on `base` along +Y with `segments` sides (flat caps, smooth sides).
pub fn cylinder(
    name: &str,
    base: V3,
    radius: f32,
    height: f32,
    segments: u32,
    material: usize,
) -> Mesh {
    let segments = segments.max(3);
    let mut m = empty(name, material);
    let ring = |k: u32| {
        let phi = std::f32::consts::TAU * k as f32 / segments as f32;
        [phi.cos(), 0.0, -phi.sin()]
    };
    // Sides: two vertices per column so the seam gets its own uv.
    for k in 0..=segments {
        let n = ring(k);
        for y in [0.0, height] {
            m.positions
                .push(add(base, add(scale(n, radius), [0.0, y, 0.0])));
            m.normals.push(n);
            m.uvs
                .push([k as f32 / segments as f32, y / height.max(1e-6)]);
        }
    }
    for k in 0..segments {
        let (b0, t0, b1, t1) = (2 * k, 2 * k + 1, 2 * k + 2, 2 * k + 3);
        m.indices.extend_from_slice(&[b0, b1, t1, b0, t1, t0]);
    }
    // Caps: a centre vertex fanned to the rim.
    for (y, n) in [(height, [0.0, 1.0, 0.0]), (0.0, [0.0, -1.0, 0.0])] {
        let centre = m.positions.len() as u32;
        m.positions.push(add(base, [0.0, y, 0.0]));
        m.normals.push(n);
        m.uvs.push([0.5, 0.5]);
        for k in 0..segments {
            let r = ring(k);
            m.positions
                .push(add(base, add(scale(r, radius), [0.0, y, 0.0])));
            m.normals.push(n);
            m.uvs.push([0.5 + 0.5 * r[0], 0.5 - 0.5 * r[2]]);
        }
        for k in 0..segments {
            let a = centre + 1 + k;
            let b = centre + 1 + (k + 1) % segments;
            if n[1] > 0.0 {
                m.indices.extend_from_slice(&[centre, a, b]);
            } else {
                m.indices.extend_from_slice(&[centre, b, a]);
            }
        }
    }
    m
}

impl Mesh {
    /// Applies an affine transform in place: positions by `m`, normals by its inverse transpose
    /// (renormalised), tangents' directions by its linear part (renormalised; a mirror flips
    /// their handedness), and the winding is flipped when `m` mirrors (negative determinant) so
    /// that counter-clockwise stays front-facing.
    pub fn transform(&mut self, m: &glam::Affine3A) {
        let normal_matrix = glam::Mat3::from(m.matrix3).inverse().transpose();
        for p in &mut self.positions {
            *p = m.transform_point3(glam::Vec3::from(*p)).to_array();
        }
        for n in &mut self.normals {
            *n = normalize((normal_matrix * glam::Vec3::from(*n)).to_array());
        }
        let mirrored = m.matrix3.determinant() < 0.0;
        for t in &mut self.tangents {
            let d = normalize((m.matrix3 * glam::Vec3A::new(t[0], t[1], t[2])).to_array());
            // A mirror turns the bitangent `w·(n × t)` round: its handedness flips.
            *t = [d[0], d[1], d[2], if mirrored { -t[3] } else { t[3] }];
        }
        if mirrored {
            for t in self.indices.chunks_exact_mut(3) {
                t.swap(1, 2);
            }
        }
    }
}
