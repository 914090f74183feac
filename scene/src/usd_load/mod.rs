//! USD stages (`.usda`, `.usdc`, `.usdz`) loaded into a [`Scene`] through the `openusd` crate,
//! which composes the stage (sublayers, references, payloads, variants, instancing): meshes
//! (`UsdGeomMesh`, fan-triangulated) under their composed `Xform` stacks, `UsdPreviewSurface`
//! materials (or `primvars:displayColor`), the first `UsdGeomCamera`, and UsdLux lights (mesh
//! lights included) as lightfold's area lights (`light.rs`; the mapping and units are in `docs/scenes.md` § USD).
//! Features it does not use are listed in one warning.
//!
//! Untrusted input: the stage is read only through [`resolve::Confined`], which serves the
//! root's bytes and reads every other layer inside the root's folder as a regular file under one
//! byte budget, refusing (and failing the load on) any path outside it; composition errors
//! (arc cycles, unresolved layers) fail the load too. Counts are checked against
//! [`crate::limits`] before meshes are built, every index against its array, and the crate is
//! guarded against panics.

mod light;
mod mesh;
mod motion;
mod resolve;
mod walk;

use crate::error::SceneError;
use crate::gltf_load::{Imported, model_folder};
use crate::limits::{self, Budget, LimitError};
use crate::model::Scene;
use crate::model_file::{ModelOptions, finish, stem};
use std::collections::BTreeSet;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;
use std::rc::Rc;

pub use resolve::MAX_LAYER_READS;
pub use walk::MAX_PRIMS;

/// Loads a `.usda`, `.usdc`, `.usdz` or `.usd` stage with default options.
pub fn load_usd(path: &Path) -> Result<Scene, SceneError> {
    load_usd_with(path, &ModelOptions::default())
}

/// Loads a USD stage; the layers it names are read only inside its folder.
pub fn load_usd_with(path: &Path, opts: &ModelOptions) -> Result<Scene, SceneError> {
    let label = path.display().to_string();
    let bytes = crate::gltf_load::read_model(path)?;
    let imported = import(
        &bytes,
        &label,
        &stem(path, "usd"),
        Some(model_folder(path)),
        opts,
    )?;
    finish(imported, &label, opts.complete, "USD")
}

/// Loads the bytes of a USD layer (text, binary or a `.usdz` package, told apart by their
/// first bytes); `label` names them in errors, `base` is the folder the layers it names are
/// read in (and must stay inside); without `base` it may name none.
pub fn load_usd_slice(
    bytes: &[u8],
    label: &str,
    base: Option<&Path>,
    opts: &ModelOptions,
) -> Result<Scene, SceneError> {
    let imported = import(bytes, label, &stem(Path::new(label), "usd"), base, opts)?;
    finish(imported, label, opts.complete, "USD")
}

/// The USD features a stage uses that lightfold does not render, as the loader's warning lists
/// them (empty when everything it uses is rendered).
pub fn ignored_features(path: &Path) -> Result<Vec<String>, SceneError> {
    let label = path.display().to_string();
    let bytes = crate::gltf_load::read_model(path)?;
    let opts = ModelOptions {
        complete: false,
        ..ModelOptions::default()
    };
    Ok(import(&bytes, &label, &label, Some(model_folder(path)), &opts)?.ignored)
}

/// The file name the root layer is given: the label's stem with the extension its bytes call
/// for (the crate picks the format by extension).
fn root_name(bytes: &[u8], label: &str) -> String {
    let ext = if bytes.starts_with(b"PXR-USDC") {
        "usdc"
    } else if bytes.starts_with(b"PK\x03\x04") {
        "usdz"
    } else {
        "usda"
    };
    let stem: String = stem(Path::new(label), "stage")
        .chars()
        .filter(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'))
        .take(64)
        .collect();
    format!("{}.{ext}", if stem.is_empty() { "stage" } else { &stem })
}

pub(crate) fn import(
    bytes: &[u8],
    label: &str,
    name: &str,
    base: Option<&Path>,
    opts: &ModelOptions,
) -> Result<Imported, SceneError> {
    let err = |message: String| SceneError::Usd {
        path: label.to_string(),
        message,
    };
    let limit = |e: LimitError| SceneError::limit(label, e);
    let files = Budget::new("the stage's files");
    files.take(bytes.len() as u64).map_err(limit)?;
    let base = match base {
        Some(b) => Some(b.canonicalize().map_err(|e| SceneError::Io {
            path: b.display().to_string(),
            message: e.to_string(),
        })?),
        None => None,
    };
    let shared = Rc::new(resolve::Shared::new(
        &root_name(bytes, label),
        bytes.to_vec(),
        base,
        files,
        opts.binary_usd,
    ));
    let mut ignored = BTreeSet::new();
    let converted = catch_unwind(AssertUnwindSafe(|| {
        walk::convert(Rc::clone(&shared), name, opts, &mut ignored)
    }))
    .map_err(|p| err(format!("the USD reader panicked: {}", panic_text(&p))))?;
    // A refused path is named even when composition went on without it.
    if let Some(first) = shared.refused.borrow().first() {
        return Err(err(format!("refused: {first}")));
    }
    let (scene, has_camera) = converted.map_err(|e| match e {
        walk::Error::Usd(m) => err(m),
        walk::Error::Limit(e) => limit(e),
    })?;
    let ignored: Vec<String> = ignored.into_iter().collect();
    if !ignored.is_empty() {
        tracing::warn!(scene = name, ignored = %ignored.join(", "), "USD features ignored");
    }
    Ok(Imported {
        scene,
        has_camera,
        ignored,
    })
}

fn panic_text(p: &Box<dyn std::any::Any + Send>) -> String {
    p.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".into())
}

/// Checks a running count against its limit (a `walk` helper).
fn count(what: &'static str, count: u64, limit: u64) -> Result<(), walk::Error> {
    limits::check_count(what, count, limit).map_err(walk::Error::Limit)
}
