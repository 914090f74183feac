//! A scene's own error model for the planner (`docs/planner.md` § Error model): a few renders of
//! the scene at a reduced size against its area-light truth, one curve of penumbra PSNR against
//! samples per area light for each shadow-map floor, with and without the penumbra filter, and
//! the node-seconds each took. Cached by the scene's content and image size, so a second plan of
//! the same scene reads it back.
//!
//! The reduced size divides the image by a whole factor `d` (at most 400×300); the renders keep
//! the shadow maps the full-size plan would get (the mismatch rule's target × `d`), so the maps'
//! error is the full size's, and a filter radius r measured there is radius `r·d` at full size
//! (the same footprint on the scene).

use crate::accuracy::{
    AccuracyError, Setting, TruthOptions, load_or_render_truth, measure_prepared,
};
use lightfold_compositor::ops::{LinkKind, recommended_link_format};
use lightfold_coordinator::plan::{Curve, ErrorModel};
use lightfold_node::gpu::Gpu;
use lightfold_protocol::format::PixelFormat;
use lightfold_scene::defaults::CELL_TAPS;
use lightfold_scene::{Image, MapSizing, Quality, Scene, ShadowFilter};
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The largest calibration image (a larger image is divided by a whole factor down to it).
pub const MAX_SIZE: (u32, u32) = (400, 300);
/// Samples per area light the curves measure.
pub const COUNTS: [u32; 6] = [4, 8, 16, 32, 64, 128];
/// Shadow-map floors (the mismatch rule's smallest map raised to each; those below the scene's
/// own floor are the scene's floor).
pub const FLOORS: [u32; 3] = [512, 1024, 2048];
/// Penumbra-filter radii measured at the calibration size.
pub const RADII: [u32; 2] = [1, 2];
/// The most samples per area light the cell filter is measured at: it makes few samples do
/// (measured +0.1–0.4 dB at 32 on `box` and the Fox, against +4–9 dB at 4), and its renders
/// cost 2–4× a plain one's on lavapipe.
pub const MAX_CELL_SAMPLES: u32 = 16;
/// A radius of the filter counts as a gain at a count only above this margin (dB).
const FILTER_GAIN_DB: f64 = 0.1;
/// Figures are capped here (a render equal to its truth has infinite PSNR).
const CAP_DB: f64 = 100.0;
/// The largest cached model read back (bytes).
const MAX_MODEL_BYTES: u64 = 1 << 20;

const CACHE_VERSION: &[u8] = b"lightfold-calibration-v5";

/// How to calibrate.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CalibrationOptions {
    /// Points per area light per pixel of the truth.
    pub truth_samples: u32,
    /// Where truths are cached (shared with `lightfold accuracy`).
    pub truth_cache: Option<PathBuf>,
    /// Where models are cached.
    pub model_cache: Option<PathBuf>,
    /// Samples per area light measured (rising), and the map floors.
    pub counts: Vec<u32>,
    pub floors: Vec<u32>,
}

impl CalibrationOptions {
    /// [`COUNTS`] and [`FLOORS`] with a truth of `truth_samples` points per area light, caches
    /// under `truth_cache` and `model_cache`.
    pub fn standard(
        truth_samples: u32,
        truth_cache: Option<PathBuf>,
        model_cache: Option<PathBuf>,
    ) -> CalibrationOptions {
        CalibrationOptions {
            truth_samples,
            truth_cache,
            model_cache,
            counts: COUNTS.to_vec(),
            floors: FLOORS.to_vec(),
        }
    }
}

/// One measured point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CalPoint {
    pub map_floor: u32,
    pub samples: u32,
    /// Filter radius at the plan's size (0: none).
    pub radius: u32,
    /// Rendered with the cell filter instead of the scene's shadow filter.
    pub cell: bool,
    pub penumbra_db: f64,
    pub whole_db: f64,
    pub node_seconds: f64,
}

/// A calibration: the model and how it was made.
#[derive(Debug, Clone)]
pub struct Calibration {
    pub model: ErrorModel,
    pub key: String,
    pub from_cache: bool,
    /// Wall seconds of the renders and of the truth (0 when cached).
    pub seconds: f64,
    pub truth_seconds: f64,
    /// Every point measured (empty when read from the cache).
    pub points: Vec<CalPoint>,
    /// The calibration image size and the factor it divides the scene's by.
    pub size: (u32, u32),
    pub divisor: u32,
}

/// The whole factor a `width × height` image is divided by for its calibration.
pub fn divisor(width: u32, height: u32) -> u32 {
    width
        .div_ceil(MAX_SIZE.0)
        .max(height.div_ceil(MAX_SIZE.1))
        .max(1)
}

/// The cache key of `scene`'s model: its content and image size, with the quality knobs the
/// model does not depend on (samples per area light, map sizes, K) left out, and those it does
/// (pattern, filter, biases, the area-light specular) kept.
pub fn model_key(scene: &Scene, opts: &CalibrationOptions) -> String {
    let mut content = scene.clone();
    let q = &scene.quality;
    content.quality = lightfold_scene::Quality {
        pattern: q.pattern,
        filter: q.filter,
        depth_bias: q.depth_bias,
        slope_bias: q.slope_bias,
        area_specular: q.area_specular,
        map_sizing: q.map_sizing,
        shadow_map_size: match q.map_sizing {
            MapSizing::Fixed => q.shadow_map_size,
            MapSizing::Mismatch(_) => lightfold_scene::defaults::SHADOW_MAP_SIZE,
        },
        ..lightfold_scene::defaults::quality()
    };
    for l in content.lights.iter_mut().filter(|l| l.is_area()) {
        l.samples = 1;
    }
    let mut h = Sha256::new();
    h.update(CACHE_VERSION);
    h.update(content.content_hash());
    h.update(scene.camera.width.to_le_bytes());
    h.update(scene.camera.height.to_le_bytes());
    h.update(opts.truth_samples.to_le_bytes());
    for v in opts.counts.iter().chain([&0]).chain(&opts.floors) {
        h.update(v.to_le_bytes());
    }
    hex::encode(&h.finalize()[..12])
}

/// The cached model of `scene` under `opts`' model cache, if there is a readable one.
pub fn cached_model(scene: &Scene, opts: &CalibrationOptions) -> Option<ErrorModel> {
    cached(scene, opts).map(|c| c.model)
}

fn model_path(dir: &Path, key: &str) -> PathBuf {
    dir.join(format!("{key}.json"))
}

/// Reads a model file: bounded, parsed and checked.
pub fn read_model(path: &Path) -> Result<ErrorModel, String> {
    let meta = std::fs::metadata(path).map_err(|e| e.to_string())?;
    if meta.len() > MAX_MODEL_BYTES {
        return Err(format!("{} bytes, more than a model takes", meta.len()));
    }
    let text = std::fs::read_to_string(path).map_err(|e| e.to_string())?;
    let model: ErrorModel = serde_json::from_str(&text).map_err(|e| e.to_string())?;
    model.check()?;
    Ok(model)
}

/// The calibration size of a `width × height` image: the divisor and the reduced size.
fn reduced(width: u32, height: u32) -> (u32, (u32, u32)) {
    let d = divisor(width, height);
    (d, ((width / d).max(1), (height / d).max(1)))
}

/// `scene`'s calibration from the cache, if there is a readable one (no device needed).
pub fn cached(scene: &Scene, opts: &CalibrationOptions) -> Option<Calibration> {
    let key = model_key(scene, opts);
    let model = read_model(&model_path(opts.model_cache.as_ref()?, &key)).ok()?;
    let (d, size) = reduced(scene.camera.width, scene.camera.height);
    Some(Calibration {
        model,
        key,
        from_cache: true,
        seconds: 0.0,
        truth_seconds: 0.0,
        points: Vec::new(),
        size,
        divisor: d,
    })
}

/// The model of `scene` from the cache, or calibrated on `gpu` (and cached).
pub fn calibrate(
    gpu: &Gpu,
    scene: &Scene,
    opts: &CalibrationOptions,
) -> Result<Calibration, AccuracyError> {
    let key = model_key(scene, opts);
    check_request(scene, opts)?;
    if let Some(c) = cached(scene, opts) {
        return Ok(c);
    }
    let (w, h) = (scene.camera.width, scene.camera.height);
    let (d, size) = reduced(w, h);
    let mut cal = scene.clone();
    (cal.camera.width, cal.camera.height) = size;
    let truth = load_or_render_truth(
        &cal,
        &TruthOptions {
            samples_per_light: opts.truth_samples.max(1),
            cache_dir: opts.truth_cache.clone(),
        },
    )?;
    let started = Instant::now();
    let q = scene.quality;
    let floors = floor_rules(&q, opts, d);
    let radii: Vec<u32> = RADII
        .iter()
        .copied()
        .filter(|r| r * d <= lightfold_compositor::ops::penumbra::MAX_RADIUS)
        .collect();
    let curves_of = Calibrating {
        gpu,
        truth: &truth.truth,
        quality: q,
        counts: &opts.counts,
        radii: &radii,
        format: recommended_link_format(LinkKind::NodeToCompositor),
        d,
    };
    let mut points = Vec::new();
    let mut curves = Vec::new();
    for &floor in &floors {
        curves.push(curves_of.curve(&mut cal, floor, &mut points)?);
    }
    let seconds = started.elapsed().as_secs_f64();
    let model = ErrorModel {
        source: format!(
            "this scene's calibration ({}×{} for {w}×{h}, {}-point truth, key {key})",
            size.0, size.1, opts.truth_samples
        ),
        calibrated: true,
        curves,
        truth_floor_db: truth
            .floor
            .penumbra
            .map_or(0.0, |p| p.psnr.min(CAP_DB) as f32),
        key: key.clone(),
    };
    model.check().map_err(|message| AccuracyError::Render {
        setting: "calibration".into(),
        message,
    })?;
    if let Some(dir) = &opts.model_cache {
        write_model(dir, &key, &model)?;
    }
    Ok(Calibration {
        model,
        key,
        from_cache: false,
        seconds,
        truth_seconds: truth.render_seconds,
        points,
        size,
        divisor: d,
    })
}

/// Refuses a calibration of a scene without area lights, or with fewer than two rising sample
/// counts or no map floor.
fn check_request(scene: &Scene, opts: &CalibrationOptions) -> Result<(), AccuracyError> {
    if scene.area_samples().is_none() {
        return Err(AccuracyError::Render {
            setting: "calibration".into(),
            message: "the scene has no area light: its samples per light are no choice to \
                      calibrate"
                .into(),
        });
    }
    if opts.counts.len() < 2
        || opts.counts.windows(2).any(|w| w[0] >= w[1])
        || opts.floors.is_empty()
    {
        return Err(AccuracyError::Render {
            setting: "calibration".into(),
            message: "a calibration needs two or more rising sample counts and a map floor".into(),
        });
    }
    Ok(())
}

/// The floors, each with the map sizing its renders use and the largest map they get, for a
/// scene of quality `q` at divisor `d`.
fn floor_rules(q: &Quality, opts: &CalibrationOptions, d: u32) -> Vec<(u32, MapSizing, u32)> {
    // The floors: the scene's own rule first (its smallest map), then the larger ones; a scene
    // that fixes one size for every map has that one curve only.
    match q.map_sizing {
        MapSizing::Fixed => vec![(0, MapSizing::Fixed, q.shadow_map_size)],
        MapSizing::Mismatch(m) => {
            let mut f: Vec<u32> = opts.floors.iter().map(|&f| f.max(m.min)).collect();
            f.sort_unstable();
            f.dedup();
            f.into_iter()
                .map(|floor| {
                    let rule = lightfold_scene::shadow_views::Mismatch {
                        min: floor,
                        max: m.max.max(floor),
                        target: m.target * d as f32,
                    };
                    (floor, MapSizing::Mismatch(rule), m.max.max(floor))
                })
                .collect()
        }
    }
}

/// What every curve of one calibration is measured with: the device, the truth, the scene's
/// quality, the counts and filter radii measured, the link format and the size divisor.
struct Calibrating<'a> {
    gpu: &'a Gpu,
    truth: &'a lightfold_reference::GroundTruth,
    quality: Quality,
    counts: &'a [u32],
    radii: &'a [u32],
    format: PixelFormat,
    d: u32,
}

/// The renders of one count: a setting per radius (0 first), what each measured, and its
/// penumbra and whole-image PSNR.
struct CountRenders {
    settings: Vec<Setting>,
    measured: Vec<crate::accuracy::Measured>,
    dbs: Vec<f64>,
    wholes: Vec<f64>,
}

impl Calibrating<'_> {
    /// The curve of one floor (`floor`, its sizing and largest map) over every count, rendering
    /// `cal` switched to that floor; every point measured goes to `points`.
    fn curve(
        &self,
        cal: &mut Scene,
        (floor, sizing, largest): (u32, MapSizing, u32),
        points: &mut Vec<CalPoint>,
    ) -> Result<Curve, AccuracyError> {
        let (q, d) = (self.quality, self.d);
        cal.quality.map_sizing = sizing;
        if floor > 0 {
            cal.quality.shadow_map_size = floor;
        }
        let mut unfiltered = Vec::new();
        let mut filtered = Vec::new();
        let mut cell = Vec::new();
        let mut filter_gains = true;
        let (mut sum_nt, mut sum_nn, mut sum_cell_nt, mut sum_cell_nn) = (0.0, 0.0, 0.0, 0.0);
        for &n in self.counts {
            cal.quality.samples_per_area_light = Some(n);
            let CountRenders {
                settings,
                measured,
                dbs,
                wholes,
            } = self.radius_renders(cal, floor, largest, n, points)?;
            // The cell filter, where the scene does not already ask for it: a render of its
            // own (the nodes' filter changes), kept where it gains in the penumbra and the whole
            // image loses nothing.
            if !matches!(q.filter, ShadowFilter::Cell { .. }) && n <= MAX_CELL_SAMPLES {
                let (db, whole, secs) = self.cell_render(cal, floor, n, &settings[0], points)?;
                sum_cell_nt += f64::from(n) * secs;
                sum_cell_nn += f64::from(n) * f64::from(n);
                if db > dbs[0] + FILTER_GAIN_DB && whole >= wholes[0] {
                    cell.push((n, db as f32));
                }
            }
            let secs = full_size_seconds(&measured[0], d);
            sum_nt += f64::from(n) * secs;
            sum_nn += f64::from(n) * f64::from(n);
            unfiltered.push((n, dbs[0] as f32));
            // The filter's curve is the counts from the fewest up to the first where no radius
            // gains: the planner reads it as "filter up to here". A radius gains where the
            // penumbra does and the whole image loses nothing (the filter also averages shading
            // and contact shadows outside the penumbra).
            let best = dbs[1..]
                .iter()
                .zip(&wholes[1..])
                .zip(self.radii)
                .filter(|((_, whole), _)| **whole >= wholes[0])
                .map(|((db, _), r)| (db, r))
                .max_by(|a, b| a.0.total_cmp(b.0));
            match best {
                Some((&db, &r)) if filter_gains && db > dbs[0] + FILTER_GAIN_DB => {
                    filtered.push((n, r * d, db as f32));
                }
                _ => filter_gains = false,
            }
        }
        Ok(Curve {
            map_floor: floor,
            unfiltered,
            filtered,
            seconds_per_sample: if sum_nn > 0.0 { sum_nt / sum_nn } else { 0.0 },
            cell_seconds_per_sample: if sum_cell_nn > 0.0 && !cell.is_empty() {
                sum_cell_nt / sum_cell_nn
            } else {
                0.0
            },
            cell,
        })
    }

    /// Renders `cal` at `n` samples per area light without the penumbra filter and with each
    /// radius, maps of at most `largest`, and measures each against the truth (a point each).
    fn radius_renders(
        &self,
        cal: &Scene,
        floor: u32,
        largest: u32,
        n: u32,
        points: &mut Vec<CalPoint>,
    ) -> Result<CountRenders, AccuracyError> {
        let (q, d) = (self.quality, self.d);
        let settings: Vec<Setting> = std::iter::once(0)
            .chain(self.radii.iter().copied())
            .map(|penumbra| Setting {
                samples: n,
                pattern: q.pattern,
                map_size: largest,
                filter: q.filter,
                format: self.format,
                k: q.lights_per_node,
                penumbra,
            })
            .collect();
        let measured = measure_prepared(self.gpu, cal, &settings, 1)?;
        let mut dbs = Vec::with_capacity(measured.len());
        let mut wholes = Vec::with_capacity(measured.len());
        for (s, m) in settings.iter().zip(&measured) {
            let (db, whole) = psnr(self.truth, &m.image)?;
            wholes.push(whole);
            let secs = full_size_seconds(m, d);
            points.push(CalPoint {
                map_floor: floor,
                samples: n,
                radius: s.penumbra * d,
                penumbra_db: db,
                whole_db: whole,
                node_seconds: secs,
                cell: false,
            });
            dbs.push(db);
        }
        Ok(CountRenders {
            settings,
            measured,
            dbs,
            wholes,
        })
    }

    /// Renders `cal` at `n` samples per area light as `unfiltered` (no penumbra filter) does
    /// but with the cell filter, and measures it (a point): its penumbra and whole-image PSNR
    /// and full-size node-seconds.
    fn cell_render(
        &self,
        cal: &mut Scene,
        floor: u32,
        n: u32,
        unfiltered: &Setting,
        points: &mut Vec<CalPoint>,
    ) -> Result<(f64, f64, f64), AccuracyError> {
        let setting = Setting {
            filter: ShadowFilter::Cell { taps: CELL_TAPS },
            penumbra: 0,
            ..*unfiltered
        };
        // The scene's own filter is put back before the next count's renders (no
        // copy of the scene: a city's meshes are hundreds of megabytes).
        cal.quality.filter = setting.filter;
        let m = measure_prepared(self.gpu, cal, &[setting], 1);
        cal.quality.filter = self.quality.filter;
        let m = m?.remove(0);
        let (db, whole) = psnr(self.truth, &m.image)?;
        let secs = full_size_seconds(&m, self.d);
        points.push(CalPoint {
            map_floor: floor,
            samples: n,
            radius: 0,
            penumbra_db: db,
            whole_db: whole,
            node_seconds: secs,
            cell: true,
        });
        Ok((db, whole, secs))
    }
}

/// Node-seconds of a render at the calibration size as the full-size image would take them:
/// the pixel-bound part (eye pass, readback, pack, the screen-space filter) scaled by the pixel
/// ratio `d²`, the rest (shadow passes, which keep the full size's maps, and set-up) as measured.
/// Without it a filter whose cost is per pixel looked `d²` times cheaper than it is.
fn full_size_seconds(m: &crate::accuracy::Measured, d: u32) -> f64 {
    let total: f64 = m.node_seconds.iter().sum();
    let pixels: f64 = m.pixel_seconds.iter().sum();
    total + pixels * (f64::from(d * d) - 1.0)
}

/// Penumbra PSNR of `image` against the truth (the whole image's where the truth has no
/// penumbra) and whole-image PSNR, capped at [`CAP_DB`].
fn psnr(
    truth: &lightfold_reference::GroundTruth,
    image: &Image,
) -> Result<(f64, f64), AccuracyError> {
    let m = truth.compare(image)?;
    let cap = |db: f64| {
        if db.is_finite() {
            db.min(CAP_DB)
        } else {
            CAP_DB
        }
    };
    let e = m.penumbra.filter(|p| p.pixels > 0).unwrap_or(m.whole);
    Ok((cap(e.psnr), cap(m.whole.psnr)))
}

/// Writes the model beside the others (a temporary file renamed into place, so a reader never
/// sees half of one).
fn write_model(dir: &Path, key: &str, model: &ErrorModel) -> Result<(), AccuracyError> {
    let path = model_path(dir, key);
    let err = |message: String| AccuracyError::Cache {
        path: path.display().to_string(),
        message,
    };
    std::fs::create_dir_all(dir).map_err(|e| err(e.to_string()))?;
    let text = serde_json::to_string_pretty(model).map_err(|e| err(e.to_string()))?;
    let tmp = dir.join(format!("{key}.json.{}.tmp", std::process::id()));
    std::fs::write(&tmp, text).map_err(|e| err(e.to_string()))?;
    std::fs::rename(&tmp, &path).map_err(|e| err(e.to_string()))
}
