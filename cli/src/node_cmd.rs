//! `lightfold node`: run a render-node daemon. Prints `listening <addr>` on stdout once bound (a
//! launcher parses it); logs go to stderr. The cluster token comes from `--token-file` or
//! `LIGHTFOLD_TOKEN`, never from argv. SIGTERM, Ctrl-C or the death of the launching process
//! (`--parent-pid`, so a killed launcher leaves no orphans) stops the daemon cleanly.

use anyhow::Context;
use lightfold_node::daemon::{self, NodeOptions};
use lightfold_node::gpu::GpuOptions;
use lightfold_node::gpu::device::parse_backend;
use std::io::Write;
use std::path::PathBuf;
use tokio::net::TcpListener;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Address to bind (control links from the coordinator arrive here), e.g. `0.0.0.0:7300`.
    #[arg(long)]
    pub listen: String,
    /// Address other daemons should use for this node (default: the bound address).
    #[arg(long)]
    pub advertise: Option<String>,
    /// Daemon id, authenticated in every handshake (default: `node-<host>-<port>`).
    #[arg(long)]
    pub id: Option<String>,
    /// File holding the cluster token (else `LIGHTFOLD_TOKEN`).
    #[arg(long)]
    pub token_file: Option<PathBuf>,
    /// Graphics backend (else `LIGHTFOLD_BACKEND`, else Vulkan before GL).
    #[arg(long, value_parser = ["vulkan", "gl"])]
    pub backend: Option<String>,
    /// Case-insensitive part of the adapter name to use (e.g. `llvmpipe`).
    #[arg(long)]
    pub adapter: Option<String>,
    /// Keep received scenes here by content hash, across restarts.
    #[arg(long)]
    pub cache_dir: Option<PathBuf>,
    /// Stop when this process is no longer our parent (set by launchers such as `demo`).
    #[arg(long)]
    pub parent_pid: Option<u32>,
}

fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty() && !s.contains(char::is_whitespace))
        .unwrap_or_else(|| "localhost".into())
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let token = lightfold_net::load_token(args.token_file.as_deref())?;
    let backend = args.backend.as_deref().map(parse_backend).transpose()?;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    rt.block_on(async move {
        let listener = TcpListener::bind(&args.listen)
            .await
            .with_context(|| format!("cannot listen on {}", args.listen))?;
        let local = listener.local_addr()?;
        let id = args
            .id
            .unwrap_or_else(|| format!("node-{}-{}", host_name(), local.port()));
        let mut opts = NodeOptions::new(id, &token);
        opts.advertise = args.advertise;
        opts.cache_dir = args.cache_dir;
        opts.gpu = GpuOptions {
            backend,
            adapter_name: args.adapter,
        };
        {
            let mut out = std::io::stdout().lock();
            writeln!(out, "listening {local}")?;
            out.flush()?;
        }
        let shutdown = crate::lifecycle::shutdown_token(args.parent_pid);
        daemon::run(listener, opts, shutdown).await
    })
}
