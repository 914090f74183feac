//! lightfold's WGSL shaders, as source strings, validated by a naga unit test so a broken shader
//! fails `cargo test` without a GPU.
//!
//! Depends on nothing; the node crate builds its pipelines from these sources. WGSL has no
//! includes, so each pipeline's module is a concatenation of the shared pieces it needs.

/// Lighting maths mirrored from `scene::shading`.
pub const SHADING_WGSL: &str = include_str!("../wgsl/shading.wgsl");
/// Materials, textures and alpha masking (group 0), shared by every pass.
pub const MATERIALS_WGSL: &str = include_str!("../wgsl/materials.wgsl");

/// Shadow pass: entry points `vs_depth` (opaque casters, no fragment stage),
/// `vs_masked`/`fs_masked` (alpha-masked casters), and `vs_masked` with `fs_translucent_depth` /
/// `fs_transmit` (translucent casters' depth and transmittance maps).
pub const SHADOW_WGSL: &str = concat!(
    include_str!("../wgsl/shading.wgsl"),
    include_str!("../wgsl/materials.wgsl"),
    include_str!("../wgsl/shadow.wgsl"),
);

/// An eye module: `const METALLIC_ROUGHNESS` (`$mr`: some material is glTF metallic-roughness),
/// the shared pieces, the lights' binding (`$lights`), the vertex stage (`$vertex`: with or
/// without tangents) and the pass (`$pass`).
macro_rules! eye_module {
    ($mr:literal, $lights:literal, $vertex:literal, $pass:literal) => {
        concat!(
            "const METALLIC_ROUGHNESS: bool = ",
            $mr,
            ";\n",
            include_str!("../wgsl/shading.wgsl"),
            include_str!("../wgsl/materials.wgsl"),
            include_str!("../wgsl/lighting.wgsl"),
            include_str!(concat!("../wgsl/", $lights)),
            include_str!(concat!("../wgsl/", $vertex)),
            include_str!("../wgsl/eye.wgsl"),
            include_str!(concat!("../wgsl/", $pass)),
        )
    };
    ($mr:literal, $lights:literal, $vertex:literal, $pass:literal, $extra:literal) => {
        concat!(
            "const METALLIC_ROUGHNESS: bool = ",
            $mr,
            ";\n",
            include_str!("../wgsl/shading.wgsl"),
            include_str!("../wgsl/materials.wgsl"),
            include_str!("../wgsl/lighting.wgsl"),
            include_str!(concat!("../wgsl/", $lights)),
            include_str!(concat!("../wgsl/", $vertex)),
            include_str!("../wgsl/eye.wgsl"),
            include_str!(concat!("../wgsl/", $pass)),
            include_str!(concat!("../wgsl/", $extra)),
        )
    };
}

/// Forward eye pass: `vs_eye` with `fs_illumination` (illumination + depth) or `fs_layers` (plus
/// the material layers m^d, m^s, m^a, e as extra render targets); lights and views in storage
/// buffers. For scenes without metallic-roughness materials.
pub const FORWARD_WGSL: &str = eye_module!(
    "false",
    "lights_storage.wgsl",
    "eye_vertex.wgsl",
    "forward.wgsl"
);

/// [`FORWARD_WGSL`] with glTF metallic-roughness shading.
pub const FORWARD_MR_WGSL: &str = eye_module!(
    "true",
    "lights_storage.wgsl",
    "eye_vertex.wgsl",
    "forward.wgsl"
);

/// [`FORWARD_MR_WGSL`] for a scene with normal maps: `vs_eye` also takes each vertex's tangent
/// (`@location(6)`, a second vertex buffer).
pub const FORWARD_MR_MAPPED_WGSL: &str = eye_module!(
    "true",
    "lights_storage.wgsl",
    "eye_vertex_mapped.wgsl",
    "forward.wgsl"
);

/// Deferred variant: `vs_eye` with `fs_gbuffer` / `fs_gbuffer_layers`, then the compute pass
/// `cs_lights` once per chunk of [`CHUNK_LIGHTS`] lights held in uniform buffers. For scenes
/// without metallic-roughness materials.
pub const DEFERRED_WGSL: &str = eye_module!(
    "false",
    "lights_uniform.wgsl",
    "eye_vertex.wgsl",
    "deferred.wgsl"
);

/// [`DEFERRED_WGSL`] with glTF metallic-roughness shading.
pub const DEFERRED_MR_WGSL: &str = eye_module!(
    "true",
    "lights_uniform.wgsl",
    "eye_vertex.wgsl",
    "deferred.wgsl"
);

/// [`DEFERRED_MR_WGSL`] for a scene with normal maps (see [`FORWARD_MR_MAPPED_WGSL`]).
pub const DEFERRED_MR_MAPPED_WGSL: &str = eye_module!(
    "true",
    "lights_uniform.wgsl",
    "eye_vertex_mapped.wgsl",
    "deferred.wgsl"
);

/// The eye modules (forward, deferred) a scene's pipelines are built from: with glTF
/// metallic-roughness shading where some material is, with per-vertex tangents where some
/// normal-mapped mesh is (only metallic-roughness materials have normal maps).
pub fn eye_modules(metallic_roughness: bool, normal_mapped: bool) -> (&'static str, &'static str) {
    match (metallic_roughness, normal_mapped) {
        (false, _) => (FORWARD_WGSL, DEFERRED_WGSL),
        (true, false) => (FORWARD_MR_WGSL, DEFERRED_MR_WGSL),
        (true, true) => (FORWARD_MR_MAPPED_WGSL, DEFERRED_MR_MAPPED_WGSL),
    }
}

/// Peeled eye layers (`NodeConfig::peel`): the forward module with `peel.wgsl` after it, entry
/// points `fs_peel_opaque_illumination` / `fs_peel_opaque_layers` (the opaque layer),
/// `fs_peel_opaque` (its depth alone), `fs_peel_depth` and `fs_peel_layers` (a translucent
/// layer's peel passes); the previous pass's eye depth and [`PEEL_EPSILON`] in group 2. A module
/// of its own, so the forward pass's is what it was.
pub const PEEL_WGSL: &str = eye_module!(
    "false",
    "lights_storage.wgsl",
    "eye_vertex.wgsl",
    "forward.wgsl",
    "peel.wgsl"
);

/// [`PEEL_WGSL`] with glTF metallic-roughness shading.
pub const PEEL_MR_WGSL: &str = eye_module!(
    "true",
    "lights_storage.wgsl",
    "eye_vertex.wgsl",
    "forward.wgsl",
    "peel.wgsl"
);

/// [`PEEL_MR_WGSL`] for a scene with normal maps.
pub const PEEL_MR_MAPPED_WGSL: &str = eye_module!(
    "true",
    "lights_storage.wgsl",
    "eye_vertex_mapped.wgsl",
    "forward.wgsl",
    "peel.wgsl"
);

/// Peel 0 in the deferred variant: the deferred module with `peel_gbuffer.wgsl` after it, entry
/// points `fs_gbuffer_peel` / `fs_gbuffer_layers_peel` (the G-buffer rasters with every
/// translucent material rejected).
pub const PEEL_DEFERRED_WGSL: &str = eye_module!(
    "false",
    "lights_uniform.wgsl",
    "eye_vertex.wgsl",
    "deferred.wgsl",
    "peel_gbuffer.wgsl"
);

/// [`PEEL_DEFERRED_WGSL`] with glTF metallic-roughness shading.
pub const PEEL_DEFERRED_MR_WGSL: &str = eye_module!(
    "true",
    "lights_uniform.wgsl",
    "eye_vertex.wgsl",
    "deferred.wgsl",
    "peel_gbuffer.wgsl"
);

/// [`PEEL_DEFERRED_MR_WGSL`] for a scene with normal maps.
pub const PEEL_DEFERRED_MR_MAPPED_WGSL: &str = eye_module!(
    "true",
    "lights_uniform.wgsl",
    "eye_vertex_mapped.wgsl",
    "deferred.wgsl",
    "peel_gbuffer.wgsl"
);

/// The deferred peel-0 module for a scene (see [`eye_modules`]).
pub fn peel_deferred_module(metallic_roughness: bool, normal_mapped: bool) -> &'static str {
    match (metallic_roughness, normal_mapped) {
        (false, _) => PEEL_DEFERRED_WGSL,
        (true, false) => PEEL_DEFERRED_MR_WGSL,
        (true, true) => PEEL_DEFERRED_MR_MAPPED_WGSL,
    }
}

/// The peel module for a scene (see [`eye_modules`]).
pub fn peel_module(metallic_roughness: bool, normal_mapped: bool) -> &'static str {
    match (metallic_roughness, normal_mapped) {
        (false, _) => PEEL_WGSL,
        (true, false) => PEEL_MR_WGSL,
        (true, true) => PEEL_MR_MAPPED_WGSL,
    }
}

/// A peel pass keeps a translucent fragment only where its eye depth exceeds the previous pass's
/// by more than this fraction of it: a surface is never found twice (the same triangle's depth
/// is recomputed bit for bit, and a mesh's shared edges are rasterised once), and two
/// translucent surfaces nearer each other than 1e-5 of their depth (10 µm at 1 m; the CPU
/// reference's ε is 1e-5 of the scene's diagonal) count as one, the nearer drawn.
pub const PEEL_EPSILON: f32 = 1e-5;

/// Lights one `cs_lights` dispatch takes (`CHUNK_LIGHTS` in `lights_uniform.wgsl`).
pub const CHUNK_LIGHTS: usize = 64;
/// Views one `cs_lights` dispatch takes (`CHUNK_VIEWS`): six per light.
pub const CHUNK_VIEWS: usize = 384;

/// Pipeline-overridable constants of the eye modules: the sample kinds handled (bit mask of
/// `KIND_*`), the ways lights pick their view (bit mask of `MODE_*`), the shadow filter
/// (`FILTER_*`) and its taps per axis.
pub const OVERRIDE_LIGHT_KINDS: &str = "LIGHT_KINDS";
pub const OVERRIDE_VIEW_MODES: &str = "VIEW_MODES";
/// Whether any light has a range window (`bool`).
pub const OVERRIDE_LIGHT_RANGES: &str = "LIGHT_RANGES";
pub const OVERRIDE_SHADOW_FILTER: &str = "SHADOW_FILTER";
pub const OVERRIDE_SHADOW_TAPS: &str = "SHADOW_TAPS";
/// Whether the pipeline reads transmittance maps (`bool`): only a scene with translucent casters
/// needs it (`docs/translucency.md`).
pub const OVERRIDE_TRANSLUCENT: &str = "TRANSLUCENT";

/// The node's pack pass: `cs_pack` writes one layer of a frame in its link format, bit for bit
/// what `protocol::format::pack` writes (`node::gpu::pack`).
pub const PACK_WGSL: &str = include_str!("../wgsl/pack.wgsl");

/// The node's ambient-mask pass: `cs_ambient_mask` writes eq. 7's `I^a = m^a ⊘ m^d` from the eye
/// pass's material targets (`node::gpu::ambient_mask`).
pub const AMBIENT_MASK_WGSL: &str = include_str!("../wgsl/ambient_mask.wgsl");

/// The eye pass's occlusion culling: `cs_reduce_depth` and `cs_reduce` build a hierarchical depth
/// of the farthest depth per texel, `cs_test` tests boxes against it (`node::gpu::occlusion`).
/// The occluders' depth pass is the forward module's `fs_occluder`.
pub const OCCLUSION_WGSL: &str = include_str!("../wgsl/occlusion.wgsl");

/// Every complete shader module with a name, for validation and diagnostics.
pub const MODULES: &[(&str, &str)] = &[
    ("shadow", SHADOW_WGSL),
    ("forward", FORWARD_WGSL),
    ("forward, metallic-roughness", FORWARD_MR_WGSL),
    (
        "forward, metallic-roughness, normal-mapped",
        FORWARD_MR_MAPPED_WGSL,
    ),
    ("deferred", DEFERRED_WGSL),
    ("deferred, metallic-roughness", DEFERRED_MR_WGSL),
    (
        "deferred, metallic-roughness, normal-mapped",
        DEFERRED_MR_MAPPED_WGSL,
    ),
    ("peel", PEEL_WGSL),
    ("peel, metallic-roughness", PEEL_MR_WGSL),
    (
        "peel, metallic-roughness, normal-mapped",
        PEEL_MR_MAPPED_WGSL,
    ),
    ("pack", PACK_WGSL),
    ("ambient mask", AMBIENT_MASK_WGSL),
    ("occlusion", OCCLUSION_WGSL),
];

#[cfg(test)]
mod tests {
    use super::*;

    fn validate(name: &str, src: &str) -> naga::Module {
        let module = naga::front::wgsl::parse_str(src)
            .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(src)));
        naga::valid::Validator::new(
            naga::valid::ValidationFlags::all(),
            naga::valid::Capabilities::empty(),
        )
        .validate(&module)
        .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(src)));
        module
    }

    #[test]
    fn every_module_parses_and_validates() {
        for (name, src) in MODULES {
            validate(name, src);
        }
    }

    #[test]
    fn entry_points_the_renderer_uses_exist() {
        let names = |src: &str, name: &str| -> Vec<String> {
            validate(name, src)
                .entry_points
                .iter()
                .map(|e| e.name.clone())
                .collect()
        };
        let shadow = names(SHADOW_WGSL, "shadow");
        for e in [
            "vs_depth",
            "fs_depth",
            "vs_masked",
            "fs_masked",
            "fs_translucent_depth",
            "fs_transmit",
        ] {
            assert!(shadow.iter().any(|n| n == e), "shadow lacks {e}");
        }
        assert!(names(PACK_WGSL, "pack").iter().any(|n| n == "cs_pack"));
        assert!(
            names(AMBIENT_MASK_WGSL, "ambient mask")
                .iter()
                .any(|n| n == "cs_ambient_mask")
        );
        let occlusion = names(OCCLUSION_WGSL, "occlusion");
        for e in ["cs_reduce_depth", "cs_reduce", "cs_test"] {
            assert!(occlusion.iter().any(|n| n == e), "occlusion lacks {e}");
        }
        for src in [FORWARD_WGSL, FORWARD_MR_WGSL, FORWARD_MR_MAPPED_WGSL] {
            let forward = names(src, "forward");
            for e in [
                "vs_eye",
                "fs_illumination",
                "fs_layers",
                "fs_eye_filter",
                "fs_occluder",
            ] {
                assert!(forward.iter().any(|n| n == e), "forward lacks {e}");
            }
        }
        for src in [PEEL_WGSL, PEEL_MR_WGSL, PEEL_MR_MAPPED_WGSL] {
            let peel = names(src, "peel");
            for e in [
                "vs_eye",
                "fs_peel_opaque_illumination",
                "fs_peel_opaque_layers",
                "fs_peel_opaque",
                "fs_peel_depth",
                "fs_peel_layers",
            ] {
                assert!(peel.iter().any(|n| n == e), "peel lacks {e}");
            }
        }
        for src in [
            PEEL_DEFERRED_WGSL,
            PEEL_DEFERRED_MR_WGSL,
            PEEL_DEFERRED_MR_MAPPED_WGSL,
        ] {
            let peel = names(src, "peel deferred");
            for e in ["vs_eye", "fs_gbuffer_peel", "fs_gbuffer_layers_peel"] {
                assert!(peel.iter().any(|n| n == e), "peel deferred lacks {e}");
            }
        }
        for src in [DEFERRED_WGSL, DEFERRED_MR_WGSL, DEFERRED_MR_MAPPED_WGSL] {
            let deferred = names(src, "deferred");
            for e in [
                "vs_eye",
                "fs_gbuffer",
                "fs_gbuffer_layers",
                "fs_eye_filter",
                "cs_lights",
            ] {
                assert!(deferred.iter().any(|n| n == e), "deferred lacks {e}");
            }
        }
    }

    #[test]
    fn chunk_sizes_match_the_wgsl() {
        for (name, value) in [("CHUNK_LIGHTS", CHUNK_LIGHTS), ("CHUNK_VIEWS", CHUNK_VIEWS)] {
            let decl = format!("const {name}: u32 = {value}u;");
            assert!(DEFERRED_WGSL.contains(&decl), "{decl} missing");
        }
        for (name, ty) in [
            (OVERRIDE_LIGHT_KINDS, "u32"),
            (OVERRIDE_VIEW_MODES, "u32"),
            (OVERRIDE_LIGHT_RANGES, "bool"),
            (OVERRIDE_SHADOW_FILTER, "u32"),
            (OVERRIDE_SHADOW_TAPS, "u32"),
            (OVERRIDE_TRANSLUCENT, "bool"),
        ] {
            for (module, src) in [("forward", FORWARD_WGSL), ("deferred", DEFERRED_WGSL)] {
                let decl = format!("override {name}: {ty}");
                assert!(src.contains(&decl), "{module}: {decl}");
            }
        }
    }

    #[test]
    fn a_broken_shader_fails_validation() {
        // The check itself must be able to fail: a type error is caught without a GPU.
        let broken = DEFERRED_WGSL.replace("s.intensity * abs(c)", "abs(c) + 1u");
        assert_ne!(broken, DEFERRED_WGSL);
        let parsed = naga::front::wgsl::parse_str(&broken);
        let failed = match parsed {
            Err(_) => true,
            Ok(m) => naga::valid::Validator::new(
                naga::valid::ValidationFlags::all(),
                naga::valid::Capabilities::empty(),
            )
            .validate(&m)
            .is_err(),
        };
        assert!(failed);
    }
}
