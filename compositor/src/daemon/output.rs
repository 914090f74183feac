//! The downstream writer: one task that owns the link to the next stage (or the coordinator's
//! sink), dials it with retry until a deadline, writes bands as the engine produces them and
//! reports `FrameDone` once a frame's last band is on the wire. A slow consumer blocks `send`,
//! which blocks the engine through the bounded queue, which stops the input reads: backpressure
//! end to end. The link is a `lightfold_net::Downstream`: a consumer that lets it go (a re-plan
//! that left this stage out of its inputs for a while) is redialled before the next band instead
//! of failing a frame on a closed connection.

use super::control::ControlOut;
use super::metrics::{Held, StageMetrics, peak_rss_bytes};
use bytes::Bytes;
use lightfold_net::{Downstream, Identity, NetError, Timeouts};
use lightfold_protocol::{BandHeader, ErrorCode, Frame, FrameStats, Message};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::mpsc;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

/// Bands queued between the engine and the writer: enough to keep the socket busy while the
/// next band is combined, small enough to bound memory.
pub(crate) const OUT_QUEUE: usize = 4;

/// What the engine tells the writer, in order.
#[derive(Debug)]
pub(crate) enum Out {
    /// A configuration names this downstream; dial it now so the first frame does not wait.
    Connect { addr: String },
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
    mut rx: mpsc::Receiver<Out>,
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
        failed: None,
        bytes_out: 0,
        send_time: Duration::ZERO,
    };
    loop {
        let item = tokio::select! {
            _ = shutdown.cancelled() => break,
            item = rx.recv() => match item {
                Some(item) => item,
                None => break,
            },
        };
        tokio::select! {
            _ = shutdown.cancelled() => break,
            _ = w.handle(item) => {}
        }
    }
}

impl Writer {
    async fn handle(&mut self, item: Out) {
        match item {
            Out::Connect { addr } => {
                self.link.set_address(&addr);
                if let Err(e) = self.link.writer().await {
                    self.control
                        .error(ErrorCode::PeerLost, format!("cannot reach downstream: {e}"));
                }
            }
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
        self.control
            .error(code, format!("frame {frame}: downstream write failed: {e}"));
        self.metrics.frame_failed();
        self.link.close();
        self.failed = Some(frame);
    }
}
