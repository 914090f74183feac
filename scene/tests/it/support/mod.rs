//! A small test-only ray tracer over a scene's triangles (median-split BVH, alpha masks honoured)
//! used to measure shadow coverage of the built-in scenes and to write preview images. It is
//! deliberately independent of the `reference` crate, which the scene crate must not depend on.

use lightfold_scene::shading::{self, V3, add, cross, dot, normalize, scale, sub};
use lightfold_scene::{AlphaMode, Image, LightSample, Scene};

struct Tri {
    p0: V3,
    e1: V3,
    e2: V3,
    mesh: u32,
    first_index: u32,
}

#[derive(Clone, Copy)]
struct Node {
    lo: V3,
    hi: V3,
    /// Leaf: first triangle and count; inner: left child and 0 (right child = left + 1).
    start: u32,
    count: u32,
}

pub(crate) struct Tracer<'a> {
    scene: &'a Scene,
    tris: Vec<Tri>,
    nodes: Vec<Node>,
}

#[derive(Debug, Clone, Copy)]
pub(crate) struct Hit {
    pub t: f32,
    pub mesh: u32,
    pub first_index: u32,
    pub u: f32,
    pub v: f32,
}

impl<'a> Tracer<'a> {
    pub(crate) fn new(scene: &'a Scene) -> Self {
        let mut tris = Vec::new();
        for (mi, m) in scene.meshes.iter().enumerate() {
            for (k, t) in m.indices.chunks_exact(3).enumerate() {
                let p = |i: u32| m.positions[i as usize];
                let p0 = p(t[0]);
                tris.push(Tri {
                    p0,
                    e1: sub(p(t[1]), p0),
                    e2: sub(p(t[2]), p0),
                    mesh: mi as u32,
                    first_index: (k * 3) as u32,
                });
            }
        }
        let mut tracer = Tracer {
            scene,
            tris,
            nodes: Vec::new(),
        };
        let n = tracer.tris.len() as u32;
        tracer.nodes.push(Node {
            lo: [0.0; 3],
            hi: [0.0; 3],
            start: 0,
            count: n,
        });
        tracer.split(0);
        tracer
    }

    fn tri_bounds(t: &Tri) -> (V3, V3) {
        let a = t.p0;
        let b = add(t.p0, t.e1);
        let c = add(t.p0, t.e2);
        let lo = [0, 1, 2].map(|k| a[k].min(b[k]).min(c[k]));
        let hi = [0, 1, 2].map(|k| a[k].max(b[k]).max(c[k]));
        (lo, hi)
    }

    fn split(&mut self, node: usize) {
        let Node { start, count, .. } = self.nodes[node];
        let range = start as usize..(start + count) as usize;
        let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
        for t in &self.tris[range.clone()] {
            let (a, b) = Self::tri_bounds(t);
            for k in 0..3 {
                lo[k] = lo[k].min(a[k]);
                hi[k] = hi[k].max(b[k]);
            }
        }
        self.nodes[node].lo = lo;
        self.nodes[node].hi = hi;
        if count <= 4 {
            return;
        }
        let ext = sub(hi, lo);
        let axis = if ext[0] >= ext[1] && ext[0] >= ext[2] {
            0
        } else if ext[1] >= ext[2] {
            1
        } else {
            2
        };
        let centre = |t: &Tri| t.p0[axis] + (t.e1[axis] + t.e2[axis]) / 3.0;
        self.tris[range.clone()].sort_by(|a, b| centre(a).total_cmp(&centre(b)));
        let half = count / 2;
        let left = self.nodes.len();
        self.nodes.push(Node {
            lo,
            hi,
            start,
            count: half,
        });
        self.nodes.push(Node {
            lo,
            hi,
            start: start + half,
            count: count - half,
        });
        self.nodes[node].start = left as u32;
        self.nodes[node].count = 0;
        self.split(left);
        self.split(left + 1);
    }

    /// Nearest hit along `o + t·d`, `t ∈ (tmin, tmax)`; with `any` the first accepted hit.
    pub(crate) fn trace(&self, o: V3, d: V3, tmin: f32, tmax: f32, any: bool) -> Option<Hit> {
        let inv = d.map(|x| 1.0 / x);
        let mut best: Option<Hit> = None;
        let mut limit = tmax;
        let mut stack = vec![0usize];
        while let Some(n) = stack.pop() {
            let node = self.nodes[n];
            if !slab(node.lo, node.hi, o, inv, limit) {
                continue;
            }
            if node.count == 0 {
                stack.push(node.start as usize);
                stack.push(node.start as usize + 1);
                continue;
            }
            for t in &self.tris[node.start as usize..(node.start + node.count) as usize] {
                if let Some((dist, u, v)) = intersect(t, o, d)
                    && dist > tmin
                    && dist < limit
                {
                    let hit = Hit {
                        t: dist,
                        mesh: t.mesh,
                        first_index: t.first_index,
                        u,
                        v,
                    };
                    if !self.opaque_at(&hit) {
                        continue;
                    }
                    if any {
                        return Some(hit);
                    }
                    limit = dist;
                    best = Some(hit);
                }
            }
        }
        best
    }

    fn opaque_at(&self, hit: &Hit) -> bool {
        let m = &self.scene.meshes[hit.mesh as usize];
        let mat = &self.scene.materials[m.material];
        match mat.alpha_mode {
            AlphaMode::Opaque => true,
            AlphaMode::Mask { cutoff } => {
                let a = mat.alpha
                    * mat
                        .diffuse_texture
                        .map(|t| shading::sample_texture(&self.scene.textures[t], self.uv(hit))[3])
                        .unwrap_or(1.0);
                a >= cutoff
            }
        }
    }

    fn corners(&self, hit: &Hit) -> [usize; 3] {
        let m = &self.scene.meshes[hit.mesh as usize];
        let i = hit.first_index as usize;
        [
            m.indices[i] as usize,
            m.indices[i + 1] as usize,
            m.indices[i + 2] as usize,
        ]
    }

    pub(crate) fn uv(&self, hit: &Hit) -> [f32; 2] {
        let m = &self.scene.meshes[hit.mesh as usize];
        if m.uvs.is_empty() {
            return [0.0, 0.0];
        }
        let [a, b, c] = self.corners(hit).map(|k| m.uvs[k]);
        let w = 1.0 - hit.u - hit.v;
        [
            w * a[0] + hit.u * b[0] + hit.v * c[0],
            w * a[1] + hit.u * b[1] + hit.v * c[1],
        ]
    }

    /// Geometric normal of the hit triangle (unit, not flipped).
    pub(crate) fn geometric_normal(&self, hit: &Hit) -> V3 {
        let m = &self.scene.meshes[hit.mesh as usize];
        let [a, b, c] = self.corners(hit).map(|k| m.positions[k]);
        normalize(cross(sub(b, a), sub(c, a)))
    }
}

fn slab(lo: V3, hi: V3, o: V3, inv: V3, tmax: f32) -> bool {
    let (mut t0, mut t1) = (0.0f32, tmax);
    for k in 0..3 {
        let a = (lo[k] - o[k]) * inv[k];
        let b = (hi[k] - o[k]) * inv[k];
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    t0 <= t1
}

/// Möller–Trumbore.
fn intersect(t: &Tri, o: V3, d: V3) -> Option<(f32, f32, f32)> {
    let p = cross(d, t.e2);
    let det = dot(t.e1, p);
    if det.abs() < 1e-12 {
        return None;
    }
    let inv = 1.0 / det;
    let s = sub(o, t.p0);
    let u = dot(s, p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = cross(s, t.e1);
    let v = dot(d, q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    Some((dot(t.e2, q) * inv, u, v))
}

/// Per pixel of a `w×h` view: `None` for background, else whether some sample with non-zero
/// unshadowed irradiance is blocked (shadow or penumbra), and the shaded linear RGB.
pub(crate) struct View {
    pub shadowed: Vec<Option<bool>>,
    pub image: Image,
}

pub(crate) fn render(scene: &Scene, samples: &[LightSample], width: u32, height: u32) -> View {
    let tracer = Tracer::new(scene);
    let mut cam = scene.camera;
    cam.width = width;
    cam.height = height;
    let mut shadowed = Vec::with_capacity((width * height) as usize);
    let mut image = Image::new(width, height, 3);
    for y in 0..height {
        for x in 0..width {
            let d = cam.ray_dir(x as f32 + 0.5, y as f32 + 0.5);
            let Some(hit) = tracer.trace(cam.position, d, 1e-4, f32::INFINITY, false) else {
                shadowed.push(None);
                continue;
            };
            let p = add(cam.position, scale(d, hit.t));
            let mut n = tracer.geometric_normal(&hit);
            if dot(n, d) > 0.0 {
                n = scale(n, -1.0);
            }
            let mesh = &scene.meshes[hit.mesh as usize];
            let mat = &scene.materials[mesh.material];
            let tex = mat
                .diffuse_texture
                .map(|t| shading::sample_texture(&scene.textures[t], tracer.uv(&hit)))
                .unwrap_or([1.0; 4]);
            let albedo = [0, 1, 2].map(|k| mat.diffuse[k] * tex[k]);
            let origin = add(p, scale(n, 1e-3));
            let mut blocked = false;
            let mut rgb = mat.emissive;
            for s in samples {
                let e = shading::irradiance(s, origin, n);
                if e <= 0.0 {
                    continue;
                }
                let (l, r) = shading::to_light(s, origin);
                if tracer.trace(origin, l, 1e-4, r - 1e-3, true).is_some() {
                    blocked = true;
                } else {
                    for k in 0..3 {
                        rgb[k] += albedo[k] * s.color[k] * e / std::f32::consts::PI;
                    }
                }
            }
            shadowed.push(Some(blocked));
            image.pixel_mut(x, y).copy_from_slice(&rgb);
        }
    }
    View { shadowed, image }
}

impl View {
    /// Fraction of all pixels that are in shadow or penumbra.
    pub(crate) fn shadow_fraction(&self) -> f64 {
        let n = self.shadowed.iter().filter(|s| **s == Some(true)).count();
        n as f64 / self.shadowed.len() as f64
    }

    /// Mean linear luminance over the non-background pixels.
    pub(crate) fn mean_luminance(&self) -> f64 {
        let mut sum = 0.0;
        let mut n = 0;
        for (i, s) in self.shadowed.iter().enumerate() {
            if s.is_some() {
                let p = &self.image.data[i * 3..i * 3 + 3];
                sum += (0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]) as f64;
                n += 1;
            }
        }
        sum / n.max(1) as f64
    }
}
