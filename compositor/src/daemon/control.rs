//! The coordinator's control link: `Register` first, then the first message decides who holds
//! the stage (`claim.rs`: a `Claim` is answered `Claimed` or refused `Busy`; anything else makes
//! the link unclaimed), then configurations (checked here, applied by the engine in order),
//! per-frame requests, pings and shutdown. One coordinator at a time (the control queue has one
//! reader): a claimed session holds the stage until its link closes or another session takes it
//! over; while none does, a new unclaimed link replaces the old. A coordinator that goes away
//! leaves the stage running.

use super::engine::{Command, FrameRequest};
use super::stage_plan::{Operators, StagePlan};
use lightfold_net::claim::{Claims, FAREWELL, Ticket};
use lightfold_net::{Link, LinkReader, LinkWriter, NetError};
use lightfold_protocol::{Capabilities, ErrorCode, Frame, Message, PixelFormat, Role};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::{mpsc, watch};
use tokio_util::sync::CancellationToken;

/// Messages waiting for a coordinator. Full means nobody is listening: later ones are dropped.
const CONTROL_QUEUE: usize = 1024;

/// The sending side of the control link, usable from any task without ever blocking.
#[derive(Debug, Clone)]
pub(crate) struct ControlOut {
    tx: mpsc::Sender<Message>,
}

impl ControlOut {
    pub(super) fn send(&self, msg: Message) {
        if let Err(e) = self.tx.try_send(msg) {
            tracing::warn!("control message dropped (no coordinator reading): {e}");
        }
    }

    /// An error about the link itself (a message the stage does not take).
    pub(super) fn error(&self, code: ErrorCode, message: String) {
        tracing::warn!(?code, "{message}");
        self.send(Message::error(code, message));
    }

    /// An error about the configuration of `epoch`.
    pub(super) fn epoch_error(&self, epoch: u64, code: ErrorCode, message: String) {
        tracing::warn!(?code, epoch, "{message}");
        self.send(Message::epoch_error(epoch, code, message));
    }

    /// An error about `frame` of `epoch`.
    pub(super) fn frame_error(&self, epoch: u64, frame: u64, code: ErrorCode, message: String) {
        tracing::warn!(?code, epoch, frame, "{message}");
        self.send(Message::frame_error(epoch, frame, code, message));
    }
}

/// The control side of the stage, shared by every coordinator session.
#[derive(Debug)]
pub(crate) struct ControlHub {
    out: ControlOut,
    rx: tokio::sync::Mutex<mpsc::Receiver<Message>>,
    claims: Arc<Claims>,
    commands: mpsc::Sender<Command>,
    generation: watch::Sender<u64>,
    capabilities: Capabilities,
    max_frame: usize,
    /// How long a claimed link may bring nothing before it is released (zero: never).
    silence: Duration,
}

/// A configuration the engine should apply, and the ordinal of that configuration.
#[derive(Debug)]
pub(crate) struct NewConfig {
    pub plan: StagePlan,
    pub ops: Operators,
    pub generation: u64,
}

impl ControlHub {
    pub(super) fn new(
        commands: mpsc::Sender<Command>,
        generation: watch::Sender<u64>,
        daemon_id: &str,
        advertise: &str,
        max_frame: usize,
        silence: Duration,
    ) -> ControlHub {
        let (tx, rx) = mpsc::channel(CONTROL_QUEUE);
        ControlHub {
            out: ControlOut { tx },
            rx: tokio::sync::Mutex::new(rx),
            claims: Claims::new(daemon_id, true),
            commands,
            generation,
            capabilities: Capabilities {
                advertise: advertise.to_string(),
                formats: PixelFormat::ALL.to_vec(),
                threads: std::thread::available_parallelism().map_or(1, |n| n.get() as u32),
                version: env!("CARGO_PKG_VERSION").to_string(),
                ..Capabilities::unmeasured(Role::Compositor, daemon_id)
            },
            max_frame,
            silence,
        }
    }

    pub(super) fn out(&self) -> ControlOut {
        self.out.clone()
    }

    /// Serves one coordinator until it leaves, another takes the stage over (it is told
    /// `TakenOver` first), or the stage shuts down.
    pub(super) async fn session(&self, link: Link, shutdown: &CancellationToken) {
        let coordinator = link.peer.daemon_id.clone();
        let addr = link.addr.clone();
        tracing::info!(%coordinator, %addr, "coordinator connected");
        let (mut reader, mut writer) = link.split();
        if let Err(e) = writer
            .send_msg(Message::Register(self.capabilities.clone()))
            .await
        {
            tracing::warn!(%coordinator, "cannot register: {e}");
            return;
        }
        let first = tokio::select! {
            _ = shutdown.cancelled() => return,
            f = reader.next() => f,
        };
        let first = match first {
            None => {
                tracing::info!(%coordinator, "coordinator disconnected");
                return;
            }
            Some(Err(e)) => {
                tracing::warn!(%coordinator, "control link failed: {e}");
                return;
            }
            Some(Ok(f)) => f,
        };
        let claim = match &first {
            Frame::Control(Message::Claim { session, take_over }) => Some((*session, *take_over)),
            _ => None,
        };
        let ticket = tokio::select! {
            _ = shutdown.cancelled() => return,
            t = self.claims.enter(claim, &addr) => t,
        };
        let ticket = match ticket {
            Ok(t) => t,
            Err(refusal) => {
                let _ = writer.send_msg(refusal).await;
                return;
            }
        };
        // Only a claimed link is released when its coordinator falls silent.
        let silence = claim.map(|_| self.silence);
        let first = match claim {
            Some((session, _)) => Err(session),
            None => Ok(first),
        };
        let farewell = self
            .serve(&mut reader, &mut writer, first, silence, &ticket, shutdown)
            .await;
        if let Some(msg) = farewell {
            let _ = tokio::time::timeout(FAREWELL, writer.send_msg(msg)).await;
        }
        // Close the link before letting go of the claim: whoever displaced it waits for this.
        drop((reader, writer));
        drop(ticket);
    }

    /// Serves a granted link: `first` is its first frame, or the session its `Claim` named
    /// (answered `Claimed` here, once this link has the control queue). Returns what to send
    /// the link last when another one displaced it.
    async fn serve(
        &self,
        reader: &mut LinkReader,
        writer: &mut LinkWriter,
        first: Result<Frame, u64>,
        silence: Option<Duration>,
        ticket: &Ticket,
        shutdown: &CancellationToken,
    ) -> Option<Message> {
        let addr = reader.addr.clone();
        let mut rx = tokio::select! {
            biased;
            _ = shutdown.cancelled() => return None,
            farewell = ticket.revoked() => return farewell,
            rx = self.rx.lock() => rx,
        };
        // What was queued for an earlier coordinator means nothing to this one.
        while rx.try_recv().is_ok() {}
        match first {
            Err(session) => {
                if let Err(e) = writer.send_msg(Message::Claimed { session }).await {
                    tracing::warn!(%addr, "cannot answer the claim: {e}");
                    return None;
                }
            }
            Ok(frame) => {
                if !self.frame(frame, shutdown).await {
                    return None;
                }
            }
        }
        // Registered; ready (`/readyz`) once this link has configured the stage.
        let mut registered = lightfold_telemetry::health::ControlLink::open();
        let write = async {
            while let Some(msg) = rx.recv().await {
                match &msg {
                    Message::FrameDone(stats) => lightfold_telemetry::record::frame_done(stats),
                    Message::Configured { epoch } => {
                        registered.configured();
                        lightfold_telemetry::record::plan_epoch(*epoch);
                    }
                    _ => {}
                }
                if let Err(e) = writer.send_msg(msg).await {
                    tracing::warn!(%addr, "control write failed: {e}");
                    return;
                }
            }
        };
        let read = async {
            loop {
                match reader.next_within(silence).await {
                    None => {
                        tracing::info!(%addr, "coordinator disconnected");
                        return;
                    }
                    Some(Err(NetError::Timeout {
                        what: "silence",
                        after,
                        ..
                    })) => {
                        lightfold_telemetry::health::released_silent_coordinator(&addr, after);
                        return;
                    }
                    Some(Err(e)) => {
                        tracing::warn!(%addr, "control link failed: {e}");
                        return;
                    }
                    Some(Ok(frame)) => {
                        if !self.frame(frame, shutdown).await {
                            return;
                        }
                    }
                }
            }
        };
        tokio::select! {
            _ = shutdown.cancelled() => None,
            farewell = ticket.revoked() => farewell,
            _ = write => None,
            _ = read => None,
        }
    }

    /// Handles one frame from the control link; false ends the session.
    async fn frame(&self, frame: Frame, shutdown: &CancellationToken) -> bool {
        match frame {
            Frame::Control(msg) => self.handle(msg, shutdown).await,
            _ => {
                self.out.error(
                    ErrorCode::BadConfig,
                    "the control link carries control messages only".into(),
                );
                true
            }
        }
    }

    /// Handles one message; false ends the session.
    async fn handle(&self, msg: Message, shutdown: &CancellationToken) -> bool {
        match msg {
            Message::ConfigureCompositor(config) => {
                let epoch = config.epoch;
                match StagePlan::new(config, self.max_frame) {
                    Ok((plan, ops)) => {
                        let mut generation = 0;
                        self.generation.send_modify(|g| {
                            *g += 1;
                            generation = *g;
                        });
                        let cmd = Command::Configure(Box::new(NewConfig {
                            plan,
                            ops,
                            generation,
                        }));
                        // The engine answers `Configured` once it has switched, so a band of
                        // the new epoch can never meet the old configuration.
                        if self.commands.send(cmd).await.is_err() {
                            return false;
                        }
                    }
                    Err(e) => self.out.epoch_error(
                        epoch,
                        e.code(),
                        format!("configuration of epoch {epoch} refused: {e}"),
                    ),
                }
            }
            Message::RenderFrame {
                epoch,
                frame,
                params,
                ..
            } => {
                let req = FrameRequest {
                    epoch,
                    frame,
                    params,
                };
                if let Err(e) = self.commands.try_send(Command::Frame(req)) {
                    let why = match e {
                        mpsc::error::TrySendError::Full(_) => "too many frames are queued",
                        mpsc::error::TrySendError::Closed(_) => "the stage is stopping",
                    };
                    self.out.frame_error(
                        epoch,
                        frame,
                        ErrorCode::Internal,
                        format!("frame {frame} refused: {why}"),
                    );
                }
            }
            Message::Release { epoch } => {
                // Preempts whatever the engine does for an older configuration, as a new one
                // would (`Engine::apply`), then leaves the stage unconfigured.
                let mut generation = 0;
                self.generation.send_modify(|g| {
                    *g += 1;
                    generation = *g;
                });
                let cmd = Command::Release { generation, epoch };
                if self.commands.send(cmd).await.is_err() {
                    return false;
                }
            }
            Message::Ping { seq } => self.out.send(Message::Pong { seq }),
            Message::Shutdown => {
                tracing::info!("shutdown requested by the coordinator");
                shutdown.cancel();
                return false;
            }
            other => {
                let name = message_name(&other);
                self.out.error(
                    ErrorCode::BadConfig,
                    format!("a compositor does not take {name} messages"),
                );
            }
        }
        true
    }
}

/// A message's variant name, for errors (never its payload, which may be a 4 MiB scene chunk).
fn message_name(m: &Message) -> &'static str {
    match m {
        Message::Register(_) => "Register",
        Message::SceneOffer { .. } => "SceneOffer",
        Message::SceneNeed { .. } => "SceneNeed",
        Message::SceneChunk { .. } => "SceneChunk",
        Message::SceneReady { .. } => "SceneReady",
        Message::ConfigureNode(_) => "ConfigureNode",
        Message::ConfigureCompositor(_) => "ConfigureCompositor",
        Message::Configured { .. } => "Configured",
        Message::RenderFrame { .. } => "RenderFrame",
        Message::FrameDone(_) => "FrameDone",
        Message::Error { .. } => "Error",
        Message::Ping { .. } => "Ping",
        Message::Pong { .. } => "Pong",
        Message::Shutdown => "Shutdown",
        Message::Claim { .. } => "Claim",
        Message::Claimed { .. } => "Claimed",
        Message::Release { .. } => "Release",
    }
}
