//! The coordinator's control link: `Register` first, then configurations (checked here, applied
//! by the engine in order), per-frame requests, pings and shutdown. One coordinator at a time; a
//! new one replaces the old, and a coordinator that goes away leaves the stage running.

use super::config::{Operators, StagePlan};
use super::engine::{Command, FrameRequest};
use lightfold_net::Link;
use lightfold_protocol::{Capabilities, ErrorCode, Frame, Message, PixelFormat, Role};
use std::sync::Mutex;
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
    pub fn send(&self, msg: Message) {
        if let Err(e) = self.tx.try_send(msg) {
            tracing::warn!("control message dropped (no coordinator reading): {e}");
        }
    }

    pub fn error(&self, code: ErrorCode, message: String) {
        tracing::warn!(?code, "{message}");
        self.send(Message::Error { code, message });
    }
}

/// The control side of the stage, shared by every coordinator session.
#[derive(Debug)]
pub(crate) struct ControlHub {
    out: ControlOut,
    rx: tokio::sync::Mutex<mpsc::Receiver<Message>>,
    session: Mutex<Option<CancellationToken>>,
    commands: mpsc::Sender<Command>,
    generation: watch::Sender<u64>,
    capabilities: Capabilities,
    max_frame: usize,
}

/// A configuration the engine should apply, and the ordinal of that configuration.
#[derive(Debug)]
pub(crate) struct NewConfig {
    pub plan: StagePlan,
    pub ops: Operators,
    pub generation: u64,
}

impl ControlHub {
    pub fn new(
        commands: mpsc::Sender<Command>,
        generation: watch::Sender<u64>,
        daemon_id: &str,
        advertise: &str,
        max_frame: usize,
    ) -> ControlHub {
        let (tx, rx) = mpsc::channel(CONTROL_QUEUE);
        ControlHub {
            out: ControlOut { tx },
            rx: tokio::sync::Mutex::new(rx),
            session: Mutex::new(None),
            commands,
            generation,
            capabilities: Capabilities {
                role: Role::Compositor,
                daemon_id: daemon_id.to_string(),
                advertise: advertise.to_string(),
                adapter: String::new(),
                backend: String::new(),
                max_lights: 0,
                max_texture_size: 0,
                formats: PixelFormat::ALL.to_vec(),
                cost_per_light_us: 0,
                fixed_cost_us: 0,
                threads: std::thread::available_parallelism().map_or(1, |n| n.get() as u32),
                version: env!("CARGO_PKG_VERSION").to_string(),
            },
            max_frame,
        }
    }

    pub fn out(&self) -> ControlOut {
        self.out.clone()
    }

    /// Serves one coordinator until it leaves, a newer one arrives, or the stage shuts down.
    pub async fn session(&self, link: Link, shutdown: &CancellationToken) {
        let token = shutdown.child_token();
        if let Some(old) = self
            .session
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .replace(token.clone())
        {
            tracing::info!("a new coordinator replaces the previous one");
            old.cancel();
        }
        let coordinator = link.peer.daemon_id.clone();
        tracing::info!(%coordinator, addr = %link.addr, "coordinator connected");
        let (mut reader, mut writer) = link.split();
        let mut rx = tokio::select! {
            _ = token.cancelled() => return,
            rx = self.rx.lock() => rx,
        };
        // What was queued for an earlier coordinator means nothing to this one.
        while rx.try_recv().is_ok() {}
        if let Err(e) = writer
            .send_msg(Message::Register(self.capabilities.clone()))
            .await
        {
            tracing::warn!(%coordinator, "cannot register: {e}");
            return;
        }
        let write = async {
            while let Some(msg) = rx.recv().await {
                if let Err(e) = writer.send_msg(msg).await {
                    tracing::warn!(%coordinator, "control write failed: {e}");
                    return;
                }
            }
        };
        let read = async {
            loop {
                match reader.next().await {
                    None => {
                        tracing::info!(%coordinator, "coordinator disconnected");
                        return;
                    }
                    Some(Err(e)) => {
                        tracing::warn!(%coordinator, "control link failed: {e}");
                        return;
                    }
                    Some(Ok(Frame::Control(msg))) => {
                        if !self.handle(msg, shutdown).await {
                            return;
                        }
                    }
                    Some(Ok(_)) => {
                        self.out.error(
                            ErrorCode::BadConfig,
                            "the control link carries control messages only".into(),
                        );
                    }
                }
            }
        };
        tokio::select! {
            _ = token.cancelled() => {}
            _ = write => {}
            _ = read => {}
        }
        token.cancel();
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
                    Err(e) => self.out.error(
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
                    self.out
                        .error(ErrorCode::Internal, format!("frame {frame} refused: {why}"));
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
    }
}
