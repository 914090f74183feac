//! Liveness and readiness of this process, for `/healthz` and `/readyz`.
//!
//! A daemon is *live* once its service loop runs (a node after its device opened and was
//! calibrated). It is *ready* while a coordinator's control link that has configured it is open:
//! registered and configured. A coordinator is ready while it serves frames. The state is
//! process-wide: one daemon per process.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

static LIVE: AtomicBool = AtomicBool::new(false);
static SERVING: AtomicBool = AtomicBool::new(false);
static CONFIGURED_LINKS: AtomicUsize = AtomicUsize::new(0);
static OPEN_LINKS: AtomicUsize = AtomicUsize::new(0);
/// The last claimed control link ended because its coordinator fell silent (cleared when a
/// coordinator connects again).
static RELEASED_SILENT: AtomicBool = AtomicBool::new(false);

/// A claimed control link from the coordinator at `addr` was released because it brought nothing
/// for `after`: logged, and `/readyz` says so until a coordinator connects again.
pub fn released_silent_coordinator(addr: &str, after: std::time::Duration) {
    tracing::warn!(
        %addr,
        "no word from the coordinator for {} s (stopped, hung or cut off): releasing its claim",
        after.as_secs_f64()
    );
    RELEASED_SILENT.store(true, Ordering::Relaxed);
}

/// The daemon's service loop runs (or, with false, has stopped).
pub fn set_live(live: bool) {
    LIVE.store(live, Ordering::Relaxed);
}

/// The coordinator has its cluster and drives frames (or, with false, no longer does).
pub fn set_serving(serving: bool) {
    SERVING.store(serving, Ordering::Relaxed);
}

pub fn is_live() -> bool {
    LIVE.load(Ordering::Relaxed)
}

/// What `/readyz` answers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Readiness {
    pub ready: bool,
    /// Why, in a few words (the body of the answer).
    pub why: &'static str,
}

pub fn readiness() -> Readiness {
    let (ready, why) = if SERVING.load(Ordering::Relaxed) {
        (true, "serving")
    } else if !is_live() {
        (false, "starting")
    } else if CONFIGURED_LINKS.load(Ordering::Relaxed) > 0 {
        (true, "registered and configured")
    } else if OPEN_LINKS.load(Ordering::Relaxed) > 0 {
        (false, "registered, not configured yet")
    } else if RELEASED_SILENT.load(Ordering::Relaxed) {
        (
            false,
            "released a coordinator that fell silent; waiting for a coordinator",
        )
    } else {
        (false, "waiting for a coordinator")
    };
    Readiness { ready, why }
}

/// One coordinator's control link, from registration to its end (drop).
#[derive(Debug)]
pub struct ControlLink {
    configured: bool,
}

impl ControlLink {
    pub fn open() -> ControlLink {
        OPEN_LINKS.fetch_add(1, Ordering::Relaxed);
        RELEASED_SILENT.store(false, Ordering::Relaxed);
        ControlLink { configured: false }
    }

    /// The coordinator on this link configured the daemon (idempotent).
    pub fn configured(&mut self) {
        if !self.configured {
            self.configured = true;
            CONFIGURED_LINKS.fetch_add(1, Ordering::Relaxed);
        }
    }
}

impl Drop for ControlLink {
    fn drop(&mut self) {
        OPEN_LINKS.fetch_sub(1, Ordering::Relaxed);
        if self.configured {
            CONFIGURED_LINKS.fetch_sub(1, Ordering::Relaxed);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    // One test: the state is process-wide.
    #[test]
    fn ready_while_a_configured_link_is_open() {
        assert_eq!(readiness().why, "starting");
        set_live(true);
        assert_eq!(readiness().why, "waiting for a coordinator");
        let mut a = ControlLink::open();
        assert!(!readiness().ready);
        assert_eq!(readiness().why, "registered, not configured yet");
        a.configured();
        a.configured();
        assert!(readiness().ready);
        let mut b = ControlLink::open();
        b.configured();
        drop(a);
        assert!(readiness().ready, "b still configures it");
        drop(b);
        assert!(!readiness().ready);
        released_silent_coordinator("127.0.0.1:1", std::time::Duration::from_secs(5));
        assert!(
            readiness()
                .why
                .starts_with("released a coordinator that fell silent")
        );
        drop(ControlLink::open());
        assert_eq!(readiness().why, "waiting for a coordinator");
        set_serving(true);
        assert_eq!(readiness().why, "serving");
        set_serving(false);
        set_live(false);
        assert!(!readiness().ready);
    }
}
