//! Helpers on a whole `Scene` that every part needs: construction, bounds, counts and the exact
//! emitted power of area lights.

use crate::defaults;
use crate::model::{Camera, Light, LightShape, Material, Mesh, Quality, Scene};
use crate::shading::{V3, cross, length, sub};
use std::f64::consts::PI;

impl Quality {
    /// The point samples area light `light` is drawn with: the override where this quality sets
    /// one, else the light's own count, at least 1.
    pub fn samples_of(&self, light: &Light) -> u32 {
        self.samples_per_area_light.unwrap_or(light.samples).max(1)
    }
}

impl Scene {
    /// The largest count of point samples an area light of the scene is drawn with
    /// ([`Quality::samples_of`]); `None` without area lights.
    pub fn area_samples(&self) -> Option<u32> {
        self.lights
            .iter()
            .filter(|l| l.is_area())
            .map(|l| self.quality.samples_of(l))
            .max()
    }

    /// An empty scene: no geometry or lights, the default camera and quality, exposure 1.
    pub fn new(name: &str) -> Self {
        Scene {
            name: name.to_string(),
            meshes: Vec::new(),
            materials: Vec::new(),
            textures: Vec::new(),
            lights: Vec::new(),
            camera: Camera {
                position: [0.0, 1.0, 5.0],
                target: [0.0, 0.0, 0.0],
                up: [0.0, 1.0, 0.0],
                fov_y_deg: 45.0,
                width: defaults::WIDTH,
                height: defaults::HEIGHT,
            },
            ambient: [0.0; 3],
            exposure: 1.0,
            quality: defaults::quality(),
            animation: None,
        }
    }

    /// Whether mesh `m`'s material lets light through (it casts into transmittance maps). A mesh
    /// or material index out of range is opaque.
    pub fn is_translucent_mesh(&self, m: usize) -> bool {
        self.meshes
            .get(m)
            .and_then(|mesh| self.materials.get(mesh.material))
            .is_some_and(Material::is_translucent)
    }

    /// Appends a material and returns its index.
    pub fn add_material(&mut self, material: Material) -> usize {
        self.materials.push(material);
        self.materials.len() - 1
    }

    /// Appends a mesh and returns its index.
    pub fn add_mesh(&mut self, mesh: Mesh) -> usize {
        self.meshes.push(mesh);
        self.meshes.len() - 1
    }

    /// Axis-aligned bounds `(min, max)` of all finite mesh positions; `None` without geometry.
    pub fn bounds(&self) -> Option<(V3, V3)> {
        self.meshes
            .iter()
            .filter_map(Mesh::bounds)
            .reduce(|(alo, ahi), (blo, bhi)| {
                (
                    [alo[0].min(blo[0]), alo[1].min(blo[1]), alo[2].min(blo[2])],
                    [ahi[0].max(bhi[0]), ahi[1].max(bhi[1]), ahi[2].max(bhi[2])],
                )
            })
    }

    /// Total number of triangles over all meshes.
    pub fn triangle_count(&self) -> usize {
        self.meshes.iter().map(Mesh::triangle_count).sum()
    }

    /// Number of point samples the scene's lights turn into with its quality options.
    pub fn sample_count(&self) -> usize {
        self.lights
            .iter()
            .map(|l| {
                if l.is_area() {
                    self.quality.samples_of(l) as usize
                } else {
                    1
                }
            })
            .sum()
    }

    /// Emitting area `A` (m²) of an area light and whether it emits on both sides; `None` for
    /// point, spot and directional lights (a soft sun too: it has no area, only an angle).
    pub fn light_area(&self, light: &Light) -> Option<(f64, bool)> {
        match &light.shape {
            LightShape::Rect { size, .. } => Some((size[0] as f64 * size[1] as f64, false)),
            LightShape::Disk { radius, .. } => Some((PI * (*radius as f64).powi(2), false)),
            LightShape::Sphere { radius, .. } => Some((4.0 * PI * (*radius as f64).powi(2), false)),
            LightShape::Cylinder { length, radius, .. } => {
                Some((2.0 * PI * f64::from(*radius) * f64::from(*length), false))
            }
            LightShape::EmissiveMesh { mesh } => {
                let m = self.meshes.get(*mesh)?;
                let two_sided = self
                    .materials
                    .get(m.material)
                    .is_some_and(|mat| mat.double_sided);
                Some((mesh_area(m), two_sided))
            }
            _ => None,
        }
    }

    /// Exact radiant power (W, scalar radiance × area × π per side) of an area light:
    /// `π·L·A` one-sided, `2π·L·A` two-sided.
    pub fn area_light_power(&self, light: &Light) -> Option<f64> {
        let (area, two_sided) = self.light_area(light)?;
        let sides = if two_sided { 2.0 } else { 1.0 };
        Some(sides * PI * light.power as f64 * area)
    }
}

/// Sum of the triangle areas of a mesh (triangles with out-of-range indices are skipped).
pub fn mesh_area(m: &Mesh) -> f64 {
    m.indices
        .chunks_exact(3)
        .filter_map(|t| {
            let p0 = m.positions.get(t[0] as usize)?;
            let p1 = m.positions.get(t[1] as usize)?;
            let p2 = m.positions.get(t[2] as usize)?;
            let a = 0.5 * length(cross(sub(*p1, *p0), sub(*p2, *p0))) as f64;
            a.is_finite().then_some(a)
        })
        .sum()
}
