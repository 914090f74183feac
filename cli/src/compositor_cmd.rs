//! `lightfold compositor`: run a compositor stage daemon. Prints `listening <addr>` on stdout once
//! bound (a launcher parses it); logs go to stderr. The cluster token comes from `--token-file` or
//! `LIGHTFOLD_TOKEN`, never from argv. SIGTERM, Ctrl-C, the coordinator's `Shutdown`, or the exit
//! of the launching process (`--parent-pid`) stop it cleanly.

use crate::lifecycle::DaemonArgs;
use anyhow::Context;
use lightfold_compositor::daemon::{self, CompositorOptions};
use std::time::Duration;

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    #[command(flatten)]
    pub daemon: DaemonArgs,
    /// Longest wait for one input band once a frame is due, in seconds.
    #[arg(long, default_value_t = 30.0)]
    pub input_timeout: f64,
    /// How long to keep dialing the downstream stage, in seconds.
    #[arg(long, default_value_t = 10.0)]
    pub dial_timeout: f64,
    /// Threads that combine bands (a band is split across them). Raise it where the stage has
    /// cores to itself; on a machine shared with other daemons one is faster.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=256))]
    pub compute_threads: u16,
}

fn seconds(what: &str, s: f64) -> anyhow::Result<Duration> {
    Duration::try_from_secs_f64(s).with_context(|| format!("--{what} {s} is not a duration"))
}

pub(crate) fn run(args: Args) -> anyhow::Result<()> {
    if let Some(id) = &args.daemon.id {
        lightfold_telemetry::logging::set_daemon(id);
    }
    let token = lightfold_net::load_token(args.daemon.token_file.as_deref())?;
    let input_timeout = seconds("input-timeout", args.input_timeout)?;
    let dial_timeout = seconds("dial-timeout", args.dial_timeout)?;
    let silence = args.daemon.coordinator_silence()?;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    rt.block_on(async move {
        let (listener, id) = args.daemon.bind("compositor").await?;
        let local = listener.local_addr()?;
        let advertise = args.daemon.advertise.unwrap_or_else(|| local.to_string());
        let mut opts = CompositorOptions::new(id.clone(), advertise, &token);
        opts.input_timeout = input_timeout;
        opts.dial_timeout = dial_timeout;
        opts.coordinator_silence = silence;
        opts.compute_threads = usize::from(args.compute_threads);
        let shutdown = crate::lifecycle::shutdown_token(args.daemon.parent_pid);
        lightfold_view::metrics::start(
            args.daemon.metrics.metrics_listen.as_deref(),
            "compositor",
            &id,
            shutdown.clone(),
        )
        .await?;
        daemon::run(listener, opts, shutdown).await
    })
}
