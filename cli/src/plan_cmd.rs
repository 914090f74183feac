//! `lightfold plan`: print what the planner decides for a scene — stages, lights per node, dropped
//! lights and why, shadow passes, bytes per frame per link — on a cluster file's daemons or on a
//! synthetic cluster of local daemons. Nodes are assumed to take at most `--max-lights` lights,
//! and K is raised towards it when the cluster has too few nodes, as the coordinator does with
//! the limits its nodes report.

use anyhow::Context;
use lightfold_coordinator::cluster::ClusterFile;
use lightfold_coordinator::plan::{
    ClusterSpec, DaemonSpec, MapSizing, PlanError, PlanOptions, Topology, plan,
};
use lightfold_harness::{out, outln};
use lightfold_protocol::{Capabilities, Role};
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Built-in scene name, scene file (.toml) or model (.gltf/.glb, .obj, .ply,
    /// .usda/.usdc/.usdz) [default: balls].
    #[arg(
        long = "scene",
        value_name = "SCENE",
        conflicts_with = "scene_positional"
    )]
    pub scene: Option<String>,
    /// The scene as a positional argument (the same as `--scene`).
    #[arg(value_name = "SCENE", hide = true)]
    pub scene_positional: Option<String>,
    /// Cluster file (TOML) listing the daemons; without it a synthetic local cluster is used.
    #[arg(long)]
    pub cluster: Option<PathBuf>,
    /// Render nodes of the synthetic cluster (default: as many as the plan needs at -K). With
    /// fewer, K is raised as the coordinator raises it, up to --max-lights.
    #[arg(long)]
    pub nodes: Option<usize>,
    /// Compositors of the synthetic cluster (default: as many as the plan uses).
    #[arg(long)]
    pub compositors: Option<usize>,
    /// Lights per node (the paper's K); raised when the cluster has too few nodes.
    #[arg(short = 'K', long, default_value_t = lightfold_scene::defaults::LIGHTS_PER_NODE)]
    pub lights_per_node: u32,
    #[command(flatten)]
    pub indirect: crate::indirect_args::IndirectArgs,
    /// The most lights one node's device takes, the ceiling K is raised to. A real node reports
    /// its own at registration (its "render node ready" log line; lavapipe's is 85); the default
    /// is what every device takes (wgpu's default limits at the default shadow-map size).
    #[arg(long, value_name = "K", default_value_t = default_max_lights())]
    pub max_lights: u32,
    /// Compositor topology: `chain` (a linear pipeline, each stage adds its nodes to the upstream
    /// sum), `tree` (leaf stages sum nodes, the stages above join pairs of partial sums) or
    /// `auto` (a tree where a chain would have 8 stages or more: lower latency there,
    /// docs/scaling.md).
    #[arg(long, default_value = "chain")]
    pub topology: Topology,
    /// No culling: every light, material layer and caster.
    #[arg(long)]
    pub force_all: bool,
    /// Budget of radiance (display units) culled samples may add to a pixel.
    #[arg(long, default_value_t = lightfold_coordinator::plan::DEFAULT_EPSILON)]
    pub epsilon: f32,
    /// One shadow-map size for every light instead of the mismatch-factor choice.
    #[arg(long)]
    pub shadow_map_size: Option<u32>,
    /// Image size as WIDTHxHEIGHT (default: the scene's).
    #[arg(long)]
    pub size: Option<String>,
    /// Print the plan as JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Sort-last partitions: split the scene's meshes into P spatially coherent parts; every
    /// light group is rendered once per part by a node drawing only that part's eye pass, with
    /// maps fitted to it, and the compositor chain depth-composes the parts (docs/planner.md §
    /// Partitions). Needs P × the render nodes. `auto` (the default): 1, unless the scene's
    /// geometry would not fit the memory the render nodes report.
    #[arg(long, default_value = "auto", value_parser = crate::coordinator_cmd::partitions_arg)]
    pub partitions: u32,
    /// Render the material layers on a node of their own (the paper's layout).
    #[arg(long)]
    pub material_own_node: bool,
    /// Frame-time budget in milliseconds: K becomes the largest whose slowest node fits it (by
    /// the nodes' cost model), so the plan uses as few nodes as it allows; overrides -K. When no
    /// K fits, larger shadow maps, then samples per area light, then the least important samples
    /// are given up until it does (the plan says what it gave up).
    #[arg(long, value_parser = crate::coordinator_cmd::positive_ms)]
    pub frame_budget: Option<f64>,
    /// Error target: penumbra PSNR in dB against the area-light truth. The area lights' samples
    /// are halved or doubled to the fewest the planner's error model (fitted to the default
    /// scene's accuracy sweep) expects to reach it; `lightfold accuracy` measures what it gives.
    #[arg(long, value_parser = crate::coordinator_cmd::target_db)]
    pub target_psnr: Option<f32>,
    #[command(flatten)]
    pub model: crate::model_args::ModelArgs,
    /// Screen-space penumbra filter at the last stage: a tent average of the illumination sum
    /// over each pixel's (2R+1)² window, on its own surface only (the eye depth travels with the
    /// material layers), before the material multiply, so few samples per area light give a
    /// smooth penumbra. `budget` (the default): where a frame budget or an error target lowers
    /// the samples per area light, at the radius the error model gains most with; `auto`: at
    /// every count where the model expects a gain (16 samples or fewer); `off`; or a radius
    /// 1–8 (docs/operators.md, docs/planner.md).
    #[arg(long, default_value = "budget", value_parser = crate::coordinator_cmd::penumbra_filter)]
    pub penumbra_filter: lightfold_coordinator::plan::PenumbraFilter,
}

impl Args {
    fn scene(&self) -> &str {
        self.scene
            .as_deref()
            .or(self.scene_positional.as_deref())
            .unwrap_or(lightfold_scene::defaults::DEFAULT_SCENE)
    }
}

/// The largest K every device takes: `max_lights_for` at wgpu's default limits and the shadow-map
/// size nodes report their limit at.
fn default_max_lights() -> u32 {
    lightfold_node::gpu::device::max_lights_for(
        &Default::default(),
        lightfold_scene::defaults::SHADOW_MAP_SIZE,
    )
}

pub(crate) fn run(args: Args) -> anyhow::Result<()> {
    let name = args.scene();
    let mut scene =
        lightfold_scene::load(name).with_context(|| format!("cannot load scene {name:?}"))?;
    if let Some(size) = &args.size {
        let (w, h) = crate::coordinator_cmd::parse_size(size)?;
        scene.camera.width = w;
        scene.camera.height = h;
    }
    args.indirect.apply(&mut scene)?;
    let mut options = PlanOptions {
        lights_per_node: args.lights_per_node,
        topology: args.topology,
        force_all: args.force_all,
        epsilon: args.epsilon,
        material_own_node: args.material_own_node,
        frame_budget_us: args.frame_budget.map(|b| (b * 1000.0).round() as u64),
        target_penumbra_db: args.target_psnr,
        penumbra_filter: args.penumbra_filter,
        partitions: args.partitions,
        ..PlanOptions::default()
    };
    if let Some(n) = args.shadow_map_size {
        options.map_sizing = MapSizing::Fixed(n);
    }
    args.model.apply(&scene, &mut options)?;
    let max_lights = args.max_lights;
    // The scene the coordinator plans: with partitions, meshes too large for a part in chunks
    // (clusters here report no memory, so `auto` is 1).
    let scene = lightfold_coordinator::plan::scene_for(&scene, &ClusterSpec::local(1, 1), &options)
        .into_owned();
    let cluster = match &args.cluster {
        Some(path) => from_file(&ClusterFile::load(path)?),
        None => {
            // Learn what the scene needs on an ample cluster, then plan on exactly that (or on
            // the nodes asked for, with the compositors a plan on them uses).
            let ample = |nodes: usize| with_devices(ClusterSpec::local(nodes, 1024), max_lights);
            let probe = plan(&scene, &ample(1024), &options)?;
            let nodes = args.nodes.unwrap_or(probe.nodes.len());
            let compositors = match args.compositors {
                Some(c) => c,
                None if nodes == probe.nodes.len() => probe.stages.len(),
                None => match plan(&scene, &ample(nodes), &options) {
                    Ok(p) => p.stages.len(),
                    Err(_) => probe.stages.len(),
                },
            };
            ClusterSpec::local(nodes, compositors)
        }
    };
    let cluster = with_devices(cluster, max_lights);
    let p = plan(&scene, &cluster, &options).map_err(|e| match e {
        PlanError::NotEnoughNodes { .. } => anyhow::anyhow!(
            "{e} (assuming nodes that take at most K = {max_lights}; --max-lights N to change)"
        ),
        e => e.into(),
    })?;
    let raised = (options.frame_budget_us.is_none() && p.k > args.lights_per_node).then(|| {
        format!(
            "K raised from {} to {}: {} render node(s) are too few for {} active light samples at \
             K = {} (the coordinator does the same on a cluster this size)",
            args.lights_per_node,
            p.k,
            cluster.nodes.len(),
            p.active.len(),
            args.lights_per_node
        )
    });
    if args.json {
        if let Some(note) = &raised {
            eprintln!("{note}");
        }
        outln!("{}", serde_json::to_string_pretty(&p)?);
    } else {
        if let Some(note) = &raised {
            outln!("{note}");
        }
        out!("{p}");
    }
    Ok(())
}

/// `cluster` with every render node reporting a device that takes at most `max_lights` lights
/// (what a real node reports at registration; the planner raises K only up to it).
fn with_devices(mut cluster: ClusterSpec, max_lights: u32) -> ClusterSpec {
    for n in &mut cluster.nodes {
        n.capabilities
            .get_or_insert_with(|| synthetic_node(&n.id, max_lights, 0));
    }
    cluster
}

/// What a synthetic render node `id` reports: a device taking at most `max_lights` lights and
/// `memory_bytes` of memory (0 unknown); nothing measured.
pub(crate) fn synthetic_node(id: &str, max_lights: u32, memory_bytes: u64) -> Capabilities {
    Capabilities {
        max_lights,
        memory_bytes,
        ..Capabilities::unmeasured(Role::Node, id)
    }
}

fn from_file(file: &ClusterFile) -> ClusterSpec {
    let spec = |prefix: &str, entries: &[lightfold_coordinator::cluster::DaemonEntry]| {
        entries
            .iter()
            .enumerate()
            .map(|(i, e)| DaemonSpec {
                id: e.id.clone().unwrap_or_else(|| format!("{prefix}-{i}")),
                address: e.address.clone(),
                capabilities: None,
            })
            .collect()
    };
    ClusterSpec {
        nodes: spec("node", &file.nodes),
        compositors: spec("comp", &file.compositors),
        sink: file
            .sink_advertise
            .clone()
            .unwrap_or_else(|| file.sink_listen.clone()),
    }
}
