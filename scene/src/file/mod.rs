//! Scene files (TOML, `version = 1`, unknown fields rejected) and [`load`], the one entry point
//! that accepts a built-in name, a `.toml` scene file or a `.gltf` / `.glb`, `.obj`, `.ply` or
//! USD (`.usda`, `.usdc`, `.usdz`, `.usd`) model.
//!
//! A scene file references a model (glTF, OBJ, PLY or USD, relative to the file) and/or builds primitives (plane, box,
//! sphere, cylinder) with materials, and sets camera, lights, ambient, exposure and quality.
//! Whatever it leaves out is completed like a bare glTF: a framed camera, and without lights a
//! rectangular area light (plus a ground plane when the file builds no objects).

mod build;
pub mod save;
pub mod spec;

pub use spec::SceneFile;

use crate::builtin::{builtin, builtin_names, is_builtin};
use crate::error::SceneError;
use crate::gltf_load::load_gltf;
use crate::model::Scene;
use std::path::Path;

/// Loads a built-in scene by name, a `.toml` scene file, or a `.gltf` / `.glb`, `.obj`, `.ply` or
/// USD model (a model alone is completed with a framed camera and, without lights, a light and a
/// ground plane).
pub fn load(path_or_builtin: &str) -> Result<Scene, SceneError> {
    if is_builtin(path_or_builtin) {
        return builtin(path_or_builtin);
    }
    let path = Path::new(path_or_builtin);
    match loader_for(path) {
        Some(load) => load(path),
        None => Err(SceneError::UnknownInput {
            input: path_or_builtin.to_string(),
            known: format!("{}, city[:N]", builtin_names().join(", ")),
        }),
    }
}

/// [`load`], playing the animation `clip` (by name or index) of a glTF model (`.gltf`/`.glb`);
/// without a clip, [`load`]. A clip for any other input is [`SceneError::ClipOfNonGltf`].
pub fn load_with_clip(path_or_builtin: &str, clip: Option<&str>) -> Result<Scene, SceneError> {
    let Some(clip) = clip else {
        return load(path_or_builtin);
    };
    let path = Path::new(path_or_builtin);
    let gltf = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("gltf") || e.eq_ignore_ascii_case("glb"));
    if !gltf {
        return Err(SceneError::ClipOfNonGltf {
            input: path_or_builtin.to_string(),
        });
    }
    let opts = crate::GltfOptions {
        animation: Some(clip.to_string()),
        ..Default::default()
    };
    crate::load_gltf_with(path, &opts)
}

/// Whether [`load`] reads a file named like `path` (by its extension, any case).
pub fn is_loadable(path: &Path) -> bool {
    loader_for(path).is_some()
}

/// A loader of one file format.
type Loader = fn(&Path) -> Result<Scene, SceneError>;

/// The loader of a file by its extension: the one dispatch of [`load`] and [`is_loadable`].
fn loader_for(path: &Path) -> Option<Loader> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    Some(match ext.as_str() {
        "toml" => load_scene_file,
        "gltf" | "glb" => load_gltf,
        "obj" => crate::obj_load::load_obj,
        "ply" => crate::ply_load::load_ply,
        "usda" | "usdc" | "usdz" | "usd" => crate::usd_load::load_usd,
        _ => return None,
    })
}

/// Reads and builds a scene file (a regular file of at most
/// [`crate::limits::MAX_SCENE_FILE_BYTES`]); a referenced model is resolved relative to the
/// file's folder and must lie inside it.
pub fn load_scene_file(path: &Path) -> Result<Scene, SceneError> {
    let file = read_scene_file(path)?;
    let label = path.display().to_string();
    build_checked(&file, &label, Some(crate::gltf_load::model_folder(path)))
}

/// Reads and parses a scene file without building it: a regular file of at most
/// [`crate::limits::MAX_SCENE_FILE_BYTES`], UTF-8, version-checked.
pub fn read_scene_file(path: &Path) -> Result<SceneFile, SceneError> {
    let label = path.display().to_string();
    let io = |message: String| SceneError::Io {
        path: label.clone(),
        message,
    };
    let bytes =
        crate::input::read_bounded(path, crate::limits::MAX_SCENE_FILE_BYTES).map_err(io)?;
    let text = String::from_utf8(bytes).map_err(|_| io("the file is not UTF-8 text".into()))?;
    parse(&text, &label)
}

/// Builds a scene from scene-file text; `label` names it in errors, `base` is the folder the
/// glTF path is resolved in (and must stay inside; the current folder when `None`). The scene is
/// checked against [`crate::limits`].
pub fn parse_scene_file(text: &str, label: &str, base: Option<&Path>) -> Result<Scene, SceneError> {
    build_checked(&parse(text, label)?, label, base)
}

/// Builds a parsed scene file and checks the scene against [`crate::limits`].
fn build_checked(file: &SceneFile, label: &str, base: Option<&Path>) -> Result<Scene, SceneError> {
    let scene = build::build(file, label, base)?;
    scene
        .check_limits()
        .map_err(|e| SceneError::limit(label, e))?;
    Ok(scene)
}

/// Parses and version-checks scene-file text without building it.
pub fn parse(text: &str, label: &str) -> Result<SceneFile, SceneError> {
    let err = |m: String| SceneError::file(label, m);
    if text.len() as u64 > crate::limits::MAX_SCENE_FILE_BYTES {
        return Err(err(format!(
            "{} bytes exceed the {}-byte limit of a scene file",
            text.len(),
            crate::limits::MAX_SCENE_FILE_BYTES
        )));
    }
    // The version is read first so that a newer file gets a version error, not a field error.
    let table: toml::Table = toml::from_str(text).map_err(|e| err(e.to_string()))?;
    match table.get("version") {
        Some(toml::Value::Integer(v)) if *v == spec::VERSION as i64 => {}
        Some(toml::Value::Integer(v)) => {
            return Err(SceneError::Version {
                path: label.to_string(),
                found: (*v).clamp(0, u32::MAX as i64) as u32,
                supported: spec::VERSION,
            });
        }
        Some(_) => return Err(err("`version` must be an integer".into())),
        None => return Err(err(format!("missing `version = {}`", spec::VERSION))),
    }
    toml::from_str(text).map_err(|e| err(e.to_string()))
}

/// The TOML text of a scene file (what [`parse`] reads back to an equal value).
pub fn to_toml(file: &SceneFile) -> Result<String, SceneError> {
    toml::to_string_pretty(file).map_err(|e| SceneError::Encode {
        scene: file.name.clone().unwrap_or_default(),
        message: e.to_string(),
    })
}
