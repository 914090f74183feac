//! The TOML scene-file schema (version 1). Every table denies unknown fields, so a typo is an
//! error rather than a silently ignored setting. See `docs/scenes.md` for the reference.

use serde::{Deserialize, Serialize};

/// The one scene-file version this build reads.
pub const VERSION: u32 = 1;

type V3 = [f32; 3];

fn one() -> f32 {
    1.0
}
fn yes() -> bool {
    true
}
fn white() -> V3 {
    [1.0, 1.0, 1.0]
}
fn grey() -> V3 {
    [0.8, 0.8, 0.8]
}
fn y_up() -> V3 {
    [0.0, 1.0, 0.0]
}
fn x_axis() -> V3 {
    [1.0, 0.0, 0.0]
}
fn width() -> u32 {
    crate::defaults::WIDTH
}
fn height() -> u32 {
    crate::defaults::HEIGHT
}
fn area_samples() -> u32 {
    crate::defaults::SAMPLES_PER_AREA_LIGHT
}
fn shininess() -> f32 {
    32.0
}
fn divisions() -> u32 {
    1
}
fn segments() -> u32 {
    48
}
fn rings() -> u32 {
    24
}

/// A whole scene file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    pub version: u32,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// Global ambient colour `c^a`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ambient: Option<V3>,
    /// PNG exposure: `sRGB(clamp(exposure·L))` (absent: the base scene's, or 1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exposure: Option<f32>,
    /// `false` turns every material's specular term off (glTF materials included).
    #[serde(default = "yes")]
    pub specular: bool,
    /// A scene this file starts from (a built-in, or a scene file or model in its folder):
    /// the file's objects are added to it, and its lights, camera, exposure, ambient and quality
    /// replace the base's where the file gives them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub base: Option<BaseRef>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gltf: Option<GltfRef>,
    /// A Wavefront OBJ model (with its MTL libraries); a file takes one model in all.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub obj: Option<ModelRef>,
    /// A PLY model; a file takes one model in all.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ply: Option<ModelRef>,
    /// A USD stage (`.usda`, `.usdc`, `.usdz`) with its lights and camera; a file takes one
    /// model in all.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub usd: Option<ModelRef>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<CameraSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub quality: Option<QualitySpec>,
    #[serde(default, rename = "material", skip_serializing_if = "Vec::is_empty")]
    pub materials: Vec<MaterialSpec>,
    #[serde(default, rename = "object", skip_serializing_if = "Vec::is_empty")]
    pub objects: Vec<ObjectSpec>,
    #[serde(default, rename = "light", skip_serializing_if = "Vec::is_empty")]
    pub lights: Vec<LightSpec>,
    /// Objects and lights that move (`docs/scenes.md`, "Motion").
    #[serde(default, rename = "motion", skip_serializing_if = "Vec::is_empty")]
    pub motions: Vec<crate::animation::MotionSpec>,
    /// Meshes moved from where the model or base has them, by mesh index
    /// (`crate::moves::MeshMove`; what a saved live session writes for the objects its viewers
    /// moved).
    #[serde(default, rename = "move", skip_serializing_if = "Vec::is_empty")]
    pub moves: Vec<crate::moves::MeshMove>,
}

/// The scene a file starts from: a built-in's name, or the path (relative to the file, inside
/// its folder) of a scene file without a base of its own, or of a glTF, OBJ or PLY model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BaseRef {
    pub scene: String,
}

/// A glTF / GLB model, its path relative to the scene file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GltfRef {
    pub path: String,
    /// Uniform scale at the root (0.01 for a model in centimetres).
    #[serde(default = "one")]
    pub scale: f32,
    #[serde(default)]
    pub translation: V3,
    /// The animation to play (name or index); the first when not given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub animation: Option<String>,
}

/// An OBJ, PLY or USD model, its path relative to the scene file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelRef {
    pub path: String,
    /// Uniform scale (0.01 for a model in centimetres).
    #[serde(default = "one")]
    pub scale: f32,
    #[serde(default)]
    pub translation: V3,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    pub position: V3,
    pub target: V3,
    #[serde(default = "y_up")]
    pub up: V3,
    /// Vertical field of view in degrees.
    pub fov_y_deg: f32,
    #[serde(default = "width")]
    pub width: u32,
    #[serde(default = "height")]
    pub height: u32,
}

/// Overrides of the default quality options.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QualitySpec {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub samples_per_area_light: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pattern: Option<PatternSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    /// Every map's side; setting it alone fixes every map at it (`shadow_map_sizing = "fixed"`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shadow_map_size: Option<u32>,
    /// `"fixed"`, `"mismatch"` (the default bounds and target) or `{ target = 1.0, min = 256,
    /// max = 2048 }`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shadow_map_sizing: Option<SizingSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub filter: Option<FilterSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_bias: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub slope_bias: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lights_per_node: Option<u32>,
    /// Virtual point lights of one-bounce indirect light (0: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub indirect: Option<u32>,
    /// Their falloff clamp, metres.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub indirect_clamp: Option<f32>,
    /// `"analytic"` (the default: glossy specular integrated over each area light in closed
    /// form) or `"sampled"` (each sample's own point highlight).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub area_specular: Option<crate::model::AreaSpecular>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PatternSpec {
    Grid,
    Jittered,
    Halton,
}

/// How a scene file sizes shadow maps (`Quality::map_sizing`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum SizingSpec {
    Word(SizingWord),
    Mismatch(MismatchSpec),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SizingWord {
    Fixed,
    Mismatch,
}

/// The mismatch rule with any of its defaults replaced.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MismatchSpec {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max: Option<u32>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FilterSpec {
    None,
    Pcf2x2,
    Pcf3x3,
    Pcf5x5,
    /// The cell filter ([`crate::ShadowFilter::Cell`]) with [`crate::defaults::CELL_TAPS`].
    Cell,
}

/// A named material that objects refer to.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    pub name: String,
    #[serde(default = "grey")]
    pub diffuse: V3,
    #[serde(default)]
    pub specular: V3,
    #[serde(default = "shininess")]
    pub shininess: f32,
    #[serde(default)]
    pub ambient: V3,
    #[serde(default)]
    pub emissive: V3,
    #[serde(default = "yes")]
    pub double_sided: bool,
    /// Linear RGB transmittance of a translucent caster (a red glass pane: `[0.9, 0.1, 0.1]`):
    /// its shadows are tinted, not black (`docs/translucency.md`). Absent: opaque.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub transmission: Option<V3>,
}

/// A primitive object.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ObjectSpec {
    /// A rectangle facing `normal`, `size[0]` along `u_axis`.
    Plane {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
        center: V3,
        #[serde(default = "y_up")]
        normal: V3,
        #[serde(default = "x_axis")]
        u_axis: V3,
        size: [f32; 2],
        #[serde(default = "divisions")]
        divisions: u32,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        material: Option<String>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        diffuse: Option<V3>,
    },
    /// A box of full extents `size`, turned by `rotation_y_deg` about its vertical axis.
    Box {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
        center: V3,
        size: V3,
        #[serde(default)]
        rotation_y_deg: f32,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        material: Option<String>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        diffuse: Option<V3>,
    },
    Sphere {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
        center: V3,
        radius: f32,
        #[serde(default = "segments")]
        segments: u32,
        #[serde(default = "rings")]
        rings: u32,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        material: Option<String>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        diffuse: Option<V3>,
    },
    /// A closed cylinder standing on `base` along +Y.
    Cylinder {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
        base: V3,
        radius: f32,
        height: f32,
        #[serde(default = "segments")]
        segments: u32,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        material: Option<String>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        diffuse: Option<V3>,
    },
}

/// A light. Area lights give radiance (W/(sr·m²)); point and spot intensity (W/sr);
/// directional irradiance (W/m²).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum LightSpec {
    Point {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
        position: V3,
        intensity: f32,
        #[serde(default = "white")]
        color: V3,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        range: Option<f32>,
    },
    Spot {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
        position: V3,
        direction: V3,
        intensity: f32,
        #[serde(default)]
        inner_angle_deg: f32,
        outer_angle_deg: f32,
        #[serde(default = "white")]
        color: V3,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        range: Option<f32>,
    },
    /// Parallel light, or a soft sun when `angle_deg` > 0: a disk of that apparent diameter
    /// (the sun's is 0.53°) sampled by `samples` parallel lights (the area-light default).
    Directional {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
        /// Direction the light travels.
        direction: V3,
        irradiance: f32,
        #[serde(default = "white")]
        color: V3,
        /// Written always, so that an editor of the table offers it.
        #[serde(default)]
        angle_deg: f32,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        samples: Option<u32>,
    },
    /// One-sided rectangle emitting along `normal`.
    Rect {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
        center: V3,
        size: [f32; 2],
        normal: V3,
        u_axis: V3,
        radiance: f32,
        #[serde(default = "white")]
        color: V3,
        #[serde(default = "area_samples")]
        samples: u32,
    },
    Disk {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
        center: V3,
        normal: V3,
        radius: f32,
        radiance: f32,
        #[serde(default = "white")]
        color: V3,
        #[serde(default = "area_samples")]
        samples: u32,
    },
    Sphere {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
        center: V3,
        radius: f32,
        radiance: f32,
        #[serde(default = "white")]
        color: V3,
        #[serde(default = "area_samples")]
        samples: u32,
    },
    /// The curved side of a tube emitting outward (its caps do not emit): `length` along `axis`
    /// about `center`.
    Cylinder {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
        center: V3,
        axis: V3,
        length: f32,
        radius: f32,
        radiance: f32,
        #[serde(default = "white")]
        color: V3,
        #[serde(default = "area_samples")]
        samples: u32,
    },
    /// The named `[[object]]` glows with this radiance and lights the scene (both faces when
    /// `two_sided`).
    EmissiveMesh {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
        object: String,
        radiance: f32,
        #[serde(default = "white")]
        color: V3,
        #[serde(default)]
        two_sided: bool,
        #[serde(default = "area_samples")]
        samples: u32,
    },
}
