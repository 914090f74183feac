//! A coordinator session: dial, authenticate, register and claim daemons, keep one reader task
//! per control link (its messages, tagged with the link's generation, arrive on one channel), run
//! the sink, and redial lost daemons in the background. The event loop that drives frames over it
//! is `super::live`. Every wait has a deadline; a daemon that never answers is named (with its
//! address) in the error.

use super::sink::{SinkEvent, SinkGeometry, run_sink};
use lightfold_net::{Identity, LinkWriter, NetError, Timeouts};
use lightfold_protocol::frame::Frame;
use lightfold_protocol::{Capabilities, ErrorCode, FrameStats, Message, Role};
use std::collections::{BTreeMap, HashSet};
use std::hash::{BuildHasher, Hasher};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};
use tokio::net::TcpListener;
use tokio::sync::{mpsc, watch};
use tokio_util::sync::CancellationToken;

/// How long `Session::shutdown` waits for its `Shutdown` messages to be written.
const SHUTDOWN_FLUSH: Duration = Duration::from_secs(2);

/// Largest scene chunk sent in one message.
pub const SCENE_CHUNK: usize = 4 << 20;

/// Deadlines of the control loop.
#[derive(Debug, Clone, Copy)]
pub struct ControlOptions {
    pub link: Timeouts,
    /// A daemon must register this soon after the handshake.
    pub register: Duration,
    /// Once a daemon of every listed role has registered, those still registering are waited
    /// for this long after the latest registration, then started without and redialled
    /// (`Session::connect`).
    pub stragglers: Duration,
    /// Scene transfer and configuration must finish within this.
    pub configure: Duration,
    /// A frame must reach the sink this long after it was requested.
    pub frame: Duration,
    /// Frames requested before the first one is received.
    pub frames_in_flight: usize,
    /// Every daemon is pinged this often.
    pub heartbeat: Duration,
    /// A daemon silent for this long (no message, no `Pong`) is lost: stopped, hung or cut off.
    pub heartbeat_timeout: Duration,
    /// A frame not finished after `slow_factor` × the plan's estimate (at least `slow_floor`) is
    /// reported slow, naming the daemons it waits on. Slow is not lost: a daemon that answers its
    /// heartbeats is waited for until `frame`.
    pub slow_factor: f64,
    pub slow_floor: Duration,
    /// Lost daemons are redialled this often (DNS names re-resolved) and folded into the next
    /// plan epoch when they answer; zero disables rejoining.
    pub redial: Duration,
    /// With too few daemons for any plan, wait this long for lost ones to come back.
    pub wait_for_daemons: Duration,
    /// Claim daemons another coordinator session holds (that session is told it was taken over).
    pub take_over: bool,
}

impl Default for ControlOptions {
    fn default() -> Self {
        ControlOptions {
            link: Timeouts::default(),
            register: Duration::from_secs(10),
            stragglers: Duration::from_secs(15),
            configure: Duration::from_secs(120),
            frame: Duration::from_secs(120),
            frames_in_flight: 2,
            heartbeat: Duration::from_millis(250),
            heartbeat_timeout: Duration::from_secs(1),
            slow_factor: 3.0,
            slow_floor: Duration::from_secs(1),
            redial: Duration::from_millis(500),
            wait_for_daemons: Duration::ZERO,
            take_over: false,
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
    #[error(
        "daemon at {address} is held by another coordinator session ({message}); pass --take-over to claim it"
    )]
    Busy { address: String, message: String },
    #[error("daemon {id} ({address}) was taken over by another coordinator: {message}")]
    TakenOver {
        id: String,
        address: String,
        message: String,
    },
    #[error("the cluster cannot go on: {0}")]
    Stuck(String),
    #[error("no daemon could be reached ({count} tried); {address}: {why}")]
    Unreachable {
        count: usize,
        address: String,
        why: String,
    },
    #[error("sink: {0}")]
    Sink(String),
    #[error("cannot bind the sink listener on {addr}: {source}")]
    SinkBind {
        addr: String,
        source: std::io::Error,
    },
}

impl ControlError {
    /// Whether a daemon failed to register for want of an answer (not listening, closed,
    /// silent) rather than by answering wrongly: such a daemon is redialled like a lost one.
    pub fn is_unreachable(&self) -> bool {
        match self {
            ControlError::NoRegister { .. } => true,
            ControlError::Link { source, .. } => {
                matches!(source, NetError::Connect { .. } | NetError::Timeout { .. })
                    || source.is_disconnect()
            }
            _ => false,
        }
    }
}

/// A connected, registered daemon.
#[derive(Debug)]
pub struct Daemon {
    /// The address it was dialled at.
    pub address: String,
    pub caps: Capabilities,
    /// The cluster file's (or caller's) entry, for redialling.
    pub(crate) entry: DaemonAddr,
    /// Which control link of this daemon is current (events of older links are ignored).
    pub(crate) link: u64,
    /// Its writer task's queues (`write_control`): control messages, and scene chunks behind
    /// them. The loop never waits on a daemon's socket.
    out: Queues,
    writer: tokio::task::JoinHandle<()>,
}

/// A message (or the end) of one control link: daemon id, link generation, when the reader task
/// took it off the socket, what arrived.
pub(crate) type Event = (String, u64, Instant, Result<Message, NetError>);

/// The two queues of a daemon's writer task: control messages (bounded at `CONTROL_QUEUE`;
/// `Session::send` never waits) and scene chunks (`Session::send_scene`, written only when no
/// control message waits, so heartbeats and frame requests never queue behind a scene).
#[derive(Debug, Clone)]
struct Queues {
    control: mpsc::Sender<Message>,
    bulk: mpsc::Sender<Message>,
}

/// A registered and claimed daemon (at the start, or answering a redial): ready to be folded
/// into the next plan. Its writer task runs from the claim on, so the daemon hears the
/// coordinator's keepalives while the session waits for the others.
#[derive(Debug)]
pub(crate) struct Joined {
    pub entry: DaemonAddr,
    pub caps: Capabilities,
    reader: lightfold_net::LinkReader,
    out: Queues,
    writer: tokio::task::JoinHandle<()>,
}

/// Messages queued for one daemon's socket. A daemon this far behind is stalled: the loop loses
/// it rather than wait (scene chunks wait for room up to the link's send deadline).
const CONTROL_QUEUE: usize = 64;
/// Scene chunks queued for one daemon's writer task ahead of its socket.
const BULK_QUEUE: usize = 2;
/// The `seq` of the writer tasks' keepalive pings (the loop's heartbeats use 0).
const KEEPALIVE_SEQ: u64 = u64::MAX;

/// A live cluster.
#[derive(Debug)]
pub struct Session {
    /// The daemons connected now (lost ones are removed and redialled).
    pub daemons: BTreeMap<String, Daemon>,
    pub(crate) events: mpsc::Receiver<Event>,
    event_tx: mpsc::Sender<Event>,
    pub(crate) sink_events: mpsc::Receiver<SinkEvent>,
    pub(crate) sink_geometry: watch::Sender<SinkGeometry>,
    pub(crate) joined: mpsc::Receiver<Joined>,
    joined_tx: mpsc::Sender<Joined>,
    /// Address the sink compositor must dial.
    pub sink_address: String,
    /// Daemons that did not answer while the session connected, and why: redialled in the
    /// background like lost ones, and folded in when they answer.
    pub unreachable: Vec<(String, String)>,
    cancel: CancellationToken,
    pub opts: ControlOptions,
    me: Identity,
    /// This coordinator session's identity, random per start (sent in every `Claim`).
    pub id: u64,
    /// Epochs and frame ids of this session start here: milliseconds since the Unix epoch times
    /// 2¹⁶, so they never restart at values an earlier session used.
    pub base: u64,
    epochs: u64,
    links: u64,
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
    /// sink listener. The session starts with the daemons that answered within
    /// `ControlOptions::register`: one that cannot be reached (not listening, closed, silent) is
    /// a loss like any later one — redialled in the background and folded in when it answers
    /// (`unreachable`). A daemon that answers wrongly (another role or id, a duplicate id, held by
    /// another session, a wrong token) fails the connect, as does reaching none.
    pub async fn connect(
        daemons: &[DaemonAddr],
        sink_listener: TcpListener,
        sink_advertise: Option<String>,
        me: Identity,
        opts: ControlOptions,
    ) -> Result<Session, ControlError> {
        let id = session_id();
        let mut joins = tokio::task::JoinSet::new();
        let mut pending: BTreeMap<tokio::task::Id, DaemonAddr> = BTreeMap::new();
        for d in daemons {
            let (entry, me) = (d.clone(), me.clone());
            let task =
                joins.spawn(async move { (entry.clone(), register(entry, me, opts, id).await) });
            pending.insert(task.id(), d.clone());
        }
        let (event_tx, events) = mpsc::channel(1024);
        let (joined_tx, joined) = mpsc::channel(64);
        let local = sink_listener
            .local_addr()
            .map_err(|source| ControlError::SinkBind {
                addr: "sink".into(),
                source,
            })?;
        let sink_address = sink_advertise.clone().unwrap_or_else(|| local.to_string());
        let (sink_tx, sink_events) = mpsc::channel(16);
        let (sink_geometry, geometry_rx) = watch::channel(SinkGeometry {
            epoch: u64::MAX,
            width: 0,
            height: 0,
            band_height: 1,
            supersample: 1,
        });
        let cancel = CancellationToken::new();
        let base = unix_ms() << 16;
        let mut session = Session {
            daemons: BTreeMap::new(),
            events,
            event_tx,
            sink_events,
            sink_geometry,
            joined,
            joined_tx,
            sink_address,
            unreachable: Vec::new(),
            cancel: cancel.clone(),
            opts,
            me: me.clone(),
            id,
            base,
            epochs: 0,
            links: 0,
        };
        // Each daemon is taken in as it registers: its writer task keeps it hearing from this
        // coordinator while the others are waited for.
        let mut first_error = None;
        // Once a daemon of every listed role has registered, the others get `stragglers` more
        // after the latest registration: a daemon killed while the coordinator connects is
        // redialled after that, not waited for until the register deadline (`--connect-timeout`,
        // minutes in `demo`). Until then nothing could be planned, so a slow start (a loaded
        // machine, a node still compiling its shaders) is waited for up to that deadline: a
        // session that started without its only render node would end at once.
        let mut missing_roles: HashSet<Role> = daemons.iter().map(|d| d.role).collect();
        let mut cut_off: Option<tokio::time::Instant> = None;
        loop {
            let next = match cut_off {
                Some(at) => match tokio::time::timeout_at(at, joins.join_next_with_id()).await {
                    Ok(n) => n,
                    Err(_) => break,
                },
                None => joins.join_next_with_id().await,
            };
            let Some(done) = next else { break };
            let done = done.map(|(task, r)| {
                pending.remove(&task);
                r
            });
            match done {
                Ok((_, Ok(r))) => {
                    missing_roles.remove(&r.entry.role);
                    if missing_roles.is_empty() {
                        cut_off = Some(tokio::time::Instant::now() + opts.stragglers);
                    }
                    if let Some(prev) = session.daemons.get(&r.caps.daemon_id) {
                        first_error.get_or_insert(ControlError::DuplicateId {
                            id: r.caps.daemon_id.clone(),
                            a: prev.address.clone(),
                            b: r.entry.address.clone(),
                        });
                        continue;
                    }
                    session.admit(r);
                }
                Ok((d, Err(e))) if e.is_unreachable() => {
                    session.start_without(d, format!("not reached while connecting ({e})"));
                }
                Ok((_, Err(e))) => {
                    first_error.get_or_insert(e);
                }
                Err(e) => {
                    first_error.get_or_insert(ControlError::Sink(format!(
                        "registration task failed: {e}"
                    )));
                }
            }
        }
        joins.abort_all();
        for d in pending.into_values() {
            let why = format!(
                "did not register within {:.0} s of the others",
                opts.stragglers.as_secs_f64()
            );
            session.start_without(d, why);
        }
        if let Some(e) = first_error {
            cancel.cancel();
            return Err(e);
        }
        if session.daemons.is_empty()
            && let Some((address, why)) = session.unreachable.first()
        {
            cancel.cancel();
            return Err(ControlError::Unreachable {
                count: session.unreachable.len(),
                address: address.clone(),
                why: why.clone(),
            });
        }
        if sink_advertise.is_none() && local.ip().is_unspecified() {
            let remote = session
                .daemons
                .values()
                .find(|d| !is_loopback(&d.entry.address));
            if let Some(d) = remote {
                tracing::warn!(
                    sink = %local,
                    daemon = %d.entry.address,
                    "the sink listens on a wildcard address and no sink advertise address was \
                     given: compositors on other hosts will dial {local} and fail \
                     (pass --sink-advertise HOST:PORT)"
                );
            }
        }
        tokio::spawn(run_sink(
            sink_listener,
            me,
            sink_timeouts(opts.link),
            geometry_rx,
            sink_tx,
            cancel,
        ));
        tracing::info!(session = %format!("{id:016x}"), daemons = session.daemons.len(), unreachable = session.unreachable.len(), "coordinator session connected");
        Ok(session)
    }

    /// Reserves the plan epochs of one run over this session (`Live`): the run numbers its
    /// epochs from the returned value + 1, above every epoch this session or an earlier one used,
    /// and never uses more than `count`.
    pub(crate) fn reserve_epochs(&mut self, count: u64) -> u64 {
        let first = self.base + self.epochs;
        self.epochs += count;
        first
    }

    /// Takes a registered daemon into the session: its reader task starts feeding `events`.
    /// Returns its id and the generation of its control link.
    pub(crate) fn admit(&mut self, j: Joined) -> (String, u64) {
        let Joined {
            entry,
            caps,
            reader,
            out,
            writer,
        } = j;
        let id = caps.daemon_id.clone();
        self.links += 1;
        let generation = self.links;
        tokio::spawn(read_control(
            reader,
            id.clone(),
            generation,
            self.event_tx.clone(),
            self.cancel.child_token(),
        ));
        let address = entry.address.clone();
        self.daemons.insert(
            id.clone(),
            Daemon {
                address,
                caps,
                entry,
                link: generation,
                out,
                writer,
            },
        );
        (id, generation)
    }

    /// Drops a daemon's link and, unless rejoining is off, redials it in the background until it
    /// answers (or the session ends); it then arrives on `joined`.
    pub(crate) fn lose(&mut self, id: &str) -> Option<Daemon> {
        let d = self.daemons.remove(id)?;
        let mut entry = d.entry.clone();
        entry.id.get_or_insert_with(|| id.to_string());
        self.redial(entry);
        Some(d)
    }

    /// A daemon of the cluster that did not register while the session connected: listed as
    /// unreachable (`why`) and redialled like a lost one.
    fn start_without(&mut self, d: DaemonAddr, why: String) {
        tracing::warn!(address = %d.address, "{why}: starting without it, redialling");
        self.unreachable.push((d.address.clone(), why));
        self.redial(d);
    }

    /// Redials `entry` in the background until it answers (then it arrives on `joined`) or the
    /// session ends; nothing when rejoining is off.
    fn redial(&self, entry: DaemonAddr) {
        if !self.opts.redial.is_zero() {
            let (me, opts, session, tx, cancel) = (
                self.me.clone(),
                self.opts,
                self.id,
                self.joined_tx.clone(),
                self.cancel.child_token(),
            );
            tokio::spawn(async move {
                loop {
                    let attempt = register(entry.clone(), me.clone(), opts, session);
                    let result = tokio::select! {
                        _ = cancel.cancelled() => return,
                        r = attempt => r,
                    };
                    match result {
                        Ok(j) => {
                            let _ = tx.send(j).await;
                            return;
                        }
                        Err(e) => tracing::debug!(address = %entry.address, "redial: {e}"),
                    }
                    tokio::select! {
                        _ = cancel.cancelled() => return,
                        _ = tokio::time::sleep(opts.redial) => {}
                    }
                }
            });
        }
    }

    /// Ids of registered daemons of a role, in id order.
    pub fn ids(&self, role: Role) -> Vec<String> {
        self.daemons
            .iter()
            .filter(|(_, d)| d.caps.role == role)
            .map(|(id, _)| id.clone())
            .collect()
    }

    /// Queues `msg` for daemon `id`'s writer task: never waits on its socket. A daemon whose
    /// writer has failed (its link is broken) or that is `CONTROL_QUEUE` messages behind
    /// (stalled) is an error, which the loop takes for a loss.
    pub fn send(&mut self, id: &str, msg: Message) -> Result<(), ControlError> {
        let d = self
            .daemons
            .get(id)
            .ok_or_else(|| ControlError::UnknownDaemon(id.to_string()))?;
        d.out.control.try_send(msg).map_err(|e| {
            let why = match e {
                mpsc::error::TrySendError::Full(_) => {
                    format!("{CONTROL_QUEUE} messages to it are still unwritten (stalled)")
                }
                mpsc::error::TrySendError::Closed(_) => "its control link broke".to_string(),
            };
            ControlError::Link {
                address: d.address.clone(),
                source: NetError::Closed {
                    addr: format!("{} ({why})", d.address),
                },
            }
        })
    }

    /// Sends a scene to daemon `id` in chunks of `SCENE_CHUNK`, from a task of its own: the
    /// loop goes on meanwhile. A chunk the writer does not take within the link's send deadline
    /// (the daemon does not read) ends the daemon's control link: the loop hears it as the link's
    /// end and loses the daemon.
    pub(crate) fn send_scene(&self, id: &str, hash: [u8; 32], bytes: std::sync::Arc<Vec<u8>>) {
        let Some(d) = self.daemons.get(id) else {
            return;
        };
        let (bulk, tx, after) = (
            d.out.bulk.clone(),
            self.event_tx.clone(),
            self.opts.link.send,
        );
        let (id, link, addr) = (id.to_string(), d.link, d.address.clone());
        tokio::spawn(async move {
            let total = bytes.len();
            let chunks = total.div_ceil(SCENE_CHUNK).max(1);
            for i in 0..chunks {
                let range = (i * SCENE_CHUNK).min(total)..((i + 1) * SCENE_CHUNK).min(total);
                let msg = Message::SceneChunk {
                    hash,
                    offset: range.start as u64,
                    data: bytes[range].to_vec(),
                    last: i + 1 == chunks,
                };
                let error = match tokio::time::timeout(after, bulk.send(msg)).await {
                    Ok(Ok(())) => continue,
                    Ok(Err(_)) => NetError::Closed { addr },
                    Err(_) => NetError::Timeout {
                        what: "scene send",
                        addr,
                        after,
                    },
                };
                let _ = tx.send((id, link, Instant::now(), Err(error))).await;
                return;
            }
        });
    }

    /// Asks every daemon to stop, waits (briefly) for the writer tasks to deliver it, and closes
    /// the sink.
    pub async fn shutdown(mut self) {
        let ids: Vec<String> = self.daemons.keys().cloned().collect();
        for id in ids {
            let _ = self.send(&id, Message::Shutdown);
        }
        let writers: Vec<_> = std::mem::take(&mut self.daemons)
            .into_values()
            .map(|d| d.writer)
            .collect();
        let _ = tokio::time::timeout(SHUTDOWN_FLUSH, futures::future::join_all(writers)).await;
        self.cancel.cancel();
        drop(self.event_tx);
    }

    /// Closes links without stopping the daemons (they wait for the next coordinator).
    pub fn detach(self) {
        self.cancel.cancel();
    }
}

/// A finished frame and every daemon's report of it.
#[derive(Debug)]
pub struct FrameResult {
    /// The frame's number in the run (1, 2, …, in request order).
    pub frame: u64,
    /// Its id on the wire and the plan epoch that rendered it.
    pub wire_frame: u64,
    pub epoch: u64,
    pub requested_at: Instant,
    pub received_at: Instant,
    pub latency_frames: u32,
    pub image: lightfold_scene::Image,
    pub sink_bytes: u64,
    pub stats: Vec<FrameStats>,
}

pub(crate) async fn register(
    d: DaemonAddr,
    me: Identity,
    opts: ControlOptions,
    session: u64,
) -> Result<Joined, ControlError> {
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
    let link_err = |source| ControlError::Link {
        address: d.address.clone(),
        source,
    };
    link.send_msg(Message::Claim {
        session,
        take_over: opts.take_over,
    })
    .await
    .map_err(link_err)?;
    match link.recv_msg(opts.register).await.map_err(link_err)? {
        Message::Claimed { session: s } if s == session => {}
        Message::Error {
            code: ErrorCode::Busy,
            message,
            ..
        } => {
            return Err(ControlError::Busy {
                address: d.address,
                message,
            });
        }
        other => {
            return Err(ControlError::Unexpected {
                id: caps.daemon_id,
                address: d.address,
                expected: "Claimed",
                got: format!("{other:?}").chars().take(80).collect(),
            });
        }
    }
    let (reader, writer) = link.split();
    let (control, rx) = mpsc::channel(CONTROL_QUEUE);
    let (bulk, bulk_rx) = mpsc::channel(BULK_QUEUE);
    let writer = tokio::spawn(write_control(writer, rx, bulk_rx, opts.heartbeat));
    let out = Queues { control, bulk };
    Ok(Joined {
        entry: d,
        caps,
        reader,
        out,
        writer,
    })
}

/// One daemon's writer task: writes what the session queues, control messages in order and
/// ahead of any scene chunk waiting, and a keepalive `Ping` whenever nothing was written for
/// `keepalive`, so a claimed daemon hears from its coordinator however long the loop is busy
/// elsewhere (daemons release a coordinator that falls silent). Ends when the control queue's
/// sender is dropped (the daemon lost, the session over) or a write fails (the queues then refuse
/// further messages: `Session::send` reports it).
async fn write_control(
    mut writer: LinkWriter,
    mut rx: mpsc::Receiver<Message>,
    mut bulk: mpsc::Receiver<Message>,
    keepalive: Duration,
) {
    let keepalive = keepalive.max(Duration::from_millis(10));
    let mut bulk_open = true;
    loop {
        let msg = tokio::select! {
            biased;
            m = rx.recv() => match m {
                Some(m) => m,
                None => return,
            },
            m = bulk.recv(), if bulk_open => match m {
                Some(m) => m,
                None => {
                    bulk_open = false;
                    continue;
                }
            },
            _ = tokio::time::sleep(keepalive) => Message::Ping { seq: KEEPALIVE_SEQ },
        };
        if let Err(e) = writer.send_msg(msg).await {
            tracing::debug!(addr = %writer.addr, "control write failed: {e}");
            return;
        }
    }
}

/// Forwards one control link's messages to the session until it ends, then says how it ended.
async fn read_control(
    mut reader: lightfold_net::LinkReader,
    id: String,
    generation: u64,
    tx: mpsc::Sender<Event>,
    cancel: CancellationToken,
) {
    loop {
        let next = tokio::select! {
            _ = cancel.cancelled() => return,
            n = reader.next() => n,
        };
        let at = Instant::now();
        let end = match next {
            None => NetError::Closed {
                addr: reader.addr.clone(),
            },
            Some(Ok(Frame::Control(m))) => {
                if tx.send((id.clone(), generation, at, Ok(m))).await.is_err() {
                    return;
                }
                continue;
            }
            Some(Ok(other)) => NetError::Unexpected {
                addr: reader.addr.clone(),
                expected: "a control message",
                got: lightfold_net::describe(&other),
            },
            Some(Err(e)) => e,
        };
        let _ = tx.send((id, generation, at, Err(end))).await;
        return;
    }
}

/// The sink's deadlines: those of the control links, but a peer must finish its handshake as
/// soon as a daemon's listener asks (`Timeouts::default`, 5 s), however long the coordinator
/// waits for daemons to answer its own dials (`--connect-timeout`). Unauthenticated connections
/// then hold the sink's handshake slots for seconds, not minutes, and the sink compositor, whose
/// dials retry a listener that closed at once (`lightfold_net::dial_retry`), gets in.
fn sink_timeouts(link: Timeouts) -> Timeouts {
    Timeouts {
        handshake: link.handshake.min(Timeouts::default().handshake),
        ..link
    }
}

/// A random id for this coordinator session (the standard library's per-process random hash
/// keys, mixed with the clock and the process id).
fn session_id() -> u64 {
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u128(
        SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos()),
    );
    h.write_u32(std::process::id());
    h.finish()
}

fn unix_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
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
