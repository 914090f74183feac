//! The coordinator's event loop: one task owns the plan, the membership and the frames in
//! flight, and reacts to events — frame requests (a channel: a scripted path today, a viewer
//! later), daemon messages and the end of their control links, the sink's frames, daemons that
//! answer a redial, and a 50 ms tick for heartbeats and deadlines (`docs/failover.md`).
//!
//! - **Lost** (control link closed or broken, heartbeats unanswered for
//!   `ControlOptions::heartbeat_timeout`, a frame not finished within `ControlOptions::frame`):
//!   the daemon is dropped and redialled in the background; if the plan used it, a new epoch is
//!   planned over the daemons left (`plan::replan`, moving as few lights as it can), configured,
//!   and the frames of the old epoch that had not reached the sink are requested again.
//! - **Slow** (a frame past `slow_factor` × the plan's estimate): reported, naming the daemons
//!   the frame waits on; a daemon that answers its heartbeats is waited for.
//! - **Joined** (a lost daemon answered its redial): folded into the next epoch once the frames in
//!   flight are done.
//! - **Frame failures** reported by daemons or the sink: the frames in flight are requested again
//!   under a new epoch over the same daemons.
//! - **Stopping** (the run's stop token, `Live::stop_on`, was cancelled — Ctrl-C): no frame is
//!   requested any more and the frames in flight are finished; a daemon whose link ends from then
//!   on is taken to be stopping with the run (a Ctrl-C at a terminal reaches every process of its
//!   group), not lost: nothing is re-planned, the frames that waited on it are abandoned, and the
//!   run ends with what was delivered (`LiveSummary::stopped`).
//!
//! Frames are handed to `on_frame` complete, in request order, exactly once.

mod epoch;
mod frames;
mod ledger;

use super::session::{ControlError, Event, FrameResult, Joined, Session};
use super::sink::{SinkEvent, SinkFrame};
use crate::plan::{Plan, PlanOptions};
use crate::run::RunError;
use frames::waiting_on;
pub use frames::{SEED64_HEADROOM, seed64_scale};
use lightfold_protocol::{ErrorCode, FrameStats, Message, WireCamera};
use lightfold_scene::Scene;
use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::{mpsc, watch};
use tokio_util::sync::CancellationToken;

/// Incidents kept in `LiveStatus` (the newest).
const STATUS_INCIDENTS: usize = 50;
/// How often the loop looks at heartbeats and deadlines.
const TICK: Duration = Duration::from_millis(50);
/// A frame failure waits this long before the frames are requested again, so that the loss
/// behind it (which usually arrives at the same time) makes one re-plan, not two.
const RESET_DEBOUNCE: Duration = Duration::from_millis(300);
/// Re-plans in a row without a frame delivered before the run gives up.
const MAX_REPLANS_WITHOUT_PROGRESS: u32 = 8;
/// How much longer the first frames of an epoch may take before they count as slow.
const WARM_UP: f64 = 3.0;
/// Settled frames an epoch measures before the cost model is checked against them, and how far
/// (as a factor either way) the median may stray from the estimate before it is corrected.
const ADAPT_FRAMES: usize = 6;
const ADAPT_BAND: f64 = 1.25;
/// Frames under this share of the budget may re-plan for more quality.
const RAISE_BELOW: f64 = 0.8;
/// Sink warnings (stray connections) logged at most this often.
const WARNING_EVERY: Duration = Duration::from_secs(1);

/// One frame to render: its camera (`None`: the plan's) and the light colours in effect
/// (source light → colour; lights not named keep the scene's colour).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FrameSpec {
    pub camera: Option<WireCamera>,
    pub light_colors: Vec<(u32, [f32; 3])>,
    /// Scene time (seconds) an animated scene is posed at; `None`: the rest pose.
    pub time: Option<f32>,
    /// The frame budget to plan under from this frame on (µs; `Some(None)`: none), where it
    /// differs from the session's: the loop re-plans before sending the frame
    /// (`plan/budget.rs`). `None` keeps the session's.
    pub frame_budget_us: Option<Option<u64>>,
}

/// Something that happened to a daemon during the run.
#[derive(Debug, Clone, PartialEq)]
pub enum IncidentKind {
    Lost { reason: String },
    Slow { frame: u64, waited: Duration },
    Rejoined,
}

#[derive(Debug, Clone)]
pub struct Incident {
    pub daemon: String,
    pub kind: IncidentKind,
    pub at: Instant,
}

/// One plan epoch the run used.
#[derive(Debug, Clone)]
pub struct EpochRecord {
    pub epoch: u64,
    /// Why it was planned ("start", "node-3 lost: …", "node-3 rejoined", …).
    pub reason: String,
    /// When it was configured everywhere, and how long configuring took.
    pub at: Instant,
    pub configure: Duration,
    pub nodes: usize,
    pub stages: usize,
    pub k: u32,
    /// Lights of the previous epoch that moved to another node.
    pub lights_moved: usize,
}

/// What a run did, also when it failed.
#[derive(Debug, Default)]
pub struct LiveSummary {
    pub plan: Option<Plan>,
    pub epochs: Vec<EpochRecord>,
    pub incidents: Vec<Incident>,
    pub delivered: u64,
    /// Frame requests sent again after a re-plan.
    pub rerequested: u64,
    /// Daemons whose links ended after the run was told to stop (stopping with it, not lost).
    pub stopped: Vec<String>,
    /// Frames requested but not finished because daemons stopped with the run.
    pub abandoned: u64,
    /// Values the daemons' links clamped to their format's range, over the run
    /// (`FrameStats::saturated`), and the frames in which any were.
    pub saturated: u64,
    pub saturated_frames: u64,
}

/// What the loop is doing, for a watcher.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LiveState {
    /// Before the first plan is configured.
    #[default]
    Starting,
    /// Rendering with every daemon it has ever had.
    Running,
    /// Planning and configuring a new epoch.
    Replanning,
    /// Rendering, with daemons lost.
    Degraded,
}

/// The loop's state as a watcher sees it (`Live::observe`), published whenever it changes.
#[derive(Debug, Clone, Default)]
pub struct LiveStatus {
    pub state: LiveState,
    pub plan: Option<Arc<Plan>>,
    pub epochs: Vec<EpochRecord>,
    /// The newest incidents (at most 50).
    pub incidents: Vec<Incident>,
    /// Lost daemons and why.
    pub lost: Vec<(String, String)>,
    /// The latest notice (a re-plan the user caused, …), numbered from 1.
    pub notice: Option<(u64, String)>,
}

#[derive(Debug)]
struct InFlight {
    index: u64,
    spec: FrameSpec,
    wire: u64,
    sent_at: Instant,
    image: Option<SinkFrame>,
    stats: Vec<FrameStats>,
    slow_warned: bool,
    /// Among the first frames of its epoch (they also pay for shadow maps, pipelines and links
    /// the epoch sets up, so they get `WARM_UP` × the time before they count as slow).
    warming: bool,
}

/// Why establishing an epoch stopped.
enum Halt {
    /// A daemon of the new plan was lost: plan again.
    Interrupted,
    /// A daemon refused the new plan's scene or configuration (`Live::absorb_refusal`).
    Refused {
        id: String,
        code: ErrorCode,
        message: String,
    },
    Fatal(RunError),
}

impl From<RunError> for Halt {
    fn from(e: RunError) -> Halt {
        Halt::Fatal(e)
    }
}

impl From<ControlError> for Halt {
    fn from(e: ControlError) -> Halt {
        Halt::Fatal(e.into())
    }
}

/// The settings of an epoch every daemon took: what a refused configuration goes back to.
#[derive(Debug, Clone)]
struct Settings {
    epoch: u64,
    /// Each scene light's colour.
    colors: Vec<[f32; 3]>,
    opts: PlanOptions,
}

/// Settings daemons refused: frame requests asking for them again are sent without them.
#[derive(Debug, Default)]
struct Refused {
    /// (scene light, colour) pairs.
    colors: Vec<(u32, [f32; 3])>,
    /// A frame budget (`FrameSpec::frame_budget_us`).
    budget: Option<Option<u64>>,
}

impl Refused {
    /// Takes out of `spec` what was refused: those lights keep their colour, the budget stays.
    fn strip(&self, spec: &mut FrameSpec) {
        spec.light_colors.retain(|(l, c)| {
            !self
                .colors
                .iter()
                .any(|(rl, rc)| rl == l && rc.map(f32::to_bits) == c.map(f32::to_bits))
        });
        if spec.frame_budget_us.is_some() && spec.frame_budget_us == self.budget {
            spec.frame_budget_us = None;
        }
    }
}

/// A scene's content hash and encoding, shared by the nodes it is sent to.
pub(super) type SceneBytes = ([u8; 32], std::sync::Arc<Vec<u8>>);

/// The loop's state over one session.
pub struct Live<'s> {
    session: &'s mut Session,
    /// The scene as the nodes have it (light colours change when a colour change splits a
    /// node's colour group, which re-plans).
    scene: Scene,
    opts: PlanOptions,
    bytes: std::sync::Arc<Vec<u8>>,
    hash: [u8; 32],
    /// Sort-last partitions: the scene each node needs (`scene::partition::keep_meshes`), by
    /// the meshes it keeps whole; cleared when the scene changes.
    subsets: std::collections::HashMap<Vec<u32>, SceneBytes>,
    plan: Option<Plan>,
    /// Under a frame budget: each settled frame of this epoch, its slowest node's measured
    /// render time (µs), and per node and frame the fixed and per-light costs measured over the
    /// registered model's (`adapt_costs`).
    measured: Vec<f64>,
    scales: Vec<(f64, f64)>,
    /// Per render node of the plan: its registered model (fixed µs, µs per light) and the
    /// model's weights of its lights (whole, shadow passes).
    model: std::collections::HashMap<String, [f64; 4]>,
    /// Plans (`choices`) whose frames were measured over the current budget.
    over_budget: std::collections::HashSet<String>,
    /// The best plan measured within the current budget: its quality and the cost factors it
    /// was planned under; and the factors the current plan was planned under.
    known_good: Option<((usize, std::cmp::Reverse<usize>), crate::plan::CostScale)>,
    plan_scale: crate::plan::CostScale,
    /// The plan's daemons, compositors first.
    participants: Vec<String>,
    /// The settings of the newest epoch every daemon took, refusals since, what was refused,
    /// and daemons left out for refusing their part (`Live::absorb_refusal`).
    good: Option<Settings>,
    refusals: u32,
    refused: Refused,
    shunned: std::collections::BTreeSet<String>,
    /// Frame requests sent in the current epoch.
    sent_in_epoch: u64,
    /// The frames from request to delivery.
    frames: ledger::Ledger,
    source_open: bool,
    /// Why the next re-plan is due now (a participant was lost).
    need_replan: Option<String>,
    /// A daemon joined: re-plan once the frames in flight are done.
    pending_join: Option<String>,
    /// A frame failed: re-request at this time.
    reset_at: Option<(Instant, String)>,
    /// Daemons lost since the last look, and why each lost daemon was lost.
    just_lost: Vec<String>,
    lost: BTreeMap<String, String>,
    replans_without_progress: u32,
    last_ping: Option<Instant>,
    last_warning: Option<Instant>,
    /// One tick for every phase, so heartbeats go out however busy the event channels are.
    tick: tokio::time::Interval,
    observer: watch::Sender<LiveStatus>,
    notices: u64,
    /// Cancelled when the run is to stop (`stop_on`).
    stop: Option<CancellationToken>,
    /// A daemon of the plan stopped with the run: the frames in flight cannot finish.
    abandon: bool,
    /// Each node's latest `FrameStats::peak` in this epoch: the next `seed64` scale's input.
    peaks: std::collections::HashMap<String, f32>,
    pub summary: LiveSummary,
}

impl std::fmt::Debug for Live<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Live")
            .field("epoch", &self.plan.as_ref().map(|p| p.epoch))
            .field("queued", &self.frames.queue.len())
            .field("in_flight", &self.frames.inflight.len())
            .field("delivered", &self.summary.delivered)
            .finish_non_exhaustive()
    }
}

impl<'s> Live<'s> {
    pub fn new(
        session: &'s mut Session,
        scene: &Scene,
        opts: &PlanOptions,
    ) -> Result<Live<'s>, RunError> {
        // `--aa N`: everything the cluster renders is N × the camera's size; the sink resolves.
        // Partitions resolved once for the run (automatic ones from the nodes' memory), and
        // meshes too large for a part split into chunks first.
        let cluster = crate::run::cluster_spec(session);
        let opts = &PlanOptions {
            partitions: crate::plan::partitions_for(scene, &cluster, opts),
            ..opts.clone()
        };
        let mut scene = crate::plan::scene_for(scene, &cluster, opts).into_owned();
        scene.camera = scene.camera.supersampled(opts.supersample)?;
        let bytes = scene
            .to_bytes()
            .map_err(|e| RunError::Scene(e.to_string()))?;
        let scene_hash = scene.content_hash();
        // Daemons not reached while connecting are lost from the start (and redialled).
        let lost = session.unreachable.iter().cloned().collect();
        Ok(Live {
            session,
            scene,
            opts: opts.clone(),
            bytes: std::sync::Arc::new(bytes),
            subsets: std::collections::HashMap::new(),
            // Nodes decode what they receive and check it against this.
            hash: scene_hash,
            plan: None,
            measured: Vec::new(),
            scales: Vec::new(),
            model: std::collections::HashMap::new(),
            over_budget: std::collections::HashSet::new(),
            known_good: None,
            plan_scale: crate::plan::CostScale::default(),
            participants: Vec::new(),
            good: None,
            refusals: 0,
            refused: Refused::default(),
            shunned: std::collections::BTreeSet::new(),
            sent_in_epoch: 0,
            frames: ledger::Ledger::default(),
            source_open: true,
            need_replan: None,
            pending_join: None,
            reset_at: None,
            just_lost: Vec::new(),
            peaks: std::collections::HashMap::new(),
            lost,
            replans_without_progress: 0,
            last_ping: None,
            last_warning: None,
            tick: {
                let mut t = tokio::time::interval(TICK);
                t.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
                t
            },
            observer: watch::Sender::new(LiveStatus::default()),
            notices: 0,
            stop: None,
            abandon: false,
            summary: LiveSummary::default(),
        })
    }

    /// A watcher of the loop's state (plan, epochs, incidents, lost daemons, notices).
    pub fn observe(&self) -> watch::Receiver<LiveStatus> {
        self.observer.subscribe()
    }

    /// Publishes the state to watchers.
    pub(super) fn publish(&self, replanning: bool) {
        let state = if replanning {
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
        });
    }

    /// Tells watchers something the user should see (and logs it).
    pub(super) fn notice(&mut self, text: String) {
        tracing::info!("{text}");
        self.notices += 1;
        let n = self.notices;
        self.observer.send_modify(|s| s.notice = Some((n, text)));
    }

    /// The token that stops the run (Ctrl-C): once it is cancelled, daemons whose links end are
    /// stopping with the run, not lost (see the module docs). The caller still closes the
    /// request channel to stop new frames.
    pub fn stop_on(&mut self, stop: CancellationToken) {
        self.stop = Some(stop);
    }

    /// Whether the run was told to stop.
    pub(super) fn stopping(&self) -> bool {
        self.stop.as_ref().is_some_and(|t| t.is_cancelled())
    }

    /// Resolves once the run is told to stop (never without a stop token): the waits of a
    /// re-plan (`wait_for_join`, `wait_message`) end on it, so Ctrl-C is not held up by a wait
    /// for lost daemons or configurations.
    pub(super) fn stopped(&self) -> impl std::future::Future<Output = ()> + use<> {
        let stop = self.stop.clone();
        async move {
            match stop {
                Some(t) => t.cancelled_owned().await,
                None => std::future::pending().await,
            }
        }
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

    /// The plan in use.
    pub fn plan(&self) -> Option<&Plan> {
        self.plan.as_ref()
    }

    /// Plans, configures and renders every frame `requests` yields until it closes, handing
    /// each finished frame to `on_frame` in order. On an error the frames delivered so far have
    /// been handed over and `summary` says what happened.
    pub async fn run(
        &mut self,
        mut requests: mpsc::Receiver<FrameSpec>,
        mut on_frame: impl FnMut(FrameResult),
    ) -> Result<(), RunError> {
        self.replan("start".to_string()).await?;
        loop {
            self.collect();
            self.deliver(&mut on_frame);
            if self.abandon {
                self.abandon_frames();
                return Ok(());
            }
            if let Some(reason) = self.due_replan() {
                self.replan(reason).await?;
                continue;
            }
            self.issue()?;
            if !self.source_open && self.frames.idle() {
                self.deliver(&mut on_frame);
                return Ok(());
            }
            let lookahead = self.session.opts.frames_in_flight.max(1);
            let want = self.source_open && self.frames.queue.len() < lookahead;
            let (stopped, running) = (self.stopped(), !self.stopping());
            tokio::select! {
                // Only to wake the loop: losses from now on are read as stopping.
                () = stopped, if running => {}
                ev = self.session.events.recv() => match ev {
                    Some(ev) => self.on_run_event(ev)?,
                    None => return Err(ControlError::Sink("event channel closed".into()).into()),
                },
                s = self.session.sink_events.recv() => match s {
                    Some(s) => self.on_sink(s),
                    None => return Err(ControlError::Sink("the sink stopped".into()).into()),
                },
                j = self.session.joined.recv() => if let Some(j) = j { self.on_join(j) },
                spec = requests.recv(), if want => match spec {
                    Some(spec) => self.frames.request(spec),
                    None => self.source_open = false,
                },
                _ = self.tick.tick() => self.on_tick()?,
            }
        }
    }

    /// Takes one daemon event: liveness bookkeeping, losses, take-overs. Returns the message for
    /// the caller's phase, if any.
    fn accept(&mut self, (id, link, result): Event) -> Result<Option<(String, Message)>, RunError> {
        let Some(d) = self.session.daemons.get(&id) else {
            return Ok(None); // a daemon already lost
        };
        if d.link != link {
            return Ok(None); // an older link of a daemon that rejoined
        }
        match result {
            Err(e) => {
                self.lose(&id, format!("its control link ended: {e}"));
                Ok(None)
            }
            Ok(Message::Pong { .. }) => Ok(None),
            Ok(Message::Error {
                code: ErrorCode::TakenOver,
                message,
                ..
            }) => Err(ControlError::TakenOver {
                address: self.session.address(&id),
                id,
                message,
            }
            .into()),
            Ok(m) => Ok(Some((id, m))),
        }
    }

    fn on_run_event(&mut self, ev: Event) -> Result<(), RunError> {
        let Some((id, m)) = self.accept(ev)? else {
            return Ok(());
        };
        let epoch = self.plan.as_ref().map(|p| p.epoch);
        match m {
            Message::FrameDone(s) if Some(s.epoch) == epoch => {
                if s.peak.is_finite() && s.peak > 0.0 {
                    self.peaks.insert(s.daemon_id.clone(), s.peak);
                }
                if let Some(f) = self.frames.inflight.iter_mut().find(|f| f.wire == s.frame)
                    && !f.stats.iter().any(|x| x.daemon_id == s.daemon_id)
                {
                    if s.saturated > 0 {
                        if self.summary.saturated == 0 {
                            tracing::warn!(
                                daemon = %s.daemon_id,
                                frame = f.index,
                                saturated = s.saturated,
                                "values above the link format's range were clamped (counted in \
                                 the frame stats and the run summary)"
                            );
                        }
                        if !f.stats.iter().any(|x| x.saturated > 0) {
                            self.summary.saturated_frames += 1;
                        }
                        self.summary.saturated += s.saturated;
                    }
                    f.stats.push(s);
                }
            }
            Message::FrameDone(_) => {} // of an older epoch
            Message::Error {
                code,
                message,
                epoch: about,
                frame,
            } => self.daemon_error(&id, code, &message, about, frame),
            other => tracing::debug!(daemon = %id, "ignored {other:?}"),
        }
        Ok(())
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
                Instant::now() + RESET_DEBOUNCE,
                format!("{id} reported {code:?}: {message}"),
            ));
        }
    }

    fn on_sink(&mut self, ev: SinkEvent) {
        let epoch = self.plan.as_ref().map(|p| p.epoch);
        match ev {
            SinkEvent::Frame(f) if Some(f.epoch) == epoch => {
                if let Some(x) = self.frames.inflight.iter_mut().find(|x| x.wire == f.frame) {
                    x.image = Some(f);
                }
            }
            SinkEvent::Frame(_) => {}
            SinkEvent::Failed { frame, reason } => {
                tracing::warn!(frame, "{reason}");
                if self.frames.inflight.iter().any(|f| f.wire == frame) && self.reset_at.is_none() {
                    self.reset_at = Some((Instant::now() + RESET_DEBOUNCE, reason));
                }
            }
            SinkEvent::Warning(w) => self.warn_rate_limited(&w),
        }
    }

    fn warn_rate_limited(&mut self, w: &str) {
        let now = Instant::now();
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

    fn on_join(&mut self, j: Joined) {
        let id = j.caps.daemon_id.clone();
        tracing::info!(daemon = %id, address = %j.entry.address, "rejoined");
        lightfold_ops::record::daemon_rejoined();
        // Lost under its id, or under its address when it was not reached at the start.
        self.lost.remove(&j.entry.address);
        self.session.admit(j);
        self.lost.remove(&id);
        self.summary.incidents.push(Incident {
            daemon: id.clone(),
            kind: IncidentKind::Rejoined,
            at: Instant::now(),
        });
        if self.shunned.remove(&id) {
            // It refused its part: it takes part again when something else re-plans.
            tracing::info!(daemon = %id, "rejoined after refusing its configuration: folded in at the next re-plan");
        } else {
            self.pending_join.get_or_insert(format!("{id} rejoined"));
        }
        self.publish(false);
    }

    /// Drops a daemon; a re-plan is due if the plan used it. Once the run is stopping, the daemon
    /// is taken to be stopping too: no incident, no re-plan, and the frames that need it are
    /// abandoned.
    fn lose(&mut self, id: &str, reason: String) {
        let Some(d) = self.session.lose(id) else {
            return;
        };
        let used = self.participants.iter().any(|p| p == id);
        if self.stopping() {
            tracing::info!(daemon = %id, address = %d.address, "stopped with the run ({reason})");
            self.summary.stopped.push(id.to_string());
            self.abandon |= used;
            return;
        }
        tracing::warn!(daemon = %id, address = %d.address, in_plan = used, "lost: {reason}");
        lightfold_ops::record::daemon_lost();
        self.summary.incidents.push(Incident {
            daemon: id.to_string(),
            kind: IncidentKind::Lost {
                reason: reason.clone(),
            },
            at: Instant::now(),
        });
        self.lost.insert(id.to_string(), reason.clone());
        self.just_lost.push(id.to_string());
        if used {
            self.need_replan
                .get_or_insert(format!("{id} lost: {reason}"));
        }
        self.publish(self.need_replan.is_some());
    }

    /// Sends heartbeats and judges silence; a heartbeat counts as unanswered only from when it
    /// was sent, so a loop that was busy never mistakes its own delay for a daemon's silence.
    fn heartbeat(&mut self) {
        let now = Instant::now();
        let opts = self.session.opts;
        let mut silent = Vec::new();
        for (id, d) in &mut self.session.daemons {
            if let Some(t) = d.ping_pending
                && d.last_seen() >= t
            {
                d.ping_pending = None;
            }
            if let Some(t) = d.ping_pending
                && now.duration_since(t) > opts.heartbeat_timeout
            {
                silent.push((id.clone(), now.duration_since(t)));
            }
        }
        for (id, waited) in silent {
            self.lose(
                &id,
                format!(
                    "no answer to heartbeats for {} ms (stopped, hung or cut off)",
                    waited.as_millis()
                ),
            );
        }
        if self
            .last_ping
            .is_some_and(|t| now.duration_since(t) < opts.heartbeat)
        {
            return;
        }
        self.last_ping = Some(now);
        let ids: Vec<String> = self.session.daemons.keys().cloned().collect();
        for id in ids {
            match self.session.send(&id, Message::Ping { seq: 0 }) {
                Ok(()) => {
                    if let Some(d) = self.session.daemons.get_mut(&id) {
                        d.ping_pending.get_or_insert(now);
                    }
                }
                Err(e) => self.lose(&id, format!("cannot send to it: {e}")),
            }
        }
    }

    fn on_tick(&mut self) -> Result<(), RunError> {
        self.heartbeat();
        let Some(plan) = &self.plan else {
            return Ok(());
        };
        let now = Instant::now();
        let opts = self.session.opts;
        let predicted = Duration::from_micros(plan.est_frame_us);
        let slow = predicted.mul_f64(opts.slow_factor).max(opts.slow_floor);
        let mut slow_frames = Vec::new();
        let mut hung = Vec::new();
        for f in &mut self.frames.inflight {
            let waited = now.duration_since(f.sent_at);
            if waited > opts.frame {
                hung.push((f.index, waiting_on(plan, f)));
            } else if waited > slow.mul_f64(if f.warming { WARM_UP } else { 1.0 }) && !f.slow_warned
            {
                f.slow_warned = true;
                slow_frames.push((f.index, waited, waiting_on(plan, f)));
            }
        }
        for (index, waited, culprits) in slow_frames {
            tracing::warn!(
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
                );
            }
        }
        Ok(())
    }

    fn due_replan(&mut self) -> Option<String> {
        if let Some(r) = self.need_replan.take() {
            return Some(r);
        }
        if let Some((at, _)) = &self.reset_at
            && Instant::now() >= *at
        {
            return self
                .reset_at
                .take()
                .map(|(_, r)| format!("frame failure: {r}"));
        }
        if self.pending_join.is_some() && self.frames.inflight.is_empty() {
            return self.pending_join.take();
        }
        self.adapt_costs()
    }

    /// Under a frame budget, once `ADAPT_FRAMES` settled frames of an epoch are measured: each
    /// node's shadow passes give its cost per light (over the model's shadow weight of its
    /// lights), the rest of its work its fixed cost. When the medians stray from the scales in
    /// use by more than `ADAPT_BAND`×, the model takes them (`PlanOptions::cost_scale`). A
    /// re-plan is due only when the corrected model changes the plan's choices (K, samples,
    /// what was given up, lights per node) and the frames are over the budget, or under
    /// `RAISE_BELOW` of it with a candidate of more quality (more samples or fewer concessions;
    /// never only to free nodes); a plan whose frames were measured over this budget is never
    /// chosen again (no oscillation between two plans the model cannot tell apart).
    fn adapt_costs(&mut self) -> Option<String> {
        let budget = self.opts.frame_budget_us?;
        if self.measured.len() < ADAPT_FRAMES || self.scales.is_empty() {
            return None;
        }
        let took = median(std::mem::take(&mut self.measured));
        let scales = std::mem::take(&mut self.scales);
        let fixed = median(scales.iter().map(|s| s.0).collect());
        let light = median(scales.iter().map(|s| s.1).collect());
        let current = self.plan.as_ref()?;
        let over = took > budget as f64;
        if over {
            self.over_budget.insert(choices(current));
        } else if self.known_good.is_none_or(|(q, _)| quality(current) > q) {
            self.known_good = Some((quality(current), self.plan_scale));
        }
        // Over the budget where a plan of more quality was measured within it: back to that one
        // (the factors it was planned under give it again on the same cluster).
        if over
            && let Some((q, scale)) = self.known_good
            && q > quality(current)
        {
            self.known_good = None;
            self.opts.cost_scale = scale;
            let why = format!(
                "measured frames take {:.1} ms, over the {:.1} ms budget: back to the last plan \
                 measured within it",
                took / 1e3,
                budget as f64 / 1e3
            );
            self.notice(why.clone());
            return Some(why);
        }
        let now = self.opts.cost_scale;
        let strays = |measured: f64, used: f64| (measured / used).ln().abs() > ADAPT_BAND.ln();
        if !(fixed.is_finite() && light.is_finite() && fixed > 0.0 && light > 0.0)
            || !(strays(fixed, now.fixed) || strays(light, now.light))
        {
            return None;
        }
        let mut o = self.opts.clone();
        o.cost_scale = crate::plan::CostScale {
            fixed: fixed.clamp(1e-4, 1e4),
            light: light.clamp(1e-4, 1e4),
        };
        let cluster = crate::run::cluster_spec(self.session);
        let candidate = crate::plan::replan(&self.scene, &cluster, &o, current).ok()?;
        let text = format!(
            "measured frames ({:.1} ms, the model's estimate {:.1} ms) put the nodes' fixed cost \
             at {fixed:.3}× and their cost per light at {light:.3}× what they registered",
            took / 1e3,
            current.est_frame_us as f64 / 1e3
        );
        self.opts.cost_scale = o.cost_scale;
        let key = choices(&candidate);
        // Under the budget, only for more quality (not to free nodes: the frames fit as they are).
        let better = quality(&candidate) > quality(current);
        let act = over || (took < RAISE_BELOW * budget as f64 && better);
        if key == choices(current) || !act || self.over_budget.contains(&key) {
            tracing::info!("{text}: the corrected cost model keeps the plan");
            return None;
        }
        let why = format!(
            "{text}: re-planning for the {:.1} ms budget",
            budget as f64 / 1e3
        );
        self.notice(why.clone());
        Some(why)
    }

    /// Records a settled frame's measurements for `adapt_costs` (under a frame budget).
    pub(super) fn measure(&mut self, epoch: u64, stats: &[FrameStats]) {
        let Some(plan) = &self.plan else { return };
        if self.opts.frame_budget_us.is_none() || plan.epoch != epoch {
            return;
        }
        let mut slowest = None::<u64>;
        for s in stats {
            let Some(&[fixed_us, light_us, w_all, w_shadow]) = self.model.get(&s.daemon_id) else {
                continue;
            };
            let work = s.pose_us + s.shadow_us + s.eye_us + s.readback_us + s.pack_us;
            slowest = Some(slowest.map_or(work, |w| w.max(work)));
            // Kept maps (walkthrough) hide the shadow passes' cost: no per-light figure.
            if w_shadow <= 0.0 || s.maps_kept > 0 || fixed_us <= 0.0 || light_us <= 0.0 {
                continue;
            }
            let per_light = s.shadow_us as f64 / w_shadow;
            let rest = (work as f64 - per_light * w_all).max(0.05 * work as f64);
            self.scales.push((rest / fixed_us, per_light / light_us));
        }
        if let Some(w) = slowest {
            self.measured.push(w as f64);
        }
    }

    /// The registered cost model of each render node of `plan` (`measure`).
    pub(super) fn set_model(&mut self, plan: &Plan) {
        let cluster = crate::run::cluster_spec(self.session);
        self.model = plan
            .nodes
            .iter()
            .filter_map(|n| {
                let spec = cluster.nodes.iter().find(|d| d.id == n.node)?;
                let (fixed, light) = crate::plan::node_cost(spec, plan);
                let (w_all, w_shadow) = n
                    .shadows
                    .iter()
                    .map(crate::plan::light_weight)
                    .fold((0.0, 0.0), |a, w| (a.0 + w.0, a.1 + w.1));
                Some((n.node.clone(), [fixed, light, w_all, w_shadow]))
            })
            .collect();
    }
}

/// What a daemon's error means to the loop while frames run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ErrorVerdict {
    /// About an epoch the loop has left, a frame no longer in flight, or the link alone (no
    /// epoch): nothing to do beyond a log line.
    History,
    /// About the current epoch, but nothing that stops its frames (a value it ignored, say).
    Logged,
    /// The frames in flight of the current epoch cannot complete: request them again.
    FramesFail,
}

/// Judges an error about epoch `about` (and `frame`, a wire frame id) while the loop runs epoch
/// `current` with the wire frames `inflight`. Pure, so the rule that nothing of an old epoch can
/// fail a new one is tested without a cluster.
fn judge_error(
    current: Option<u64>,
    inflight: &[u64],
    code: ErrorCode,
    about: Option<u64>,
    frame: Option<u64>,
) -> ErrorVerdict {
    if about.is_none() || about != current || frame.is_some_and(|w| !inflight.contains(&w)) {
        return ErrorVerdict::History;
    }
    let fails = matches!(
        code,
        ErrorCode::BandMismatch
            | ErrorCode::Timeout
            | ErrorCode::PeerLost
            | ErrorCode::RenderFailed
            | ErrorCode::Internal
    );
    if fails && !inflight.is_empty() {
        ErrorVerdict::FramesFail
    } else {
        ErrorVerdict::Logged
    }
}

/// What a plan chose, estimates aside: K, what it gave up, the active samples and each node's
/// lights (two plans with the same key render the same frames at the same cost).
fn choices(p: &Plan) -> String {
    let given: Vec<(crate::plan::Knob, &str)> = p
        .concessions
        .iter()
        .map(|c| (c.knob, c.to.as_str()))
        .collect();
    let lights: Vec<&[usize]> = p.nodes.iter().map(|n| n.lights.as_slice()).collect();
    format!(
        "K {} · {given:?} · {} samples, active {:?} · {lights:?}",
        p.k,
        p.samples.len(),
        p.active
    )
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// A plan's quality for the budget's purposes: more samples, then fewer concessions.
fn quality(p: &Plan) -> (usize, std::cmp::Reverse<usize>) {
    (p.samples.len(), std::cmp::Reverse(p.concessions.len()))
}

#[cfg(test)]
mod tests {
    use super::{ErrorVerdict, judge_error};
    use lightfold_protocol::ErrorCode;

    #[test]
    fn a_stale_timeout_after_a_re_plan_fails_nothing() {
        // The loss of a node re-planned epoch 7 into 8; a stage the new plan dropped reports its
        // old frame's input timeout 30 s later, when frames 41 and 42 of epoch 8 are in flight.
        let inflight = [41, 42];
        let stale = judge_error(Some(8), &inflight, ErrorCode::Timeout, Some(7), Some(12));
        assert_eq!(stale, ErrorVerdict::History);
        // The same report about epoch 8's frame 41 is a failure of the frames in flight.
        let fresh = judge_error(Some(8), &inflight, ErrorCode::Timeout, Some(8), Some(41));
        assert_eq!(fresh, ErrorVerdict::FramesFail);
        // A frame of the current epoch already delivered, and errors without an epoch (a
        // message the daemon does not take), change nothing either.
        let done = judge_error(Some(8), &inflight, ErrorCode::PeerLost, Some(8), Some(40));
        assert_eq!(done, ErrorVerdict::History);
        let link = judge_error(Some(8), &inflight, ErrorCode::Internal, None, None);
        assert_eq!(link, ErrorVerdict::History);
        // A downstream the current epoch cannot reach (epoch, no frame) fails its frames; an
        // ignored colour does not.
        let unreachable = judge_error(Some(8), &inflight, ErrorCode::PeerLost, Some(8), None);
        assert_eq!(unreachable, ErrorVerdict::FramesFail);
        let ignored = judge_error(Some(8), &inflight, ErrorCode::BadConfig, Some(8), Some(42));
        assert_eq!(ignored, ErrorVerdict::Logged);
        // With nothing in flight there is nothing to request again.
        let idle = judge_error(Some(8), &[], ErrorCode::PeerLost, Some(8), None);
        assert_eq!(idle, ErrorVerdict::Logged);
    }
}
