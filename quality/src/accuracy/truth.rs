//! The area-light ground truth of a sweep and its noise floor, cached on disk by a hash of the
//! scene's content, the image size and the truth's samples, so a second sweep of the same scene
//! skips the CPU render. The cache holds EXRs (shadowed, unoccluded, depth, the second-seed
//! render); the penumbra mask and the floor are recomputed from them, which is cheap.

use super::AccuracyError;
use lightfold_reference::{AreaOptions, GroundTruth, Metrics, render_area};
use lightfold_scene::{Image, Scene};
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};

/// How the truth is rendered.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TruthOptions {
    /// Points per area light per pixel.
    pub samples_per_light: u32,
    /// Where cached truths live (`None`: no cache).
    pub cache_dir: Option<PathBuf>,
}

/// The truth, the floor (the truth against a second seed) and where it came from.
#[derive(Debug, Clone)]
pub struct CachedTruth {
    pub truth: GroundTruth,
    pub floor: Metrics,
    /// Hex key of the cache entry.
    pub key: String,
    pub from_cache: bool,
    /// Seconds spent rendering (0 when cached).
    pub render_seconds: f64,
}

const CACHE_VERSION: &[u8] = b"lightfold-accuracy-truth-v2";

/// The cache key: scene content, image size, samples. The scene's quality options are left out
/// (hashed at their defaults): the truth integrates the area lights itself and never reads them,
/// so a change of a default (e.g. the sample pattern) keeps the cached truths.
pub fn truth_key(scene: &Scene, samples_per_light: u32) -> String {
    let mut h = Sha256::new();
    h.update(CACHE_VERSION);
    let mut content = scene.clone();
    content.quality = lightfold_scene::Quality::default();
    h.update(content.content_hash());
    h.update(scene.camera.width.to_le_bytes());
    h.update(scene.camera.height.to_le_bytes());
    h.update(samples_per_light.to_le_bytes());
    hex::encode(&h.finalize()[..12])
}

/// Loads the truth from the cache or renders (and caches) it.
pub fn load_or_render_truth(
    scene: &Scene,
    opts: &TruthOptions,
) -> Result<CachedTruth, AccuracyError> {
    let key = truth_key(scene, opts.samples_per_light);
    let dir = opts.cache_dir.as_ref().map(|d| d.join(&key));
    let area = AreaOptions {
        samples_per_light: opts.samples_per_light.max(1),
        seed: 1,
        shadows: true,
    };
    if let Some(dir) = &dir
        && let Ok(files) = read_entry(dir)
    {
        let truth = assemble(scene, area, files.0, files.1, files.2);
        let floor = truth.compare(&files.3)?;
        return Ok(CachedTruth {
            truth,
            floor,
            key,
            from_cache: true,
            render_seconds: 0.0,
        });
    }
    let t = std::time::Instant::now();
    let truth = GroundTruth::render(scene, &area);
    let other = render_area(
        scene,
        &AreaOptions {
            seed: area.seed.wrapping_add(1),
            ..area
        },
    )
    .radiance([1.0; 3], scene.ambient);
    let render_seconds = t.elapsed().as_secs_f64();
    let floor = truth.compare(&other)?;
    if let Some(dir) = &dir {
        write_entry(dir, &truth, &other)?;
    }
    Ok(CachedTruth {
        truth,
        floor,
        key,
        from_cache: false,
        render_seconds,
    })
}

fn assemble(
    scene: &Scene,
    options: AreaOptions,
    radiance: Image,
    unoccluded: Image,
    depth3: Image,
) -> GroundTruth {
    let mut depth = Image::new(depth3.width, depth3.height, 1);
    for (d, px) in depth.data.iter_mut().zip(depth3.data.chunks_exact(3)) {
        *d = px[0];
    }
    // The reference writes depth 0 where no surface is hit.
    let coverage: Vec<bool> = depth.data.iter().map(|&z| z > 0.0).collect();
    GroundTruth::assemble(scene, options, radiance, unoccluded, depth, coverage)
}

const FILES: [&str; 4] = [
    "radiance.exr",
    "unoccluded.exr",
    "depth.exr",
    "second_seed.exr",
];

fn read_entry(dir: &Path) -> Result<(Image, Image, Image, Image), AccuracyError> {
    let read = |name: &str| {
        let path = dir.join(name);
        Image::read_exr(&path).map_err(|e| AccuracyError::Cache {
            path: path.display().to_string(),
            message: e.to_string(),
        })
    };
    Ok((
        read(FILES[0])?,
        read(FILES[1])?,
        read(FILES[2])?,
        read(FILES[3])?,
    ))
}

fn write_entry(dir: &Path, truth: &GroundTruth, other: &Image) -> Result<(), AccuracyError> {
    let cache_err = |path: &Path, message: String| AccuracyError::Cache {
        path: path.display().to_string(),
        message,
    };
    std::fs::create_dir_all(dir).map_err(|e| cache_err(dir, e.to_string()))?;
    let mut depth3 = Image::new(truth.depth.width, truth.depth.height, 3);
    for (o, &z) in depth3.data.chunks_exact_mut(3).zip(&truth.depth.data) {
        o.fill(z);
    }
    for (name, img) in FILES
        .iter()
        .zip([&truth.radiance, &truth.unoccluded, &depth3, other])
    {
        let path = dir.join(name);
        img.write_exr(&path)
            .map_err(|e| cache_err(&path, e.to_string()))?;
    }
    Ok(())
}
