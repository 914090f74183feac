//! Process lifecycle shared by every daemon subcommand: a cancellation token fired by SIGTERM,
//! Ctrl-C, or the death of the launching process (`--parent-pid`, so a killed launcher leaves no
//! orphans).

use std::time::Duration;
use tokio_util::sync::CancellationToken;

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
