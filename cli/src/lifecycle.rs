//! Process lifecycle shared by every daemon subcommand: a cancellation token fired by SIGTERM,
//! Ctrl-C, or the death of the launching process (`--parent-pid`, so a killed launcher leaves no
//! orphans) — and what launchers (`demo`, `soak`) need to signal and measure the processes they
//! start.

use anyhow::Context;
use std::io::Write;
use std::path::PathBuf;
use std::time::Duration;
use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;

/// Flags every daemon takes.
#[derive(Debug, clap::Args)]
pub(crate) struct DaemonArgs {
    /// Address to bind (control and data links arrive here), e.g. `0.0.0.0:7300`.
    #[arg(long)]
    pub listen: String,
    /// Address other daemons should dial for this one (default: the bound address).
    #[arg(long)]
    pub advertise: Option<String>,
    /// Daemon id, authenticated in every handshake (default: `<role>-<host>-<port>`).
    #[arg(long)]
    pub id: Option<String>,
    /// File holding the cluster token (else `LIGHTFOLD_TOKEN`).
    #[arg(long)]
    pub token_file: Option<PathBuf>,
    /// Stop when this process is no longer our parent (set by launchers such as `demo`).
    #[arg(long)]
    pub parent_pid: Option<u32>,
    /// Release a coordinator's claim when its control link brings nothing (its keepalives come
    /// every 250 ms) for this many seconds: a stopped, hung or cut-off coordinator then holds
    /// this daemon no longer. 0: never.
    #[arg(long, default_value_t = 5.0, value_name = "SECONDS")]
    pub coordinator_silence: f64,
    #[command(flatten)]
    pub metrics: MetricsArgs,
}

impl DaemonArgs {
    /// `--coordinator-silence` as a duration.
    pub(crate) fn coordinator_silence(&self) -> anyhow::Result<std::time::Duration> {
        let s = self.coordinator_silence;
        if !(s.is_finite() && (0.0..=86_400.0).contains(&s)) {
            anyhow::bail!("--coordinator-silence {s} is not a number of seconds from 0 to 86400");
        }
        Ok(std::time::Duration::from_secs_f64(s))
    }

    /// Binds the listener, prints `listening <addr>` (flushed) for launchers, and returns the
    /// listener with the daemon id (`<role>-<host>-<port>` unless given).
    pub(crate) async fn bind(&self, role: &str) -> anyhow::Result<(TcpListener, String)> {
        let listener = TcpListener::bind(&self.listen)
            .await
            .with_context(|| format!("cannot listen on {}", self.listen))?;
        let local = listener.local_addr()?;
        let id = self
            .id
            .clone()
            .unwrap_or_else(|| format!("{role}-{}-{}", host_name(), local.port()));
        let mut out = std::io::stdout().lock();
        writeln!(out, "listening {local}")?;
        out.flush()?;
        Ok((listener, id))
    }
}

fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty() && !s.contains(char::is_whitespace))
        .unwrap_or_else(|| "localhost".into())
}

/// A token cancelled on SIGTERM, SIGINT, or when `parent_pid` stops being our parent. Must be
/// called inside a tokio runtime.
/// A run stopped by Ctrl-C (or SIGTERM to `demo`): not a failure of the command. `main` prints
/// its message, if any, as the one line the run ends with and exits with [`INTERRUPTED_EXIT`].
pub(crate) use lightfold_coordinator::console::Interrupted;

/// The exit status of an interrupted run (128 + SIGINT, as shells report it).
pub(crate) const INTERRUPTED_EXIT: i32 = 130;

pub(crate) fn shutdown_token(parent_pid: Option<u32>) -> CancellationToken {
    let token = CancellationToken::new();
    let t = token.clone();
    tokio::spawn(async move {
        let mut term =
            match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
                Ok(s) => s,
                Err(e) => {
                    tracing::warn!("cannot watch SIGTERM: {e}");
                    return;
                }
            };
        tokio::select! {
            _ = term.recv() => tracing::info!("SIGTERM: shutting down"),
            _ = tokio::signal::ctrl_c() => tracing::info!("interrupted: shutting down"),
            _ = t.cancelled() => {}
        }
        lightfold_view::metrics::notify_stopping();
        t.cancel();
    });
    if let Some(pid) = parent_pid {
        let t = token.clone();
        tokio::spawn(async move {
            loop {
                if std::os::unix::process::parent_id() != pid {
                    tracing::info!(parent = pid, "launcher exited: shutting down");
                    lightfold_view::metrics::notify_stopping();
                    t.cancel();
                    return;
                }
                tokio::select! {
                    _ = tokio::time::sleep(Duration::from_millis(250)) => {}
                    _ = t.cancelled() => return,
                }
            }
        });
    }
    token
}

/// The `--metrics-listen` flag every daemon takes.
#[derive(Debug, Clone, clap::Args)]
pub(crate) struct MetricsArgs {
    /// Serve `/metrics` (Prometheus text), `/healthz` and `/readyz` on this address, e.g.
    /// `127.0.0.1:9300` (port 0: any; the address is printed as `metrics <addr>` on stdout).
    /// Off by default.
    #[arg(long, value_name = "ADDR", env = "LIGHTFOLD_METRICS_LISTEN")]
    pub metrics_listen: Option<String>,
}
