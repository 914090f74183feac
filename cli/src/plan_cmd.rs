//! `lightfold plan`: print what the planner decides for a scene — stages, lights per node, dropped
//! lights and why, shadow passes, bytes per frame per link — on a cluster file's daemons or on a
//! synthetic cluster of local daemons.

use anyhow::Context;
use lightfold_coordinator::cluster::ClusterFile;
use lightfold_coordinator::plan::{
    ClusterSpec, DaemonSpec, MapSizing, PlanOptions, Topology, plan,
};
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Built-in scene name.
    #[arg(default_value = lightfold_scene::defaults::DEFAULT_SCENE)]
    pub scene: String,
    /// Cluster file (TOML) listing the daemons; without it a synthetic local cluster is used.
    #[arg(long)]
    pub cluster: Option<PathBuf>,
    /// Render nodes of the synthetic cluster (default: as many as the plan needs).
    #[arg(long)]
    pub nodes: Option<usize>,
    /// Compositors of the synthetic cluster (default: as many as the plan uses).
    #[arg(long)]
    pub compositors: Option<usize>,
    /// Lights per node (the paper's K).
    #[arg(short = 'K', long, default_value_t = lightfold_scene::defaults::LIGHTS_PER_NODE)]
    pub lights_per_node: u32,
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
    /// Render the material layers on a node of their own (the paper's layout).
    #[arg(long)]
    pub material_own_node: bool,
    /// Frame-time budget in milliseconds: K becomes the largest whose slowest node fits it (by
    /// the nodes' cost model), so the plan uses as few nodes as it allows; overrides -K.
    #[arg(long, value_parser = crate::coordinator_cmd::positive_ms)]
    pub frame_budget: Option<f64>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let mut scene = lightfold_scene::builtin(&args.scene)
        .with_context(|| format!("cannot load scene {:?}", args.scene))?;
    if let Some(size) = &args.size {
        let (w, h) = crate::coordinator_cmd::parse_size(size)?;
        scene.camera.width = w;
        scene.camera.height = h;
    }
    let mut options = PlanOptions {
        lights_per_node: args.lights_per_node,
        topology: args.topology,
        force_all: args.force_all,
        epsilon: args.epsilon,
        material_own_node: args.material_own_node,
        frame_budget_us: args.frame_budget.map(|b| (b * 1000.0).round() as u64),
        ..PlanOptions::default()
    };
    if let Some(n) = args.shadow_map_size {
        options.map_sizing = MapSizing::Fixed(n);
    }
    let cluster = match &args.cluster {
        Some(path) => from_file(&ClusterFile::load(path)?),
        None => {
            // Learn what the scene needs on an ample cluster, then plan on exactly that.
            let probe = plan(&scene, &ClusterSpec::local(1024, 1024), &options)?;
            let nodes = args.nodes.unwrap_or(probe.nodes.len());
            let compositors = args.compositors.unwrap_or(probe.stages.len());
            ClusterSpec::local(nodes, compositors)
        }
    };
    let p = plan(&scene, &cluster, &options)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&p)?);
    } else {
        print!("{p}");
    }
    Ok(())
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
