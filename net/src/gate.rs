//! Admission of accepted connections before they authenticate (or, on the HTTP listeners, before
//! their request is read): at most `MAX_HANDSHAKES` at once per listener, and at most a share of
//! them from any one address (more are closed at once, before anything is read), with refused
//! peers logged at most once a second with a count of the others — so a port scan or a connect
//! loop neither exhausts a daemon's memory nor floods its log, and one address holding
//! connections open leaves room for everyone else.

use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Connections a listener authenticates at once.
pub const MAX_HANDSHAKES: usize = 64;
/// Of those, from one address.
pub const MAX_HANDSHAKES_PER_ADDRESS: usize = 16;
/// How long an accept loop waits after a failed accept before it tries again.
pub const ACCEPT_BACKOFF: Duration = Duration::from_millis(100);
/// Refusals are logged at most this often.
const LOG_EVERY: Duration = Duration::from_secs(1);

/// One listener's gate (cheap to clone).
#[derive(Debug, Clone)]
pub struct Gate {
    limit: usize,
    per_address: usize,
    open: Arc<Mutex<Open>>,
    log: Arc<Mutex<LogState>>,
}

/// The connections a gate has admitted and not yet given back, in all and by address.
#[derive(Debug, Default)]
struct Open {
    total: usize,
    by_address: HashMap<IpAddr, usize>,
}

/// A connection's place in a [`Gate`], given back when dropped.
#[derive(Debug)]
pub struct Slot {
    peer: IpAddr,
    open: Arc<Mutex<Open>>,
}

impl Drop for Slot {
    fn drop(&mut self) {
        let mut open = self.open.lock().unwrap_or_else(|e| e.into_inner());
        open.total -= 1;
        if let Some(n) = open.by_address.get_mut(&self.peer) {
            *n -= 1;
            if *n == 0 {
                open.by_address.remove(&self.peer);
            }
        }
    }
}

/// Why a connection was not admitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum Full {
    #[error("{0} connections are open")]
    Listener(usize),
    #[error("{0} connections from this address are open")]
    Address(usize),
}

#[derive(Debug, Default)]
struct LogState {
    last: Option<Instant>,
    quiet: u64,
}

impl Gate {
    /// A gate of `limit` connections, at most `per_address` of them from one address.
    pub fn new(limit: usize, per_address: usize) -> Gate {
        Gate {
            limit: limit.max(1),
            per_address: per_address.max(1),
            open: Arc::default(),
            log: Arc::default(),
        }
    }

    /// The gate of a daemon's (or the sink's) listener: `MAX_HANDSHAKES`, at most
    /// `MAX_HANDSHAKES_PER_ADDRESS` from one address.
    pub fn handshakes() -> Gate {
        Gate::new(MAX_HANDSHAKES, MAX_HANDSHAKES_PER_ADDRESS)
    }

    /// A slot for one connection from `peer`, or why not (the caller closes the connection and
    /// reports it with `refused`).
    pub fn admit(&self, peer: IpAddr) -> Result<Slot, Full> {
        let mut open = self.open.lock().unwrap_or_else(|e| e.into_inner());
        let from = open.by_address.get(&peer).copied().unwrap_or(0);
        if from >= self.per_address {
            return Err(Full::Address(from));
        }
        if open.total >= self.limit {
            return Err(Full::Listener(self.limit));
        }
        open.total += 1;
        *open.by_address.entry(peer).or_insert(0) += 1;
        Ok(Slot {
            peer,
            open: Arc::clone(&self.open),
        })
    }

    /// [`Gate::admit`], logging a refusal (`refused`) as `what` (`"handshakes"`, `"the view"`):
    /// `None` when the caller is to close the connection.
    pub fn admit_or_refuse(&self, peer: std::net::SocketAddr, what: &str) -> Option<Slot> {
        match self.admit(peer.ip()) {
            Ok(slot) => Some(slot),
            Err(full) => {
                self.refused(&peer.to_string(), &format!("{what}: {full}"));
                None
            }
        }
    }

    /// The next connection `listener` accepts that this gate admits, with its slot: what every
    /// daemon's accept loop waits on. `None` once `stop` is cancelled. A failed accept (out of
    /// file descriptors and the like) is logged and retried after [`ACCEPT_BACKOFF`] instead of
    /// spun on; a peer over the gate's limits is closed at once and logged as `what`.
    pub async fn next_admitted(
        &self,
        listener: &tokio::net::TcpListener,
        stop: &tokio_util::sync::CancellationToken,
        what: &str,
    ) -> Option<(tokio::net::TcpStream, std::net::SocketAddr, Slot)> {
        loop {
            let accepted = tokio::select! {
                _ = stop.cancelled() => return None,
                a = listener.accept() => a,
            };
            match accepted {
                Ok((stream, peer)) => {
                    if let Some(slot) = self.admit_or_refuse(peer, what) {
                        return Some((stream, peer, slot));
                    }
                }
                Err(e) => {
                    tracing::warn!("{what}: accepting a connection failed: {e}");
                    tokio::select! {
                        _ = stop.cancelled() => return None,
                        _ = tokio::time::sleep(ACCEPT_BACKOFF) => {}
                    }
                }
            }
        }
    }

    /// Logs a refused peer (WARN), at most once a second; refusals in between are counted and
    /// reported with the next line.
    pub fn refused(&self, peer: &str, why: &dyn std::fmt::Display) {
        let now = Instant::now();
        let mut log = self.log.lock().unwrap_or_else(|e| e.into_inner());
        if log.last.is_some_and(|t| now.duration_since(t) < LOG_EVERY) {
            log.quiet += 1;
            tracing::debug!(%peer, "refused a connection: {why}");
            return;
        }
        let quiet = std::mem::take(&mut log.quiet);
        log.last = Some(now);
        if quiet > 0 {
            tracing::warn!(%peer, "refused a connection: {why} ({quiet} more refused since the last report)");
        } else {
            tracing::warn!(%peer, "refused a connection: {why}");
        }
    }

    /// Refusals not yet reported in a log line.
    pub fn unreported(&self) -> u64 {
        self.log.lock().unwrap_or_else(|e| e.into_inner()).quiet
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn admits_up_to_the_limit_and_counts_quiet_refusals() {
        let ip = |n: u8| IpAddr::from([10, 0, 0, n]);
        let g = Gate::new(2, 2);
        let a = g.admit(ip(1)).unwrap();
        let _b = g.admit(ip(2)).unwrap();
        assert_eq!(g.admit(ip(3)).unwrap_err(), Full::Listener(2));
        drop(a);
        assert!(g.admit(ip(3)).is_ok());
        for _ in 0..5 {
            g.refused("p", &"no");
        }
        assert_eq!(g.unreported(), 4, "the first is logged, the others wait");
    }

    #[test]
    fn one_address_leaves_room_for_the_others() {
        let ip = |n: u8| IpAddr::from([10, 0, 0, n]);
        let g = Gate::new(4, 2);
        let a = g.admit(ip(1)).unwrap();
        let _a2 = g.admit(ip(1)).unwrap();
        assert_eq!(g.admit(ip(1)).unwrap_err(), Full::Address(2));
        let _b = g.admit(ip(2)).unwrap();
        drop(a);
        let _a3 = g.admit(ip(1)).unwrap();
        assert_eq!(g.open.lock().unwrap().by_address.get(&ip(1)), Some(&2));
    }

    /// The accept loop every daemon runs: admitted connections come out with their slot, one
    /// over the limit is closed unread and the loop goes on to the next, and a cancelled stop
    /// ends it.
    #[tokio::test]
    async fn next_admitted_passes_admitted_peers_and_ends_on_stop() {
        use tokio::io::AsyncReadExt;
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let stop = tokio_util::sync::CancellationToken::new();
        let g = Gate::new(1, 1);
        let _first = tokio::net::TcpStream::connect(addr).await.unwrap();
        let (_s, peer, slot) = g.next_admitted(&listener, &stop, "test").await.unwrap();
        assert!(peer.ip().is_loopback());
        // The gate is full: the second peer is closed at once, unread.
        let mut second = tokio::net::TcpStream::connect(addr).await.unwrap();
        let third = tokio::net::TcpStream::connect(addr);
        let waited = tokio::time::timeout(
            Duration::from_millis(300),
            g.next_admitted(&listener, &stop, "test"),
        );
        assert!(
            waited.await.is_err(),
            "nothing admitted while the gate is full"
        );
        let mut buf = [0u8; 1];
        assert_eq!(second.read(&mut buf).await.unwrap(), 0, "closed");
        drop(slot);
        let _third = third.await.unwrap();
        assert!(g.next_admitted(&listener, &stop, "test").await.is_some());
        stop.cancel();
        assert!(g.next_admitted(&listener, &stop, "test").await.is_none());
    }
}
