//! What the mesh-file loaders (OBJ/MTL, PLY) share with each other and with glTF: placement
//! options, completion of a model given alone, bounded texture decoding, and the reading of the
//! files a model names (only inside its folder).

use crate::error::SceneError;
use crate::framing;
use crate::gltf_load::Imported;
use crate::limits::{Budget, MAX_TEXTURE_SIDE};
use crate::model::{Mesh, Scene};
use std::path::{Path, PathBuf};

/// How an OBJ or PLY model is placed and completed.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelOptions {
    /// Uniform scale applied to every position (e.g. 0.01 for a model in centimetres).
    pub scale: f32,
    /// Translation applied after scaling.
    pub translation: [f32; 3],
    /// Add a framed camera, and a ground plane and area light when the model has no lights
    /// ([`crate::framing::complete`]), as for a glTF given alone.
    pub complete: bool,
    /// Read binary USD layers (`.usdc`, and inside `.usdz`): off unless the environment's
    /// `LIGHTFOLD_TRUST_BINARY_USD=1` says the files are trusted. `openusd` 0.6 allocates the
    /// counts a binary layer claims before checking them, so a hostile 3.5 kB layer can abort
    /// the process (`docs/scenes.md` § USD); text layers are read always.
    pub binary_usd: bool,
}

/// The environment variable that lets binary USD layers be read ([`ModelOptions::binary_usd`]).
pub(crate) const TRUST_BINARY_USD: &str = "LIGHTFOLD_TRUST_BINARY_USD";

impl Default for ModelOptions {
    fn default() -> Self {
        ModelOptions {
            scale: 1.0,
            translation: [0.0; 3],
            complete: true,
            binary_usd: std::env::var_os(TRUST_BINARY_USD).is_some_and(|v| v == "1"),
        }
    }
}

impl ModelOptions {
    /// Places a mesh read in the file's own coordinates (a mirroring negative scale keeps
    /// counter-clockwise front-facing, as [`Mesh::transform`] does).
    pub(crate) fn place(&self, mesh: &mut Mesh) {
        if self.scale == 1.0 && self.translation == [0.0; 3] {
            return;
        }
        mesh.transform(&glam::Affine3A::from_scale_rotation_translation(
            glam::Vec3::splat(self.scale),
            glam::Quat::IDENTITY,
            glam::Vec3::from(self.translation),
        ));
    }
}

/// Completes (when asked), sanitises and checks a converted model; `kind` names the format in
/// the log ("OBJ", "PLY").
pub(crate) fn finish(
    mut imported: Imported,
    label: &str,
    complete: bool,
    kind: &str,
) -> Result<Scene, SceneError> {
    if complete {
        framing::complete(&mut imported.scene, imported.has_camera);
    }
    let report = imported.scene.sanitize();
    if !report.is_clean() {
        tracing::warn!(scene = %imported.scene.name, %report, "{kind} geometry sanitised");
    }
    imported
        .scene
        .check_limits()
        .map_err(|e| SceneError::limit(label, e))?;
    Ok(imported.scene)
}

/// The name a model file gives its scene: its file stem.
pub(crate) fn stem(path: &Path, fallback: &str) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| fallback.into())
}

/// Decodes an image file's bytes to RGBA8: its sides ([`MAX_TEXTURE_SIDE`]) and memory (what
/// `decoded` has left) are checked from its header before it is decoded, and what it decodes to
/// is taken from `decoded`.
pub(crate) fn decode_texture(
    bytes: &[u8],
    name: &str,
    decoded: &Budget,
) -> Result<image::RgbaImage, String> {
    let cannot = |e: &dyn std::fmt::Display| format!("texture {name}: cannot decode: {e}");
    let mut reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| cannot(&e))?;
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_TEXTURE_SIDE);
    limits.max_image_height = Some(MAX_TEXTURE_SIDE);
    limits.max_alloc = Some(decoded.left());
    reader.limits(limits);
    let image = reader.decode().map_err(|e| cannot(&e))?.to_rgba8();
    decoded
        .take(image.len() as u64)
        .map_err(|e| format!("texture {name}: {e}"))?;
    Ok(image)
}

/// A path a model file names (a material library, a texture) resolved inside the model's folder
/// `base`: relative and staying inside it once links are resolved. `relative` is as the file
/// writes it: backslashes are read as separators, a drive letter as absolute.
pub(crate) fn resolve_model_path(base: Option<&Path>, relative: &str) -> Result<PathBuf, String> {
    let rel = relative.replace('\\', "/");
    let b = rel.as_bytes();
    if b.len() >= 2 && b[0].is_ascii_alphabetic() && b[1] == b':' {
        return Err(format!(
            "{relative:?} is an absolute path; only paths relative to the model's folder are read"
        ));
    }
    let base = base.ok_or_else(|| {
        format!(
            "{relative:?} is an external file but the model was given as bytes without a folder"
        )
    })?;
    Ok(crate::input::resolve_inside(base, &rel, "the model's")?)
}

/// The bytes of a resolved path: a regular file, within what `files` has left.
pub(crate) fn read_resolved(path: &Path, files: &Budget) -> Result<Vec<u8>, String> {
    let bytes = crate::input::read_bounded(path, files.left())
        .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    files.take(bytes.len() as u64).map_err(|e| e.to_string())?;
    Ok(bytes)
}
