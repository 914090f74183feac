//! `lightfold node`: run a render-node daemon. Prints `listening <addr>` on stdout once bound (a
//! launcher parses it); logs go to stderr. The cluster token comes from `--token-file` or
//! `LIGHTFOLD_TOKEN`, never from argv. SIGTERM, Ctrl-C or the death of the launching process
//! (`--parent-pid`, so a killed launcher leaves no orphans) stops the daemon cleanly.

use crate::lifecycle::DaemonArgs;
use lightfold_node::daemon::{self, NodeOptions};
use lightfold_node::gpu::GpuOptions;
use lightfold_node::gpu::device::parse_backend;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    #[command(flatten)]
    pub daemon: DaemonArgs,
    /// Graphics backend: `vulkan` (an OpenGL adapter is refused: the shadow lookups have no GLSL
    /// form). Else `LIGHTFOLD_BACKEND`, else Vulkan.
    #[arg(long, value_parser = ["vulkan"])]
    pub backend: Option<String>,
    /// Case-insensitive part of the adapter name to use (e.g. `llvmpipe`).
    #[arg(long)]
    pub adapter: Option<String>,
    /// Keep received scenes here by content hash, across restarts.
    #[arg(long)]
    pub cache_dir: Option<PathBuf>,
    /// Refuse to start unless the adapter is a hardware GPU (not lavapipe, llvmpipe or another
    /// software rasteriser): a GPU node whose driver is missing fails instead of rendering on
    /// the CPU.
    #[arg(long, env = "LIGHTFOLD_REQUIRE_GPU")]
    pub require_gpu: bool,
    /// Where frames are packed into link formats: `device` (a compute pass; only the packed
    /// bytes are read back), `cpu` (f32 readback, packed on the CPU: the reference path) or
    /// `auto` (the device, unless it is a software rasteriser such as lavapipe).
    #[arg(long, default_value = "auto", value_parser = ["auto", "device", "cpu"], env = "LIGHTFOLD_PACK")]
    pub pack: String,
    /// Render a frame whose request has arrived while the previous frame's bands stream (the
    /// device works while the socket does); `false`: one frame at a time.
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set, env = "LIGHTFOLD_RENDER_AHEAD")]
    pub render_ahead: bool,
}

pub(crate) fn run(args: Args) -> anyhow::Result<()> {
    if let Some(id) = &args.daemon.id {
        lightfold_telemetry::logging::set_daemon(id);
    }
    let token = lightfold_net::load_token(args.daemon.token_file.as_deref())?;
    let backend = args.backend.as_deref().map(parse_backend).transpose()?;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    let gpu = GpuOptions {
        backend,
        adapter_name: args.adapter.clone(),
    };
    // Refused before binding or calibrating: a supervisor sees the failure at once, and nothing
    // ever listened.
    if args.require_gpu
        && let Ok((adapter, backend, true)) = lightfold_node::gpu::device::chosen_adapter(&gpu)
    {
        anyhow::bail!(daemon::no_hardware_gpu(&adapter, &backend));
    }
    rt.block_on(async move {
        let (listener, id) = args.daemon.bind("node").await?;
        let mut opts = NodeOptions::new(id.clone(), &token);
        opts.coordinator_silence = args.daemon.coordinator_silence()?;
        opts.advertise = args.daemon.advertise;
        opts.cache_dir = args.cache_dir;
        opts.gpu = gpu;
        opts.require_gpu = args.require_gpu;
        opts.render_ahead = args.render_ahead;
        opts.pack = match args.pack.as_str() {
            "cpu" => daemon::PackOn::Cpu,
            "device" => daemon::PackOn::Device,
            _ => daemon::PackOn::Auto,
        };
        let shutdown = crate::lifecycle::shutdown_token(args.daemon.parent_pid);
        lightfold_view::metrics::start(
            args.daemon.metrics.metrics_listen.as_deref(),
            "node",
            &id,
            shutdown.clone(),
        )
        .await?;
        daemon::run(listener, opts, shutdown).await
    })
}
