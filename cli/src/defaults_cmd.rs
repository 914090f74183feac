//! `lightfold defaults`: the project defaults of ARCHITECTURE §10, and the limits every input is
//! checked against (`lightfold_scene::limits`).

use lightfold_scene::{defaults, limits};

#[derive(Debug, clap::Args)]
pub(crate) struct Args {}

pub(crate) fn run(_args: Args) -> anyhow::Result<()> {
    print!("{}", text());
    Ok(())
}

fn text() -> String {
    let q = defaults::quality();
    let mib = |b: u64| b >> 20;
    let mut out = String::new();
    let mut line = |k: &str, v: String| {
        let l = format!("{k:<24} {v}");
        out.push_str(l.trim_end());
        out.push('\n');
    };
    line("scene", defaults::DEFAULT_SCENE.to_string());
    line("image", format!("{}x{}", defaults::WIDTH, defaults::HEIGHT));
    line("samples/area", defaults::SAMPLES_PER_AREA_LIGHT.to_string());
    line("lights per node", q.lights_per_node.to_string());
    line(
        "shadow map",
        match q.map_sizing {
            lightfold_scene::MapSizing::Fixed => format!("{}²", q.shadow_map_size),
            lightfold_scene::MapSizing::Mismatch(m) => format!(
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
            limits::MAX_IMAGE_SIDE,
            limits::MAX_IMAGE_PIXELS
        ),
    );
    line(
        "  --aa N",
        "N·width x N·height within the image limit (rendered, then resolved)".to_string(),
    );
    line(
        "  shadow map",
        format!("at most {}²", limits::MAX_SHADOW_MAP_SIZE),
    );
    line(
        "  samples/area light",
        format!("at most {}", limits::MAX_SAMPLES_PER_AREA_LIGHT),
    );
    line(
        "  light samples",
        format!("at most {} per scene", limits::MAX_LIGHT_SAMPLES),
    );
    line(
        "  triangles",
        format!("at most {} per scene", limits::MAX_TRIANGLES),
    );
    line(
        "  model files",
        format!(
            "at most {} vertices per OBJ, PLY or USD stage, {} meshes and {} materials per OBJ \
             or USD stage",
            limits::MAX_VERTICES,
            limits::MAX_MODEL_MESHES,
            limits::MAX_MODEL_MATERIALS
        ),
    );
    line(
        "  USD stages",
        format!(
            "at most {} prims composed and {} layer reads per stage",
            lightfold_scene::usd_load::MAX_PRIMS,
            lightfold_scene::usd_load::MAX_LAYER_READS
        ),
    );
    line(
        "  scene bytes",
        format!(
            "at most {} MiB of files read, {} MiB decoded, {} MiB on the wire",
            mib(limits::MAX_SCENE_BYTES),
            mib(limits::MAX_SCENE_BYTES),
            mib(limits::MAX_SCENE_BYTES)
        ),
    );
    line(
        "  scene file",
        format!("at most {} MiB", mib(limits::MAX_SCENE_FILE_BYTES)),
    );
    line(
        "  texture",
        format!("at most {} per side", limits::MAX_TEXTURE_SIDE),
    );
    out
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_limits_are_printed() {
        let t = super::text();
        for want in [
            "800x600",
            "at most 8192 per side and 16777216 pixels (4096x4096)",
            "at most 4096²",
            "samples/area light",
            "N·width x N·height within the image limit",
            "at most 16384 per scene",
            "at most 10000000 per scene",
            "at most 1024 MiB of files read",
            "at most 16 MiB",
        ] {
            assert!(t.contains(want), "{want:?} missing from\n{t}");
        }
    }
}
