//! `lightfold compositor`: run a compositor stage daemon. Prints `listening <addr>` on stdout once
//! bound (a launcher parses it); logs go to stderr. The cluster token comes from `--token-file` or
//! `LIGHTFOLD_TOKEN`, never from argv. SIGTERM, Ctrl-C, the coordinator's `Shutdown`, or the exit
//! of the launching process (`--parent-pid`) stop it cleanly.

use anyhow::Context;
use lightfold_compositor::daemon::{self, CompositorOptions};
use std::io::Write;
use std::path::PathBuf;
use std::time::Duration;
use tokio::net::TcpListener;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Address to bind (control and data links arrive here), e.g. `0.0.0.0:7400`.
    #[arg(long)]
    pub listen: String,
    /// Address other daemons should dial for this stage (default: the bound address).
    #[arg(long)]
    pub advertise: Option<String>,
    /// Daemon id, authenticated in every handshake (default: `compositor-<host>-<port>`).
    #[arg(long)]
    pub id: Option<String>,
    /// File holding the cluster token (else `LIGHTFOLD_TOKEN`).
    #[arg(long)]
    pub token_file: Option<PathBuf>,
    /// Longest wait for one input band once a frame is due, in seconds.
    #[arg(long, default_value_t = 30.0)]
    pub input_timeout: f64,
    /// How long to keep dialing the downstream stage, in seconds.
    #[arg(long, default_value_t = 10.0)]
    pub dial_timeout: f64,
    /// Stop when this process (the launcher) is no longer our parent.
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

fn seconds(what: &str, s: f64) -> anyhow::Result<Duration> {
    Duration::try_from_secs_f64(s).with_context(|| format!("--{what} {s} is not a duration"))
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let token = lightfold_net::load_token(args.token_file.as_deref())?;
    let input_timeout = seconds("input-timeout", args.input_timeout)?;
    let dial_timeout = seconds("dial-timeout", args.dial_timeout)?;
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
            .unwrap_or_else(|| format!("compositor-{}-{}", host_name(), local.port()));
        let advertise = args.advertise.unwrap_or_else(|| local.to_string());
        let mut opts = CompositorOptions::new(id, advertise, &token);
        opts.input_timeout = input_timeout;
        opts.dial_timeout = dial_timeout;
        {
            let mut out = std::io::stdout().lock();
            writeln!(out, "listening {local}")?;
            out.flush()?;
        }
        let shutdown = crate::lifecycle::shutdown_token(args.parent_pid);
        daemon::run(listener, opts, shutdown).await
    })
}
