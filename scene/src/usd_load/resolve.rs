//! The asset resolver a stage is opened through: the root layer comes from the bytes already
//! read, and every other layer a stage names (sublayers, references, payloads, the layers of a
//! `.usdz` package) only from inside the root's folder, as a regular file, under one byte budget
//! for the whole stage. A path that leads outside the folder is refused and remembered, so that
//! the load fails naming it rather than composing without it.

use crate::limits::Budget;
use openusd::ar::{self, Asset, ResolvedPath, Resolver};
use std::cell::{Cell, RefCell};
use std::io::{Cursor, Read};
use std::path::{Component, Path, PathBuf};
use std::rc::Rc;

/// Most layer and package reads one stage may make (a sublayer or reference fan-out that
/// re-reads the same files is bounded by this and by the byte budget).
pub const MAX_LAYER_READS: u32 = 4096;

/// What the resolver of one stage load holds.
#[derive(Debug)]
pub(super) struct Shared {
    /// The root layer's identifier (a path inside `base`, or under `/` without one).
    pub root_id: String,
    pub root: Vec<u8>,
    /// The folder every other file must lie in (canonical); `None`: the stage was given as
    /// bytes and may name no other file.
    pub base: Option<PathBuf>,
    pub files: Budget,
    /// Why a path the stage names was refused (outside the folder, or no folder).
    pub refused: RefCell<Vec<String>>,
    reads: Cell<u32>,
    /// Binary layers are read (`ModelOptions::binary_usd`); else each is refused.
    binary: bool,
}

/// The first bytes of a binary USD layer.
const BINARY_MAGIC: &[u8] = b"PXR-USDC";

impl Shared {
    pub(super) fn new(
        root_name: &str,
        root: Vec<u8>,
        base: Option<PathBuf>,
        files: Budget,
        binary: bool,
    ) -> Shared {
        let root_id = match &base {
            Some(b) => b.join(root_name).to_string_lossy().into_owned(),
            None => format!("/{root_name}"),
        };
        Shared {
            root_id,
            root,
            base,
            files,
            refused: RefCell::new(Vec::new()),
            reads: Cell::new(0),
            binary,
        }
    }

    /// Refuses a binary layer unless they are trusted: the crate would read it (`Err`: why).
    fn check_binary(&self, path: &str, bytes: &[u8]) -> std::io::Result<()> {
        if self.binary || !bytes.starts_with(BINARY_MAGIC) {
            return Ok(());
        }
        let why = binary_refused(path);
        self.refuse(why.clone());
        Err(std::io::Error::other(why))
    }

    fn refuse(&self, message: String) {
        let mut refused = self.refused.borrow_mut();
        if refused.len() < 16 && !refused.contains(&message) {
            refused.push(message);
        }
    }

    /// The file `id` names, inside the folder (links resolved), or why not.
    fn confine(&self, id: &str) -> Option<PathBuf> {
        let Some(base) = &self.base else {
            self.refuse(format!(
                "{id:?} is an external file but the stage was given as bytes without a folder"
            ));
            return None;
        };
        let Ok(relative) = Path::new(id).strip_prefix(base) else {
            self.refuse(format!(
                "{id:?} lies outside the stage's folder {}; only files inside it are read",
                base.display()
            ));
            return None;
        };
        match crate::input::resolve_inside(base, &relative.to_string_lossy(), "the stage's") {
            Ok(path) => Some(path),
            // A missing file is the stage's own composition error ("unresolved layer").
            Err(e) if e.io.is_some() => None,
            Err(e) => {
                self.refuse(e.message);
                None
            }
        }
    }

    /// The bytes of a resolved layer or package (not package-relative).
    fn read(&self, resolved: &str) -> std::io::Result<Vec<u8>> {
        let reads = self.reads.get() + 1;
        self.reads.set(reads);
        if reads > MAX_LAYER_READS {
            return Err(std::io::Error::other(format!(
                "more than {MAX_LAYER_READS} layer reads (a reference or sublayer fan-out)"
            )));
        }
        if resolved == self.root_id {
            return Ok(self.root.clone());
        }
        crate::model_file::read_resolved(Path::new(resolved), &self.files)
            .map_err(std::io::Error::other)
    }

    /// The bytes of `inner` in the package at `package`, read within the budget.
    fn read_packaged(&self, package: &str, inner: &str) -> std::io::Result<Vec<u8>> {
        let bytes = self.read(package)?;
        let mut zip = zip::ZipArchive::new(Cursor::new(bytes)).map_err(std::io::Error::other)?;
        let entry = zip.by_name(inner).map_err(std::io::Error::other)?;
        let left = self.files.left();
        if entry.size() > left {
            return Err(std::io::Error::other(format!(
                "{inner} in {package} unpacks to {} bytes, more than the {left} left of the \
                 stage's budget",
                entry.size()
            )));
        }
        let mut out = Vec::new();
        entry.take(left.saturating_add(1)).read_to_end(&mut out)?;
        self.files
            .take(out.len() as u64)
            .map_err(|e| std::io::Error::other(e.to_string()))?;
        Ok(out)
    }
}

/// The resolver handed to the stage (it owns a share of [`Shared`]).
pub(super) struct Confined(pub Rc<Shared>);

/// `path` with `.` dropped and `..` applied lexically (a `..` above the root is kept, so the
/// result never lands inside the folder by accident).
fn normalize(path: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in path.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                if !out.pop() {
                    out.push("..");
                }
            }
            c => out.push(c),
        }
    }
    out
}

/// A path inside a package joined and normalised (`a/b.usda` + `../c.usda` = `c.usda`).
fn packaged(dir: &str, relative: &str) -> String {
    normalize(&Path::new(dir).join(relative))
        .to_string_lossy()
        .into_owned()
}

impl Resolver for Confined {
    fn create_identifier(&self, asset_path: &str, anchor: Option<&ResolvedPath>) -> String {
        if asset_path.is_empty() {
            return String::new();
        }
        if ar::is_package_relative_path(asset_path) {
            return match ar::split_package_relative_path_outer(asset_path) {
                Some((package, inner)) => ar::join_package_relative_path(
                    &self.create_identifier(&package, anchor),
                    &inner,
                ),
                None => asset_path.to_string(),
            };
        }
        let asset = asset_path.replace('\\', "/");
        if let Some(anchor) = anchor {
            let anchor = anchor.to_string_lossy();
            // Inside a package, a relative path stays inside it.
            if !Path::new(&asset).is_absolute() {
                if ar::is_package_relative_path(&anchor)
                    && let Some((package, inner)) = ar::split_package_relative_path_inner(&anchor)
                {
                    let dir = inner.rsplit_once('/').map_or("", |(d, _)| d);
                    return ar::join_package_relative_path(&package, &packaged(dir, &asset));
                }
                if anchor.to_ascii_lowercase().ends_with(".usdz") {
                    return ar::join_package_relative_path(&anchor, &packaged("", &asset));
                }
            }
            let dir = Path::new(anchor.as_ref())
                .parent()
                .map(Path::to_path_buf)
                .unwrap_or_default();
            return normalize(&dir.join(&asset)).to_string_lossy().into_owned();
        }
        let dir = Path::new(&self.0.root_id)
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_default();
        normalize(&dir.join(&asset)).to_string_lossy().into_owned()
    }

    fn resolve(&self, asset_path: &str) -> Option<ResolvedPath> {
        if asset_path.is_empty() {
            return None;
        }
        if asset_path == self.0.root_id {
            return Some(ResolvedPath::new(asset_path));
        }
        if ar::is_package_relative_path(asset_path) {
            let (package, inner) = ar::split_package_relative_path_outer(asset_path)?;
            let package = self.resolve(&package)?;
            return Some(ResolvedPath::new(ar::join_package_relative_path(
                &package.to_string_lossy(),
                &inner,
            )));
        }
        self.0.confine(asset_path).map(ResolvedPath::new)
    }

    fn resolve_for_new_asset(&self, _asset_path: &str) -> Option<ResolvedPath> {
        None
    }

    fn open_asset(&self, resolved: &ResolvedPath) -> std::io::Result<Box<dyn Asset>> {
        let path = resolved.to_string_lossy();
        let bytes = if ar::is_package_relative_path(&path) {
            let (package, inner) = ar::split_package_relative_path_outer(&path)
                .ok_or_else(|| std::io::Error::other(format!("invalid package path {path}")))?;
            if ar::is_package_relative_path(&package) {
                return Err(std::io::Error::other("nested packages are not read"));
            }
            self.0.read_packaged(&package, &inner)?
        } else {
            self.0.read(&path)?
        };
        self.0.check_binary(&path, &bytes)?;
        Ok(Box::new(Cursor::new(bytes)))
    }

    fn get_modification_timestamp(
        &self,
        _asset_path: &str,
        _resolved: &ResolvedPath,
    ) -> Option<std::time::SystemTime> {
        None
    }
}

/// Why binary layer `path` is not read.
fn binary_refused(path: &str) -> String {
    format!(
        "{path} is a binary USD layer, read only from trusted files ({}=1): the USD reader \
         (openusd 0.6) allocates the counts a binary layer claims before checking them, so a \
         hostile one can abort the process; convert it to text with `usdcat -o stage.usda`",
        crate::model_file::TRUST_BINARY_USD
    )
}
