//! Process lifecycle shared by every daemon subcommand: a cancellation token fired by SIGTERM,
//! Ctrl-C, or the death of the launching process (`--parent-pid`, so a killed launcher leaves no
//! orphans).

use anyhow::Context;
use std::io::Write;
use std::path::PathBuf;
use std::time::Duration;
use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;

/// Flags every daemon takes.
#[derive(Debug, clap::Args)]
pub struct DaemonArgs {
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
}

impl DaemonArgs {
    /// Binds the listener, prints `listening <addr>` (flushed) for launchers, and returns the
    /// listener with the daemon id (`<role>-<host>-<port>` unless given).
    pub async fn bind(&self, role: &str) -> anyhow::Result<(TcpListener, String)> {
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
pub fn shutdown_token(parent_pid: Option<u32>) -> CancellationToken {
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
        t.cancel();
    });
    if let Some(pid) = parent_pid {
        let t = token.clone();
        tokio::spawn(async move {
            loop {
                if std::os::unix::process::parent_id() != pid {
                    tracing::info!(parent = pid, "launcher exited: shutting down");
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
