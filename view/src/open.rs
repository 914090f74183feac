//! Opening another scene from the page (`scene_open`): the scenes a viewer may pick are the
//! built-ins and the scene files and models directly in the folder the view was started with
//! (`--scene-dir`), each named by its file name alone — never a path, so nothing below or outside
//! that folder is reachable. The command line loads a pick as it loads `--scene` (same size and
//! plan options, this scene's error model) on a blocking thread; the loop plans it from the next
//! frame on (`FrameSpec::scene`), and every page is sent the welcome again. A scene the cluster
//! cannot plan is refused by the loop, and the view goes back to the scene it had.

use crate::hub::Hub;
use lightfold_coordinator::plan::PlanOptions;
use lightfold_scene::Scene;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::Ordering;

/// At most this many files of the folder are offered (the first by name).
pub const MAX_LISTED: usize = 500;
/// How long a scene opened holds the next back while the loop has neither taken nor refused it
/// (frames carry a new scene only as room frees in the pipeline).
const SETTLE: std::time::Duration = std::time::Duration::from_secs(120);

/// A scene loaded for the page, as the command line loads `--scene`.
#[derive(Debug)]
pub struct Opened {
    pub scene: Scene,
    /// Its plan options: the session's, with this scene's error model.
    pub options: PlanOptions,
}

/// Loads a pick from what [`SceneCatalog::resolve`] gave: a built-in's name or a file's path.
pub type Opener = dyn Fn(&str) -> anyhow::Result<Opened> + Send + Sync;

/// The scenes a viewer may open, and how they are loaded.
pub struct SceneCatalog {
    /// The folder whose scene files and models are offered (`None`: the built-ins only).
    pub dir: Option<PathBuf>,
    /// Loads a built-in by its name or a file of `dir` by its path.
    pub open: Box<Opener>,
}

impl std::fmt::Debug for SceneCatalog {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SceneCatalog")
            .field("dir", &self.dir)
            .finish_non_exhaustive()
    }
}

impl SceneCatalog {
    /// The names offered: the built-ins (the `city` at its default size), then the regular
    /// files directly in the folder whose extension `lightfold_scene::load` reads, by name.
    pub fn names(&self) -> Vec<String> {
        let mut names: Vec<String> = lightfold_scene::builtin_names()
            .iter()
            .map(|s| s.to_string())
            .chain(std::iter::once("city".to_string()))
            .collect();
        if let Some(dir) = &self.dir {
            names.extend(files(dir));
        }
        names
    }

    /// What `name` loads: a built-in's name, or the path of that file of the folder. `None`
    /// when it is not one of [`SceneCatalog::names`].
    pub fn resolve(&self, name: &str) -> Option<String> {
        if !self.names().iter().any(|n| n == name) {
            return None;
        }
        if lightfold_scene::is_builtin(name) {
            return Some(name.to_string());
        }
        let dir = self.dir.as_ref()?;
        Some(dir.join(name).to_string_lossy().into_owned())
    }
}

/// The loadable regular files directly in `dir` (symbolic links and folders left out), sorted,
/// at most [`MAX_LISTED`]; an unreadable folder lists none.
fn files(dir: &Path) -> Vec<String> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut out: Vec<String> = entries
        .filter_map(Result::ok)
        .filter(|e| e.file_type().is_ok_and(|t| t.is_file()))
        .filter_map(|e| e.file_name().into_string().ok())
        .filter(|n| lightfold_scene::is_loadable(Path::new(n)))
        .collect();
    out.sort();
    out.truncate(MAX_LISTED);
    out
}

/// Starts opening `name` for the viewers: checked against the catalog now, loaded on a blocking
/// thread, then made the scene frames ask for. Refused at once when the view has no catalog, the
/// name is not offered, or another scene is being opened.
pub(crate) fn start(hub: &Arc<Hub>, name: String) -> Result<(), String> {
    let catalog = hub
        .catalog
        .clone()
        .ok_or("this view opens no other scene (start it with --scene-dir, or pick a built-in)")?;
    let source = catalog
        .resolve(&name)
        .ok_or_else(|| format!("{name:?} is not a scene this view offers"))?;
    if hub.opening.swap(true, Ordering::AcqRel) {
        return Err("another scene is being opened".into());
    }
    let hub = Arc::clone(hub);
    tokio::spawn(async move {
        let loaded = {
            let source = source.clone();
            tokio::task::spawn_blocking(move || (catalog.open)(&source)).await
        };
        match loaded {
            Ok(Ok(opened)) => {
                // The next scene waits until the loop has taken this one or refused it: a
                // refusal goes back to the scene before, which must be the one the loop shows.
                let id = hub.install_scene(name, source, opened);
                hub.scene_settled(id, SETTLE).await;
            }
            Ok(Err(e)) => hub.tell(format!("cannot open {name:?}: {e:#}")),
            Err(e) => hub.tell(format!("cannot open {name:?}: {e}")),
        }
        hub.opening.store(false, Ordering::Release);
    });
    Ok(())
}

/// The scene frames show, as the view keeps it: what the page is welcomed with and what a saved
/// session is built from.
#[derive(Debug)]
pub(crate) struct SceneInfo {
    /// `OpenScene::id` (0: the session's first).
    pub id: u64,
    /// How it was named (the command line's `--scene`, or the page's pick).
    pub name: String,
    /// The scene as the page is told it (`crate::json::scene`).
    pub json: serde_json::Value,
    /// Its own exposure, stops (what the page's exposure resets to).
    pub stops: f32,
    /// The scene without its geometry, and the base a saved session names (`crate::save`).
    pub skeleton: Scene,
    pub save_base: Result<String, String>,
    /// Its objects, for picking and moving them (`crate::objects`).
    pub objects: Arc<crate::objects::Objects>,
}

impl SceneInfo {
    pub(crate) fn new(id: u64, name: String, scene: &Scene, source: Option<&str>) -> SceneInfo {
        SceneInfo {
            id,
            name,
            json: crate::json::scene(scene),
            stops: crate::encode::stops_of(scene.exposure),
            skeleton: crate::save::skeleton(scene),
            save_base: crate::save::base_of(source),
            objects: Arc::new(crate::objects::Objects::new(scene)),
        }
    }
}
