//! Ray tracing of a scene for the CPU reference: primary hits through pixel centres with the
//! surface attributes shading needs, and shadow visibility towards a point-light sample.
//!
//! Conventions the GPU renderer must match: eye rays skip the back faces of single-sided
//! materials; a back-face hit on a double-sided material negates both normals (like WGSL's
//! `front_facing`); the shading normal is the interpolated vertex normal, or the geometric normal
//! when that is missing or degenerate, then bent by a metallic-roughness material's normal map
//! (`shading::mapped_normal`, on the front face before the flip); alpha-masked texels below the
//! cutoff are transparent to eye and shadow rays alike; every other triangle casts shadows
//! whatever its sidedness.
//!
//! Peeled eye rays ([`Tracer::eye_layers`], `docs/translucency.md`) split that: the opaque layer
//! is the nearest surface that is not translucent; the translucent surfaces in front of it are
//! layers of their own, nearest first, each covering by [`shading::eye_cover`] (a coverage
//! material is never cut out by its mask there).

use crate::bvh::{Bvh, Hit};
use crate::shading::{self, EyeCover, V3, dot, normalize, sample_texture};
use crate::{AlphaMode, LightSample, Material, SampleKind, Scene};

/// Shadow-ray origin offset and end shortening, relative to the scene's bounding diagonal.
const EPSILON_REL: f64 = 1e-5;

/// Where a primary ray met the scene, with everything shading needs.
#[derive(Debug, Clone, Copy)]
pub struct SurfaceHit {
    /// World position (f64 keeps shadow-ray origins clean).
    pub position: [f64; 3],
    /// Unit geometric normal on the viewer's side.
    pub geometric_normal: V3,
    /// Unit shading normal (flipped with the geometric one for back faces).
    pub normal: V3,
    /// Unit direction from the surface to the viewer.
    pub to_viewer: V3,
    /// Eye-space depth: distance along the camera's forward axis.
    pub depth: f32,
    pub uv: [f32; 2],
    pub material: usize,
}

impl SurfaceHit {
    pub fn position_f32(&self) -> V3 {
        self.position.map(|c| c as f32)
    }
}

/// An eye ray peeled into layers ([`Tracer::eye_layers`]).
#[derive(Debug, Clone, Default)]
pub struct EyeLayers {
    /// The nearest surface that is not translucent (layer 0), `None` where the ray meets none.
    pub opaque: Option<SurfaceHit>,
    /// The translucent surfaces in front of it, nearest first.
    pub translucent: Vec<TranslucentHit>,
}

/// One translucent layer of an eye ray: the surface, shaded like any other, and what the eye
/// sees of it there.
#[derive(Debug, Clone, Copy)]
pub struct TranslucentHit {
    pub surface: SurfaceHit,
    /// Its coverage `a` (its material layers' factor) and transmittance `T` at the hit.
    pub cover: EyeCover,
}

/// Per-triangle data, indexed by the BVH triangle id.
#[derive(Debug, Clone, Copy)]
struct TriInfo {
    mesh: u32,
    first_index: u32,
}

/// The traced scene: a BVH over every mesh triangle plus the lookups shading needs.
#[derive(Debug)]
pub struct Tracer<'a> {
    scene: &'a Scene,
    bvh: Bvh,
    tris: Vec<TriInfo>,
    /// Absolute epsilon for shadow-ray offsets (scene diagonal × `EPSILON_REL`).
    epsilon: f64,
    /// Whether any material lets light through (shadow rays then carry a transmittance).
    translucent: bool,
    /// Whether any is a filter, which eye rays see through (`docs/translucency.md`).
    filters: bool,
}

impl<'a> Tracer<'a> {
    /// Builds the BVH over every triangle of every mesh; out-of-range indices and degenerate
    /// triangles are skipped (they cannot be hit).
    pub fn new(scene: &'a Scene) -> Self {
        let mut tris = Vec::new();
        let mut verts = Vec::new();
        for (m, mesh) in scene.meshes.iter().enumerate() {
            for (k, idx) in mesh.indices.chunks_exact(3).enumerate() {
                let get = |i: u32| mesh.positions.get(i as usize).copied();
                if let (Some(a), Some(b), Some(c)) = (get(idx[0]), get(idx[1]), get(idx[2])) {
                    verts.push([a, b, c]);
                    tris.push(TriInfo {
                        mesh: m as u32,
                        first_index: (k * 3) as u32,
                    });
                }
            }
        }
        let bvh = Bvh::build(&verts);
        let diag = bvh.bounds().map_or(1.0, |(lo, hi)| {
            let d = [0, 1, 2].map(|k| f64::from(hi[k]) - f64::from(lo[k]));
            (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
        });
        let epsilon = EPSILON_REL * diag.max(1e-3);
        Tracer {
            scene,
            bvh,
            tris,
            epsilon,
            translucent: scene.materials.iter().any(|m| m.is_translucent()),
            filters: scene.materials.iter().any(Material::is_filter),
        }
    }

    pub fn scene(&self) -> &'a Scene {
        self.scene
    }

    pub fn bvh(&self) -> &Bvh {
        &self.bvh
    }

    /// Absolute shadow-ray epsilon in metres.
    pub fn epsilon(&self) -> f64 {
        self.epsilon
    }

    /// The primary hit through the centre of pixel `(x, y)`.
    pub fn primary(&self, x: u32, y: u32) -> Option<SurfaceHit> {
        self.primary_at(x as f32 + 0.5, y as f32 + 0.5)
    }

    /// The eye ray through image point `(fx, fy)` (pixels, `(0.5, 0.5)` the first pixel's
    /// centre) and what it hits.
    pub fn primary_at(&self, fx: f32, fy: f32) -> Option<SurfaceHit> {
        let (o, dir, depth_scale) = self.eye_origin_dir(fx, fy);
        self.hit_along(o, dir, depth_scale, true)
            .map(|(hit, _)| hit)
    }

    /// The eye ray through image point `(fx, fy)` peeled into layers (`docs/translucency.md`):
    /// the nearest surface that is not translucent (the opaque layer; single-sided back faces and
    /// masked-out texels skipped, as [`Tracer::primary_at`] skips them), and the translucent
    /// surfaces strictly in front of it (anywhere along the ray without one), nearest first, at
    /// most `max` of them, each with what the eye sees of it ([`shading::eye_cover`]). A
    /// translucent hit skips single-sided back faces and, for a filter, masked-out texels; a
    /// coverage material is never masked out here (it blends by its coverage instead). Hits
    /// within the tracer's epsilon of the previous one count once (a shared edge).
    pub fn eye_layers(&self, fx: f32, fy: f32, max: usize) -> EyeLayers {
        let (o, dir, depth_scale) = self.eye_origin_dir(fx, fy);
        let opaque = self.opaque_eye_hit(o, dir);
        let mut translucent = Vec::new();
        if max > 0 && self.translucent {
            let tmax = opaque.map_or(f64::INFINITY, |h| h.t);
            self.walk_hits(
                o,
                dir.map(f64::from),
                tmax,
                |id, u, v| self.peels(id, dir, u, v),
                |hit| {
                    let mat = self.triangle_material(hit.id);
                    // `peels` accepts translucent materials only.
                    if let Some(tr) = &mat.transmission {
                        let texel = self.texel_at(hit.id, mat, hit.u, hit.v);
                        translucent.push(TranslucentHit {
                            surface: self.surface_hit(o, dir, hit, depth_scale).0,
                            cover: shading::eye_cover(tr, mat.alpha, texel),
                        });
                    }
                    translucent.len() < max
                },
            );
        }
        EyeLayers {
            opaque: opaque.map(|h| self.surface_hit(o, dir, &h, depth_scale).0),
            translucent,
        }
    }

    /// How many translucent layers [`Tracer::eye_layers`] finds through image point `(fx, fy)`,
    /// at most `cap`, without shading any of them (cheap enough for a planner's coarse grid).
    pub fn translucent_count(&self, fx: f32, fy: f32, cap: usize) -> usize {
        if cap == 0 || !self.translucent {
            return 0;
        }
        let (o, dir, _) = self.eye_origin_dir(fx, fy);
        let tmax = self.opaque_eye_hit(o, dir).map_or(f64::INFINITY, |h| h.t);
        let mut n = 0;
        self.walk_hits(
            o,
            dir.map(f64::from),
            tmax,
            |id, u, v| self.peels(id, dir, u, v),
            |_| {
                n += 1;
                n < cap
            },
        );
        n
    }

    /// The eye ray through image point `(fx, fy)`: origin, unit direction and the factor from
    /// ray distance to eye depth.
    fn eye_origin_dir(&self, fx: f32, fy: f32) -> ([f64; 3], V3, f32) {
        let cam = &self.scene.camera;
        let dir = cam.ray_dir(fx, fy);
        let forward = cam.frame().forward;
        (cam.position.map(f64::from), dir, dot(dir, forward))
    }

    /// The opaque layer's hit of an eye ray: the nearest triangle that is not translucent,
    /// single-sided back faces and masked-out texels skipped.
    fn opaque_eye_hit(&self, o: [f64; 3], dir: V3) -> Option<Hit> {
        self.bvh
            .closest(o, dir.map(f64::from), 0.0, f64::INFINITY, |id, u, v| {
                let mat = self.triangle_material(id);
                !mat.is_translucent()
                    && !self.single_sided_back(id, mat, dir)
                    && !self.masked_out(id, mat, u, v)
            })
    }

    /// Whether an eye ray along `dir` peels triangle `id` at `(u, v)` as a translucent layer:
    /// translucent, not a single-sided back face, and for a filter not masked out.
    fn peels(&self, id: u32, dir: V3, u: f64, v: f64) -> bool {
        let mat = self.triangle_material(id);
        let Some(tr) = &mat.transmission else {
            return false;
        };
        !self.single_sided_back(id, mat, dir) && (tr.coverage || !self.masked_out(id, mat, u, v))
    }

    /// What the filters in front of the primary hit of pixel `(x, y)` let through (RGB): the
    /// product of their transmittance, 1 without any. The pixel's radiance is this times what
    /// the hit surface sends (`docs/translucency.md`); a pixel no surface covers has none.
    pub fn eye_transmittance(&self, x: u32, y: u32, hit: &SurfaceHit) -> V3 {
        let cam = &self.scene.camera;
        let dir = cam.ray_dir(x as f32 + 0.5, y as f32 + 0.5);
        self.filters_along(cam.position.map(f64::from), dir, hit, true)
    }

    /// The product of the transmittance of the filters a ray from `o` along `dir` passes before
    /// `hit` (1 without any); `eye`: single-sided back faces do not count, as eye rays skip them.
    fn filters_along(&self, o: [f64; 3], dir: V3, hit: &SurfaceHit, eye: bool) -> V3 {
        if !self.filters {
            return [1.0; 3];
        }
        let d = dir.map(f64::from);
        let to_hit = [0, 1, 2].map(|k| hit.position[k] - o[k]);
        let tmax = dot64(to_hit, d) / dot64(d, d).max(1e-30);
        let walked = self.walk(o, d, tmax, |id, u, v| {
            let mat = self.triangle_material(id);
            if !mat.is_filter() || (eye && self.single_sided_back(id, mat, dir)) {
                return Step::Skip;
            }
            self.tint(id, mat, u, v)
        });
        walked.map_or([0.0; 3], |t| t.map(|c| c as f32))
    }

    /// Closest visible surface along an eye ray; `depth_scale` converts ray distance to depth.
    pub fn eye_ray(&self, origin: V3, dir: V3, depth_scale: f32) -> Option<SurfaceHit> {
        let o = origin.map(f64::from);
        self.hit_along(o, dir, depth_scale, true)
            .map(|(hit, _)| hit)
    }

    /// The first opaque surface a light ray from `o` along unit `dir` meets, whatever its
    /// sidedness (every triangle casts shadows), and whether that is the back of a single-sided
    /// material (which nothing sees, so it reflects nothing). Normals face the ray's origin.
    pub fn light_ray(&self, o: [f64; 3], dir: V3) -> Option<(SurfaceHit, bool)> {
        self.hit_along(o, dir, 1.0, false)
    }

    /// [`Tracer::light_ray`] and what the filters (glass) it passes on the way let through: the
    /// light that reaches the hit is that product times what left `o`.
    pub fn light_ray_tinted(&self, o: [f64; 3], dir: V3) -> Option<(SurfaceHit, bool, V3)> {
        let (hit, back) = self.light_ray(o, dir)?;
        let t = self.filters_along(o, dir, &hit, false);
        Some((hit, back, t))
    }

    fn hit_along(
        &self,
        o: [f64; 3],
        dir: V3,
        depth_scale: f32,
        skip_single_sided_backs: bool,
    ) -> Option<(SurfaceHit, bool)> {
        let d = dir.map(f64::from);
        let hit = self.bvh.closest(o, d, 0.0, f64::INFINITY, |id, u, v| {
            let mat = self.triangle_material(id);
            // Filters (glass) are seen and lit through (`filters_along` tints the way).
            if mat.is_filter() {
                return false;
            }
            if skip_single_sided_backs && self.single_sided_back(id, mat, dir) {
                return false;
            }
            !self.masked_out(id, mat, u, v)
        })?;
        Some(self.surface_hit(o, dir, &hit, depth_scale))
    }

    /// The [`SurfaceHit`] of BVH hit `hit` on the ray from `o` along unit `dir` (normals facing
    /// the ray's origin, depth `t · depth_scale`), and whether it is the back of a single-sided
    /// material.
    fn surface_hit(&self, o: [f64; 3], dir: V3, hit: &Hit, depth_scale: f32) -> (SurfaceHit, bool) {
        let d = dir.map(f64::from);
        let info = self.tris[hit.id as usize];
        let mesh = &self.scene.meshes[info.mesh as usize];
        let ng_raw = self.geometric_normal(hit.id);
        let idx = self.indices(hit.id);
        let (u, v) = (hit.u as f32, hit.v as f32);
        let w = 1.0 - u - v;
        let bary =
            |a: V3, b: V3, c: V3| -> V3 { [0, 1, 2].map(|k| w * a[k] + u * b[k] + v * c[k]) };
        let mut n = if mesh.normals.len() == mesh.positions.len() {
            let nn = |i: u32| mesh.normals[i as usize];
            let n = normalize(bary(nn(idx[0]), nn(idx[1]), nn(idx[2])));
            if n == [0.0; 3] { ng_raw } else { n }
        } else {
            ng_raw
        };
        let uv = if mesh.uvs.len() == mesh.positions.len() {
            let t = |i: u32| mesh.uvs[i as usize];
            let (a, b, c) = (t(idx[0]), t(idx[1]), t(idx[2]));
            let tangent = || {
                if mesh.tangents.len() == mesh.positions.len() {
                    let t = |i: u32| mesh.tangents[i as usize];
                    shading::interpolated_tangent([t(idx[0]), t(idx[1]), t(idx[2])], [w, u, v])
                } else {
                    let p = |i: u32| mesh.positions[i as usize];
                    shading::triangle_tangent([p(idx[0]), p(idx[1]), p(idx[2])], [a, b, c])
                }
            };
            n = shading::mapped_normal(
                material_of(self.scene, mesh.material),
                &self.scene.textures,
                n,
                tangent,
                [0, 1].map(|k| w * a[k] + u * b[k] + v * c[k]),
            );
            [0, 1].map(|k| w * a[k] + u * b[k] + v * c[k])
        } else {
            [0.0; 2]
        };
        let mut ng = ng_raw;
        let back = dot(ng, dir) > 0.0;
        if back {
            // Back face of a double-sided material (eye rays rejected single-sided back faces).
            ng = shading::scale(ng, -1.0);
            n = shading::scale(n, -1.0);
        }
        let position = [0, 1, 2].map(|k| o[k] + hit.t * d[k]);
        let surface = SurfaceHit {
            position,
            geometric_normal: ng,
            normal: n,
            to_viewer: shading::scale(dir, -1.0),
            depth: (hit.t as f32) * depth_scale,
            uv,
            material: mesh.material,
        };
        let mat = material_of(self.scene, mesh.material);
        (surface, back && !mat.double_sided)
    }

    /// Whether `sample` is visible from the surface point (`s_λ ∈ {0, 1}`): no opaque triangle
    /// blocks the way (translucent ones let light through: [`Tracer::transmittance`] says how
    /// much). The ray starts `epsilon` off the surface on the light's side of the geometric
    /// normal and, measured from that origin, stops `epsilon` short of the sample, so geometry
    /// the sample lies on (an emissive mesh, a ceiling a rectangle light sits on) does not shadow
    /// it.
    pub fn visible(&self, hit: &SurfaceHit, sample: &LightSample) -> bool {
        match self.shadow_ray(hit, sample) {
            Some((o, d, tmax)) => self.clear(o, d, tmax),
            None => true,
        }
    }

    /// Whether any material of the scene lets light through.
    pub fn has_translucent(&self) -> bool {
        self.translucent
    }

    /// `s_λ` as RGB along the ray [`Tracer::visible`] traces: 0 where an opaque triangle blocks
    /// it, else the product of the transmittance (`scene::shading::transmittance`) of every
    /// translucent texel it passes; 1 where nothing is in the way.
    pub fn transmittance(&self, hit: &SurfaceHit, sample: &LightSample) -> V3 {
        let Some((o, dir, tmax)) = self.shadow_ray(hit, sample) else {
            return [1.0; 3];
        };
        let walked = self.walk(o, dir, tmax, |id, u, v| {
            let mat = self.triangle_material(id);
            if mat.is_translucent() {
                self.tint(id, mat, u, v)
            } else if self.masked_out(id, mat, u, v) {
                Step::Skip
            } else {
                Step::Block
            }
        });
        walked.map_or([0.0; 3], |t| t.map(|c| c as f32))
    }

    /// What a texel of translucent `mat` does to a ray: a filter's masked-out texel lets it
    /// through untouched, any other tints it by `shading::transmittance`.
    fn tint(&self, id: u32, mat: &Material, u: f64, v: f64) -> Step {
        let Some(tr) = &mat.transmission else {
            return Step::Skip;
        };
        if !tr.coverage && self.masked_out(id, mat, u, v) {
            return Step::Skip;
        }
        let texel = self.texel_at(id, mat, u, v);
        Step::Tint(shading::transmittance(
            tr,
            mat.alpha * texel[3],
            [texel[0], texel[1], texel[2]],
        ))
    }

    /// Walks the ray from `o` along unit `d` over `(0, tmax)`, nearest hit first: `None` at the
    /// first texel `step` blocks, else the product of the tints of those it passes. Hits within
    /// `epsilon` of the previous one count once (the shared edge of two triangles of one surface).
    fn walk(
        &self,
        o: [f64; 3],
        d: [f64; 3],
        tmax: f64,
        step: impl Fn(u32, f64, f64) -> Step,
    ) -> Option<[f64; 3]> {
        let mut t = [1.0f64; 3];
        let mut blocked = false;
        self.walk_hits(
            o,
            d,
            tmax,
            |id, u, v| !matches!(step(id, u, v), Step::Skip),
            |hit| match step(hit.id, hit.u, hit.v) {
                Step::Block => {
                    blocked = true;
                    false
                }
                Step::Tint(x) => {
                    for k in 0..3 {
                        t[k] *= f64::from(x[k]);
                    }
                    blocked = t == [0.0; 3];
                    !blocked
                }
                Step::Skip => true,
            },
        );
        (!blocked).then_some(t)
    }

    /// Visits the hits `accept` allows on the ray from `o` along unit `d` over `(0, tmax)`,
    /// nearest first, until `visit` returns false. A hit within `epsilon` beyond the previous
    /// visited one is not visited (the shared edge of two triangles of one surface counts once).
    fn walk_hits(
        &self,
        o: [f64; 3],
        d: [f64; 3],
        tmax: f64,
        accept: impl Fn(u32, f64, f64) -> bool,
        mut visit: impl FnMut(&Hit) -> bool,
    ) {
        let mut tmin = 0.0;
        // Bounded: each hit moves `tmin` on by at least `epsilon`.
        for _ in 0..MAX_LAYERS {
            let Some(hit) = self.bvh.closest(o, d, tmin, tmax, &accept) else {
                return;
            };
            if !visit(&hit) {
                return;
            }
            tmin = hit.t + self.epsilon;
        }
    }

    /// The shadow ray of `visible` (origin, unit direction, length), `None` where there is
    /// nothing to trace.
    fn shadow_ray(
        &self,
        hit: &SurfaceHit,
        sample: &LightSample,
    ) -> Option<([f64; 3], [f64; 3], f64)> {
        let p = hit.position;
        let ng = hit.geometric_normal.map(f64::from);
        match sample.kind {
            SampleKind::Directional => {
                let l = normalize(shading::scale(sample.direction, -1.0)).map(f64::from);
                let o = self.offset(p, ng, l);
                Some((o, l, f64::INFINITY))
            }
            _ => {
                let q = sample.position.map(f64::from);
                let towards = [0, 1, 2].map(|k| q[k] - p[k]);
                let o = self.offset(p, ng, towards);
                let d = [0, 1, 2].map(|k| q[k] - o[k]);
                let r = dot64(d, d).sqrt();
                // Also catches a NaN distance: nothing sensible to trace.
                if r.is_nan() || r <= 2.0 * self.epsilon {
                    return None;
                }
                Some((o, d.map(|c| c / r), r - self.epsilon))
            }
        }
    }

    /// `p` moved `epsilon` along `±ng`, on the side `towards` points to.
    fn offset(&self, p: [f64; 3], ng: [f64; 3], towards: [f64; 3]) -> [f64; 3] {
        let side = if dot64(ng, towards) >= 0.0 { 1.0 } else { -1.0 };
        [0, 1, 2].map(|k| p[k] + side * self.epsilon * ng[k])
    }

    /// Whether the ray from `o` along unit `dir` meets no opaque triangle before `tmax`
    /// (translucent triangles let it through).
    pub fn clear(&self, o: [f64; 3], dir: [f64; 3], tmax: f64) -> bool {
        !self.bvh.occluded(o, dir, 0.0, tmax, |id, u, v| {
            let mat = self.triangle_material(id);
            !mat.is_translucent() && !self.masked_out(id, mat, u, v)
        })
    }

    /// The hit's material (a grey diffuse fallback for an out-of-range index).
    pub fn material(&self, hit: &SurfaceHit) -> &'a Material {
        material_of(self.scene, hit.material)
    }

    /// The material layers and lobe at the hit (`shading::surface_point`).
    pub fn surface(&self, hit: &SurfaceHit) -> shading::SurfacePoint {
        shading::surface_point(self.material(hit), &self.scene.textures, hit.uv)
    }

    /// Diffuse albedo `m^d` at the hit: material colour times texture colour.
    pub fn diffuse(&self, hit: &SurfaceHit) -> V3 {
        self.surface(hit).diffuse
    }

    fn indices(&self, id: u32) -> [u32; 3] {
        let info = self.tris[id as usize];
        let mesh = &self.scene.meshes[info.mesh as usize];
        let f = info.first_index as usize;
        [mesh.indices[f], mesh.indices[f + 1], mesh.indices[f + 2]]
    }

    fn triangle_material(&self, id: u32) -> &'a Material {
        let info = self.tris[id as usize];
        material_of(self.scene, self.scene.meshes[info.mesh as usize].material)
    }

    /// Unit geometric normal (counter-clockwise front), computed in f64 so tiny triangles keep
    /// a direction.
    fn geometric_normal(&self, id: u32) -> V3 {
        let info = self.tris[id as usize];
        let mesh = &self.scene.meshes[info.mesh as usize];
        let idx = self.indices(id);
        let p = |i: u32| mesh.positions[i as usize].map(f64::from);
        let (a, b, c) = (p(idx[0]), p(idx[1]), p(idx[2]));
        let e1 = [0, 1, 2].map(|k| b[k] - a[k]);
        let e2 = [0, 1, 2].map(|k| c[k] - a[k]);
        let n = [
            e1[1] * e2[2] - e1[2] * e2[1],
            e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0],
        ];
        let l = dot64(n, n).sqrt();
        if l > 0.0 {
            n.map(|c| (c / l) as f32)
        } else {
            [0.0; 3]
        }
    }

    /// Whether the ray along `dir` meets triangle `id` of `mat` from the back of a single-sided
    /// material (which eye rays skip).
    fn single_sided_back(&self, id: u32, mat: &Material, dir: V3) -> bool {
        !mat.double_sided && dot(self.geometric_normal(id), dir) >= 0.0
    }

    /// True when an alpha-masked texel at barycentrics `(u, v)` is below the cutoff.
    fn masked_out(&self, id: u32, mat: &Material, u: f64, v: f64) -> bool {
        let AlphaMode::Mask { cutoff } = mat.alpha_mode else {
            return false;
        };
        mat.alpha * self.texel_at(id, mat, u, v)[3] < cutoff
    }

    /// The diffuse texture's linear RGBA at barycentrics `(u, v)` of triangle `id`; white where
    /// the material has no texture or the mesh no UVs (as the GPU reads it).
    fn texel_at(&self, id: u32, mat: &Material, u: f64, v: f64) -> [f32; 4] {
        let Some(tex) = mat.diffuse_texture.and_then(|t| self.scene.textures.get(t)) else {
            return [1.0; 4];
        };
        let info = self.tris[id as usize];
        let mesh = &self.scene.meshes[info.mesh as usize];
        if mesh.uvs.len() != mesh.positions.len() {
            return [1.0; 4];
        }
        let idx = self.indices(id);
        let t = |i: u32| mesh.uvs[i as usize];
        let (a, b, c) = (t(idx[0]), t(idx[1]), t(idx[2]));
        let (u, v) = (u as f32, v as f32);
        let w = 1.0 - u - v;
        let uv = [0, 1].map(|k| w * a[k] + u * b[k] + v * c[k]);
        sample_texture(tex, uv)
    }
}

/// What a texel does to a ray that carries a transmittance.
enum Step {
    /// Lets it through untouched (not a caster of this kind, a masked-out texel).
    Skip,
    Block,
    Tint(V3),
}

/// Most translucent layers one ray is walked through (a bound, not a limit any scene meets).
const MAX_LAYERS: usize = 4096;

/// A fallback for meshes whose material index is out of range: mid-grey diffuse.
fn material_of(scene: &Scene, index: usize) -> &Material {
    static FALLBACK: std::sync::OnceLock<Material> = std::sync::OnceLock::new();
    scene
        .materials
        .get(index)
        .unwrap_or_else(|| FALLBACK.get_or_init(|| Material::diffuse("fallback", [0.5; 3])))
}

#[inline]
fn dot64(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
