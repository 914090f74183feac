//! The downstream writer: one task that owns the link to the next stage (or the coordinator's
//! sink), dials it with retry until a deadline, writes bands as the engine produces them and
//! reports `FrameDone` once a frame's last band is on the wire. A slow consumer blocks `send`,
//! which blocks the engine through the bounded queue, which stops the input reads: backpressure
//! end to end. The link is a `lightfold_net::Downstream`: a consumer that lets it go (a re-plan
//! that left this stage out of its inputs for a while) is redialled before the next band instead
//! of failing a frame on a closed connection.
//!
//! The writer follows the engine's newest configuration (`Target`, a watch, so `Engine::apply`
//! never waits for it): when one is applied, whatever the writer was doing for an older one (a
//! dial of a dead downstream, a send to a stalled one) is abandoned at once, that link is closed,
//! the new downstream is dialled, and queued bands and frame ends of older configurations are
//! dropped (the frame is not reported done).

use super::control::ControlOut;
use super::metrics::{Held, StageMetrics};
use bytes::Bytes;
use lightfold_net::{Downstream, Identity, NetError, Timeouts};
use lightfold_protocol::{BandHeader, ErrorCode, Frame, FrameStats, Message};
use lightfold_telemetry::process::peak_rss_bytes;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::{mpsc, watch};
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

/// Bands queued between the engine and the writer: enough to keep the socket busy while the
/// next band is combined, small enough to bound memory.
const OUT_QUEUE: usize = 4;

/// The newest configuration the engine has applied: its ordinal (`NewConfig::generation`) and
/// downstream address, which the writer dials at once so the first frame does not wait.
#[derive(Debug, Clone, Default)]
pub(crate) struct Target {
    pub generation: u64,
    /// The plan epoch of that configuration (what the writer's errors are about).
    pub epoch: u64,
    pub addr: String,
}

/// The engine's side of the writer: the queue of what to write and the newest configuration.
#[derive(Debug)]
pub(crate) struct Feed {
    pub queue: mpsc::Sender<Queued>,
    pub target: watch::Sender<Target>,
}

/// The engine's `Feed` and the writer's ends of it.
pub(crate) fn feed() -> (Feed, mpsc::Receiver<Queued>, watch::Receiver<Target>) {
    let (queue, rx) = mpsc::channel(OUT_QUEUE);
    let (target, target_rx) = watch::channel(Target::default());
    (Feed { queue, target }, rx, target_rx)
}

/// What the engine tells the writer, in order, with the configuration it belongs to.
#[derive(Debug)]
pub(crate) struct Queued {
    pub generation: u64,
    pub item: Out,
}

#[derive(Debug)]
pub(crate) enum Out {
    Band {
        header: BandHeader,
        payload: Bytes,
        held: Held,
    },
    /// The engine finished the frame; `stats` has its side filled in.
    End { stats: FrameStats, started: Instant },
    /// The engine gave up on the frame (already reported); forget it.
    Abort { frame: u64 },
}

/// The writer's settings.
#[derive(Debug, Clone)]
pub(crate) struct WriterSettings {
    pub identity: Identity,
    pub timeouts: Timeouts,
    pub dial_timeout: Duration,
}

struct Writer {
    control: ControlOut,
    metrics: Arc<StageMetrics>,
    link: Downstream,
    /// The configuration the writer serves (`Target::generation`).
    generation: u64,
    /// Its plan epoch.
    epoch: u64,
    /// A dial of the configured downstream has started and nobody has waited for it yet.
    dialling: bool,
    /// Frame whose output failed: its remaining bands are discarded.
    failed: Option<u64>,
    bytes_out: u64,
    send_time: Duration,
}

/// Runs the writer until `shutdown`.
pub(crate) async fn run(
    settings: WriterSettings,
    control: ControlOut,
    metrics: Arc<StageMetrics>,
    mut rx: mpsc::Receiver<Queued>,
    mut target: watch::Receiver<Target>,
    shutdown: CancellationToken,
) {
    let link = Downstream::new(
        settings.identity.clone(),
        settings.timeouts,
        settings.dial_timeout,
    );
    let mut w = Writer {
        control,
        metrics,
        link,
        generation: 0,
        epoch: 0,
        dialling: false,
        failed: None,
        bytes_out: 0,
        send_time: Duration::ZERO,
    };
    loop {
        let queued = tokio::select! {
            biased;
            _ = shutdown.cancelled() => break,
            changed = target.changed() => {
                if changed.is_err() {
                    break;
                }
                let t = target.borrow_and_update().clone();
                w.retarget(t);
                continue;
            }
            dialled = w.link.writer(), if w.dialling => {
                w.dialling = false;
                if let Err(e) = dialled {
                    w.control.epoch_error(
                        w.epoch,
                        ErrorCode::PeerLost,
                        format!("cannot reach downstream: {e}"),
                    );
                }
                continue;
            }
            queued = rx.recv() => match queued {
                Some(q) => q,
                None => break,
            },
        };
        if target.has_changed().unwrap_or(false) {
            let t = target.borrow_and_update().clone();
            w.retarget(t);
        }
        tokio::select! {
            biased;
            _ = shutdown.cancelled() => break,
            changed = target.changed() => {
                if changed.is_err() {
                    break;
                }
                // A newer configuration: give up on this item (and on the link it may have
                // left a partial band on, or was still dialling).
                tracing::info!("downstream write abandoned: reconfigured");
                w.link.close();
                let t = target.borrow_and_update().clone();
                w.retarget(t);
            }
            _ = w.handle(queued) => {}
        }
    }
}

impl Writer {
    /// Follows a newly applied configuration: points the link at its downstream (kept if it is
    /// the same and still up, dialled otherwise) and forgets the older configuration's frame.
    fn retarget(&mut self, t: Target) {
        self.generation = t.generation;
        self.epoch = t.epoch;
        self.failed = None;
        self.bytes_out = 0;
        self.send_time = Duration::ZERO;
        if t.addr.is_empty() {
            self.link.close();
            self.dialling = false;
        } else {
            self.link.set_address(&t.addr);
            self.dialling = true;
        }
    }

    async fn handle(&mut self, queued: Queued) {
        let Queued { generation, item } = queued;
        if generation < self.generation {
            // Of a configuration older than the newest one: its frame was abandoned.
            if let Out::End { stats, .. } = &item {
                tracing::info!(
                    frame = stats.frame,
                    epoch = stats.epoch,
                    "frame abandoned: reconfigured"
                );
            }
            return;
        }
        match item {
            Out::Band {
                header,
                payload,
                held,
            } => {
                if self.failed == Some(header.frame) {
                    return;
                }
                let frame = header.frame;
                let start = Instant::now();
                let len = payload.len() as u64;
                let result = match self.ensure_link().await {
                    Ok(link) => link.send(Frame::Band(header, payload)).await,
                    Err(e) => Err(e),
                };
                drop(held);
                self.send_time += start.elapsed();
                match result {
                    Ok(()) => {
                        self.bytes_out += len + lightfold_protocol::BAND_HEADER_LEN as u64 + 5
                    }
                    Err(e) => self.fail(frame, e),
                }
            }
            Out::End { mut stats, started } => {
                let frame = stats.frame;
                let (bytes_out, send_time) = (self.bytes_out, self.send_time);
                self.bytes_out = 0;
                self.send_time = Duration::ZERO;
                if self.failed.take() == Some(frame) {
                    return;
                }
                stats.bytes_out = bytes_out;
                stats.send_us = send_time.as_micros() as u64;
                stats.total_us = started.elapsed().as_micros() as u64;
                stats.peak_rss_bytes = peak_rss_bytes();
                self.metrics.frame_done();
                tracing::debug!(frame, total_us = stats.total_us, "frame done");
                self.control.send(Message::FrameDone(stats));
            }
            Out::Abort { frame } => {
                self.bytes_out = 0;
                self.send_time = Duration::ZERO;
                if self.failed == Some(frame) {
                    self.failed = None;
                }
            }
        }
    }

    async fn ensure_link(&mut self) -> Result<&mut lightfold_net::LinkWriter, NetError> {
        self.dialling = false;
        if self.link.address().is_empty() {
            return Err(NetError::Closed {
                addr: "(no downstream configured)".into(),
            });
        }
        self.link.writer().await
    }

    fn fail(&mut self, frame: u64, e: NetError) {
        let code = match e {
            NetError::Timeout { .. } => ErrorCode::Timeout,
            _ => ErrorCode::PeerLost,
        };
        self.control.frame_error(
            self.epoch,
            frame,
            code,
            format!("frame {frame}: downstream write failed: {e}"),
        );
        self.metrics.frame_failed();
        self.link.close();
        self.failed = Some(frame);
    }
}
