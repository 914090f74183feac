//! The coordinator's control loop: dial and register daemons, distribute the scene, apply a plan,
//! drive frames and collect the final images. Every wait has a deadline; a daemon that never
//! answers is named (with its address) in the error.

use super::sink::{SinkEvent, SinkFrame, SinkGeometry, run_sink};
use lightfold_net::{Identity, LinkWriter, NetError, Timeouts};
use lightfold_protocol::frame::Frame;
use lightfold_protocol::{
    Capabilities, ErrorCode, FrameParams, FrameStats, Message, Role, WireCamera,
};
use std::collections::{BTreeMap, HashMap};
use std::time::{Duration, Instant};
use tokio::net::TcpListener;
use tokio::sync::{mpsc, watch};
use tokio_util::sync::CancellationToken;

/// Largest scene chunk sent in one message.
pub const SCENE_CHUNK: usize = 4 << 20;

/// Deadlines of the control loop.
#[derive(Debug, Clone, Copy)]
pub struct ControlOptions {
    pub link: Timeouts,
    /// A daemon must register this soon after the handshake.
    pub register: Duration,
    /// Scene transfer and configuration must finish within this.
    pub configure: Duration,
    /// A frame must reach the sink this long after it was requested.
    pub frame: Duration,
    /// Frames requested before the first one is received.
    pub frames_in_flight: usize,
}

impl Default for ControlOptions {
    fn default() -> Self {
        ControlOptions {
            link: Timeouts::default(),
            register: Duration::from_secs(10),
            configure: Duration::from_secs(120),
            frame: Duration::from_secs(120),
            frames_in_flight: 2,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ControlError {
    #[error("daemon at {address}: {source}")]
    Link { address: String, source: NetError },
    #[error("daemon at {address} did not register within {after:?}")]
    NoRegister { address: String, after: Duration },
    #[error(
        "daemon at {address} registered as {got:?}, the cluster file lists it as a {expected:?}"
    )]
    WrongRole {
        address: String,
        expected: Role,
        got: Role,
    },
    #[error("daemon at {address} registered as {got:?}, the cluster file expects id {expected:?}")]
    WrongId {
        address: String,
        expected: String,
        got: String,
    },
    #[error("two daemons registered with the same id {id:?} ({a} and {b})")]
    DuplicateId { id: String, a: String, b: String },
    #[error("daemon {id} ({address}) reported {code:?}: {message}")]
    Remote {
        id: String,
        address: String,
        code: ErrorCode,
        message: String,
    },
    #[error("daemon {id} ({address}) sent {got} while the coordinator waited for {expected}")]
    Unexpected {
        id: String,
        address: String,
        expected: &'static str,
        got: String,
    },
    #[error("timed out after {after:?} waiting for {what} from {pending}")]
    Timeout {
        what: &'static str,
        after: Duration,
        pending: String,
    },
    #[error("the plan names daemon {0:?} which is not connected")]
    UnknownDaemon(String),
    #[error("sink: {0}")]
    Sink(String),
    #[error("cannot bind the sink listener on {addr}: {source}")]
    SinkBind {
        addr: String,
        source: std::io::Error,
    },
}

/// A connected, registered daemon.
#[derive(Debug)]
pub struct Daemon {
    pub address: String,
    pub caps: Capabilities,
    writer: LinkWriter,
}

type Event = (String, Result<Message, NetError>);

/// A live cluster.
#[derive(Debug)]
pub struct Session {
    pub daemons: BTreeMap<String, Daemon>,
    events: mpsc::Receiver<Event>,
    event_tx: mpsc::Sender<Event>,
    sink_events: mpsc::Receiver<SinkEvent>,
    sink_geometry: watch::Sender<SinkGeometry>,
    /// Address the sink compositor must dial.
    pub sink_address: String,
    cancel: CancellationToken,
    pub opts: ControlOptions,
    /// Frame stats and errors that arrived while waiting for something else.
    backlog: Vec<(String, Message)>,
}

/// One daemon to connect to: its address, the role the cluster file gives it, and optionally its id.
#[derive(Debug, Clone)]
pub struct DaemonAddr {
    pub address: String,
    pub role: Role,
    pub id: Option<String>,
}

impl DaemonAddr {
    /// Render nodes then compositors, by address, with no expected ids.
    pub fn list(nodes: &[String], compositors: &[String]) -> Vec<DaemonAddr> {
        let with = |role: Role| {
            move |a: &String| DaemonAddr {
                address: a.clone(),
                role,
                id: None,
            }
        };
        nodes
            .iter()
            .map(with(Role::Node))
            .chain(compositors.iter().map(with(Role::Compositor)))
            .collect()
    }
}

impl Session {
    /// Dials every daemon concurrently, authenticates it and collects its registration; binds the
    /// sink listener.
    pub async fn connect(
        daemons: &[DaemonAddr],
        sink_listener: TcpListener,
        sink_advertise: Option<String>,
        me: Identity,
        opts: ControlOptions,
    ) -> Result<Session, ControlError> {
        let mut joins = Vec::new();
        for d in daemons {
            let (d, me) = (d.clone(), me.clone());
            joins.push(tokio::spawn(async move { register(d, me, opts).await }));
        }
        let (event_tx, events) = mpsc::channel(1024);
        let mut map = BTreeMap::new();
        let mut first_error = None;
        for j in joins {
            match j.await.expect("registration task") {
                Ok((caps, address, link)) => {
                    let id = caps.daemon_id.clone();
                    if let Some(prev) = map.get(&id) {
                        let prev: &Daemon = prev;
                        first_error.get_or_insert(ControlError::DuplicateId {
                            id,
                            a: prev.address.clone(),
                            b: address,
                        });
                        continue;
                    }
                    let (mut reader, writer) = link.split();
                    let tx = event_tx.clone();
                    let rid = id.clone();
                    tokio::spawn(async move {
                        loop {
                            match reader.next().await {
                                None => {
                                    let _ = tx
                                        .send((
                                            rid.clone(),
                                            Err(NetError::Closed {
                                                addr: reader.addr.clone(),
                                            }),
                                        ))
                                        .await;
                                    return;
                                }
                                Some(Ok(Frame::Control(m))) => {
                                    if tx.send((rid.clone(), Ok(m))).await.is_err() {
                                        return;
                                    }
                                }
                                Some(Ok(other)) => {
                                    let e = NetError::Unexpected {
                                        addr: reader.addr.clone(),
                                        expected: "a control message",
                                        got: lightfold_net::describe(&other),
                                    };
                                    let _ = tx.send((rid.clone(), Err(e))).await;
                                    return;
                                }
                                Some(Err(e)) => {
                                    let _ = tx.send((rid.clone(), Err(e))).await;
                                    return;
                                }
                            }
                        }
                    });
                    map.insert(
                        id,
                        Daemon {
                            address,
                            caps,
                            writer,
                        },
                    );
                }
                Err(e) => {
                    first_error.get_or_insert(e);
                }
            }
        }
        if let Some(e) = first_error {
            return Err(e);
        }
        let local = sink_listener
            .local_addr()
            .map_err(|source| ControlError::SinkBind {
                addr: "sink".into(),
                source,
            })?;
        if sink_advertise.is_none() && local.ip().is_unspecified() {
            let remote = map.values().find(|d| !is_loopback(&d.address));
            if let Some(d) = remote {
                tracing::warn!(
                    sink = %local,
                    daemon = %d.address,
                    "the sink listens on a wildcard address and no sink advertise address was \
                     given: compositors on other hosts will dial {local} and fail \
                     (pass --sink-advertise HOST:PORT)"
                );
            }
        }
        let sink_address = sink_advertise.unwrap_or_else(|| local.to_string());
        let (sink_tx, sink_events) = mpsc::channel(16);
        let (sink_geometry, geometry_rx) = watch::channel(SinkGeometry {
            epoch: u64::MAX,
            width: 0,
            height: 0,
            band_height: 1,
        });
        let cancel = CancellationToken::new();
        tokio::spawn(run_sink(
            sink_listener,
            me,
            opts.link,
            geometry_rx,
            sink_tx,
            cancel.clone(),
        ));
        Ok(Session {
            daemons: map,
            events,
            event_tx,
            sink_events,
            sink_geometry,
            sink_address,
            cancel,
            opts,
            backlog: Vec::new(),
        })
    }

    /// Ids of registered daemons of a role, in id order.
    pub fn ids(&self, role: Role) -> Vec<String> {
        self.daemons
            .iter()
            .filter(|(_, d)| d.caps.role == role)
            .map(|(id, _)| id.clone())
            .collect()
    }

    pub async fn send(&mut self, id: &str, msg: Message) -> Result<(), ControlError> {
        let d = self
            .daemons
            .get_mut(id)
            .ok_or_else(|| ControlError::UnknownDaemon(id.to_string()))?;
        d.writer
            .send_msg(msg)
            .await
            .map_err(|source| ControlError::Link {
                address: d.address.clone(),
                source,
            })
    }

    fn address(&self, id: &str) -> String {
        self.daemons
            .get(id)
            .map(|d| d.address.clone())
            .unwrap_or_default()
    }

    /// Waits for the next control message from any daemon, at most until `deadline`.
    async fn next_event(
        &mut self,
        deadline: Instant,
        what: &'static str,
        pending: &dyn Fn() -> String,
    ) -> Result<(String, Message), ControlError> {
        let left = deadline.saturating_duration_since(Instant::now());
        match tokio::time::timeout(left, self.events.recv()).await {
            Err(_) => Err(ControlError::Timeout {
                what,
                after: self.opts.configure.min(left.max(Duration::from_millis(1))),
                pending: pending(),
            }),
            Ok(None) => Err(ControlError::Sink("event channel closed".into())),
            Ok(Some((id, Err(source)))) => Err(ControlError::Link {
                address: self.address(&id),
                source,
            }),
            Ok(Some((id, Ok(Message::Error { code, message })))) => Err(ControlError::Remote {
                address: self.address(&id),
                id,
                code,
                message,
            }),
            Ok(Some((id, Ok(m)))) => Ok((id, m)),
        }
    }

    /// Sends the scene to every node that does not have it cached. `bytes` is the scene's
    /// network encoding and `hash` its content hash.
    pub async fn distribute_scene(
        &mut self,
        nodes: &[String],
        hash: [u8; 32],
        bytes: &[u8],
    ) -> Result<(), ControlError> {
        for id in nodes {
            self.send(
                id,
                Message::SceneOffer {
                    hash,
                    size: bytes.len() as u64,
                },
            )
            .await?;
        }
        let deadline = Instant::now() + self.opts.configure;
        let mut waiting: Vec<String> = nodes.to_vec();
        let mut need_send: Vec<String> = Vec::new();
        let mut answered = 0;
        while answered < nodes.len() {
            let pending = waiting.join(", ");
            let (id, m) = self
                .next_event(deadline, "scene offers to be answered", &|| pending.clone())
                .await?;
            match m {
                Message::SceneNeed { hash: h, need } if h == hash => {
                    answered += 1;
                    if need {
                        need_send.push(id.clone());
                    } else {
                        waiting.retain(|w| *w != id);
                    }
                    if need {
                        // Keep waiting for its SceneReady.
                    }
                }
                other => self.backlog_or_unexpected(id, other, "SceneNeed")?,
            }
        }
        for id in &need_send {
            let chunks = bytes.chunks(SCENE_CHUNK).count().max(1);
            for (i, chunk) in bytes.chunks(SCENE_CHUNK).enumerate() {
                let msg = Message::SceneChunk {
                    hash,
                    offset: (i * SCENE_CHUNK) as u64,
                    data: chunk.to_vec(),
                    last: i + 1 == chunks,
                };
                self.send(id, msg).await?;
            }
            if bytes.is_empty() {
                self.send(
                    id,
                    Message::SceneChunk {
                        hash,
                        offset: 0,
                        data: Vec::new(),
                        last: true,
                    },
                )
                .await?;
            }
        }
        let mut ready = 0;
        while ready < need_send.len() {
            let pending = waiting.join(", ");
            let (id, m) = self
                .next_event(deadline, "scenes to load", &|| pending.clone())
                .await?;
            match m {
                Message::SceneReady { hash: h, .. } if h == hash => {
                    ready += 1;
                    waiting.retain(|w| *w != id);
                }
                other => self.backlog_or_unexpected(id, other, "SceneReady")?,
            }
        }
        Ok(())
    }

    /// Sends configurations (compositors first) and waits for every `Configured { epoch }`.
    pub async fn configure(
        &mut self,
        configs: Vec<(String, Message)>,
        epoch: u64,
        geometry: SinkGeometry,
    ) -> Result<(), ControlError> {
        self.sink_geometry.send_replace(geometry);
        let mut waiting: Vec<String> = Vec::new();
        for (id, msg) in configs {
            self.send(&id, msg).await?;
            waiting.push(id);
        }
        let deadline = Instant::now() + self.opts.configure;
        while !waiting.is_empty() {
            let pending = waiting.join(", ");
            let (id, m) = self
                .next_event(deadline, "configurations to be applied", &|| {
                    pending.clone()
                })
                .await?;
            match m {
                Message::Configured { epoch: e } if e == epoch => waiting.retain(|w| *w != id),
                Message::Configured { .. } => {}
                other => self.backlog_or_unexpected(id, other, "Configured")?,
            }
        }
        Ok(())
    }

    fn backlog_or_unexpected(
        &mut self,
        id: String,
        m: Message,
        expected: &'static str,
    ) -> Result<(), ControlError> {
        match m {
            Message::FrameDone(_) | Message::Pong { .. } => {
                self.backlog.push((id, m));
                Ok(())
            }
            other => Err(ControlError::Unexpected {
                address: self.address(&id),
                id,
                expected,
                got: format!("{other:?}").chars().take(80).collect(),
            }),
        }
    }

    /// Drives `frames`: keeps up to `frames_in_flight` requested ahead of the sink, collects each
    /// final image with every daemon's `FrameDone` for it. `requests` gives, per frame, the
    /// messages to send (compositors first, then nodes).
    pub async fn drive(
        &mut self,
        epoch: u64,
        participants: &Participants,
        frames: &[FrameRequest],
        mut on_frame: impl FnMut(FrameResult),
    ) -> Result<(), ControlError> {
        let all: Vec<String> = participants
            .compositors
            .iter()
            .chain(&participants.nodes)
            .cloned()
            .collect();
        let mut sent_at: HashMap<u64, Instant> = HashMap::new();
        let mut stats: HashMap<u64, Vec<FrameStats>> = HashMap::new();
        let mut images: HashMap<u64, SinkFrame> = HashMap::new();
        for (id, m) in std::mem::take(&mut self.backlog) {
            if let Message::FrameDone(s) = m {
                let _ = id;
                stats.entry(s.frame).or_default().push(s);
            }
        }
        let mut next_send = 0usize;
        let mut done = 0usize;
        let mut requested_seq: Vec<u64> = Vec::new();
        while done < frames.len() {
            while next_send < frames.len() && next_send < done + self.opts.frames_in_flight.max(1) {
                let req = &frames[next_send];
                for id in &all {
                    let params = req.params.get(id).cloned().unwrap_or(FrameParams {
                        colors: Vec::new(),
                        scale: None,
                    });
                    self.send(
                        id,
                        Message::RenderFrame {
                            epoch,
                            frame: req.frame,
                            camera: req.camera,
                            params,
                        },
                    )
                    .await?;
                }
                sent_at.insert(req.frame, Instant::now());
                requested_seq.push(req.frame);
                next_send += 1;
            }
            let current = frames[done].frame;
            let deadline = sent_at[&current] + self.opts.frame;
            let complete = |images: &HashMap<u64, SinkFrame>,
                            stats: &HashMap<u64, Vec<FrameStats>>| {
                images.contains_key(&current)
                    && stats.get(&current).map_or(0, |s| s.len()) >= all.len()
            };
            while !complete(&images, &stats) {
                let left = deadline.saturating_duration_since(Instant::now());
                tokio::select! {
                    ev = self.events.recv() => match ev {
                        None => return Err(ControlError::Sink("event channel closed".into())),
                        Some((id, Err(source))) => return Err(ControlError::Link { address: self.address(&id), source }),
                        Some((id, Ok(Message::Error { code, message }))) => {
                            return Err(ControlError::Remote { address: self.address(&id), id, code, message });
                        }
                        Some((_, Ok(Message::FrameDone(s)))) => stats.entry(s.frame).or_default().push(s),
                        Some((_, Ok(_))) => {}
                    },
                    sink = self.sink_events.recv() => match sink {
                        None => return Err(ControlError::Sink("sink stopped".into())),
                        Some(SinkEvent::Error(e)) => return Err(ControlError::Sink(e)),
                        Some(SinkEvent::Frame(f)) => { if f.epoch == epoch { images.insert(f.frame, f); } }
                    },
                    _ = tokio::time::sleep(left) => {
                        let have: Vec<String> = stats.get(&current).map(|s| s.iter().map(|s| s.daemon_id.clone()).collect()).unwrap_or_default();
                        let mut pending: Vec<String> = all.iter().filter(|p| !have.contains(p)).cloned().collect();
                        if !images.contains_key(&current) { pending.push(format!("the sink (frame {current})")); }
                        return Err(ControlError::Timeout { what: "a frame", after: self.opts.frame, pending: pending.join(", ") });
                    }
                }
            }
            let image = images.remove(&current).expect("complete");
            let s = stats.remove(&current).unwrap_or_default();
            // Frames received after this request was sent measure the pipeline's depth.
            let latency_frames = requested_seq.iter().filter(|&&f| f > current).count() as u32;
            on_frame(FrameResult {
                frame: current,
                requested_at: sent_at[&current],
                received_at: image.received_at,
                latency_frames,
                image: image.image,
                sink_bytes: image.bytes,
                stats: s,
            });
            done += 1;
        }
        Ok(())
    }

    /// Asks every daemon to stop and closes the sink.
    pub async fn shutdown(mut self) {
        let ids: Vec<String> = self.daemons.keys().cloned().collect();
        for id in ids {
            let _ = self.send(&id, Message::Shutdown).await;
        }
        self.cancel.cancel();
        drop(self.event_tx);
    }

    /// Closes links without stopping the daemons (they wait for the next coordinator).
    pub fn detach(self) {
        self.cancel.cancel();
    }
}

/// The daemons a plan uses: frames are requested from these (compositors first).
#[derive(Debug, Clone, Default)]
pub struct Participants {
    pub compositors: Vec<String>,
    pub nodes: Vec<String>,
}

/// What to send for one frame.
#[derive(Debug, Clone)]
pub struct FrameRequest {
    pub frame: u64,
    pub camera: Option<WireCamera>,
    /// Per-daemon frame parameters (compositors: per-input colour overrides).
    pub params: HashMap<String, FrameParams>,
}

/// A finished frame and every daemon's report of it.
#[derive(Debug)]
pub struct FrameResult {
    pub frame: u64,
    pub requested_at: Instant,
    pub received_at: Instant,
    pub latency_frames: u32,
    pub image: lightfold_scene::Image,
    pub sink_bytes: u64,
    pub stats: Vec<FrameStats>,
}

async fn register(
    d: DaemonAddr,
    me: Identity,
    opts: ControlOptions,
) -> Result<(Capabilities, String, lightfold_net::Link), ControlError> {
    // Daemons started by an engine at the same time may not listen yet: retry refused dials.
    let mut link = lightfold_net::dial_retry(&d.address, &me, opts.link, opts.register)
        .await
        .map_err(|source| ControlError::Link {
            address: d.address.clone(),
            source,
        })?;
    let caps = match link.recv_msg(opts.register).await {
        Ok(Message::Register(c)) => c,
        Ok(other) => {
            return Err(ControlError::Unexpected {
                id: link.peer.daemon_id.clone(),
                address: d.address.clone(),
                expected: "Register",
                got: format!("{other:?}").chars().take(80).collect(),
            });
        }
        Err(NetError::Timeout { .. }) => {
            return Err(ControlError::NoRegister {
                address: d.address.clone(),
                after: opts.register,
            });
        }
        Err(source) => {
            return Err(ControlError::Link {
                address: d.address.clone(),
                source,
            });
        }
    };
    if caps.role != d.role || link.peer.role != d.role {
        return Err(ControlError::WrongRole {
            address: d.address,
            expected: d.role,
            got: caps.role,
        });
    }
    if let Some(expected) = &d.id
        && *expected != caps.daemon_id
    {
        return Err(ControlError::WrongId {
            address: d.address,
            expected: expected.clone(),
            got: caps.daemon_id,
        });
    }
    Ok((caps, d.address, link))
}

/// Whether `address` (`host:port`) names this machine's loopback interface.
fn is_loopback(address: &str) -> bool {
    let host = address.rsplit_once(':').map_or(address, |(h, _)| h);
    let host = host.trim_start_matches('[').trim_end_matches(']');
    host == "localhost"
        || host
            .parse::<std::net::IpAddr>()
            .is_ok_and(|ip| ip.is_loopback())
}
