//! `lightfold plan`: print what the planner decides for a scene — stages, lights per node, dropped
//! lights and why, shadow passes, bytes per frame per link — on a cluster file's daemons or on a
//! synthetic cluster of local daemons. Nodes are assumed to take at most `--max-lights` lights,
//! and K is raised towards it when the cluster has too few nodes, as the coordinator does with
//! the limits its nodes report.

use crate::plan_args::PlanArgs;
use anyhow::Context;
use lightfold_coordinator::cluster::ClusterFile;
use lightfold_coordinator::plan::{ClusterSpec, PlanError, plan};
use lightfold_telemetry::{out, outln};
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
    pub(crate) scene: Option<String>,
    /// The scene as a positional argument (the same as `--scene`).
    #[arg(value_name = "SCENE", hide = true)]
    pub(crate) scene_positional: Option<String>,
    /// Cluster file (TOML) listing the daemons; without it a synthetic local cluster is used.
    #[arg(long)]
    pub(crate) cluster: Option<PathBuf>,
    /// Render nodes of the synthetic cluster (default: as many as the plan needs at -K). With
    /// fewer, K is raised as the coordinator raises it, up to --max-lights.
    #[arg(long)]
    pub(crate) nodes: Option<usize>,
    /// Compositors of the synthetic cluster (default: as many as the plan uses).
    #[arg(long)]
    pub(crate) compositors: Option<usize>,
    /// The most lights one node's device takes, the ceiling K is raised to. A real node reports
    /// its own at registration (its "render node ready" log line; lavapipe's is 85); the default
    /// is what every device takes (wgpu's default limits at the default shadow-map size).
    #[arg(long, value_name = "K", default_value_t = default_max_lights())]
    pub(crate) max_lights: u32,
    #[command(flatten)]
    pub(crate) plan: PlanArgs,
    /// Print the plan as JSON instead of text.
    #[arg(long)]
    pub(crate) json: bool,
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
    args.plan.apply(&mut scene)?;
    let options = args.plan.plan_options_for(&scene)?;
    let max_lights = args.max_lights;
    // The scene the coordinator plans: with partitions, meshes too large for a part in chunks
    // (clusters here report no memory, so `auto` is 1).
    let scene = lightfold_coordinator::plan::scene_for(&scene, &ClusterSpec::local(1, 1), &options)
        .into_owned();
    let cluster = match &args.cluster {
        Some(path) => ClusterSpec::from_file(&ClusterFile::load(path)?),
        None => {
            // Learn what the scene needs on an ample cluster, then plan on exactly that (or on
            // the nodes asked for, with the compositors a plan on them uses).
            let ample = |nodes: usize| {
                ClusterSpec::local(nodes, 1024).with_synthetic_nodes(max_lights, 0, false)
            };
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
    let cluster = cluster.with_synthetic_nodes(max_lights, 0, false);
    let p = plan(&scene, &cluster, &options).map_err(|e| match e {
        PlanError::NotEnoughNodes { .. } => anyhow::anyhow!(
            "{e} (assuming nodes that take at most K = {max_lights}; --max-lights N to change)"
        ),
        e => e.into(),
    })?;
    let raised = (options.frame_budget_us.is_none() && p.k > args.plan.lights_per_node).then(|| {
        format!(
            "K raised from {} to {}: {} render node(s) are too few for {} active light samples at \
             K = {} (the coordinator does the same on a cluster this size)",
            args.plan.lights_per_node,
            p.k,
            cluster.nodes.len(),
            p.active.len(),
            args.plan.lights_per_node
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
