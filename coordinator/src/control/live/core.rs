//! The session core without I/O (in the manner of quinn-proto's `Connection`): the plan, the
//! membership, the frames in flight and the phase of the session, changed only by
//! `Core::handle(input, now)`, which queues `Command`s for the driver (`Live::run`) to carry out.
//! The core owns no socket, task or clock: sends, scene transfers, dropped links and delivered
//! frames are commands; messages, ends of links, sink frames, rejoined daemons, frame requests
//! and the driver's tick are inputs, each with the time it is handled at. Configuring a new
//! epoch is a phase (`Phase::Configuring`), not a nested loop, so frame requests, joins, the
//! stop and heartbeats are handled the same way in every phase, and tests drive the core on
//! virtual time with no cluster (`live/tests.rs`).

use super::epoch::Establishing;
use super::{
    ErrorVerdict, FrameSpec, Incident, IncidentKind, LiveState, LiveStatus, LiveSummary, Refine,
    Refused, STATUS_INCIDENTS, Settings, WARM_UP, WARNING_EVERY, judge_error, ledger,
};
use crate::control::session::{ControlError, ControlOptions, FrameResult};
use crate::control::sink::{SinkEvent, SinkGeometry};
use crate::plan::{ClusterSpec, Plan, PlanOptions};
use crate::run::RunError;
use lightfold_net::NetError;
use lightfold_protocol::{Capabilities, ErrorCode, FrameStats, Message};
use lightfold_scene::Scene;
use lightfold_scene::moves::MeshMove;
use std::collections::{BTreeMap, BTreeSet, HashMap, VecDeque};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::watch;

/// A scene's content hash and encoding, shared by the nodes it is sent to.
pub(in crate::control) type SceneBytes = ([u8; 32], Arc<Vec<u8>>);

/// A daemon of the session as the core knows it.
#[derive(Debug, Clone)]
pub(crate) struct Member {
    /// The address it was dialled at.
    pub address: String,
    pub caps: Capabilities,
    /// The generation of its current control link (inputs of older links are ignored).
    pub link: u64,
    /// When anything last arrived from it.
    pub seen: Instant,
    /// The first heartbeat sent since it last said anything.
    pub ping_pending: Option<Instant>,
    /// The scene it holds, by content hash.
    pub scene: Option<[u8; 32]>,
}

impl Member {
    pub(super) fn new(address: String, caps: Capabilities, link: u64, now: Instant) -> Member {
        Member {
            address,
            caps,
            link,
            seen: now,
            ping_pending: None,
            scene: None,
        }
    }
}

/// What happened, as the driver tells the core.
#[derive(Debug)]
pub(crate) enum Input {
    /// A message, or the end, of daemon `id`'s control link `link`, taken off the socket `at`.
    Daemon {
        id: String,
        link: u64,
        at: Instant,
        msg: Result<Message, NetError>,
    },
    /// A message to daemon `id` could not be queued (its link broke, or it is stalled).
    Unsendable {
        id: String,
        why: String,
    },
    /// A lost or unreached daemon registered again (its link is open as generation `link`);
    /// `dialled` is the address it was dialled at (it is lost under it when it was not reached
    /// at the start).
    Joined {
        id: String,
        dialled: String,
        caps: Capabilities,
        link: u64,
    },
    Sink(SinkEvent),
    /// A frame request, or the end of them.
    Request(FrameSpec),
    RequestsClosed,
    /// The run is to stop (Ctrl-C): see `Live`'s docs.
    Stop,
    /// The driver's regular tick (heartbeats, deadlines, debounces).
    Tick,
}

/// What the core asks the driver to do.
#[derive(Debug)]
pub(crate) enum Command {
    /// Queue a message for a daemon (the driver answers a failure with `Input::Unsendable`).
    Send { to: String, msg: Message },
    /// Send a scene, chunked, without waiting for it.
    SendScene {
        to: String,
        hash: [u8; 32],
        bytes: Arc<Vec<u8>>,
    },
    /// Close the daemon's link and redial it in the background.
    Drop { id: String },
    /// The frame geometry the sink is to expect from now on.
    SinkGeometry(SinkGeometry),
    /// A finished frame, in request order.
    Deliver(FrameResult),
}

/// Where the session is.
#[derive(Debug)]
pub(super) enum Phase {
    /// Rendering under `Core::plan` (or, before the first plan, about to plan).
    Running,
    /// Establishing a new epoch: scene transfers and configurations sent, answers awaited.
    Configuring(Box<Establishing>),
    /// No plan fits the daemons connected: waiting until `deadline` for a lost one to answer.
    Waiting { reason: String, deadline: Instant },
}

/// The session core (see the module docs).
pub(crate) struct Core {
    /// The daemons connected now, by id.
    pub(super) members: BTreeMap<String, Member>,
    pub(super) control: ControlOptions,
    sink_address: String,
    /// Wire frame ids are `base + frame number`; epochs `first_epoch + 1, + 2, …`
    /// (`Session::reserve_epochs`).
    pub(super) base: u64,
    pub(super) first_epoch: u64,
    pub(super) epochs_used: u64,
    pub(super) phase: Phase,
    /// Commands not yet taken by the driver.
    out: VecDeque<Command>,
    /// The scene as the nodes have it (light colours change when a colour change splits a
    /// node's colour group, which re-plans).
    pub(super) scene: Scene,
    /// Each light's colour in the scene as given: what a frame that names no colour for a light
    /// renders it with, whatever the light was recoloured to since.
    pub(super) scene_colors: Vec<[f32; 3]>,
    /// Meshes split into chunks for partitions (`CoreSetup::chunked`).
    pub(super) chunked: bool,
    /// The objects as viewers moved them (`FrameSpec::moves`): `scene` stays as the nodes hold
    /// it, the planner sees it moved (`Core::planned_scene`) and nodes are sent the matrices.
    pub(super) moves: Arc<Vec<MeshMove>>,
    pub(super) opts: PlanOptions,
    /// The scene frames show (`OpenScene::id`; 0: the session's first), and whether the next
    /// plan starts afresh (a scene opened: nothing of the plan before carries over).
    pub(super) scene_id: u64,
    pub(super) fresh_plan: bool,
    /// The refinement the plan renders (`FrameSpec::refine`), above the session's quality.
    pub(super) refine: Option<Refine>,
    /// Lights a viewer moved since the epoch began, where the plan stayed the same but for
    /// them: per node, its lights as moved (`FrameParams::lights`), sent with every frame of
    /// the epoch (`frames.rs`, `light_edit_in_place`).
    pub(super) light_frames: std::collections::HashMap<String, Vec<lightfold_protocol::WireLight>>,
    /// The samples per area light an error target chose in the newest plan without a
    /// refinement: refinements plan no target, and never fewer samples than it chose.
    pub(super) target_samples: Option<u32>,
    pub(super) bytes: Arc<Vec<u8>>,
    pub(super) hash: [u8; 32],
    /// Sort-last partitions: the scene each node needs (`scene::partition::keep_meshes`), by
    /// the meshes it keeps whole; cleared when the scene changes.
    pub(super) subsets: HashMap<Vec<u32>, SceneBytes>,
    pub(super) plan: Option<Plan>,
    /// Cost-model adaptation under a frame budget (`plan::adapt`).
    pub(super) adapt: crate::plan::adapt::Adapt,
    /// The plan's daemons, compositors first.
    pub(super) participants: Vec<String>,
    /// The settings of the newest epoch every daemon took, refusals since, what was refused,
    /// and daemons left out for refusing their part (`Core::absorb_refusal`).
    pub(super) good: Option<Settings>,
    pub(super) refusals: u32,
    pub(super) refused: Refused,
    pub(super) shunned: BTreeSet<String>,
    /// Frame requests sent in the current epoch, and whether one of them set light colours (the
    /// stages keep them: later frames name every colour, `run::frame_params`).
    pub(super) sent_in_epoch: u64,
    pub(super) recoloured: bool,
    /// The frames from request to delivery.
    pub(super) frames: ledger::Ledger,
    pub(super) source_open: bool,
    /// Why the next re-plan is due now: a participant was lost (a failure, counted towards
    /// `MAX_REPLANS_WITHOUT_PROGRESS`).
    pub(super) need_replan: Option<String>,
    /// A daemon joined: re-plan once the frames in flight are done.
    pub(super) pending_join: Option<String>,
    /// The user steered (a colour that splits a node's colour group, a frame budget): re-plan
    /// once the frames in flight, sent under the settings before, are done. Re-planning at once
    /// would put them back to be sent again under the new settings, where their own colours may
    /// split a group again: two frames of different colours would re-plan each other for ever.
    pub(super) pending_steer: Option<String>,
    /// A frame failed: re-request at this time.
    pub(super) reset_at: Option<(Instant, String)>,
    /// Daemons lost since the last look, and why each lost daemon was lost.
    pub(super) just_lost: Vec<String>,
    pub(super) lost: BTreeMap<String, String>,
    pub(super) replans_without_progress: u32,
    /// Since when a re-plan has found no plan for the daemons left.
    pub(super) waited_since: Option<Instant>,
    last_ping: Option<Instant>,
    last_warning: Option<Instant>,
    pub(super) observer: watch::Sender<LiveStatus>,
    notices: u64,
    /// The run was told to stop (`Input::Stop`).
    pub(super) stopping: bool,
    /// A daemon of the plan stopped with the run: the frames in flight cannot finish.
    pub(super) abandon: bool,
    /// The run is over (every request delivered, or stopped).
    pub(super) finished: bool,
    /// Each node's latest `FrameStats::peak` in this epoch: the next `seed64` scale's input.
    pub(super) peaks: HashMap<String, f32>,
    /// The epoch's sort-first tiles and their balancer; `None` without tiles.
    pub(super) tiles: Option<crate::tiles::TileBalancer>,
    pub summary: LiveSummary,
}

impl std::fmt::Debug for Core {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Core")
            .field("epoch", &self.plan.as_ref().map(|p| p.epoch))
            .field("queued", &self.frames.queue.len())
            .field("in_flight", &self.frames.inflight.len())
            .field("delivered", &self.summary.delivered)
            .finish_non_exhaustive()
    }
}

/// What a core starts from.
pub(crate) struct CoreSetup {
    /// The scene as the cluster renders it (partitioned, supersampled: `Live::new`).
    pub scene: Scene,
    /// Whether `scene` has meshes split into chunks for partitions (its meshes are then not
    /// the ones viewers see, and none may be moved).
    pub chunked: bool,
    pub opts: PlanOptions,
    pub control: ControlOptions,
    pub members: BTreeMap<String, Member>,
    /// Daemons not reached while connecting, and why (lost from the start, redialled).
    pub unreachable: Vec<(String, String)>,
    pub sink_address: String,
    pub base: u64,
    pub first_epoch: u64,
}

impl Core {
    /// The scene the planner plans where objects were moved (the nodes' scene with the objects
    /// moved); `None`: the nodes' scene as it is.
    pub(super) fn moved_scene(&self) -> Option<Scene> {
        (!self.moves.iter().all(MeshMove::is_identity)).then(|| self.scene.moved(&self.moves))
    }

    /// Each moved mesh's matrix, as nodes are sent it (`NodeConfig::moves`).
    pub(super) fn wire_moves(&self) -> Vec<lightfold_protocol::WireMove> {
        self.scene
            .move_matrices(&self.moves)
            .into_iter()
            .map(|(mesh, m)| lightfold_protocol::WireMove {
                mesh,
                matrix: m.to_cols_array(),
            })
            .collect()
    }

    /// Why `moves` cannot be the session's, or `Ok`.
    pub(super) fn check_moves(&self, moves: &[MeshMove]) -> Result<(), String> {
        if self.chunked && !moves.is_empty() {
            return Err(
                "the cluster renders this scene's meshes split into chunks for partitions: \
                 its objects cannot be moved"
                    .into(),
            );
        }
        lightfold_scene::moves::check(&self.scene, moves)
    }
}

impl Core {
    pub(super) fn new(setup: CoreSetup) -> Result<Core, RunError> {
        let CoreSetup {
            scene,
            chunked,
            opts,
            control,
            members,
            unreachable,
            sink_address,
            base,
            first_epoch,
        } = setup;
        let bytes = scene
            .to_bytes()
            .map_err(|e| RunError::Scene(e.to_string()))?;
        // Nodes decode what they receive and check it against this.
        let hash = scene.content_hash();
        let scene_colors = scene.lights.iter().map(|l| l.color).collect();
        Ok(Core {
            members,
            scene_colors,
            control,
            sink_address,
            base,
            first_epoch,
            epochs_used: 0,
            phase: Phase::Running,
            out: VecDeque::new(),
            scene,
            chunked,
            moves: Arc::new(Vec::new()),
            opts,
            scene_id: 0,
            fresh_plan: false,
            refine: None,
            light_frames: std::collections::HashMap::new(),
            target_samples: None,
            bytes: Arc::new(bytes),
            hash,
            subsets: HashMap::new(),
            plan: None,
            adapt: Default::default(),
            participants: Vec::new(),
            good: None,
            refusals: 0,
            refused: Refused::default(),
            shunned: BTreeSet::new(),
            sent_in_epoch: 0,
            recoloured: false,
            frames: ledger::Ledger::default(),
            source_open: true,
            need_replan: None,
            pending_join: None,
            pending_steer: None,
            reset_at: None,
            just_lost: Vec::new(),
            lost: unreachable.into_iter().collect(),
            replans_without_progress: 0,
            waited_since: None,
            last_ping: None,
            last_warning: None,
            observer: watch::Sender::new(LiveStatus::default()),
            notices: 0,
            stopping: false,
            abandon: false,
            finished: false,
            peaks: HashMap::new(),
            tiles: None,
            summary: LiveSummary::default(),
        })
    }

    /// Plans and configures the first epoch (`Phase::Configuring`).
    pub(super) fn start(&mut self, now: Instant) -> Result<(), RunError> {
        self.replan("start".to_string(), true, now)?;
        self.settle(now)
    }

    /// Takes one input at `now`. An error ends the run (`summary` says what happened).
    pub(super) fn handle(&mut self, input: Input, now: Instant) -> Result<(), RunError> {
        match input {
            Input::Daemon { id, link, at, msg } => {
                if let Some((id, m)) = self.accept(id, link, at, msg)? {
                    if matches!(self.phase, Phase::Configuring(_)) {
                        self.configuring_message(&id, m, now)?;
                    } else {
                        self.on_run_message(&id, m, now);
                    }
                }
            }
            Input::Unsendable { id, why } => {
                self.lose(&id, format!("cannot send to it: {why}"), now);
            }
            Input::Joined {
                id,
                dialled,
                caps,
                link,
            } => {
                self.on_join(id, dialled, caps, link, now);
                if let Phase::Waiting { reason, .. } = &self.phase {
                    let reason = format!("{reason}; then a daemon rejoined");
                    self.pending_join = None;
                    self.plan_next(reason, now)?;
                }
            }
            Input::Sink(ev) => self.on_sink(ev, now),
            Input::Request(spec) => self.frames.request(spec),
            Input::RequestsClosed => self.source_open = false,
            Input::Stop => {
                self.stopping = true;
                if !matches!(self.phase, Phase::Running) {
                    // Told to stop while configuring or waiting for daemons: the frames of the
                    // old epoch were put back, so what is not delivered is abandoned.
                    self.abandon = true;
                    self.phase = Phase::Running;
                }
            }
            Input::Tick => self.on_tick(now)?,
        }
        self.settle(now)
    }

    /// The next command for the driver.
    pub(super) fn poll_command(&mut self) -> Option<Command> {
        self.out.pop_front()
    }

    /// Whether the run is over (nothing more will be requested or delivered).
    pub(super) fn finished(&self) -> bool {
        self.finished
    }

    /// Whether the core takes frame requests now (the lookahead is not full).
    pub(super) fn wants_requests(&self) -> bool {
        self.source_open && self.frames.queue.len() < self.control.frames_in_flight.max(1)
    }

    /// The plan in use.
    pub(super) fn plan(&self) -> Option<&Plan> {
        self.plan.as_ref()
    }

    /// The antialiasing factor frames are rendered at: the session's, or its refinement's.
    pub(super) fn supersample(&self) -> u32 {
        let session = self.opts.supersample.max(1);
        self.refine.map_or(session, |r| r.supersample.max(session))
    }

    /// A watcher of the state (plan, epochs, incidents, lost daemons, notices).
    pub(super) fn observe(&self) -> watch::Receiver<LiveStatus> {
        self.observer.subscribe()
    }

    pub(super) fn command(&mut self, c: Command) {
        self.out.push_back(c);
    }

    pub(super) fn send(&mut self, to: &str, msg: Message) {
        self.command(Command::Send {
            to: to.to_string(),
            msg,
        });
    }

    /// The cluster as the planner sees it: the daemons connected now.
    pub(super) fn cluster(&self) -> ClusterSpec {
        crate::run::cluster_of(
            self.members
                .iter()
                .map(|(id, m)| (id.as_str(), m.address.as_str(), &m.caps)),
            &self.sink_address,
        )
    }

    pub(super) fn address(&self, id: &str) -> String {
        self.members
            .get(id)
            .map(|m| m.address.clone())
            .unwrap_or_default()
    }

    /// Moves the session on after an input: delivers, re-plans when one is due, issues frames,
    /// and ends the run when every request is delivered.
    fn settle(&mut self, now: Instant) -> Result<(), RunError> {
        while !self.finished {
            match self.phase {
                Phase::Configuring(_) => {
                    if self.advance(now)? {
                        continue;
                    }
                    break;
                }
                Phase::Waiting { .. } => break,
                Phase::Running => {}
            }
            self.collect();
            self.deliver();
            if self.abandon {
                self.abandon_frames();
                self.finished = true;
                break;
            }
            if self.plan.is_none() {
                break; // before `start`
            }
            if let Some((reason, failure)) = self.due_replan(now) {
                self.replan(reason, failure, now)?;
                continue;
            }
            self.issue(now)?;
            if !self.source_open && self.frames.idle() {
                self.deliver();
                self.finished = true;
            }
            break;
        }
        Ok(())
    }

    /// Publishes the state to watchers.
    pub(super) fn publish(&self) {
        let state = if !matches!(self.phase, Phase::Running)
            || self.need_replan.is_some()
            || self.pending_steer.is_some()
        {
            LiveState::Replanning
        } else if self.plan.is_none() {
            LiveState::Starting
        } else if self.lost.is_empty() {
            LiveState::Running
        } else {
            LiveState::Degraded
        };
        let skip = self
            .summary
            .incidents
            .len()
            .saturating_sub(STATUS_INCIDENTS);
        let plan = self.plan.clone().map(Arc::new);
        self.observer.send_modify(|s| {
            s.state = state;
            if plan.as_ref().map(|p| p.epoch) != s.plan.as_ref().map(|p| p.epoch) {
                s.plan = plan;
            }
            s.epochs.clone_from(&self.summary.epochs);
            s.incidents = self.summary.incidents[skip..].to_vec();
            s.lost = self
                .lost
                .iter()
                .map(|(a, b)| (a.clone(), b.clone()))
                .collect();
            s.scene = self.scene_id;
        });
    }

    /// Tells watchers something the user should see (and logs it).
    pub(super) fn notice(&mut self, text: String) {
        tracing::info!("{text}");
        self.notices += 1;
        let n = self.notices;
        self.observer.send_modify(|s| s.notice = Some((n, text)));
    }

    /// Gives up the frames not yet finished (daemons stopped with the run).
    fn abandon_frames(&mut self) {
        let left = self.frames.abandon();
        self.summary.abandoned += left as u64;
        if left > 0 {
            tracing::info!(
                frames = left,
                stopped = %self.summary.stopped.join(", "),
                "stopping: frames not finished are abandoned (daemons stopped with the run)"
            );
        }
        self.source_open = false;
    }

    /// Takes one daemon input: liveness bookkeeping, losses, take-overs. Returns the message for
    /// the phase, if any.
    fn accept(
        &mut self,
        id: String,
        link: u64,
        at: Instant,
        result: Result<Message, NetError>,
    ) -> Result<Option<(String, Message)>, RunError> {
        let Some(m) = self.members.get_mut(&id) else {
            return Ok(None); // a daemon already lost
        };
        if m.link != link {
            return Ok(None); // an older link of a daemon that rejoined
        }
        m.seen = m.seen.max(at);
        match result {
            Err(e) => {
                self.lose(&id, format!("its control link ended: {e}"), at);
                Ok(None)
            }
            Ok(Message::Pong { .. }) => Ok(None),
            Ok(Message::Error {
                code: ErrorCode::TakenOver,
                message,
                ..
            }) => Err(ControlError::TakenOver {
                address: self.address(&id),
                id,
                message,
            }
            .into()),
            Ok(m) => Ok(Some((id, m))),
        }
    }

    fn on_run_message(&mut self, id: &str, m: Message, now: Instant) {
        let epoch = self.plan.as_ref().map(|p| p.epoch);
        match m {
            Message::FrameDone(s) if Some(s.epoch) == epoch => self.frame_done(s),
            Message::FrameDone(_) => {} // of an older epoch
            Message::Error {
                code,
                message,
                epoch: about,
                frame,
            } => self.daemon_error(id, code, &message, about, frame, now),
            other => tracing::debug!(daemon = %id, "ignored {other:?}"),
        }
    }

    fn frame_done(&mut self, s: FrameStats) {
        if s.peak.is_finite() && s.peak > 0.0 {
            self.peaks.insert(s.daemon_id.clone(), s.peak);
        }
        let Some(f) = self.frames.inflight.iter_mut().find(|f| f.wire == s.frame) else {
            return;
        };
        if f.stats.iter().any(|x| x.daemon_id == s.daemon_id) {
            return;
        }
        if let Some(b) = &mut self.tiles {
            // What a tile's rows cost its node: the passes and copies that grow with them.
            let cost = s.eye_us + s.readback_us + s.pack_us;
            if b.reported(s.frame, &s.daemon_id, cost as f64) {
                self.summary.tile_rows = b.rows().to_vec();
                self.summary.tile_steps += 1;
            }
        }
        if s.saturated > 0 {
            if self.summary.saturated == 0 {
                tracing::warn!(
                    daemon = %s.daemon_id,
                    frame = f.index,
                    saturated = s.saturated,
                    "values above the link format's range were clamped (counted in the frame \
                     stats and the run summary)"
                );
            }
            if !f.stats.iter().any(|x| x.saturated > 0) {
                self.summary.saturated_frames += 1;
            }
            self.summary.saturated += s.saturated;
        }
        f.stats.push(s);
    }

    /// A daemon's error while frames run. Errors name the epoch (and frame) they are about: one
    /// of an epoch the loop has left, or of a frame no longer in flight, is history and changes
    /// nothing; errors about the link alone (no epoch) are logged.
    fn daemon_error(
        &mut self,
        id: &str,
        code: ErrorCode,
        message: &str,
        about: Option<u64>,
        frame: Option<u64>,
        now: Instant,
    ) {
        let current = self.plan.as_ref().map(|p| p.epoch);
        let inflight: Vec<u64> = self.frames.inflight.iter().map(|f| f.wire).collect();
        let verdict = judge_error(current, &inflight, code, about, frame);
        if verdict == ErrorVerdict::History {
            tracing::info!(daemon = %id, ?code, epoch = ?about, frame = ?frame, "{message} (of an epoch or frame no longer run: ignored)");
            return;
        }
        tracing::warn!(daemon = %id, ?code, "{message}");
        if verdict == ErrorVerdict::FramesFail && self.reset_at.is_none() {
            self.reset_at = Some((
                now + super::RESET_DEBOUNCE,
                format!("{id} reported {code:?}: {message}"),
            ));
        }
    }

    fn on_sink(&mut self, ev: SinkEvent, now: Instant) {
        let epoch = self.plan.as_ref().map(|p| p.epoch);
        let running = matches!(self.phase, Phase::Running);
        match ev {
            SinkEvent::Frame(f) if Some(f.epoch) == epoch && running => {
                if let Some(x) = self.frames.inflight.iter_mut().find(|x| x.wire == f.frame) {
                    x.image = Some(f);
                }
            }
            SinkEvent::Frame(_) => {}
            SinkEvent::Failed { frame, reason } => {
                tracing::warn!(frame, "{reason}");
                if self.frames.inflight.iter().any(|f| f.wire == frame) && self.reset_at.is_none() {
                    self.reset_at = Some((now + super::RESET_DEBOUNCE, reason));
                }
            }
            SinkEvent::Warning(w) => self.warn_rate_limited(&w, now),
        }
    }

    fn warn_rate_limited(&mut self, w: &str, now: Instant) {
        if self
            .last_warning
            .is_none_or(|t| now.duration_since(t) >= WARNING_EVERY)
        {
            self.last_warning = Some(now);
            tracing::warn!("{w}");
        } else {
            tracing::debug!("{w}");
        }
    }

    fn on_join(
        &mut self,
        id: String,
        dialled: String,
        caps: Capabilities,
        link: u64,
        now: Instant,
    ) {
        tracing::info!(daemon = %id, address = %dialled, "rejoined");
        lightfold_telemetry::record::daemon_rejoined();
        // Lost under its id, or under its address when it was not reached at the start.
        self.lost.remove(&dialled);
        self.lost.remove(&id);
        self.members
            .insert(id.clone(), Member::new(dialled, caps, link, now));
        self.summary.incidents.push(Incident {
            daemon: id.clone(),
            kind: IncidentKind::Rejoined,
            at: now,
        });
        if self.shunned.remove(&id) {
            // It refused its part: it takes part again when something else re-plans.
            tracing::info!(daemon = %id, "rejoined after refusing its configuration: folded in at the next re-plan");
        } else {
            self.pending_join.get_or_insert(format!("{id} rejoined"));
        }
        self.publish();
    }

    /// Drops a daemon; a re-plan is due if the plan used it. Once the run is stopping, the daemon
    /// is taken to be stopping too: no incident, no re-plan, and the frames that need it are
    /// abandoned.
    pub(super) fn lose(&mut self, id: &str, reason: String, now: Instant) {
        let Some(m) = self.members.remove(id) else {
            return;
        };
        self.command(Command::Drop { id: id.to_string() });
        let used = self.participants.iter().any(|p| p == id);
        if self.stopping {
            tracing::info!(daemon = %id, address = %m.address, "stopped with the run ({reason})");
            self.summary.stopped.push(id.to_string());
            self.abandon |= used;
            return;
        }
        tracing::warn!(daemon = %id, address = %m.address, in_plan = used, "lost: {reason}");
        lightfold_telemetry::record::daemon_lost();
        self.summary.incidents.push(Incident {
            daemon: id.to_string(),
            kind: IncidentKind::Lost {
                reason: reason.clone(),
            },
            at: now,
        });
        self.lost.insert(id.to_string(), reason.clone());
        self.just_lost.push(id.to_string());
        if used {
            self.need_replan
                .get_or_insert(format!("{id} lost: {reason}"));
        }
        self.publish();
    }

    /// Sends heartbeats and judges silence; a heartbeat counts as unanswered only from when it
    /// was sent, and the driver hands the core every message already read before a tick, so a
    /// busy loop never mistakes its own delay for a daemon's silence.
    fn heartbeat(&mut self, now: Instant) {
        let opts = self.control;
        let mut silent = Vec::new();
        for (id, m) in &mut self.members {
            if let Some(t) = m.ping_pending
                && m.seen >= t
            {
                m.ping_pending = None;
            }
            if let Some(t) = m.ping_pending
                && now.saturating_duration_since(t) > opts.heartbeat_timeout
            {
                silent.push((id.clone(), now.saturating_duration_since(t)));
            }
        }
        for (id, waited) in silent {
            self.lose(
                &id,
                format!(
                    "no answer to heartbeats for {} ms (stopped, hung or cut off)",
                    waited.as_millis()
                ),
                now,
            );
        }
        if self
            .last_ping
            .is_some_and(|t| now.saturating_duration_since(t) < opts.heartbeat)
        {
            return;
        }
        self.last_ping = Some(now);
        let ids: Vec<String> = self.members.keys().cloned().collect();
        for id in ids {
            self.send(&id, Message::Ping { seq: 0 });
            if let Some(m) = self.members.get_mut(&id) {
                m.ping_pending.get_or_insert(now);
            }
        }
    }

    fn on_tick(&mut self, now: Instant) -> Result<(), RunError> {
        self.heartbeat(now);
        match &self.phase {
            Phase::Running => self.frame_deadlines(now),
            Phase::Configuring(_) => self.configuring_tick(now)?,
            Phase::Waiting { deadline, .. } => {
                if now >= *deadline {
                    return Err(RunError::TooFewDaemons {
                        error: crate::plan::PlanError::NoNodes,
                        lost: self.lost_list(),
                    });
                }
            }
        }
        Ok(())
    }

    /// Frames past the slow threshold are reported, frames past `ControlOptions::frame` lose the
    /// daemons they wait on.
    fn frame_deadlines(&mut self, now: Instant) {
        let Some(plan) = &self.plan else {
            return;
        };
        let opts = self.control;
        let predicted = Duration::from_micros(plan.est_frame_us);
        let slow = predicted.mul_f64(opts.slow_factor).max(opts.slow_floor);
        let mut slow_frames = Vec::new();
        let mut hung = Vec::new();
        for f in &mut self.frames.inflight {
            let waited = now.saturating_duration_since(f.sent_at);
            if waited > opts.frame {
                hung.push((f.index, super::frames::waiting_on(plan, f)));
            } else if waited > slow.mul_f64(if f.warming { WARM_UP } else { 1.0 }) && !f.slow_warned
            {
                f.slow_warned = true;
                slow_frames.push((f.index, waited, super::frames::waiting_on(plan, f)));
            }
        }
        // One line per slow frame only in the log's detail: the run's summary says it once.
        for (index, waited, culprits) in slow_frames {
            tracing::debug!(
                frame = index,
                "frame {index} is slow: {} ms so far (the plan estimates {} ms); waiting on {}",
                waited.as_millis(),
                predicted.as_millis(),
                culprits.join(", ")
            );
            for c in culprits {
                self.summary.incidents.push(Incident {
                    daemon: c,
                    kind: IncidentKind::Slow {
                        frame: index,
                        waited,
                    },
                    at: now,
                });
            }
        }
        for (index, culprits) in hung {
            for c in culprits {
                self.lose(
                    &c,
                    format!(
                        "frame {index} not finished after {} s",
                        opts.frame.as_secs_f64()
                    ),
                    now,
                );
            }
        }
    }

    /// The re-plan due now, if any: why, and whether for a failure.
    fn due_replan(&mut self, now: Instant) -> Option<(String, bool)> {
        if let Some(r) = self.need_replan.take() {
            return Some((r, true));
        }
        if let Some((at, _)) = &self.reset_at
            && now >= *at
        {
            return self
                .reset_at
                .take()
                .map(|(_, r)| (format!("frame failure: {r}"), true));
        }
        if self.frames.inflight.is_empty()
            && let Some(r) = self
                .pending_steer
                .take()
                .or_else(|| self.pending_join.take())
        {
            // A join waiting as well is folded into the same epoch.
            self.pending_join = None;
            return Some((r, false));
        }
        // A refinement is planned with no budget: its frames say nothing of the budget's plan.
        if self.refine.is_some() {
            return None;
        }
        let plan = self.plan.as_ref()?;
        let cluster = self.cluster();
        let step = self
            .adapt
            .review(&self.scene, &cluster, &mut self.opts, plan)?;
        self.notice(step.clone());
        Some((step, false))
    }

    pub(super) fn lost_list(&self) -> String {
        if self.lost.is_empty() {
            return "none".to_string();
        }
        self.lost
            .iter()
            .map(|(id, why)| format!("{id} ({why})"))
            .collect::<Vec<_>>()
            .join("; ")
    }
}
