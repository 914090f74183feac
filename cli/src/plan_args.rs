//! How a scene is planned: the flags every command that plans takes (`coordinator`, `demo` and
//! `plan` flatten [`PlanArgs`]), their parsers, and the plan options and scene they give — one
//! definition, so the commands cannot drift apart.

use lightfold_coordinator::plan::{FormatChoice, MapSizing, PlanOptions, Topology};
use lightfold_scene::Scene;

/// The planning flags.
#[derive(Debug, Clone, clap::Args, serde::Serialize, serde::Deserialize)]
pub(crate) struct PlanArgs {
    /// Image size as WIDTHxHEIGHT (default: the scene's).
    #[arg(long)]
    pub(crate) size: Option<String>,
    /// Lights per node (K).
    #[arg(short = 'K', long, default_value_t = lightfold_scene::defaults::LIGHTS_PER_NODE)]
    pub(crate) lights_per_node: u32,
    /// Antialiasing: N×N samples per pixel. The cluster renders N·width × N·height (within the
    /// image limits of `lightfold defaults`) and the coordinator's sink box-filters the final
    /// radiance back to the image size; the sink link carries N² times the pixels.
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub(crate) aa: u32,
    #[command(flatten)]
    pub(crate) indirect: crate::indirect_args::IndirectArgs,
    /// Compositor topology: `chain` (a linear pipeline, each stage adds its nodes to the upstream
    /// sum), `tree` (leaf stages sum nodes, the stages above join pairs of partial sums) or
    /// `auto` (a tree where a chain would have 8 stages or more: lower latency there,
    /// docs/scaling.md).
    #[arg(long, default_value = "chain")]
    pub(crate) topology: Topology,
    /// No culling: every light, stage and caster.
    #[arg(long)]
    pub(crate) force_all: bool,
    /// One shadow-map size for every light (default: the scene's, as `lightfold render` uses).
    #[arg(long)]
    pub(crate) shadow_map_size: Option<u32>,
    /// Pixel format of one class of link, as CLASS=FORMAT, repeatable or comma-separated:
    /// `node` (illumination, node → compositor; default rgb9e5x2), `chain` (compositor →
    /// compositor; f16x6), `sink` (final radiance to the coordinator; f32x3), `material`
    /// (material colours in [0, 1]; f16x4). See `docs/precision.md` for what each costs.
    #[arg(long, value_name = "CLASS=FORMAT", value_delimiter = ',', value_parser = parse_link_format)]
    pub(crate) link_format: Vec<(LinkClass, lightfold_protocol::PixelFormat)>,
    /// Sort-last partitions: split the scene's meshes into P spatially coherent parts; every
    /// light group is rendered once per part by a node drawing only that part's eye pass, with
    /// maps fitted to it, and the compositor chain depth-composes the parts (docs/planner.md §
    /// Partitions). Needs P × the render nodes. `auto` (the default): 1, unless the scene's
    /// geometry would not fit the memory the render nodes report or, with `--frame-budget`, its
    /// eye pass would take more than half the budget on the fastest node.
    #[arg(long, default_value = "auto", value_parser = partitions_arg)]
    pub(crate) partitions: u32,
    /// Sort-first tiles: split the image into T bands of rows; every light group is rendered
    /// once per tile by a node drawing only those rows (the whole scene, the whole scene's
    /// maps), and the coordinator moves rows between tiles each frame from the nodes' measured
    /// eye passes, so a heavier tile gets fewer rows (docs/planner.md § Tiles). Needs T × the
    /// render nodes (K rises to fit; with --partitions P, T × P × the groups); fewer nodes than
    /// needed take fewer tiles. 1: none. `auto` (the default): the tile count whose estimated frame is at
    /// least 10 % shorter than the untiled one by the cost model, none where the scene is
    /// partitioned; the plan says why (docs/planner.md § Choosing tiles).
    #[arg(long, default_value = "auto", value_parser = tiles_arg)]
    #[serde(default)]
    pub(crate) tiles: u32,
    /// Peeled translucency: the eye sees glass and blended surfaces as D layers in front of the
    /// opaque one (their own reflection and highlights, blended back to front over what lies
    /// behind) instead of only tinting it. Each layer takes as many render nodes as the opaque
    /// one. `off` (the default), `auto` (D = the scene's depth complexity in view, at most 4,
    /// none without translucency in view) or 1–4 (docs/translucency.md § Peeled layers).
    /// Excludes tiles, partitions and the penumbra filter.
    #[arg(long, default_value = "off", value_parser = peels_arg)]
    #[serde(default)]
    pub(crate) peels: lightfold_coordinator::plan::Peels,
    /// Render the material layers on a node of their own (the paper's layout) instead of as
    /// extra targets of an illumination node at the last stage.
    #[arg(long)]
    pub(crate) material_own_node: bool,
    /// Keep render nodes that share one GPU apart (one light group each). By default the
    /// planner gives one node per GPU all the lights of that GPU's nodes when its cost model says
    /// that is faster (`docs/planner.md` § Shared GPUs).
    #[arg(long)]
    pub(crate) no_device_merge: bool,
    /// Frame-time budget in milliseconds: K becomes the largest whose slowest node fits it (by
    /// the nodes' cost model), so the plan uses as few nodes as it allows; overrides -K. When no
    /// K fits, larger shadow maps, then samples per area light, then the least important samples
    /// are given up until it does (the plan says what it gave up).
    #[arg(long, value_parser = positive_ms)]
    pub(crate) frame_budget: Option<f64>,
    /// Error target: penumbra PSNR in dB against the area-light truth. The area lights' samples
    /// are halved or doubled to the fewest the planner's error model (fitted to the default
    /// scene's accuracy sweep) expects to reach it; `lightfold accuracy` measures what it gives.
    #[arg(long, value_parser = target_db)]
    pub(crate) target_psnr: Option<f32>,
    #[command(flatten)]
    pub(crate) model: crate::model_args::ModelArgs,
    /// Screen-space penumbra filter at the last stage: a tent average of the illumination sum
    /// over each pixel's (2R+1)² window, on its own surface only (the eye depth travels with the
    /// material layers), before the material multiply, so few samples per area light give a
    /// smooth penumbra. `budget` (the default): where a frame budget or an error target lowers
    /// the samples per area light, at the radius the error model gains most with; `auto`: at
    /// every count where the model expects a gain (16 samples or fewer); `off`; or a radius
    /// 1–8 (docs/operators.md, docs/planner.md).
    #[arg(long, default_value = "budget", value_parser = penumbra_filter)]
    pub(crate) penumbra_filter: lightfold_coordinator::plan::PenumbraFilter,
    /// Budget of radiance (display units) culled samples may add to a pixel.
    #[arg(long, default_value_t = lightfold_coordinator::plan::DEFAULT_EPSILON)]
    pub(crate) epsilon: f32,
}

impl PlanArgs {
    /// `scene` as these flags ask: the image size, the indirect light, and the checks that fail
    /// before any daemon is started or dialled (the shadow-map size, N·size under `--aa N`).
    pub(crate) fn apply(&self, scene: &mut Scene) -> anyhow::Result<()> {
        if let Some(size) = &self.size {
            let (w, h) = parse_size(size)?;
            scene.camera.width = w;
            scene.camera.height = h;
        }
        if let Some(n) = self.shadow_map_size {
            lightfold_scene::limits::check_shadow_map_size(n)
                .map_err(|e| anyhow::anyhow!("bad --shadow-map-size: {e}"))?;
        }
        self.indirect.apply(scene)?;
        scene
            .camera
            .supersampled(self.aa)
            .map_err(|e| anyhow::anyhow!("{e} (see `lightfold defaults`)"))?;
        Ok(())
    }

    /// The plan options these flags give (the error model aside: [`PlanArgs::plan_options_for`]).
    pub(crate) fn plan_options(&self) -> PlanOptions {
        PlanOptions {
            lights_per_node: self.lights_per_node,
            topology: self.topology,
            force_all: self.force_all,
            epsilon: self.epsilon,
            // The rule `lightfold render` applies too: the size asked for, else the scene's.
            map_sizing: MapSizing::from_request(self.shadow_map_size),
            material_own_node: self.material_own_node,
            merge_shared_devices: !self.no_device_merge,
            frame_budget_us: self.frame_budget.map(|b| (b * 1000.0).round() as u64),
            target_penumbra_db: self.target_psnr,
            penumbra_filter: self.penumbra_filter,
            formats: self.formats(),
            supersample: self.aa,
            partitions: self.partitions,
            tiles: self.tiles,
            peels: self.peels,
            ..PlanOptions::default()
        }
    }

    /// [`PlanArgs::plan_options`] with the error model for `scene` (`--error-model`: a
    /// calibration of it sets the default error target).
    pub(crate) fn plan_options_for(&self, scene: &Scene) -> anyhow::Result<PlanOptions> {
        let mut o = self.plan_options();
        self.model.apply(scene, &mut o)?;
        Ok(o)
    }

    /// The link formats `--link-format` sets, the planner's defaults for the others.
    pub(crate) fn formats(&self) -> FormatChoice {
        let mut f = FormatChoice::default();
        for &(class, format) in &self.link_format {
            match class {
                LinkClass::Node => f.node = format,
                LinkClass::Chain => f.chain = format,
                LinkClass::Sink => f.sink = format,
                LinkClass::Material => f.material = format,
            }
        }
        f
    }

    /// What the flags' parsers check, for flags that did not come through them (a job file).
    pub(crate) fn check(&self) -> Result<(), String> {
        if self.partitions != 0 {
            partitions_arg(&self.partitions.to_string())?;
        }
        tiles_arg(&self.tiles.to_string())?;
        if let lightfold_coordinator::plan::Peels::Layers(d) = self.peels {
            peels_arg(&d.to_string())?;
        }
        if let Some(db) = self.target_psnr {
            target_db(&db.to_string())?;
        }
        if let Some(ms) = self.frame_budget {
            positive_ms(&ms.to_string())?;
        }
        penumbra_filter(&penumbra_filter_arg(self.penumbra_filter))?;
        for (class, format) in &self.link_format {
            parse_link_format(&format!("{}={}", class.name(), format.name()))?;
        }
        if !self.epsilon.is_finite() || self.epsilon < 0.0 {
            return Err(format!(
                "--epsilon {} is not a radiance budget",
                self.epsilon
            ));
        }
        Ok(())
    }
}

/// A class of link whose format `--link-format` sets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub(crate) enum LinkClass {
    Node,
    Chain,
    Sink,
    Material,
}

impl LinkClass {
    pub(crate) fn name(self) -> &'static str {
        match self {
            LinkClass::Node => "node",
            LinkClass::Chain => "chain",
            LinkClass::Sink => "sink",
            LinkClass::Material => "material",
        }
    }
}

/// `CLASS=FORMAT` (`--link-format`): a format that carries what the class's links carry —
/// six illumination channels on `node` and `chain` links, three colour channels on `sink` links,
/// and for `material` links the 8-bit formats or half floats (what nodes emit).
pub(crate) fn parse_link_format(
    s: &str,
) -> Result<(LinkClass, lightfold_protocol::PixelFormat), String> {
    use lightfold_protocol::PixelFormat;
    let (class, format) = s
        .split_once('=')
        .ok_or_else(|| format!("{s:?} is not CLASS=FORMAT (e.g. chain=f32x6)"))?;
    let class = match class.trim() {
        "node" => LinkClass::Node,
        "chain" => LinkClass::Chain,
        "sink" => LinkClass::Sink,
        "material" => LinkClass::Material,
        other => {
            return Err(format!(
                "unknown link class {other:?}: node, chain, sink or material"
            ));
        }
    };
    let fits = |f: PixelFormat| match class {
        LinkClass::Node | LinkClass::Chain => f.channels() == 6,
        LinkClass::Sink => f.channels() == 3,
        LinkClass::Material => matches!(
            f,
            PixelFormat::Rgba8Linear | PixelFormat::Rgba8Srgb | PixelFormat::F16x4
        ),
    };
    let allowed: Vec<&str> = PixelFormat::ALL
        .into_iter()
        .filter(|&f| fits(f))
        .map(PixelFormat::name)
        .collect();
    match PixelFormat::from_name(format.trim()) {
        Some(f) if fits(f) => Ok((class, f)),
        _ => Err(format!(
            "{format:?} is not a format for {} links: {}",
            class.name(),
            allowed.join(", ")
        )),
    }
}

/// A penumbra PSNR target in dB (`--target-psnr`): finite, in (0, 200).
pub(crate) fn target_db(s: &str) -> Result<f32, String> {
    match s.parse::<f32>() {
        Ok(v) if v > 0.0 && v < 200.0 => Ok(v),
        _ => Err(format!("{s:?} is not a PSNR in dB between 0 and 200")),
    }
}

/// A duration in milliseconds that must be finite and positive (`--frame-budget`).
pub(crate) fn positive_ms(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 && v < 1e9 => Ok(v),
        _ => Err(format!("{s:?} is not a positive number of milliseconds")),
    }
}

/// `--partitions`: `auto` (0) or 1 to `MAX_PARTITIONS`.
pub(crate) fn partitions_arg(s: &str) -> Result<u32, String> {
    let max = lightfold_coordinator::plan::MAX_PARTITIONS;
    match s {
        "auto" => Ok(0),
        n => match n.parse::<u32>() {
            Ok(p) if (1..=max).contains(&p) => Ok(p),
            _ => Err(format!("expected auto or 1 to {max}, got {n:?}")),
        },
    }
}

/// `--tiles`: `auto` (0) or 1 (none) to `MAX_TILES`.
pub(crate) fn tiles_arg(s: &str) -> Result<u32, String> {
    let max = lightfold_coordinator::tiles::MAX_TILES;
    match s {
        "auto" => Ok(0),
        n => match n.parse::<u32>() {
            Ok(t) if t <= max => Ok(t),
            _ => Err(format!("expected auto or 1 to {max} tiles, got {n:?}")),
        },
    }
}

/// `--peels`: `off`, `auto` or 1 to `MAX_PEELS` translucent layers.
pub(crate) fn peels_arg(s: &str) -> Result<lightfold_coordinator::plan::Peels, String> {
    use lightfold_coordinator::plan::{MAX_PEELS, Peels};
    match s {
        "off" => Ok(Peels::Off),
        "auto" => Ok(Peels::Auto),
        n => match n.parse::<u32>() {
            Ok(d) if (1..=MAX_PEELS).contains(&d) => Ok(Peels::Layers(d)),
            _ => Err(format!(
                "expected off, auto or 1 to {MAX_PEELS} translucent layers, got {n:?}"
            )),
        },
    }
}

/// `--penumbra-filter`: `off`, `budget`, `auto` or a radius 1–8.
pub(crate) fn penumbra_filter(
    s: &str,
) -> Result<lightfold_coordinator::plan::PenumbraFilter, String> {
    use lightfold_coordinator::plan::PenumbraFilter;
    match s.trim() {
        "off" | "0" => Ok(PenumbraFilter::Off),
        "budget" => Ok(PenumbraFilter::Budget),
        "auto" => Ok(PenumbraFilter::Auto),
        r => match r.parse::<u32>() {
            Ok(r @ 1..=8) => Ok(PenumbraFilter::Radius(r)),
            _ => Err(format!(
                "{s:?}: off, budget, auto or a radius from 1 to 8 (pixels)"
            )),
        },
    }
}

/// The `--penumbra-filter` argument that gives `f`.
pub(crate) fn penumbra_filter_arg(f: lightfold_coordinator::plan::PenumbraFilter) -> String {
    use lightfold_coordinator::plan::PenumbraFilter;
    match f {
        PenumbraFilter::Off => "off".into(),
        PenumbraFilter::Budget => "budget".into(),
        PenumbraFilter::Auto => "auto".into(),
        PenumbraFilter::Radius(r) => r.to_string(),
    }
}

/// `--size WIDTHxHEIGHT`, within the image limits every input shares
/// (`lightfold_scene::limits`, printed by `lightfold defaults`).
pub(crate) fn parse_size(s: &str) -> anyhow::Result<(u32, u32)> {
    lightfold_scene::limits::parse_image_size(s)
        .map_err(|e| anyhow::anyhow!("bad --size: {e} (see `lightfold defaults`)"))
}
