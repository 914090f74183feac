//! Files from the CPU reference, for `lightfold render --reference`: the exact point sum (or the
//! area-light truth) as linear EXR plus the sRGB PNG at the scene's exposure.

use crate::area::{AreaOptions, render_area};
use crate::point_sum::{Layers, PointSumOptions, render_point_sum_with};
use lightfold_scene::image::ImageError;
use lightfold_scene::{Image, LightSample, Scene};
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Debug, thiserror::Error)]
pub enum ReferenceError {
    #[error(transparent)]
    Image(#[from] ImageError),
    #[error(transparent)]
    Metrics(#[from] crate::metrics::MetricsError),
    #[error(transparent)]
    Supersample(#[from] lightfold_scene::supersample::SupersampleError),
    #[error("cannot write {path}: {message}")]
    Write { path: String, message: String },
    #[error("light {name:?} is not in scene {scene:?} (lights: {available})")]
    UnknownLight {
        name: String,
        scene: String,
        available: String,
    },
}

/// What the CPU reference renders.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReferenceMode {
    /// The exact sum over the scene's point samples (what the GPU approximates).
    PointSum,
    /// The true area lights (what the point samples approximate).
    AreaTruth(AreaOptions),
}

/// Which files to write.
#[derive(Debug, Clone, Default)]
pub struct Outputs {
    pub exr: PathBuf,
    /// sRGB PNG at the scene's exposure.
    pub png: Option<PathBuf>,
    /// Radiance without shadows (linear EXR), for penumbra masks.
    pub unoccluded: Option<PathBuf>,
    /// Eye depth in every channel (linear EXR, 0 = background), for silhouette masks.
    pub depth: Option<PathBuf>,
    /// The scene's camera is this many times the output size per side (`--aa N`): every
    /// N × N block is resolved into one output pixel after the radiance is composed — a box
    /// average of radiance, the nearest covered depth (`lightfold_scene::supersample`). 0 and 1
    /// write the image as rendered.
    pub supersample: u32,
}

/// How long a render took and how many rays it traced at most.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderReport {
    pub seconds: f64,
    /// Upper bound: one eye ray per pixel plus one shadow ray per pixel per light point
    /// (points facing away trace none).
    pub max_rays: f64,
}

impl RenderReport {
    pub fn rays_per_second(&self) -> f64 {
        self.max_rays / self.seconds.max(1e-9)
    }
}

/// Indices into `Scene::lights` of the named lights (names, or indices as text).
pub fn light_indices(scene: &Scene, names: &[String]) -> Result<Vec<usize>, ReferenceError> {
    names
        .iter()
        .map(|name| {
            scene
                .lights
                .iter()
                .position(|l| &l.name == name)
                .or_else(|| {
                    name.parse::<usize>()
                        .ok()
                        .filter(|&i| i < scene.lights.len())
                })
                .ok_or_else(|| ReferenceError::UnknownLight {
                    name: name.clone(),
                    scene: scene.name.clone(),
                    available: scene
                        .lights
                        .iter()
                        .map(|l| l.name.as_str())
                        .collect::<Vec<_>>()
                        .join(", "),
                })
        })
        .collect()
}

/// Keeps the samples of the named source lights.
pub fn select_lights(
    scene: &Scene,
    samples: &[LightSample],
    names: &[String],
) -> Result<Vec<LightSample>, ReferenceError> {
    let keep = light_indices(scene, names)?;
    Ok(samples
        .iter()
        .filter(|s| keep.contains(&(s.light as usize)))
        .copied()
        .collect())
}

/// The scene with only the named lights (for the area truth of a subset). Sample `light`
/// indices of the result refer to the reduced list.
pub fn retain_lights(scene: &Scene, names: &[String]) -> Result<Scene, ReferenceError> {
    let keep = light_indices(scene, names)?;
    let mut out = scene.clone();
    out.lights = scene
        .lights
        .iter()
        .enumerate()
        .filter(|(i, _)| keep.contains(i))
        .map(|(_, l)| l.clone())
        .collect();
    Ok(out)
}

/// Renders `scene` on the CPU and writes the requested files. For [`ReferenceMode::AreaTruth`]
/// the scene's own lights are used (restrict them beforehand to render a subset).
pub fn render_to_files(
    scene: &Scene,
    samples: &[LightSample],
    mode: ReferenceMode,
    outputs: &Outputs,
) -> Result<RenderReport, ReferenceError> {
    let start = Instant::now();
    let pixels = scene.camera.width as f64 * scene.camera.height as f64;
    let render = |shadows: bool| -> (Layers, f64) {
        match mode {
            ReferenceMode::PointSum => (
                render_point_sum_with(scene, samples, [1.0; 3], PointSumOptions { shadows }),
                samples.len() as f64,
            ),
            ReferenceMode::AreaTruth(o) => {
                let area = scene.lights.iter().filter(|l| l.is_area()).count() as f64;
                let exact = scene.lights.len() as f64 - area;
                (
                    render_area(scene, &AreaOptions { shadows, ..o }),
                    area * f64::from(o.samples_per_light.max(1)) + exact,
                )
            }
        }
    };
    let (layers, per_pixel) = render(true);
    let report = RenderReport {
        seconds: start.elapsed().as_secs_f64(),
        max_rays: pixels * (1.0 + per_pixel),
    };
    let n = outputs.supersample.max(1);
    let radiance = layers.radiance([1.0; 3], scene.ambient).box_resolve(n)?;
    radiance.write_exr(&outputs.exr)?;
    if let Some(png) = &outputs.png {
        radiance.write_png(png, scene.exposure)?;
    }
    if let Some(path) = &outputs.depth {
        depth_rgb(&layers.depth.nearest_depth_resolve(n)?).write_exr(path)?;
    }
    if let Some(path) = &outputs.unoccluded {
        render(false)
            .0
            .radiance([1.0; 3], scene.ambient)
            .box_resolve(n)?
            .write_exr(path)?;
    }
    Ok(report)
}

/// Writes the FLIP error map of `test` against `reference` (magma colours) as PNG.
pub fn write_error_map(
    test: &Image,
    reference: &Image,
    exposure: f32,
    path: &Path,
) -> Result<(), ReferenceError> {
    let rgb = crate::metrics::flip_error_map_rgb8(test, reference, exposure)?;
    image::save_buffer(path, &rgb, test.width, test.height, image::ColorType::Rgb8).map_err(|e| {
        ReferenceError::Write {
            path: path.display().to_string(),
            message: e.to_string(),
        }
    })
}

/// The PNG path next to an EXR path (`x.exr` → `x.png`).
pub fn png_next_to(exr: &Path) -> PathBuf {
    exr.with_extension("png")
}

fn depth_rgb(depth: &Image) -> Image {
    let mut out = Image::new(depth.width, depth.height, 3);
    for (o, &z) in out.data.chunks_exact_mut(3).zip(&depth.data) {
        o.fill(z);
    }
    out
}
