//! The scene model every part of lightfold agrees on: world-space triangle meshes, materials,
//! textures, source lights, the camera and quality options.
//!
//! Meshes are stored flattened into world space (node transforms already applied) so that the GPU
//! renderer and the CPU reference see exactly the same triangles.

use serde::{Deserialize, Serialize};

pub(crate) mod keyframes;

/// A whole scene, ready to render.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Scene {
    pub name: String,
    pub meshes: Vec<Mesh>,
    pub materials: Vec<Material>,
    pub textures: Vec<Texture>,
    pub lights: Vec<Light>,
    pub camera: Camera,
    /// Global ambient colour `c^a` of the paper's eq. 2 (zero for physically based scenes).
    pub ambient: [f32; 3],
    /// Exposure applied before the sRGB transfer for PNG output (`sRGB(clamp(exposure·L))`).
    pub exposure: f32,
    pub quality: Quality,
    /// What moves over time (`None`: a still scene). `meshes` and `lights` are the rest pose;
    /// [`Scene::pose`] gives the scene at a time.
    pub animation: Option<keyframes::Animation>,
}

/// A triangle mesh in world space. `normals`, `uvs` and `tangents` are either empty or one per
/// position.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Mesh {
    pub name: String,
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub uvs: Vec<[f32; 2]>,
    /// Normal-map tangents as glTF gives them (xyz along +u, w the handedness ±1 of the
    /// bitangent `w·(n × t)`); where empty, a normal map uses each triangle's own
    /// ([`crate::shading::triangle_tangent`]).
    pub tangents: Vec<[f32; 4]>,
    pub indices: Vec<u32>,
    pub material: usize,
}

/// How a material's alpha is used by eye rays. BLEND from glTF becomes `Mask { cutoff: 0.5 }`
/// for the eye and a [`Transmission`] with `coverage` for shadows (`docs/translucency.md`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum AlphaMode {
    Opaque,
    Mask { cutoff: f32 },
}

/// Material colours of the paper's eq. 1: `m^d` (diffuse albedo), `m^s` (specular colour),
/// `m^a` (ambient), `e` (emitted radiance). Linear RGB.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Material {
    pub name: String,
    pub diffuse: [f32; 3],
    /// Texture multiplied into `diffuse` (its alpha multiplies `alpha`).
    pub diffuse_texture: Option<usize>,
    pub specular: [f32; 3],
    /// Blinn-Phong exponent of the energy-normalised lobe `(n+8)/(8π)·(n·h)^n`.
    pub shininess: f32,
    pub ambient: [f32; 3],
    pub emissive: [f32; 3],
    pub alpha: f32,
    pub alpha_mode: AlphaMode,
    pub double_sided: bool,
    /// Light the surface lets through to what lies behind it, for shadows: `None` for an
    /// opaque caster (`docs/translucency.md`).
    pub transmission: Option<Transmission>,
    /// glTF 2.0 metallic-roughness, shaded with the glTF specification's reference BRDF
    /// (`docs/shading.md`); `None` for the paper's Blinn-Phong (scene files, built-ins). When set,
    /// `diffuse`, `specular`, `shininess`, `ambient` and `emissive` hold what the material layers
    /// and the planner see at the factors (textures multiply them per texel):
    /// [`MetallicRoughness::summary`].
    pub pbr: Option<MetallicRoughness>,
}

/// A glTF metallic-roughness material (glTF 2.0 §3.9, Appendix B). The base-colour texture is
/// `Material::diffuse_texture`; every texture here is read with the same sampling rules, at
/// TEXCOORD_0.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MetallicRoughness {
    /// Linear base colour factor (its alpha is `Material::alpha`).
    pub base_color: [f32; 3],
    pub metallic: f32,
    pub roughness: f32,
    /// Roughness in green, metallic in blue (linear), multiplying the factors.
    pub metallic_roughness_texture: Option<usize>,
    /// Tangent-space normal map (linear), and its `scale` on X and Y.
    pub normal_texture: Option<usize>,
    pub normal_scale: f32,
    /// Ambient occlusion in red (linear): `1 + strength·(r − 1)` multiplies `m^a`.
    pub occlusion_texture: Option<usize>,
    pub occlusion_strength: f32,
    /// sRGB emissive texture multiplying `Material::emissive` (factor × strength).
    pub emissive_texture: Option<usize>,
    /// KHR_materials_transmission factor `τ`: the dielectric's diffuse share that passes through
    /// instead (thin-walled), so the diffuse colour is scaled by `1 − τ`.
    pub transmission: f32,
}

impl MetallicRoughness {
    /// A material of this kind with no textures.
    pub fn new(base_color: [f32; 3], metallic: f32, roughness: f32) -> Self {
        MetallicRoughness {
            base_color,
            metallic,
            roughness,
            metallic_roughness_texture: None,
            normal_texture: None,
            normal_scale: 1.0,
            occlusion_texture: None,
            occlusion_strength: 1.0,
            emissive_texture: None,
            transmission: 0.0,
        }
    }
}

/// How a translucent caster filters light (seed 001's shadows of transparent occluders):
/// a shadow ray through one of its texels keeps [`crate::shading::transmittance`] of its light.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Transmission {
    /// Linear RGB transmittance where the surface covers, multiplied by the diffuse texture's
    /// colour where the material has one (a red glass pane: `[0.9, 0.1, 0.1]`).
    pub color: [f32; 3],
    /// Alpha (× texture alpha) is coverage, as glTF BLEND means it: the uncovered `1 − α`
    /// passes untinted. Otherwise the alpha mask, if any, decides which texels cast.
    pub coverage: bool,
}

impl Material {
    /// A diffuse-only, opaque, double-sided material.
    pub fn diffuse(name: &str, rgb: [f32; 3]) -> Self {
        Material {
            name: name.to_string(),
            diffuse: rgb,
            diffuse_texture: None,
            specular: [0.0; 3],
            shininess: 1.0,
            ambient: [0.0; 3],
            emissive: [0.0; 3],
            alpha: 1.0,
            alpha_mode: AlphaMode::Opaque,
            double_sided: true,
            transmission: None,
            pbr: None,
        }
    }

    /// Whether light passes through it (it casts into transmittance maps, not depth maps).
    pub fn is_translucent(&self) -> bool {
        self.transmission.is_some()
    }

    /// Whether it is a filter (glass: transmission without coverage), which eye rays see
    /// through, tinting what lies behind (`docs/translucency.md`).
    pub fn is_filter(&self) -> bool {
        self.transmission.is_some_and(|t| !t.coverage)
    }

    pub fn has_specular(&self) -> bool {
        self.specular.iter().any(|&c| c > 0.0)
    }
}

/// An RGBA8 texture; `srgb` says whether the colour channels are sRGB-encoded.
/// Sampling (wrap: repeat, filter: bilinear) is defined in [`crate::shading::sample_texture`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Texture {
    pub name: String,
    pub width: u32,
    pub height: u32,
    pub srgb: bool,
    pub rgba8: Vec<u8>,
}

/// The geometric kind of a source light.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum LightShape {
    /// Isotropic point light; `Light::power` is intensity in W/sr.
    Point { position: [f32; 3] },
    /// glTF spot light (smooth falloff between the cone angles, radians); power in W/sr.
    Spot {
        position: [f32; 3],
        direction: [f32; 3],
        inner_angle: f32,
        outer_angle: f32,
    },
    /// Directional light travelling along `direction`; power is irradiance in W/m² on a surface
    /// facing it. `angle` is the apparent angular diameter of its source in radians (the sun's is
    /// about 0.0093): 0 is parallel light with hard shadows; above 0 it is a soft sun, a disk of
    /// uniform radiance on the sky sampled by `Light::samples` parallel lights.
    Directional { direction: [f32; 3], angle: f32 },
    /// One-sided rectangle emitting along `normal`; `u_axis` spans `size[0]`, `normal × u_axis`
    /// spans `size[1]`. Power is radiance in W/(sr·m²).
    Rect {
        center: [f32; 3],
        normal: [f32; 3],
        u_axis: [f32; 3],
        size: [f32; 2],
    },
    /// One-sided disk emitting along `normal`; power is radiance.
    Disk {
        center: [f32; 3],
        normal: [f32; 3],
        radius: f32,
    },
    /// Sphere emitting outward; power is radiance.
    Sphere { center: [f32; 3], radius: f32 },
    /// The curved side of a cylinder emitting outward (its end caps do not emit): `length` along
    /// `axis` (unit) about `center`, of `radius`. Power is radiance. A fluorescent tube, UsdLux's
    /// `CylinderLight`.
    Cylinder {
        center: [f32; 3],
        axis: [f32; 3],
        length: f32,
        radius: f32,
    },
    /// The triangles of `Scene::meshes[mesh]` emit along their geometric normals (both sides when
    /// the mesh's material is double-sided); power is radiance.
    EmissiveMesh { mesh: usize },
}

/// A source light as authored. Area lights become point samples through [`crate::sampling`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Light {
    pub name: String,
    pub shape: LightShape,
    /// Linear colour (multiplies `power` per channel).
    pub color: [f32; 3],
    pub power: f32,
    /// Optional range window (glTF KHR_lights_punctual): contribution is zero beyond it.
    pub range: Option<f32>,
    /// Number of point samples for an area light (ignored for point, spot and parallel
    /// directional lights; a soft sun's count of parallel lights).
    pub samples: u32,
}

impl Light {
    pub fn is_area(&self) -> bool {
        matches!(
            self.shape,
            LightShape::Rect { .. }
                | LightShape::Disk { .. }
                | LightShape::Sphere { .. }
                | LightShape::Cylinder { .. }
                | LightShape::EmissiveMesh { .. }
        ) || matches!(self.shape, LightShape::Directional { angle, .. } if angle > 0.0)
    }
}

/// The emission pattern of one point-light sample.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum SampleKind {
    /// `I(ω) = intensity`.
    Isotropic,
    /// `I(θ) = intensity·max(0, cos θ)` about `direction` (an area-light sample; one-sided).
    CosineLobe,
    /// `I(θ) = intensity·max(0, |cos θ|)` — a sample of a double-sided emitter.
    TwoSidedLobe,
    /// glTF spot falloff about `direction` between the cosines of the outer and inner angles.
    Spot { cos_outer: f32, cos_inner: f32 },
    /// Parallel light travelling along `direction`; `intensity` is irradiance (W/m²).
    Directional,
    /// A virtual point light of one-bounce indirect light (`docs/indirect.md`): a cosine lobe
    /// `I(θ) = intensity·max(0, cos θ)` about the surface normal `direction`, whose `1/r²` falloff
    /// is clamped to `1/max(r², clamp²)` (`clamp` in metres; 0 is no clamp).
    Bounce { clamp: f32 },
}

/// One point-light sample `λ`: what the plan carries and what nodes render. Nodes never resample.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LightSample {
    pub position: [f32; 3],
    /// Lobe axis / spot axis / direction of travel (unit); unused for `Isotropic`.
    pub direction: [f32; 3],
    pub kind: SampleKind,
    /// Peak scalar intensity in W/sr (irradiance for `Directional`).
    pub intensity: f32,
    /// Light colour `c_λ` (linear).
    pub color: [f32; 3],
    /// Range window; `None` is unbounded.
    pub range: Option<f32>,
    /// Index of the source light in `Scene::lights`.
    pub light: u32,
    /// The shape of the area light this sample belongs to, where the glossy specular of its
    /// light is integrated over that shape in closed form ([`AreaSpecular::Analytic`],
    /// [`crate::ltc`]); `None` for point, spot, directional and bounce samples, emissive meshes,
    /// and under [`AreaSpecular::Sampled`].
    pub area: Option<AreaShape>,
    /// Width of this sample's cell of its light ([`crate::sampling::cell_width`]: metres; radians
    /// for a soft sun's directions): the shadow a cell casts past a blocker, which the cell filter
    /// ([`ShadowFilter::Cell`]) spreads each sample's shadow over. 0 for samples that are no cell
    /// of a shape (points, spots, parallel light, emissive meshes, virtual point lights).
    pub cell: f32,
}

/// The emitting shape of an area light as the closed-form specular integrates it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum AreaShape {
    /// A parallelogram `center ± u ± v` (`u`, `v`: half extents along its sides).
    Rect {
        center: [f32; 3],
        u: [f32; 3],
        v: [f32; 3],
    },
    /// A disk or ellipse `center + cos φ·u + sin φ·v` (`u`, `v`: its semi-axes).
    Disk {
        center: [f32; 3],
        u: [f32; 3],
        v: [f32; 3],
    },
    /// A sphere, seen from a point as the disk of its silhouette.
    Sphere { center: [f32; 3], radius: f32 },
}

/// How the specular lobe of a glTF metallic-roughness surface meets an area light.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum AreaSpecular {
    /// The lobe's unshadowed integral over the light's shape in closed form (linearly transformed
    /// cosines), shared among the light's samples in proportion to their irradiance and
    /// modulated by each sample's visibility (`docs/shading.md`): a narrow lobe no longer
    /// breaks into one highlight per sample.
    #[default]
    Analytic,
    /// Each sample's own point-light specular: exact as the sample count grows, a grid of
    /// highlight dots on glossy surfaces at the usual counts.
    Sampled,
}

/// A pinhole camera: right-handed, Y up, vertical field of view, image row 0 at the top.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    pub position: [f32; 3],
    pub target: [f32; 3],
    pub up: [f32; 3],
    /// Vertical field of view in degrees.
    pub fov_y_deg: f32,
    pub width: u32,
    pub height: u32,
}

/// How area lights are turned into point samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
pub enum SamplePattern {
    /// A fixed stratified grid at cell centres (the default: with shadow maps one fixed grid gives
    /// lower error than one fixed jittered set).
    #[default]
    Grid,
    /// One seeded random point per grid cell.
    Jittered,
    /// The 2-D Halton sequence (bases 2, 3).
    Halton,
}

/// Percentage-closer filtering kernel of the shadow lookup.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ShadowFilter {
    /// One comparison at the texel nearest the lookup (no filtering).
    None,
    /// The hardware 2×2 bilinear comparison (one `textureSampleCompare`).
    Pcf2x2,
    /// `n×n` grid of 2×2 bilinear comparisons (n = 3 or 5), averaged.
    Pcf { taps: u32 },
    /// Each area-light sample's shadow spread over the shadow its cell of the light casts
    /// (percentage-closer soft shadows per sample; `docs/shading.md` § The cell filter): a
    /// `taps × taps` blocker search, then `taps × taps` 2×2 comparisons over the kernel that the
    /// blockers' mean distance gives. Samples without a cell (`LightSample::cell` 0) get
    /// [`ShadowFilter::Pcf2x2`].
    Cell { taps: u32 },
}

/// How shadow maps are sized (`Quality::map_sizing`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum MapSizing {
    /// Every map `Quality::shadow_map_size`².
    Fixed,
    /// Each light's maps from the eye/light mismatch factor where the camera sees its light
    /// (`shadow_views::sizing`): the renderer and the planner size them alike.
    Mismatch(Mismatch),
}

/// The mismatch rule's bounds and target (`Quality::map_sizing`; applied by
/// `shadow_views::mismatch_size`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Mismatch {
    /// Smallest and largest map side (rounded to powers of two inside them).
    pub min: u32,
    pub max: u32,
    /// The `m` to aim for: 1 puts a texel on each image pixel of a lit surface, 2 lets it span
    /// two.
    pub target: f32,
}

/// Quality options that a scene file may set and `lightfold accuracy` varies.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Quality {
    /// Overrides `Light::samples` of every area light when set.
    pub samples_per_area_light: Option<u32>,
    pub pattern: SamplePattern,
    pub seed: u64,
    /// Side of every shadow map under [`MapSizing::Fixed`]; the size of a light no probe of the
    /// mismatch rule finds lit under [`MapSizing::Mismatch`].
    pub shadow_map_size: u32,
    /// How each light's shadow maps are sized.
    pub map_sizing: MapSizing,
    pub filter: ShadowFilter,
    /// Constant depth bias in light-space depth units (metres along the light ray).
    pub depth_bias: f32,
    /// Slope-scaled bias factor.
    pub slope_bias: f32,
    /// Lights per render node (the paper's K).
    pub lights_per_node: u32,
    /// Virtual point lights of one-bounce indirect light over the whole scene (0: direct light
    /// only; `docs/indirect.md`).
    pub indirect: u32,
    /// Clamp distance of those lights' `1/r²` falloff, metres (0: none; `None`:
    /// [`crate::defaults::INDIRECT_CLAMP_REL`] of the scene's bounding diagonal).
    pub indirect_clamp: Option<f32>,
    /// How glossy (metallic-roughness) specular meets area lights.
    pub area_specular: AreaSpecular,
}
