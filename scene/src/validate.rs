//! Checking and sanitising scenes built from untrusted input: NaN positions, out-of-range
//! indices, zero-area triangles, zero normals, empty meshes, dangling material, texture and mesh
//! references, unusable lights, camera and exposure. Sanitising fixes or drops what is wrong and
//! reports it, so renderers can index and divide without further checks.

use crate::defaults;
use crate::model::{AlphaMode, Camera, Light, LightShape, Material, Mesh, Scene, Texture};
use crate::shading::{V3, add, cross, dot, length, normalize, scale, sub};
use std::fmt;

/// One problem found (and, by [`Scene::sanitize`], fixed).
#[derive(Debug, Clone, PartialEq)]
pub enum Issue {
    AttributeCount {
        mesh: String,
        attribute: &'static str,
        found: usize,
        expected: usize,
    },
    TruncatedIndices {
        mesh: String,
        len: usize,
    },
    NonFinitePositions {
        mesh: String,
        count: usize,
    },
    IndexOutOfRange {
        mesh: String,
        count: usize,
    },
    DegenerateTriangles {
        mesh: String,
        count: usize,
    },
    BadNormals {
        mesh: String,
        count: usize,
    },
    NonFiniteUvs {
        mesh: String,
        count: usize,
    },
    EmptyMesh {
        mesh: String,
    },
    MaterialOutOfRange {
        mesh: String,
        material: usize,
    },
    BadMaterial {
        material: String,
    },
    TextureOutOfRange {
        material: String,
        texture: usize,
    },
    TextureSize {
        texture: String,
    },
    BadLight {
        light: String,
        problem: &'static str,
    },
    BadCamera {
        problem: &'static str,
    },
    BadExposure,
    BadQuality {
        problem: &'static str,
    },
}

impl fmt::Display for Issue {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Issue::AttributeCount {
                mesh,
                attribute,
                found,
                expected,
            } => write!(
                f,
                "mesh {mesh:?}: {found} {attribute} for {expected} positions"
            ),
            Issue::TruncatedIndices { mesh, len } => {
                write!(f, "mesh {mesh:?}: {len} indices is not a multiple of 3")
            }
            Issue::NonFinitePositions { mesh, count } => {
                write!(f, "mesh {mesh:?}: {count} non-finite positions")
            }
            Issue::IndexOutOfRange { mesh, count } => {
                write!(
                    f,
                    "mesh {mesh:?}: {count} triangles with out-of-range indices"
                )
            }
            Issue::DegenerateTriangles { mesh, count } => {
                write!(
                    f,
                    "mesh {mesh:?}: {count} zero-area or non-finite triangles"
                )
            }
            Issue::BadNormals { mesh, count } => {
                write!(f, "mesh {mesh:?}: {count} zero or non-finite normals")
            }
            Issue::NonFiniteUvs { mesh, count } => {
                write!(f, "mesh {mesh:?}: {count} non-finite texture coordinates")
            }
            Issue::EmptyMesh { mesh } => write!(f, "mesh {mesh:?} has no usable triangles"),
            Issue::MaterialOutOfRange { mesh, material } => {
                write!(f, "mesh {mesh:?} names missing material {material}")
            }
            Issue::BadMaterial { material } => {
                write!(f, "material {material:?} has non-finite or negative values")
            }
            Issue::TextureOutOfRange { material, texture } => {
                write!(f, "material {material:?} names missing texture {texture}")
            }
            Issue::TextureSize { texture } => {
                write!(f, "texture {texture:?}: pixel data does not match its size")
            }
            Issue::BadLight { light, problem } => write!(f, "light {light:?}: {problem}"),
            Issue::BadCamera { problem } => write!(f, "camera: {problem}"),
            Issue::BadExposure => write!(f, "exposure is not a positive finite number"),
            Issue::BadQuality { problem } => write!(f, "quality: {problem}"),
        }
    }
}

/// Everything [`Scene::validate`] or [`Scene::sanitize`] found.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ValidationReport {
    pub issues: Vec<Issue>,
}

impl ValidationReport {
    pub fn is_clean(&self) -> bool {
        self.issues.is_empty()
    }
}

impl fmt::Display for ValidationReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.issues.is_empty() {
            return write!(f, "no issues");
        }
        for (i, issue) in self.issues.iter().enumerate() {
            if i > 0 {
                write!(f, "; ")?;
            }
            write!(f, "{issue}")?;
        }
        Ok(())
    }
}

impl Scene {
    /// Reports what [`Scene::sanitize`] would fix, without changing the scene.
    pub fn validate(&self) -> ValidationReport {
        let mut copy = Scene {
            textures: Vec::new(),
            ..Scene::new(&self.name)
        };
        copy.meshes = self.meshes.clone();
        copy.materials = self.materials.clone();
        copy.lights = self.lights.clone();
        copy.camera = self.camera;
        copy.ambient = self.ambient;
        copy.exposure = self.exposure;
        copy.quality = self.quality;
        let mut issues = texture_issues(&self.textures);
        issues.extend(copy.sanitize_without_textures(self.textures.len()));
        ValidationReport { issues }
    }

    /// Fixes or drops everything unusable and reports what it did. Afterwards `validate()` is
    /// clean, every index is in range and every number finite.
    pub fn sanitize(&mut self) -> ValidationReport {
        let mut issues = texture_issues(&self.textures);
        for t in &mut self.textures {
            if !texture_ok(t) {
                t.width = 1;
                t.height = 1;
                t.rgba8 = vec![255; 4];
            }
        }
        issues.extend(self.sanitize_without_textures(self.textures.len()));
        ValidationReport { issues }
    }

    fn sanitize_without_textures(&mut self, texture_count: usize) -> Vec<Issue> {
        let mut issues = Vec::new();
        for m in &mut self.materials {
            sanitize_material(m, texture_count, &mut issues);
        }
        let mut default_material = None;
        for m in &mut self.meshes {
            sanitize_mesh(m, &mut issues);
            if m.material >= self.materials.len() {
                issues.push(Issue::MaterialOutOfRange {
                    mesh: m.name.clone(),
                    material: m.material,
                });
                m.material = *default_material.get_or_insert(self.materials.len());
            }
        }
        if default_material.is_some() {
            self.materials
                .push(Material::diffuse("default", [0.8, 0.8, 0.8]));
        }
        // Drop empty meshes and renumber the emissive-mesh lights that refer to meshes.
        let mut new_index = vec![None; self.meshes.len()];
        let mut kept = Vec::with_capacity(self.meshes.len());
        for (i, m) in std::mem::take(&mut self.meshes).into_iter().enumerate() {
            if m.indices.is_empty() {
                issues.push(Issue::EmptyMesh { mesh: m.name });
            } else {
                new_index[i] = Some(kept.len());
                kept.push(m);
            }
        }
        self.meshes = kept;
        self.lights
            .retain_mut(|l| sanitize_light(l, &new_index, &mut issues));
        sanitize_camera(&mut self.camera, &mut issues);
        if !(self.exposure.is_finite() && self.exposure > 0.0) {
            issues.push(Issue::BadExposure);
            self.exposure = 1.0;
        }
        if !self.ambient.iter().all(|c| c.is_finite() && *c >= 0.0) {
            issues.push(Issue::BadCamera {
                problem: "ambient colour is not finite and non-negative",
            });
            self.ambient = [0.0; 3];
        }
        sanitize_quality(self, &mut issues);
        issues
    }
}

fn texture_ok(t: &Texture) -> bool {
    t.width > 0 && t.height > 0 && t.rgba8.len() as u64 == t.width as u64 * t.height as u64 * 4
}

fn texture_issues(textures: &[Texture]) -> Vec<Issue> {
    textures
        .iter()
        .filter(|t| !texture_ok(t))
        .map(|t| Issue::TextureSize {
            texture: t.name.clone(),
        })
        .collect()
}

fn finite3(v: &V3) -> bool {
    v.iter().all(|c| c.is_finite())
}

fn sanitize_material(m: &mut Material, texture_count: usize, issues: &mut Vec<Issue>) {
    let colour_ok = |c: &V3| c.iter().all(|x| x.is_finite() && *x >= 0.0);
    let cutoff_ok = match m.alpha_mode {
        AlphaMode::Opaque => true,
        AlphaMode::Mask { cutoff } => cutoff.is_finite(),
    };
    if !(colour_ok(&m.diffuse)
        && colour_ok(&m.specular)
        && colour_ok(&m.ambient)
        && colour_ok(&m.emissive)
        && m.shininess.is_finite()
        && m.shininess >= 0.0
        && m.alpha.is_finite()
        && cutoff_ok)
    {
        issues.push(Issue::BadMaterial {
            material: m.name.clone(),
        });
        for c in [
            &mut m.diffuse,
            &mut m.specular,
            &mut m.ambient,
            &mut m.emissive,
        ] {
            *c = c.map(|x| if x.is_finite() { x.max(0.0) } else { 0.0 });
        }
        if !(m.shininess.is_finite() && m.shininess >= 0.0) {
            m.shininess = 1.0;
        }
        if !m.alpha.is_finite() {
            m.alpha = 1.0;
        }
        if !cutoff_ok {
            m.alpha_mode = AlphaMode::Mask { cutoff: 0.5 };
        }
    }
    if let Some(t) = m.diffuse_texture
        && t >= texture_count
    {
        issues.push(Issue::TextureOutOfRange {
            material: m.name.clone(),
            texture: t,
        });
        m.diffuse_texture = None;
    }
}

fn sanitize_mesh(m: &mut Mesh, issues: &mut Vec<Issue>) {
    let n = m.positions.len();
    let name = m.name.clone();
    for (attribute, len) in [("normals", m.normals.len()), ("uvs", m.uvs.len())] {
        if len != 0 && len != n {
            issues.push(Issue::AttributeCount {
                mesh: name.clone(),
                attribute,
                found: len,
                expected: n,
            });
            if attribute == "normals" {
                m.normals.clear();
            } else {
                m.uvs.clear();
            }
        }
    }
    if !m.indices.len().is_multiple_of(3) {
        issues.push(Issue::TruncatedIndices {
            mesh: name.clone(),
            len: m.indices.len(),
        });
        m.indices.truncate(m.indices.len() - m.indices.len() % 3);
    }
    let mut bad_pos = vec![false; n];
    let mut nonfinite = 0;
    for (p, bad) in m.positions.iter_mut().zip(&mut bad_pos) {
        if !finite3(p) {
            *p = [0.0; 3];
            *bad = true;
            nonfinite += 1;
        }
    }
    let (mut out_of_range, mut degenerate) = (0, 0);
    let mut kept = Vec::with_capacity(m.indices.len());
    for t in m.indices.chunks_exact(3) {
        if t.iter().any(|&i| i as usize >= n) {
            out_of_range += 1;
            continue;
        }
        if t.iter().any(|&i| bad_pos[i as usize]) || triangle_is_degenerate(m, t) {
            degenerate += 1;
            continue;
        }
        kept.extend_from_slice(t);
    }
    m.indices = kept;
    let mut push = |count: usize, make: fn(String, usize) -> Issue| {
        if count > 0 {
            issues.push(make(name.clone(), count));
        }
    };
    push(nonfinite, |mesh, count| Issue::NonFinitePositions {
        mesh,
        count,
    });
    push(out_of_range, |mesh, count| Issue::IndexOutOfRange {
        mesh,
        count,
    });
    push(degenerate, |mesh, count| Issue::DegenerateTriangles {
        mesh,
        count,
    });
    let bad_uvs = m
        .uvs
        .iter_mut()
        .filter(|uv| !uv.iter().all(|c| c.is_finite()))
        .map(|uv| *uv = [0.0, 0.0])
        .count();
    push(bad_uvs, |mesh, count| Issue::NonFiniteUvs { mesh, count });
    let bad_normals = repair_normals(m);
    push(bad_normals, |mesh, count| Issue::BadNormals { mesh, count });
}

/// Zero area relative to the triangle's size (catches collinear and coincident corners).
fn triangle_is_degenerate(m: &Mesh, t: &[u32]) -> bool {
    let p = [0, 1, 2].map(|k| m.positions[t[k] as usize]);
    let e1 = sub(p[1], p[0]);
    let e2 = sub(p[2], p[0]);
    let c = length(cross(e1, e2));
    let scale2 = dot(e1, e1) + dot(e2, e2);
    !(c.is_finite() && c > 1e-7 * scale2)
}

/// Replaces zero or non-finite normals by the area-weighted normal of the adjacent triangles
/// (or +Y for a vertex no triangle uses); returns how many were replaced.
fn repair_normals(m: &mut Mesh) -> usize {
    if m.normals.is_empty() {
        return 0;
    }
    let bad: Vec<bool> = m
        .normals
        .iter()
        .map(|n| !(finite3(n) && length(*n) > 1e-6))
        .collect();
    let count = bad.iter().filter(|b| **b).count();
    if count == 0 {
        return 0;
    }
    let mut acc = vec![[0.0f32; 3]; m.positions.len()];
    for t in m.indices.chunks_exact(3) {
        let p = [0, 1, 2].map(|k| m.positions[t[k] as usize]);
        let face = cross(sub(p[1], p[0]), sub(p[2], p[0]));
        for &i in t {
            if bad[i as usize] {
                acc[i as usize] = add(acc[i as usize], face);
            }
        }
    }
    for (i, n) in m.normals.iter_mut().enumerate() {
        if bad[i] {
            let a = normalize(acc[i]);
            *n = if a == [0.0; 3] { [0.0, 1.0, 0.0] } else { a };
        } else {
            *n = normalize(*n);
        }
    }
    count
}

/// Returns false when the light must be dropped.
fn sanitize_light(l: &mut Light, mesh_index: &[Option<usize>], issues: &mut Vec<Issue>) -> bool {
    let mut drop = |problem: &'static str| {
        issues.push(Issue::BadLight {
            light: l.name.clone(),
            problem,
        });
        false
    };
    if !(l.power.is_finite() && l.power >= 0.0) {
        return drop("power is not finite and non-negative");
    }
    if !l.color.iter().all(|c| c.is_finite() && *c >= 0.0) {
        return drop("colour is not finite and non-negative");
    }
    let unit = |v: &V3| finite3(v) && length(*v) > 1e-6;
    let positive = |x: f32| x.is_finite() && x > 0.0;
    let mut fixes: Vec<&'static str> = Vec::new();
    match &mut l.shape {
        LightShape::Point { position } => {
            if !finite3(position) {
                return drop("position is not finite");
            }
        }
        LightShape::Spot {
            position,
            direction,
            inner_angle,
            outer_angle,
        } => {
            if !finite3(position) || !unit(direction) {
                return drop("position or direction is unusable");
            }
            let half_pi = std::f32::consts::FRAC_PI_2;
            let o = if outer_angle.is_finite() {
                outer_angle.clamp(0.0, half_pi)
            } else {
                half_pi
            };
            let i = if inner_angle.is_finite() {
                inner_angle.clamp(0.0, o)
            } else {
                0.0
            };
            if (o, i) != (*outer_angle, *inner_angle) {
                fixes.push("cone angles clamped to 0 ≤ inner ≤ outer ≤ π/2");
                (*outer_angle, *inner_angle) = (o, i);
            }
        }
        LightShape::Directional { direction } => {
            if !unit(direction) {
                return drop("direction is unusable");
            }
        }
        LightShape::Rect {
            center,
            normal,
            u_axis,
            size,
        } => {
            if !finite3(center) || !unit(normal) || !positive(size[0]) || !positive(size[1]) {
                return drop("rectangle centre, normal or size is unusable");
            }
            let n = normalize(*normal);
            let u = normalize(sub(*u_axis, scale(n, dot(*u_axis, n))));
            let u = if u == [0.0; 3] {
                crate::sampling_shapes::basis(n).0
            } else {
                u
            };
            if !finite3(u_axis) || dot(normalize(*u_axis), n).abs() > 1e-3 {
                fixes.push("u axis made perpendicular to the normal");
                *u_axis = u;
            }
        }
        LightShape::Disk {
            center,
            normal,
            radius,
        } => {
            if !finite3(center) || !unit(normal) || !positive(*radius) {
                return drop("disk centre, normal or radius is unusable");
            }
        }
        LightShape::Sphere { center, radius } => {
            if !finite3(center) || !positive(*radius) {
                return drop("sphere centre or radius is unusable");
            }
        }
        LightShape::EmissiveMesh { mesh } => match mesh_index.get(*mesh).copied().flatten() {
            Some(k) => *mesh = k,
            None => return drop("emissive mesh is missing or empty"),
        },
    }
    if l.range.is_some_and(|r| !positive(r)) {
        fixes.push("range must be positive (removed)");
        l.range = None;
    }
    if l.is_area() && l.samples == 0 {
        fixes.push("zero samples (set to 1)");
        l.samples = 1;
    }
    for problem in fixes {
        issues.push(Issue::BadLight {
            light: l.name.clone(),
            problem,
        });
    }
    true
}

fn sanitize_camera(c: &mut Camera, issues: &mut Vec<Issue>) {
    let bad = |problem, issues: &mut Vec<Issue>| issues.push(Issue::BadCamera { problem });
    if !(finite3(&c.position) && finite3(&c.target) && finite3(&c.up)) {
        bad("non-finite position, target or up", issues);
        let d = Scene::new("").camera;
        (c.position, c.target, c.up) = (d.position, d.target, d.up);
    }
    if length(sub(c.target, c.position)) < 1e-9 {
        bad("target equals position", issues);
        c.target = add(c.position, [0.0, 0.0, -1.0]);
    }
    if length(c.up) < 1e-9 {
        bad("zero up vector", issues);
        c.up = [0.0, 1.0, 0.0];
    }
    if !(c.fov_y_deg.is_finite() && c.fov_y_deg > 0.0 && c.fov_y_deg < 180.0) {
        bad("vertical field of view outside (0°, 180°)", issues);
        c.fov_y_deg = 45.0;
    }
    if c.width == 0 || c.height == 0 {
        bad("zero image size", issues);
        (c.width, c.height) = (defaults::WIDTH, defaults::HEIGHT);
    }
}

fn sanitize_quality(s: &mut Scene, issues: &mut Vec<Issue>) {
    let d = defaults::quality();
    let q = &mut s.quality;
    let mut bad = |problem| issues.push(Issue::BadQuality { problem });
    if q.samples_per_area_light == Some(0) {
        bad("zero samples per area light (set to 1)");
        q.samples_per_area_light = Some(1);
    }
    if q.shadow_map_size == 0 {
        bad("zero shadow-map size (default used)");
        q.shadow_map_size = d.shadow_map_size;
    }
    if q.lights_per_node == 0 {
        bad("zero lights per node (default used)");
        q.lights_per_node = d.lights_per_node;
    }
    if !(q.depth_bias.is_finite() && q.slope_bias.is_finite()) {
        bad("non-finite depth bias (defaults used)");
        (q.depth_bias, q.slope_bias) = (d.depth_bias, d.slope_bias);
    }
}
