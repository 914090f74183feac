//! Checking and sanitising scenes built from untrusted input: NaN positions, out-of-range
//! indices, zero-area triangles, zero normals, empty meshes, dangling material, texture and mesh
//! references, unusable lights, camera and exposure. Sanitising fixes or drops what is wrong and
//! reports it, so renderers can index and divide without further checks.

mod issue;
mod settings;

pub use issue::{Issue, ValidationReport};

use crate::model::{AlphaMode, Material, Mesh, Scene, Texture};
use crate::shading::{V3, add, cross, dot, length, normalize, sub};
use settings::{sanitize_camera, sanitize_light, sanitize_quality};

/// Checks one light as [`Scene::sanitize`] would, without a scene (an emissive mesh light, which
/// needs its mesh, is refused): `Err` says each thing sanitising would fix or drop.
pub fn check_light(light: &crate::model::Light) -> Result<(), String> {
    let mut copy = light.clone();
    let mut issues = Vec::new();
    let kept = settings::sanitize_light(&mut copy, &[], &mut issues);
    if kept && issues.is_empty() {
        Ok(())
    } else {
        Err(issues
            .iter()
            .map(ToString::to_string)
            .collect::<Vec<_>>()
            .join("; "))
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
        copy.animation = self.animation.clone();
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
        let mut light_index = Vec::with_capacity(self.lights.len());
        let mut next = 0;
        self.lights.retain_mut(|l| {
            let keep = sanitize_light(l, &new_index, &mut issues);
            light_index.push(keep.then_some(next));
            next += usize::from(keep);
            keep
        });
        if let Some(anim) = &mut self.animation {
            anim.renumber(&new_index, &light_index);
            let vertices: Vec<usize> = self.meshes.iter().map(|m| m.positions.len()).collect();
            if let Err(problem) = anim.check(&vertices, self.lights.len()) {
                issues.push(Issue::BadAnimation { problem });
                self.animation = None;
            }
        }
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

pub(super) fn finite3(v: &V3) -> bool {
    v.iter().all(|c| c.is_finite())
}

fn sanitize_material(m: &mut Material, texture_count: usize, issues: &mut Vec<Issue>) {
    let colour_ok = |c: &V3| c.iter().all(|x| x.is_finite() && *x >= 0.0);
    let cutoff_ok = match m.alpha_mode {
        AlphaMode::Opaque => true,
        AlphaMode::Mask { cutoff } => cutoff.is_finite(),
    };
    // Transmittance is a fraction: above 1, glass would brighten the light through it.
    let transmission_ok = m
        .transmission
        .is_none_or(|t| colour_ok(&t.color) && t.color.iter().all(|&x| x <= 1.0));
    let pbr_ok = m.pbr.is_none_or(|p| {
        colour_ok(&p.base_color)
            && [
                p.metallic,
                p.roughness,
                p.normal_scale,
                p.occlusion_strength,
                p.transmission,
            ]
            .iter()
            .all(|x| x.is_finite())
            && (0.0..=1.0).contains(&p.transmission)
    });
    if !(colour_ok(&m.diffuse)
        && transmission_ok
        && pbr_ok
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
        if let Some(t) = &mut m.transmission {
            // Transmittance is at most 1: a bad one blocks light (opaque), never brightens it.
            t.color = t.color.map(|x| {
                if x.is_finite() {
                    x.clamp(0.0, 1.0)
                } else {
                    0.0
                }
            });
        }
        if !cutoff_ok {
            m.alpha_mode = AlphaMode::Mask { cutoff: 0.5 };
        }
        if let Some(p) = &mut m.pbr {
            // A bad metallic-roughness factor falls back to its glTF default.
            p.base_color = p
                .base_color
                .map(|x| if x.is_finite() { x.max(0.0) } else { 1.0 });
            for (x, default) in [
                (&mut p.metallic, 1.0),
                (&mut p.roughness, 1.0),
                (&mut p.normal_scale, 1.0),
                (&mut p.occlusion_strength, 1.0),
                (&mut p.transmission, 0.0),
            ] {
                if !x.is_finite() {
                    *x = default;
                }
            }
            p.transmission = p.transmission.clamp(0.0, 1.0);
        }
    }
    // Every texture slot: the metallic-roughness ones, then the diffuse (base-colour) one.
    let pbr_slots = m.pbr.as_mut().map(|p| {
        [
            &mut p.metallic_roughness_texture,
            &mut p.normal_texture,
            &mut p.occlusion_texture,
            &mut p.emissive_texture,
        ]
    });
    for t in pbr_slots
        .into_iter()
        .flatten()
        .chain(std::iter::once(&mut m.diffuse_texture))
    {
        if let Some(k) = *t
            && k >= texture_count
        {
            issues.push(Issue::TextureOutOfRange {
                material: m.name.clone(),
                texture: k,
            });
            *t = None;
        }
    }
}

fn sanitize_mesh(m: &mut Mesh, issues: &mut Vec<Issue>) {
    let n = m.positions.len();
    let name = m.name.clone();
    for (attribute, len) in [
        ("normals", m.normals.len()),
        ("uvs", m.uvs.len()),
        ("tangents", m.tangents.len()),
    ] {
        if len != 0 && len != n {
            issues.push(Issue::AttributeCount {
                mesh: name.clone(),
                attribute,
                found: len,
                expected: n,
            });
            match attribute {
                "normals" => m.normals.clear(),
                "uvs" => m.uvs.clear(),
                _ => m.tangents.clear(),
            }
        }
    }
    if m.tangents.iter().any(|t| !t.iter().all(|c| c.is_finite())) {
        // A normal map then uses each triangle's own tangent.
        issues.push(Issue::BadTangents { mesh: name.clone() });
        m.tangents.clear();
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
