//! The one error type of scene loading, building and decoding. Every variant names the input it
//! came from (a file path, a built-in name or "scene bytes") and what was wrong with it.

/// Why a scene could not be loaded, built or decoded.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error("unknown built-in scene {name:?} (built-ins: {known})")]
    UnknownBuiltin { name: String, known: String },
    #[error("built-in scene {0}")]
    BuiltinSize(String),
    #[error(
        "{input:?} is neither a built-in scene ({known}) nor a .toml, .gltf, .glb, .obj, .ply, .usda, .usdc, .usdz or .usd file"
    )]
    UnknownInput { input: String, known: String },
    #[error("cannot read {path}: {message}")]
    Io { path: String, message: String },
    #[error("{path}: invalid glTF: {message}")]
    Gltf { path: String, message: String },
    #[error("{path}: invalid OBJ: {message}")]
    Obj { path: String, message: String },
    #[error("{path}: invalid PLY: {message}")]
    Ply { path: String, message: String },
    #[error("{path}: invalid USD: {message}")]
    Usd { path: String, message: String },
    #[error("{path}: texture {texture}: {message}")]
    Texture {
        path: String,
        texture: String,
        message: String,
    },
    #[error(
        "{input:?} is not a glTF model (.gltf/.glb): only a glTF's animations are chosen by name \
         (a scene file names its clip as `animation` in its [gltf] table)"
    )]
    ClipOfNonGltf { input: String },
    #[error("{path}: invalid scene file: {message}")]
    SceneFile { path: String, message: String },
    #[error(
        "{path}: scene file version {found} is not supported (this build reads version {supported})"
    )]
    Version {
        path: String,
        found: u32,
        supported: u32,
    },
    #[error("scene {scene:?} is unusable: {message}")]
    Invalid { scene: String, message: String },
    #[error("{input}: {source} (see `lightfold defaults`)")]
    Limit {
        input: String,
        source: crate::limits::LimitError,
    },
    #[error("cannot decode scene bytes: {message}")]
    Decode { message: String },
    #[error("cannot encode scene {scene:?}: {message}")]
    Encode { scene: String, message: String },
}

impl SceneError {
    pub(crate) fn limit(input: &str, source: crate::limits::LimitError) -> Self {
        SceneError::Limit {
            input: input.to_string(),
            source,
        }
    }

    pub(crate) fn file(path: &str, message: String) -> Self {
        SceneError::SceneFile {
            path: path.to_string(),
            message,
        }
    }
}
