//! A cluster whose daemons all run on this machine (`lightfold demo`, `lightfold cluster up`):
//! the planner's probe cluster as this machine's nodes will report themselves, and the bound on
//! how many processes such a cluster may start.

use anyhow::bail;
use lightfold_coordinator::plan::{ClusterSpec, Plan, PlanOptions, plan};

/// `cluster` with every render node reporting this machine's memory, as the demo's nodes will.
pub fn with_memory(cluster: ClusterSpec) -> ClusterSpec {
    cluster.with_synthetic_nodes(0, lightfold_node::daemon::sys::memory_bytes(), true)
}

/// The probe cluster's nodes as this machine's will be: on a hardware GPU, every node reports
/// that one device (and the lights it takes), so the plan merges them as the coordinator's will
/// (`docs/planner.md` § Shared GPUs); on a software rasteriser, every node reports this
/// machine's CPU, so the estimate adds them up as the coordinator's will (§ Cost model). The
/// demo starts only the nodes that plan uses.
pub fn on_this_machine(cluster: ClusterSpec) -> ClusterSpec {
    use lightfold_node::gpu::device::{LocalDevice, chosen_device};
    let host = lightfold_node::daemon::sys::hostname();
    let Some(local) = chosen_device(&lightfold_node::gpu::GpuOptions::default(), &host) else {
        return cluster;
    };
    let machine = lightfold_node::daemon::sys::machine();
    let mut cluster = with_memory(cluster);
    for caps in cluster
        .nodes
        .iter_mut()
        .filter_map(|n| n.capabilities.as_mut())
    {
        match &local {
            LocalDevice::Gpu {
                identity,
                max_lights,
            } => {
                caps.max_lights = *max_lights;
                caps.device = identity.clone();
            }
            LocalDevice::Cpu => caps.cpu_host = machine.clone(),
        }
    }
    cluster
}

/// Processes per core `--max-processes` allows by default, and the floor.
pub const PROCESSES_PER_CORE: usize = 4;
pub const MIN_MAX_PROCESSES: usize = 32;

/// The default of `--max-processes` on this machine.
pub fn default_max_processes() -> usize {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    (PROCESSES_PER_CORE * cores).max(MIN_MAX_PROCESSES)
}

/// Refuses a plan needing more than `max` processes (nodes, stages and the coordinator), naming
/// the smallest K that would fit.
pub fn check_processes(
    scene: &lightfold_scene::Scene,
    options: &PlanOptions,
    probe: &Plan,
    max_processes: Option<usize>,
) -> anyhow::Result<()> {
    let (max, why) = match max_processes {
        Some(n) => (n, format!("--max-processes allows {n}")),
        None => (
            default_max_processes(),
            format!(
                "this machine holds {} ({PROCESSES_PER_CORE} per core, at least \
                 {MIN_MAX_PROCESSES}; --max-processes N to change)",
                default_max_processes()
            ),
        ),
    };
    let count = |p: &Plan| p.nodes.len() + p.stages.len() + 1;
    let needed = count(probe);
    if needed <= max {
        return Ok(());
    }
    let cluster = ClusterSpec::local(256, 256);
    // The planner's node count falls as K grows: the smallest K that fits, by bisection.
    let at = |k: u32| {
        let mut opts = options.clone();
        opts.lights_per_node = k;
        opts.frame_budget_us = None;
        // Automatic tiles take the nodes there are (here 256): count the untiled plan's.
        if opts.tiles == 0 {
            opts.tiles = 1;
        }
        plan(scene, &cluster, &opts).ok()
    };
    let (mut lo, mut hi) = (probe.k + 1, 256);
    let mut fits = None;
    while lo <= hi {
        let k = lo + (hi - lo) / 2;
        match at(k).filter(|p| count(p) <= max) {
            Some(p) => {
                fits = Some((p.k, p.nodes.len(), p.stages.len(), count(&p)));
                hi = k - 1;
            }
            None => lo = k + 1,
        }
    }
    let hint = match fits {
        Some((k, n, c, total)) => format!(
            "-K {k} fits ({n} render node(s), {c} compositor(s), {total} processes), as does a \
             --frame-budget loose enough for K ≥ {k}"
        ),
        None => "no K up to 256 fits: the scene has too many light samples for this many \
                 processes"
            .into(),
    };
    bail!(
        "scene {:?} at K = {} needs {} render node(s) and {} compositor(s), {needed} \
         processes with the coordinator; {why}. {hint}",
        scene.name,
        probe.k,
        probe.nodes.len(),
        probe.stages.len(),
    )
}
