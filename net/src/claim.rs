//! Which coordinator holds this daemon (`Message::Claim`, docs/cluster-protocol.md). A control
//! link's first message after `Register` decides: a `Claim { session, take_over }` asks to hold
//! the daemon for that coordinator session; anything else makes the link unclaimed (test drivers,
//! `lightfold bench`), which holds nothing.
//!
//! - A claim while another session holds the daemon is refused `Busy` (after waiting 500 ms for
//!   the holder's link to close) unless `take_over` is set;
//!   with it the old link is sent `TakenOver` and closed first. A claim of the holder's own session
//!   (a coordinator re-dialling a daemon it had lost) replaces the old link without a message.
//! - A granted claim closes every unclaimed link; an unclaimed link is refused `Busy` while a
//!   session holds the daemon.
//! - When the holder's link closes, the daemon is free again.
//!
//! Render nodes and compositors share it (they may not depend on each other, so it lives here).

/// How long a claimed control link may bring nothing before its daemon releases it (the
/// daemons' `coordinator_silence` default): twenty of the coordinator's keepalive intervals
/// (250 ms), so a stopped, hung or cut-off coordinator holds no daemon for long.
pub const COORDINATOR_SILENCE: std::time::Duration = std::time::Duration::from_secs(5);

use lightfold_protocol::{ErrorCode, Message};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio_util::sync::CancellationToken;

/// How long a claim (or an unclaimed link) waits for another session's link to close before it
/// is refused `Busy`: a coordinator started right after its predecessor went away is not refused
/// for the moment the daemon takes to notice the old link's end.
const HANDOVER: Duration = Duration::from_millis(500);
/// How long a new holder waits for a displaced link to send its last message and close.
const RELEASE: Duration = Duration::from_secs(2);
/// How long a displaced link may take to write its last message.
pub const FAREWELL: Duration = Duration::from_secs(1);

/// The claims on one daemon.
#[derive(Debug)]
pub struct Claims {
    daemon_id: String,
    /// Whether an unclaimed link displaces the other unclaimed links (a compositor serves one
    /// coordinator at a time) or runs beside them (a node).
    exclusive: bool,
    state: Mutex<State>,
}

#[derive(Debug, Default)]
struct State {
    next: u64,
    holder: Option<Entry>,
    unclaimed: Vec<Entry>,
}

#[derive(Debug)]
struct Entry {
    serial: u64,
    session: u64,
    addr: String,
    link: Arc<LinkState>,
}

#[derive(Debug, Default)]
struct LinkState {
    /// Cancelled when another link displaces this one.
    revoked: CancellationToken,
    /// Cancelled when this link's `Ticket` drops (the link is closed).
    closed: CancellationToken,
    /// What to tell this link before closing it (`TakenOver`), if anything.
    farewell: Mutex<Option<Message>>,
}

/// A control link's place among the claims; dropping it (after closing the link) lets go.
#[derive(Debug)]
pub struct Ticket {
    claims: Arc<Claims>,
    serial: u64,
    link: Arc<LinkState>,
}

impl Claims {
    pub fn new(daemon_id: &str, exclusive: bool) -> Arc<Claims> {
        Arc::new(Claims {
            daemon_id: daemon_id.to_string(),
            exclusive,
            state: Mutex::default(),
        })
    }

    fn state(&self) -> std::sync::MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Admits a control link from `addr`: `claim` is its `(session, take_over)`, `None` for an
    /// unclaimed link. Links it displaces are revoked and closed (each given up to 2 s) before it
    /// returns. A refusal is the `Error { Busy }` to send before closing the link.
    pub async fn enter(
        self: &Arc<Self>,
        claim: Option<(u64, bool)>,
        addr: &str,
    ) -> Result<Ticket, Message> {
        let link = Arc::new(LinkState::default());
        let handover = tokio::time::Instant::now() + HANDOVER;
        let (serial, displaced) = loop {
            // A holder of another session whose link is closing (its coordinator just went
            // away) is waited for briefly instead of refusing at once.
            let holder_link = {
                let st = self.state();
                match (&claim, &st.holder) {
                    (None, Some(h)) => Some((h.link.clone(), self.busy_message(h))),
                    (Some((session, false)), Some(h)) if h.session != *session => {
                        Some((h.link.clone(), self.busy_message(h)))
                    }
                    _ => None,
                }
            };
            if let Some((holder, message)) = holder_link {
                let closed = tokio::time::timeout_at(handover, holder.closed.cancelled()).await;
                if closed.is_err() {
                    tracing::info!(%addr, "control link refused: {message}");
                    return Err(Message::error(ErrorCode::Busy, message));
                }
                continue;
            }
            let mut st = self.state();
            let serial = st.next;
            st.next += 1;
            let entry = |session| Entry {
                serial,
                session,
                addr: addr.to_string(),
                link: link.clone(),
            };
            let mut displaced = Vec::new();
            match claim {
                None => {
                    if st.holder.is_some() {
                        continue; // a holder appeared meanwhile: wait for it as above
                    }
                    if self.exclusive {
                        displaced.append(&mut st.unclaimed);
                        if !displaced.is_empty() {
                            tracing::info!(%addr, "a new coordinator replaces the previous one");
                        }
                    }
                    st.unclaimed.push(entry(0));
                }
                Some((session, take_over)) => {
                    if let Some(h) = &st.holder
                        && h.session != session
                        && !take_over
                    {
                        continue; // a holder appeared meanwhile: wait for it as above
                    }
                    if let Some(old) = st.holder.take() {
                        if old.session == session {
                            tracing::info!(
                                %addr, session = %format!("{session:016x}"),
                                "the coordinator session re-dialled: its new link replaces the old"
                            );
                        } else {
                            tracing::info!(
                                %addr, session = %format!("{session:016x}"),
                                old = %old.addr, old_session = %format!("{:016x}", old.session),
                                "taken over"
                            );
                            *old.link.farewell.lock().unwrap_or_else(|e| e.into_inner()) = Some(
                                Message::error(
                                    ErrorCode::TakenOver,
                                    format!(
                                        "{} was taken over by the coordinator at {addr} (session {session:016x})",
                                        self.daemon_id
                                    ),
                                ),
                            );
                        }
                        displaced.push(old);
                    }
                    displaced.append(&mut st.unclaimed);
                    st.holder = Some(entry(session));
                }
            }
            break (serial, displaced);
        };
        // From here on, dropping this future (the daemon stopping) lets go of the entry.
        let ticket = Ticket {
            claims: Arc::clone(self),
            serial,
            link,
        };
        for d in &displaced {
            d.link.revoked.cancel();
        }
        for d in &displaced {
            if tokio::time::timeout(RELEASE, d.link.closed.cancelled())
                .await
                .is_err()
            {
                tracing::warn!(addr = %d.addr, "a displaced control link did not close within {RELEASE:?}");
            }
        }
        if let Some((session, _)) = claim {
            tracing::info!(%addr, session = %format!("{session:016x}"), "claimed");
        }
        Ok(ticket)
    }

    fn busy_message(&self, holder: &Entry) -> String {
        format!(
            "{} is held by the coordinator at {} (session {:016x}); pass --take-over to take it over",
            self.daemon_id, holder.addr, holder.session
        )
    }
}

impl Ticket {
    /// Resolves once another link has displaced this one, with what to send it before closing.
    pub async fn revoked(&self) -> Option<Message> {
        self.link.revoked.cancelled().await;
        self.link
            .farewell
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .take()
    }
}

impl Drop for Ticket {
    fn drop(&mut self) {
        let mut st = self.claims.state();
        if st.holder.as_ref().is_some_and(|h| h.serial == self.serial)
            && let Some(h) = st.holder.take()
        {
            tracing::info!(addr = %h.addr, session = %format!("{:016x}", h.session), "claim released");
        }
        st.unclaimed.retain(|e| e.serial != self.serial);
        drop(st);
        self.link.closed.cancel();
    }
}
