//! The speed-against-error sweep behind `lightfold accuracy`: one knob at a time around the
//! scene's defaults (samples per area light, their pattern, shadow-map size, filter, illumination
//! link format, K) plus a small grid of the knobs that matter most; for each point the node cost and the error
//! against the cached area-light ground truth, and the Pareto frontier of error against cost.
//!
//! Cost is measured, not modelled: each batch of K samples is one node's frame, rendered alone on
//! this machine's renderer and timed wall-clock (with the link format's pack), so node-seconds is
//! the sum over the ⌈L/K⌉ nodes and the cluster frame-time estimate is the slowest node.

mod measure;
pub mod pareto;
pub mod planned;
pub mod report;
pub mod truth;

pub use measure::{Measured, measure_group, measure_prepared};
pub use pareto::pareto_frontier;
pub use report::{CSV_COLUMNS, write_csv, write_markdown, write_svg};
pub use truth::{CachedTruth, TruthOptions, load_or_render_truth};

use lightfold_compositor::ops::{LinkKind, recommended_link_format};
use lightfold_protocol::format::PixelFormat;
use lightfold_scene::{SamplePattern, Scene, ShadowFilter};
use std::fmt;

/// Errors of the sweep.
#[derive(Debug, thiserror::Error)]
pub enum AccuracyError {
    #[error("gpu: {message}")]
    Gpu { message: String },
    #[error("render of {setting}: {message}")]
    Render { setting: String, message: String },
    #[error("pixel format {format:?}: {source}")]
    Format {
        format: PixelFormat,
        #[source]
        source: lightfold_protocol::format::FormatError,
    },
    #[error("metrics: {0}")]
    Metrics(#[from] lightfold_reference::MetricsError),
    #[error("truth cache {path}: {message}")]
    Cache { path: String, message: String },
    #[error("writing {path}: {message}")]
    Output { path: String, message: String },
}

/// One point of the sweep: every knob's value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Setting {
    /// Point samples per area light.
    pub samples: u32,
    /// How an area light's samples are placed.
    pub pattern: SamplePattern,
    pub map_size: u32,
    pub filter: ShadowFilter,
    /// Illumination node → compositor link format.
    pub format: PixelFormat,
    /// Lights per node.
    pub k: u32,
    /// Radius of the screen-space penumbra filter on the illumination sum (the compositor's
    /// `penumbra` operator; 0: none).
    pub penumbra: u32,
}

impl Setting {
    /// The scene's defaults (`samples`: the scene's per-light count, the default's 16 when unset)
    /// with the recommended node link format.
    pub fn defaults(scene: &Scene) -> Setting {
        let q = &scene.quality;
        let samples = q.samples_per_area_light.unwrap_or_else(|| {
            scene
                .lights
                .iter()
                .find(|l| l.is_area())
                .map_or(lightfold_scene::defaults::SAMPLES_PER_AREA_LIGHT, |l| {
                    l.samples
                })
        });
        Setting {
            samples,
            pattern: q.pattern,
            map_size: q.shadow_map_size,
            filter: q.filter,
            format: recommended_link_format(LinkKind::NodeToCompositor),
            k: q.lights_per_node,
            penumbra: 0,
        }
    }

    /// Writes the knobs a scene holds (samples, pattern, map size, filter) into `scene`.
    pub fn apply(&self, scene: &mut Scene) {
        let q = &mut scene.quality;
        q.samples_per_area_light = Some(self.samples.max(1));
        q.pattern = self.pattern;
        q.shadow_map_size = self.map_size;
        q.map_sizing = lightfold_scene::MapSizing::Fixed;
        q.filter = self.filter;
    }

    /// Whether two settings render the same images before the link (they differ in format and
    /// penumbra filter only).
    fn same_render(&self, other: &Setting) -> bool {
        Setting {
            format: other.format,
            penumbra: other.penumbra,
            ..*self
        } == *other
    }
}

/// Short name of a sample pattern (`grid`, `jittered`, `halton`).
pub fn pattern_name(p: SamplePattern) -> &'static str {
    match p {
        SamplePattern::Grid => "grid",
        SamplePattern::Jittered => "jittered",
        SamplePattern::Halton => "halton",
    }
}

/// Short name of a filter (`none`, `pcf2x2`, `pcf3x3`, `pcf5x5`, `cell4`).
pub fn filter_name(f: ShadowFilter) -> String {
    match f {
        ShadowFilter::None => "none".into(),
        ShadowFilter::Pcf2x2 => "pcf2x2".into(),
        ShadowFilter::Pcf { taps } => format!("pcf{taps}x{taps}"),
        ShadowFilter::Cell { taps } => format!("cell{taps}"),
    }
}

impl fmt::Display for Setting {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "n={} map={} {} {} K={} {}",
            self.samples,
            self.map_size,
            filter_name(self.filter),
            self.format.name(),
            self.k,
            pattern_name(self.pattern)
        )?;
        if self.penumbra > 0 {
            write!(f, " penumbra r={}", self.penumbra)?;
        }
        Ok(())
    }
}

/// Which axis a point varies (`default` for the defaults themselves).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Knob {
    Default,
    Samples,
    Pattern,
    MapSize,
    Filter,
    Format,
    K,
    Grid,
    Penumbra,
}

impl Knob {
    pub fn name(self) -> &'static str {
        match self {
            Knob::Default => "default",
            Knob::Samples => "samples",
            Knob::Pattern => "pattern",
            Knob::MapSize => "map",
            Knob::Filter => "filter",
            Knob::Format => "format",
            Knob::K => "K",
            Knob::Grid => "grid",
            Knob::Penumbra => "penumbra",
        }
    }

    /// Every knob a sweep varies (not `Default`), in sweep order.
    pub const SWEPT: [Knob; 8] = [
        Knob::Samples,
        Knob::Pattern,
        Knob::MapSize,
        Knob::Filter,
        Knob::Format,
        Knob::K,
        Knob::Grid,
        Knob::Penumbra,
    ];

    /// The knob named `name` (as [`Knob::name`] spells it, any case).
    pub fn from_name(name: &str) -> Option<Knob> {
        Knob::SWEPT
            .into_iter()
            .find(|k| k.name().eq_ignore_ascii_case(name.trim()))
    }
}

/// The values each knob takes.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepPlan {
    pub samples: Vec<u32>,
    /// Every pattern at the default sample count and at each of `pattern_samples`.
    pub patterns: Vec<SamplePattern>,
    pub pattern_samples: Vec<u32>,
    pub map_sizes: Vec<u32>,
    pub filters: Vec<ShadowFilter>,
    pub formats: Vec<PixelFormat>,
    pub ks: Vec<u32>,
    /// The grid: samples × map sizes × filters.
    pub grid_samples: Vec<u32>,
    pub grid_map_sizes: Vec<u32>,
    pub grid_filters: Vec<ShadowFilter>,
    /// The screen-space penumbra filter's radii, each at the default sample count and at each of
    /// `penumbra_samples`.
    pub penumbras: Vec<u32>,
    pub penumbra_samples: Vec<u32>,
}

/// The illumination link formats (six channels: what a node sends).
pub fn illumination_formats() -> Vec<PixelFormat> {
    PixelFormat::ALL
        .into_iter()
        .filter(|f| f.channels() == 6)
        .collect()
}

impl SweepPlan {
    /// The full sweep: samples 1…256, the three patterns at the default count and at 4 and 64
    /// samples, maps 256…4096, four filters, every illumination format,
    /// K 1…16, a grid of samples {64, 256} × maps {1024, 2048} × {PCF 2×2, PCF 5×5}, and the
    /// penumbra filter at radius 1, 2 and 4 at the default count and at 1, 4 and 64 samples.
    pub fn full() -> SweepPlan {
        SweepPlan {
            samples: vec![1, 4, 16, 64, 256],
            patterns: vec![
                SamplePattern::Grid,
                SamplePattern::Jittered,
                SamplePattern::Halton,
            ],
            pattern_samples: vec![4, 64],
            map_sizes: vec![256, 512, 1024, 2048, 4096],
            filters: vec![
                ShadowFilter::None,
                ShadowFilter::Pcf2x2,
                ShadowFilter::Pcf { taps: 3 },
                ShadowFilter::Pcf { taps: 5 },
            ],
            formats: illumination_formats(),
            ks: vec![1, 2, 4, 8, 16],
            grid_samples: vec![64, 256],
            grid_map_sizes: vec![1024, 2048],
            grid_filters: vec![ShadowFilter::Pcf2x2, ShadowFilter::Pcf { taps: 5 }],
            penumbras: vec![1, 2, 4],
            penumbra_samples: vec![1, 4, 64],
        }
    }

    /// A shorter sweep for heavy scenes: samples up to 64, maps up to 2048, K {1, 4, 16}, a
    /// grid of samples {64} × maps {1024, 2048} × {PCF 2×2, PCF 5×5}.
    pub fn reduced() -> SweepPlan {
        SweepPlan {
            samples: vec![1, 4, 16, 64],
            map_sizes: vec![256, 512, 1024, 2048],
            ks: vec![1, 4, 16],
            grid_samples: vec![64],
            ..SweepPlan::full()
        }
    }

    /// A tiny sweep for tests: the defaults, one other sample count and one other format.
    pub fn tiny() -> SweepPlan {
        SweepPlan {
            samples: vec![2],
            patterns: vec![],
            pattern_samples: vec![],
            map_sizes: vec![],
            filters: vec![],
            formats: vec![PixelFormat::F16x6],
            ks: vec![],
            grid_samples: vec![],
            grid_map_sizes: vec![],
            grid_filters: vec![],
            penumbras: vec![],
            penumbra_samples: vec![],
        }
    }

    /// Whether this plan has any point that varies `knob`.
    pub fn varies(&self, knob: Knob) -> bool {
        match knob {
            Knob::Default => true,
            Knob::Samples => !self.samples.is_empty(),
            Knob::Pattern => !self.patterns.is_empty(),
            Knob::MapSize => !self.map_sizes.is_empty(),
            Knob::Filter => !self.filters.is_empty(),
            Knob::Format => !self.formats.is_empty(),
            Knob::K => !self.ks.is_empty(),
            Knob::Grid => !self.grid_samples.is_empty(),
            Knob::Penumbra => !self.penumbras.is_empty(),
        }
    }

    /// This plan with only `knobs` varied (the others keep the defaults).
    /// The sweep `name` names ("full", "reduced", "tiny"), narrowed to the knobs named in
    /// `knobs` (none: all of it); an unknown name, or a knob the sweep does not vary, is an error
    /// saying what there is.
    pub fn named(name: &str, knobs: &[String]) -> Result<SweepPlan, String> {
        let plan = match name {
            "full" => SweepPlan::full(),
            "reduced" => SweepPlan::reduced(),
            "tiny" => SweepPlan::tiny(),
            other => return Err(format!("unknown --sweep {other:?}: full, reduced or tiny")),
        };
        if knobs.is_empty() {
            return Ok(plan);
        }
        let knobs = knobs
            .iter()
            .map(|k| {
                Knob::from_name(k).ok_or_else(|| {
                    format!(
                        "unknown knob {k:?}: samples, pattern, map, filter, format, K, grid or \
                         penumbra"
                    )
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        let plan = plan.only(&knobs);
        let idle: Vec<&str> = knobs
            .iter()
            .filter(|k| !plan.varies(**k))
            .map(|k| k.name())
            .collect();
        if !idle.is_empty() {
            return Err(format!(
                "--sweep {name} does not vary {}: use --sweep reduced or full for {}",
                idle.join(", "),
                if idle.len() == 1 { "it" } else { "them" }
            ));
        }
        Ok(plan)
    }

    pub fn only(mut self, knobs: &[Knob]) -> SweepPlan {
        let keep = |k: Knob| knobs.contains(&k);
        if !keep(Knob::Samples) {
            self.samples.clear();
        }
        if !keep(Knob::Pattern) {
            self.patterns.clear();
            self.pattern_samples.clear();
        }
        if !keep(Knob::MapSize) {
            self.map_sizes.clear();
        }
        if !keep(Knob::Filter) {
            self.filters.clear();
        }
        if !keep(Knob::Format) {
            self.formats.clear();
        }
        if !keep(Knob::K) {
            self.ks.clear();
        }
        if !keep(Knob::Grid) {
            self.grid_samples.clear();
            self.grid_map_sizes.clear();
            self.grid_filters.clear();
        }
        if !keep(Knob::Penumbra) {
            self.penumbras.clear();
            self.penumbra_samples.clear();
        }
        self
    }

    /// The points around `base`, defaults first, without duplicates (a duplicate keeps the first
    /// knob that produced it).
    pub fn points(&self, base: Setting) -> Vec<(Knob, Setting)> {
        let mut out: Vec<(Knob, Setting)> = vec![(Knob::Default, base)];
        let mut push = |knob, s: Setting| {
            if !out.iter().any(|(_, t)| *t == s) {
                out.push((knob, s));
            }
        };
        for &samples in &self.samples {
            push(Knob::Samples, Setting { samples, ..base });
        }
        let pattern_counts =
            std::iter::once(base.samples).chain(self.pattern_samples.iter().copied());
        for samples in pattern_counts {
            for &pattern in &self.patterns {
                push(
                    Knob::Pattern,
                    Setting {
                        samples,
                        pattern,
                        ..base
                    },
                );
            }
        }
        for &map_size in &self.map_sizes {
            push(Knob::MapSize, Setting { map_size, ..base });
        }
        for &filter in &self.filters {
            push(Knob::Filter, Setting { filter, ..base });
        }
        for &format in &self.formats {
            push(Knob::Format, Setting { format, ..base });
        }
        for &k in &self.ks {
            push(Knob::K, Setting { k, ..base });
        }
        for &samples in &self.grid_samples {
            for &map_size in &self.grid_map_sizes {
                for &filter in &self.grid_filters {
                    push(
                        Knob::Grid,
                        Setting {
                            samples,
                            map_size,
                            filter,
                            ..base
                        },
                    );
                }
            }
        }
        let penumbra_counts =
            std::iter::once(base.samples).chain(self.penumbra_samples.iter().copied());
        for samples in penumbra_counts {
            for &penumbra in &self.penumbras {
                push(
                    Knob::Penumbra,
                    Setting {
                        samples,
                        penumbra,
                        ..base
                    },
                );
            }
        }
        out
    }
}

/// One measured point.
#[derive(Debug, Clone, PartialEq)]
pub struct Point {
    pub knob: Knob,
    /// The setting as asked.
    pub setting: Setting,
    /// K as run (the device may allow fewer lights per node at large maps).
    pub k_run: u32,
    /// Point samples in the frame (all lights).
    pub lights: usize,
    pub nodes: usize,
    /// Σ node frame times, seconds.
    pub node_seconds: f64,
    /// The slowest node's frame time, seconds (the cluster frame-time estimate).
    pub frame_seconds: f64,
    pub metrics: lightfold_reference::Metrics,
    /// Within 10× the truth's noise floor (RMSE, whole and penumbra).
    pub at_floor: bool,
    /// On the Pareto frontier of penumbra RMSE against node-seconds.
    pub pareto: bool,
}

impl Point {
    /// Penumbra PSNR (dB), the whole image's when the scene has no penumbra.
    pub fn penumbra_psnr(&self) -> f64 {
        self.metrics
            .penumbra
            .map_or(self.metrics.whole.psnr, |p| p.psnr)
    }

    /// Penumbra RMSE, the whole image's when the scene has no penumbra.
    pub fn penumbra_rmse(&self) -> f64 {
        self.metrics
            .penumbra
            .map_or(self.metrics.whole.rmse, |p| p.rmse)
    }

    pub fn penumbra_flip(&self) -> f64 {
        self.metrics.penumbra_flip.unwrap_or(self.metrics.flip)
    }
}

/// Groups `points` by what they render (format aside), keeping first-appearance order.
pub fn render_groups(points: &[(Knob, Setting)]) -> Vec<Vec<usize>> {
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for (i, (_, s)) in points.iter().enumerate() {
        match groups.iter_mut().find(|g| points[g[0]].1.same_render(s)) {
            Some(g) => g.push(i),
            None => groups.push(vec![i]),
        }
    }
    groups
}

/// Runs the sweep on `scene` against `truth`: every point of `plan` around the scene's defaults.
/// Each node's time is its fastest of `repeats` frames. `progress` is called with the number of points done after each render group.
pub fn run_sweep(
    gpu: &lightfold_node::gpu::Gpu,
    scene: &Scene,
    truth: &CachedTruth,
    plan: &SweepPlan,
    repeats: u32,
    progress: impl FnMut(usize, &str),
) -> Result<Vec<Point>, AccuracyError> {
    run_sweep_with(scene, truth, plan, progress, |scene, settings| {
        measure_group(gpu, scene, settings, repeats)
    })
}

/// [`run_sweep`] with another way to render: `measure(scene, settings)` returns one
/// [`Measured`] per setting of a render group (settings that differ in link format only), e.g.
/// through a real cluster (`lightfold accuracy --cluster`).
pub fn run_sweep_with(
    scene: &Scene,
    truth: &CachedTruth,
    plan: &SweepPlan,
    mut progress: impl FnMut(usize, &str),
    mut measure: impl FnMut(&Scene, &[Setting]) -> Result<Vec<Measured>, AccuracyError>,
) -> Result<Vec<Point>, AccuracyError> {
    let points = plan.points(Setting::defaults(scene));
    let mut out: Vec<Option<Point>> = vec![None; points.len()];
    let mut done = 0;
    for group in render_groups(&points) {
        let settings: Vec<Setting> = group.iter().map(|&i| points[i].1).collect();
        progress(done, &settings[0].to_string());
        let measured = measure(scene, &settings)?;
        for (&i, m) in group.iter().zip(measured) {
            let metrics = truth.truth.compare(&m.image)?;
            out[i] = Some(Point {
                knob: points[i].0,
                setting: points[i].1,
                k_run: m.k_run,
                lights: m.lights,
                nodes: m.node_seconds.len(),
                node_seconds: m.node_seconds.iter().sum(),
                frame_seconds: m.node_seconds.iter().copied().fold(0.0, f64::max),
                at_floor: metrics.within_floor(&truth.floor),
                metrics,
                pareto: false,
            });
        }
        done += group.len();
    }
    progress(done, "done");
    let mut points: Vec<Point> = out.into_iter().flatten().collect();
    let frontier = pareto_frontier(
        &points
            .iter()
            .map(|p| (p.node_seconds, p.penumbra_rmse()))
            .collect::<Vec<_>>(),
    );
    for i in frontier {
        points[i].pareto = true;
    }
    Ok(points)
}

#[cfg(test)]
mod tests;
