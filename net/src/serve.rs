//! The one daemon skeleton: accept connections through a [`Gate`] of handshakes (per-address and
//! total limits on connections still in their handshake), authenticate each as a [`Link`] with the daemon's
//! [`Identity`] and deadlines, and hand it to the daemon's handler on a task of the caller's
//! [`TaskTracker`], until `stop` is cancelled. Render nodes, compositors and the coordinator's
//! sink serve their links through it; HTTP listeners (metrics, the live view) share the gate and
//! its accept loop ([`Gate::next_admitted`]).

use crate::gate::Gate;
use crate::link::{Identity, Link, Timeouts, accept};
use std::future::Future;
use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

/// Serves `listener` until `stop` is cancelled: each connection the gate admits is authenticated
/// (`accept`: handshake within `timeouts`; its gate slot is given back once it is done) and, when
/// it passes, `handler` runs with its link on a task of `tracker`. A failed handshake is logged
/// through the gate (rate-limited; one that closes before its handshake at debug level), never
/// ends the daemon. `what` names the listener in the logs. Returns when `stop` is cancelled;
/// the caller closes and waits for `tracker` (handlers see `stop` too).
pub async fn serve<H, F>(
    listener: &TcpListener,
    me: &Identity,
    timeouts: Timeouts,
    stop: &CancellationToken,
    tracker: &TaskTracker,
    what: &str,
    handler: H,
) where
    H: Fn(Link) -> F + Clone + Send + 'static,
    F: Future<Output = ()> + Send + 'static,
{
    let gate = Gate::handshakes();
    while let Some((stream, peer, slot)) = gate.next_admitted(listener, stop, what).await {
        let (me, stop, gate, handler) = (me.clone(), stop.clone(), gate.clone(), handler.clone());
        // The handshake runs on the connection's task, so one slow peer never holds up the next.
        tracker.spawn(async move {
            let link = tokio::select! {
                _ = stop.cancelled() => return,
                l = accept(stream, &me, timeouts) => l,
            };
            drop(slot);
            match link {
                Ok(link) => handler(link).await,
                Err(e) if e.is_disconnect() => {
                    tracing::debug!(%peer, error = %e, "closed before its handshake")
                }
                Err(e) => gate.refused(&peer.to_string(), &format!("handshake failed: {e}")),
            }
        });
    }
}
