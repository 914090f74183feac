//! Admission of accepted connections before they authenticate: at most `MAX_HANDSHAKES` at once
//! per listener (more are closed at once, before anything is read), and refused peers logged at
//! most once a second with a count of the others, so a port scan or a connect loop neither
//! exhausts a daemon's memory nor floods its log.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};

/// Connections a listener authenticates at once.
pub const MAX_HANDSHAKES: usize = 64;
/// Refusals are logged at most this often.
const LOG_EVERY: Duration = Duration::from_secs(1);

/// One listener's gate (cheap to clone).
#[derive(Debug, Clone)]
pub struct Gate {
    slots: Arc<Semaphore>,
    log: Arc<Mutex<LogState>>,
}

#[derive(Debug, Default)]
struct LogState {
    last: Option<Instant>,
    quiet: u64,
}

impl Gate {
    pub fn new(limit: usize) -> Gate {
        Gate {
            slots: Arc::new(Semaphore::new(limit.max(1))),
            log: Arc::default(),
        }
    }

    /// A slot for one handshake, or `None` when `MAX_HANDSHAKES` are under way (the caller
    /// closes the connection and reports it with `refused`).
    pub fn admit(&self) -> Option<OwnedSemaphorePermit> {
        Arc::clone(&self.slots).try_acquire_owned().ok()
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
        let g = Gate::new(2);
        let a = g.admit().unwrap();
        let _b = g.admit().unwrap();
        assert!(g.admit().is_none());
        drop(a);
        assert!(g.admit().is_some());
        for _ in 0..5 {
            g.refused("p", &"no");
        }
        assert_eq!(g.unreported(), 4, "the first is logged, the others wait");
    }
}
