//! Data inputs: authenticated links from producers parked by daemon id until the configuration
//! claims them, a reader task per claimed link that queues bands under a byte budget (so a
//! stalled stage stops reading and TCP pushes back on the producer), and the engine's per-input
//! slot that hands out bands in order with a deadline on every wait.

use super::check::{Expect, Mismatch, Verdict, judge};
use super::metrics::{Held, StageMetrics};
use super::stage_plan::BAND_OVERHEAD;
use bytes::Bytes;
use lightfold_net::{LinkReader, LinkWriter};
use lightfold_protocol::{BandHeader, Frame};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use tokio::sync::{Notify, OwnedSemaphorePermit, Semaphore, mpsc};
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

/// Most producer links parked before any configuration claims them.
const MAX_PARKED: usize = 256;

/// One received band, holding its share of the input's budget until dropped.
#[derive(Debug)]
pub(crate) struct InBand {
    pub header: BandHeader,
    pub payload: Bytes,
    _held: Held,
    _permit: OwnedSemaphorePermit,
}

/// A producer's link. Nothing is sent to a producer, but the writing half stays open while the
/// link is held: dropping it would send a FIN, and a producer watches for end-of-stream to learn
/// that the stage has let its link go (so it dials afresh before its next frame).
#[derive(Debug)]
pub(crate) struct ProducerLink {
    pub reader: LinkReader,
    pub writer: LinkWriter,
}

/// Links accepted from producers, by authenticated daemon id, not yet claimed by an input slot,
/// and the state of each producer's attached link (so a second link claiming a live producer's
/// id is refused instead of displacing it, where the stage can tell the old link is alive).
#[derive(Debug, Default)]
pub(crate) struct Registry {
    parked: Mutex<HashMap<String, ProducerLink>>,
    attached: Mutex<HashMap<String, Arc<LinkState>>>,
    arrived: Notify,
}

/// What became of an offered producer link.
#[derive(Debug, PartialEq, Eq)]
pub(crate) enum Offer {
    Parked,
    /// Too many links are parked.
    Full,
    /// The producer's attached link (from `live`) is alive and streaming.
    Duplicate {
        live: String,
    },
}

/// An attached producer link as its pump sees it.
#[derive(Debug)]
pub(crate) struct LinkState {
    pub addr: String,
    /// The producer's daemon id (the metrics' per-link label).
    pub peer: String,
    /// Cancelled when the pump stops (the link ended or was let go).
    pub ended: CancellationToken,
    last_band: Mutex<Instant>,
    /// Whether the pump is waiting on the socket (it would see the link end at once), rather than
    /// on the stage (backpressure: then an ended link goes unnoticed until the stage catches up).
    reading: std::sync::atomic::AtomicBool,
}

/// A producer that reconnects has closed its old link: its end reaches us this soon.
const RECONNECT_GRACE: std::time::Duration = std::time::Duration::from_millis(500);
/// An attached link that delivered nothing for this long is not defended (it may be half-open:
/// a producer whose host went away without closing its connections). Long enough that a slow
/// frame on a loaded machine does not make a live producer look idle.
const IDLE: std::time::Duration = std::time::Duration::from_secs(10);

impl Registry {
    /// Parks a producer's link, replacing an older parked one from the same daemon (it
    /// reconnected). A link claiming a producer whose attached link is alive and streaming is
    /// refused, unless that link ends within `RECONNECT_GRACE`.
    pub(super) async fn offer(&self, peer: String, link: ProducerLink) -> Offer {
        let live = self
            .attached
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get(&peer)
            .cloned();
        if let Some(old) = live
            && !old.ended.is_cancelled()
        {
            let ended = tokio::time::timeout(RECONNECT_GRACE, old.ended.cancelled()).await;
            let idle = old
                .last_band
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .elapsed()
                >= IDLE;
            // Only a pump that is reading would have seen the old link end: one held back by
            // the stage cannot tell, so the newer link (a producer that reconnected) wins.
            let watching = old.reading.load(std::sync::atomic::Ordering::Acquire);
            if ended.is_err() && !idle && watching {
                return Offer::Duplicate {
                    live: old.addr.clone(),
                };
            }
        }
        {
            let mut parked = self.parked.lock().unwrap_or_else(|e| e.into_inner());
            if parked.len() >= MAX_PARKED && !parked.contains_key(&peer) {
                return Offer::Full;
            }
            parked.insert(peer, link);
        }
        self.arrived.notify_waiters();
        Offer::Parked
    }

    fn take(&self, peer: &str) -> Option<ProducerLink> {
        self.parked
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .remove(peer)
    }

    fn attach(&self, peer: &str, state: Arc<LinkState>) {
        self.attached
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .insert(peer.to_string(), state);
    }
}

/// Why no band could be had from an input.
#[derive(Debug, thiserror::Error)]
pub(crate) enum InputError {
    #[error("input {input} ({peer}) delivered no band within {waited_ms} ms ({link})")]
    Timeout {
        input: usize,
        peer: String,
        waited_ms: u128,
        /// Whether a link from the producer was connected at the deadline.
        link: &'static str,
    },
    #[error("input {input} ({peer}) link failed: {reason}")]
    Link {
        input: usize,
        peer: String,
        reason: String,
    },
    #[error("input {input} ({peer}): {mismatch}")]
    Mismatch {
        input: usize,
        peer: String,
        mismatch: Mismatch,
    },
}

enum Event {
    Band(InBand),
    Failed(String),
}

/// The engine's view of one configured input.
#[derive(Debug)]
pub(crate) struct Slot {
    pub index: usize,
    pub peer: String,
    rx: Option<mpsc::Receiver<Event>>,
    pump: CancellationToken,
    budget: Arc<Semaphore>,
    budget_total: u64,
    peeked: Option<InBand>,
    /// (epoch, frame) of a frame this input sent wrong: the rest of it is dropped.
    poisoned: Option<(u64, u64)>,
}

impl std::fmt::Debug for Event {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Event::Band(b) => write!(f, "Band({:?})", b.header),
            Event::Failed(e) => write!(f, "Failed({e})"),
        }
    }
}

impl Slot {
    pub(super) fn new(index: usize, peer: String, budget: u64) -> Slot {
        Slot {
            index,
            peer,
            rx: None,
            pump: CancellationToken::new(),
            budget: Arc::new(Semaphore::new(budget_permits(budget))),
            budget_total: budget,
            peeked: None,
            poisoned: None,
        }
    }

    /// Keeps this slot (and its link) under a new configuration; the budget only grows, so the
    /// bound is the largest budget configured while the link lives.
    pub(super) fn reconfigure(&mut self, index: usize, budget: u64) {
        self.index = index;
        if budget > self.budget_total {
            self.budget
                .add_permits(budget_permits(budget) - budget_permits(self.budget_total));
            self.budget_total = budget;
        }
    }

    /// The next band of this input that is not stale, judged against `expect`.
    pub(super) async fn next(
        &mut self,
        expect: &Expect,
        ctx: &SlotContext,
        deadline: Instant,
    ) -> Result<InBand, InputError> {
        let start = Instant::now();
        loop {
            let band = match self.peeked.take() {
                Some(b) => b,
                None => self.recv(ctx, deadline, start).await?,
            };
            let h = &band.header;
            if self.poisoned == Some((h.epoch, h.frame)) {
                ctx.metrics.stale_band();
                continue;
            }
            match judge(h, expect) {
                Verdict::Accept => return Ok(band),
                Verdict::Stale => {
                    tracing::debug!(
                        input = self.index,
                        epoch = h.epoch,
                        frame = h.frame,
                        "dropped stale band"
                    );
                    ctx.metrics.stale_band();
                }
                Verdict::Ahead(mismatch) => {
                    self.peeked = Some(band);
                    return Err(self.mismatch(mismatch));
                }
                Verdict::Reject(mismatch) => {
                    self.poisoned = Some((h.epoch, h.frame));
                    return Err(self.mismatch(mismatch));
                }
            }
        }
    }

    fn mismatch(&self, mismatch: Mismatch) -> InputError {
        InputError::Mismatch {
            input: self.index,
            peer: self.peer.clone(),
            mismatch,
        }
    }

    async fn recv(
        &mut self,
        ctx: &SlotContext,
        deadline: Instant,
        start: Instant,
    ) -> Result<InBand, InputError> {
        loop {
            let arrived = ctx.registry.arrived.notified();
            tokio::pin!(arrived);
            arrived.as_mut().enable();
            // A link parked under our peer id is newer than the one we hold: the producer
            // reconnected, so the old link is dead or abandoned.
            if let Some(link) = ctx.registry.take(&self.peer) {
                self.attach(link, ctx);
            }
            let link = if self.rx.is_some() {
                "its link is connected"
            } else {
                "no link from it is connected"
            };
            // Built when the deadline fires, so it reports the whole wait.
            let timed_out = |index: usize, peer: &str| InputError::Timeout {
                input: index,
                peer: peer.to_string(),
                waited_ms: start.elapsed().as_millis(),
                link,
            };
            let Some(rx) = self.rx.as_mut() else {
                tokio::select! {
                    _ = &mut arrived => continue,
                    _ = tokio::time::sleep_until(deadline) => return Err(timed_out(self.index, &self.peer)),
                }
            };
            tokio::select! {
                event = rx.recv() => match event {
                    Some(Event::Band(b)) => return Ok(b),
                    Some(Event::Failed(reason)) => {
                        self.rx = None;
                        return Err(InputError::Link { input: self.index, peer: self.peer.clone(), reason });
                    }
                    None => self.rx = None,
                },
                _ = &mut arrived => continue,
                _ = tokio::time::sleep_until(deadline) => return Err(timed_out(self.index, &self.peer)),
            }
        }
    }

    /// Starts reading `link` into this slot's queue (replacing any previous link).
    fn attach(&mut self, link: ProducerLink, ctx: &SlotContext) {
        self.pump.cancel();
        self.pump = ctx.shutdown.child_token();
        self.peeked = None;
        // Capacity in bands is a second bound next to the byte budget; bands cost at least
        // BAND_OVERHEAD, so the budget admits at most this many.
        let capacity = (self.budget_total / BAND_OVERHEAD).clamp(1, 1 << 16) as usize;
        let (tx, rx) = mpsc::channel(capacity);
        self.rx = Some(rx);
        tracing::info!(input = self.index, peer = %self.peer, addr = %link.reader.addr, "input link attached");
        let state = Arc::new(LinkState {
            addr: link.reader.addr.clone(),
            peer: self.peer.clone(),
            ended: CancellationToken::new(),
            last_band: Mutex::new(Instant::now()),
            reading: std::sync::atomic::AtomicBool::new(false),
        });
        ctx.registry.attach(&self.peer, Arc::clone(&state));
        ctx.tracker.spawn(pump(
            link,
            tx,
            Arc::clone(&self.budget),
            self.budget_total,
            Arc::clone(&ctx.metrics),
            self.pump.clone(),
            state,
        ));
    }
}

impl Drop for Slot {
    fn drop(&mut self) {
        self.pump.cancel();
    }
}

/// What every slot needs from the stage.
#[derive(Debug, Clone)]
pub(crate) struct SlotContext {
    pub registry: Arc<Registry>,
    pub metrics: Arc<StageMetrics>,
    pub tracker: TaskTracker,
    pub shutdown: CancellationToken,
}

fn budget_permits(bytes: u64) -> usize {
    usize::try_from(bytes)
        .unwrap_or(usize::MAX)
        .min(Semaphore::MAX_PERMITS)
}

/// Reads bands from one producer link into the slot's queue. Waiting for budget stops the reads,
/// which is what makes TCP push back on the producer.
async fn pump(
    link: ProducerLink,
    tx: mpsc::Sender<Event>,
    budget: Arc<Semaphore>,
    total: u64,
    metrics: Arc<StageMetrics>,
    cancel: CancellationToken,
    state: Arc<LinkState>,
) {
    // Whatever ends the pump, the link counts as ended from then on.
    let _ended = state.ended.clone().drop_guard();
    // `_writer` lives until the pump ends, then the whole connection closes.
    let ProducerLink {
        reader: mut link,
        writer: _writer,
    } = link;
    loop {
        state
            .reading
            .store(true, std::sync::atomic::Ordering::Release);
        let frame = tokio::select! {
            _ = cancel.cancelled() => return,
            f = link.next() => f,
        };
        state
            .reading
            .store(false, std::sync::atomic::Ordering::Release);
        let (header, payload) = match frame {
            None => return,
            Some(Err(e)) => {
                let _ = tx.send(Event::Failed(e.to_string())).await;
                return;
            }
            Some(Ok(Frame::Band(h, p))) => {
                *state.last_band.lock().unwrap_or_else(|e| e.into_inner()) = Instant::now();
                (h, p)
            }
            Some(Ok(Frame::Control(m))) => {
                tracing::debug!(addr = %link.addr, ?m, "ignored control message on a data link");
                continue;
            }
            Some(Ok(other)) => {
                let what = format!("unexpected {} after the handshake", frame_kind(&other));
                let _ = tx.send(Event::Failed(what)).await;
                return;
            }
        };
        let cost = payload.len() as u64 + BAND_OVERHEAD;
        let permits = u32::try_from(cost.min(total).max(1)).unwrap_or(u32::MAX);
        let permit = tokio::select! {
            _ = cancel.cancelled() => return,
            p = Arc::clone(&budget).acquire_many_owned(permits) => match p {
                Ok(p) => p,
                Err(_) => return,
            },
        };
        lightfold_telemetry::record::bytes_in("bands", payload.len() as u64);
        lightfold_telemetry::record::link_bytes_in(&state.peer, payload.len() as u64);
        let band = InBand {
            header,
            _held: metrics.hold(payload.len() as u64),
            payload,
            _permit: permit,
        };
        tokio::select! {
            _ = cancel.cancelled() => return,
            r = tx.send(Event::Band(band)) => if r.is_err() { return },
        }
    }
}

fn frame_kind(f: &Frame) -> &'static str {
    match f {
        Frame::Hello(_) => "hello",
        Frame::Proof(_) => "proof",
        Frame::Control(_) => "control message",
        Frame::Band(..) => "band",
    }
}
