//! Project defaults, named once (ARCHITECTURE §10).

use crate::model::Mismatch;
use crate::model::{AreaSpecular, MapSizing, Quality, SamplePattern, ShadowFilter};

/// Default image width and height.
pub const WIDTH: u32 = 800;
pub const HEIGHT: u32 = 600;
/// Point samples per area light in the default scene (two area lights × 16 = 32 lights).
pub const SAMPLES_PER_AREA_LIGHT: u32 = 16;
/// Shadow-map side where the mismatch rule finds nothing lit, and the side `--shadow-map-size`
/// used to fix for every map.
pub const SHADOW_MAP_SIZE: u32 = 512;
/// The mismatch rule's bounds and target (`MapSizing::Mismatch`): a shadow texel per image pixel
/// at the median lit point, between 256² and 2048² (docs/hard-cases.md, issue 22).
pub const MAP_MISMATCH: Mismatch = Mismatch {
    min: 512,
    max: 2048,
    target: 2.0,
};
/// Lights per render node (the paper's K).
pub const LIGHTS_PER_NODE: u32 = 4;
/// Clamp distance of the `1/r²` falloff of virtual point lights, as a fraction of the scene's
/// bounding diagonal, when the scene sets none (`docs/indirect.md`).
pub const INDIRECT_CLAMP_REL: f32 = 0.02;
/// The built-in scene `lightfold demo` renders.
pub const DEFAULT_SCENE: &str = "balls";

/// Taps per axis of the cell filter a scene file's `filter = "cell"` asks for.
pub const CELL_TAPS: u32 = 3;

pub fn quality() -> Quality {
    Quality {
        samples_per_area_light: None,
        pattern: SamplePattern::Grid,
        seed: 1,
        shadow_map_size: SHADOW_MAP_SIZE,
        map_sizing: MapSizing::Mismatch(MAP_MISMATCH),
        filter: ShadowFilter::Pcf2x2,
        depth_bias: 0.002,
        slope_bias: 1.5,
        lights_per_node: LIGHTS_PER_NODE,
        indirect: 0,
        indirect_clamp: None,
        area_specular: AreaSpecular::Analytic,
    }
}

impl Default for crate::model::Quality {
    fn default() -> Self {
        quality()
    }
}
