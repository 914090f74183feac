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

/// What `lightfold defaults` prints: the project defaults (ARCHITECTURE §10) and the limits
/// every input is checked against ([`crate::limits`]), one `name  value` line each.
pub fn describe() -> String {
    let q = quality();
    let mib = |b: u64| b >> 20;
    let mut out = String::new();
    let mut line = |k: &str, v: String| {
        let l = format!("{k:<24} {v}");
        out.push_str(l.trim_end());
        out.push('\n');
    };
    line("scene", DEFAULT_SCENE.to_string());
    line("image", format!("{}x{}", WIDTH, HEIGHT));
    line("samples/area", SAMPLES_PER_AREA_LIGHT.to_string());
    line("lights per node", q.lights_per_node.to_string());
    line(
        "shadow map",
        match q.map_sizing {
            crate::model::MapSizing::Fixed => format!("{}²", q.shadow_map_size),
            crate::model::MapSizing::Mismatch(m) => format!(
                "per light from the mismatch factor: m = {} at the median lit point, {}² to {}² \
                 ({}² where nothing seen is lit; --shadow-map-size N fixes every map)",
                m.target, m.min, m.max, q.shadow_map_size
            ),
        },
    );
    line("filter", format!("{:?}", q.filter));
    line("antialiasing", "--aa 1 (one sample per pixel)".to_string());
    line("limits:", String::new());
    line(
        "  image",
        format!(
            "at most {} per side and {} pixels (4096x4096)",
            crate::limits::MAX_IMAGE_SIDE,
            crate::limits::MAX_IMAGE_PIXELS
        ),
    );
    line(
        "  --aa N",
        "N·width x N·height within the image limit (rendered, then resolved)".to_string(),
    );
    line(
        "  shadow map",
        format!("at most {}²", crate::limits::MAX_SHADOW_MAP_SIZE),
    );
    line(
        "  samples/area light",
        format!("at most {}", crate::limits::MAX_SAMPLES_PER_AREA_LIGHT),
    );
    line(
        "  light samples",
        format!("at most {} per scene", crate::limits::MAX_LIGHT_SAMPLES),
    );
    line(
        "  triangles",
        format!("at most {} per scene", crate::limits::MAX_TRIANGLES),
    );
    line(
        "  model files",
        format!(
            "at most {} vertices per OBJ, PLY or USD stage, {} meshes and {} materials per OBJ \
             or USD stage",
            crate::limits::MAX_VERTICES,
            crate::limits::MAX_MODEL_MESHES,
            crate::limits::MAX_MODEL_MATERIALS
        ),
    );
    line(
        "  USD stages",
        format!(
            "at most {} prims composed and {} layer reads per stage",
            crate::usd_load::MAX_PRIMS,
            crate::usd_load::MAX_LAYER_READS
        ),
    );
    line(
        "  scene bytes",
        format!(
            "at most {} MiB of files read, {} MiB decoded, {} MiB on the wire",
            mib(crate::limits::MAX_SCENE_BYTES),
            mib(crate::limits::MAX_SCENE_BYTES),
            mib(crate::limits::MAX_SCENE_BYTES)
        ),
    );
    line(
        "  scene file",
        format!("at most {} MiB", mib(crate::limits::MAX_SCENE_FILE_BYTES)),
    );
    line(
        "  texture",
        format!("at most {} per side", crate::limits::MAX_TEXTURE_SIDE),
    );
    out
}
