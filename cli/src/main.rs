//! The one `lightfold` binary: every daemon role and every tool (render, plan, demo, soak, bench,
//! accuracy) as a subcommand. Each subcommand lives in its own module with an `Args` struct and a
//! `run` function; this file only dispatches.

use clap::{Parser, Subcommand};
use lightfold_harness::{bench, soak, view_probe};
use lightfold_telemetry::logging;
use lightfold_telemetry::out;

mod accuracy_cmd;
mod calibrate_cmd;
mod compare_cmd;
mod compositor_cmd;
mod coordinator_cmd;
mod defaults_cmd;
mod demo_cmd;
mod healthcheck_cmd;
mod indirect_args;
mod lifecycle;
mod model_args;
mod node_cmd;
mod plan_args;
mod plan_cmd;
mod render_cmd;

#[derive(Debug, Parser)]
#[command(
    name = "lightfold",
    version,
    about = "Distributed many-light soft-shadow renderer"
)]
struct Cli {
    /// Log filter (tracing `EnvFilter` syntax); `RUST_LOG` overrides it.
    #[arg(long, global = true, default_value = "info")]
    log: String,
    /// Log lines as text (coloured only on a terminal, never with `NO_COLOR` set) or as one JSON
    /// object per line (for collectors: daemon id, level, message, fields, span fields).
    #[arg(
        long,
        global = true,
        value_name = "text|json",
        default_value = "text",
        env = "LIGHTFOLD_LOG_FORMAT"
    )]
    log_format: logging::LogFormat,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Speed against error: sweep the quality knobs against the area-light ground truth.
    Accuracy(accuracy_cmd::Args),
    /// Fit a scene's own error model for the planner: a few renders against its area-light
    /// truth, cached; plans of the scene then aim at 45 dB penumbra PSNR at the least cost.
    Calibrate(calibrate_cmd::Args),
    /// Benchmarks that print figures (`bench node`: what K lights per node cost).
    Bench(bench::Args),
    /// Image metrics of a test EXR against a reference EXR (RMSE, PSNR, FLIP, penumbra);
    /// `--min-psnr`/`--max-flip` fail the command when not met (a CI gate).
    Compare(compare_cmd::Args),
    /// Run a compositor stage daemon.
    Compositor(compositor_cmd::Args),
    /// Run the coordinator: connect a cluster, plan the scene, drive frames, write the image.
    Coordinator(coordinator_cmd::Args),
    /// Start a local multi-process cluster and render a scene (also: `cluster up`).
    Demo(demo_cmd::Args),
    /// Local cluster commands (`cluster up` is `demo`).
    #[command(subcommand)]
    Cluster(ClusterCommand),
    /// Print the built-in defaults (image size, samples, K, shadow-map size) and the limits every
    /// input is checked against.
    Defaults(defaults_cmd::Args),
    /// Ask a daemon's `/healthz` (or `/readyz`) on its `--metrics-listen` address; exit 0 on 200
    /// (a container's `HEALTHCHECK`).
    Healthcheck(healthcheck_cmd::Args),
    /// Run a render-node daemon.
    Node(node_cmd::Args),
    /// Print the plan for a scene: stages, lights per node, culled lights, shadow passes, bytes.
    Plan(plan_cmd::Args),
    /// Render one image to EXR + PNG (`--reference`: on the CPU with ray-traced shadows).
    Render(render_cmd::Args),
    /// Failover soak: a local cluster under random daemon faults (kill, stop, terminate and
    /// restart); every frame checked; detection and recovery times, re-plans, peak RSS.
    Soak(soak::Args),
    /// Measure a live view as a viewer sees it: interaction latency, frame interval and what
    /// serving costs (`docs/live-view.md`).
    ViewProbe(view_probe::Args),
}

#[derive(Debug, Subcommand)]
enum ClusterCommand {
    /// Start a local multi-process cluster and render a scene (the same as `demo`).
    Up(demo_cmd::Args),
}

fn main() -> anyhow::Result<()> {
    mesa_environment();
    let cli = Cli::parse();
    logging::init(&cli.log, cli.log_format);
    let result = match cli.command {
        Command::Accuracy(args) => accuracy_cmd::run(args),
        Command::Bench(args) => bench::run(args),
        Command::Calibrate(args) => calibrate_cmd::run(args),
        Command::Compare(args) => compare_cmd::run(args),
        Command::Compositor(args) => compositor_cmd::run(args),
        Command::Coordinator(args) => coordinator_cmd::run_cmd(args),
        Command::Defaults(args) => defaults_cmd::run(args),
        Command::Demo(args) | Command::Cluster(ClusterCommand::Up(args)) => demo_cmd::run(args),
        Command::Healthcheck(args) => healthcheck_cmd::run(args),
        Command::Node(args) => node_cmd::run(args),
        Command::Plan(args) => plan_cmd::run(args),
        Command::Render(args) => render_cmd::run(args),
        Command::Soak(args) => soak::run(args),
        Command::ViewProbe(args) => view_probe::run(args),
    };
    // Ctrl-C: one line (the run's own) and the shell's status for it, not an error.
    if let Err(e) = &result
        && let Some(i) = e.downcast_ref::<lifecycle::Interrupted>()
    {
        if !i.0.is_empty() {
            eprintln!("{}", i.0);
        }
        std::process::exit(lifecycle::INTERRUPTED_EXIT);
    }
    // A reader that went away (`lightfold plan | head`) is not a failure of the command.
    if let Err(e) = &result
        && out::is_broken_pipe(e)
    {
        out::reader_gone();
    }
    // A collector reading JSON lines gets the error as one too, not anyhow's text.
    if let Err(e) = &result
        && cli.log_format == logging::LogFormat::Json
    {
        tracing::error!(error = %format!("{e:#}"), "exiting: {e}");
        std::process::exit(1);
    }
    result
}

/// Mesa's device-select Vulkan layer, installed with Debian's Vulkan drivers, complains twice
/// per process that opens a device ("XDG_RUNTIME_DIR is invalid") when there is no login
/// session, as for daemons, and reorders devices, where the node ranks adapters itself
/// (`lightfold_node::gpu::device`). `NODEVICE_SELECT=1` turns the layer off; children (the
/// demo's daemons) inherit it. Left alone when set, and when `MESA_VK_DEVICE_SELECT` asks the
/// layer for a device.
///
/// `set_var` is `unsafe` in edition 2024 because another thread may read the environment at the
/// same time; this runs first thing in `main`, when the process has only its main thread (no
/// runtime, logger or GPU instance exists yet), which is the one sound place for it.
#[allow(unsafe_code)]
fn mesa_environment() {
    if std::env::var_os("NODEVICE_SELECT").is_none()
        && std::env::var_os("MESA_VK_DEVICE_SELECT").is_none()
    {
        // SAFETY: single-threaded here (see above); nothing else touches the environment yet.
        unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
    }
}
