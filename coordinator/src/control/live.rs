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
//!
//! Frames are handed to `on_frame` complete, in request order, exactly once.

use super::session::{ControlError, Event, FrameResult, Joined, Session};
use super::sink::{SinkEvent, SinkFrame, SinkGeometry};
use crate::plan::{Plan, PlanError, PlanOptions, Source, lights_moved, plan, replan};
use crate::run::{RunError, cluster_spec, frame_params};
use lightfold_protocol::{ErrorCode, FrameParams, FrameStats, Message, WireCamera};
use lightfold_scene::Scene;
use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::time::{Duration, Instant};
use tokio::sync::mpsc;

/// How often the loop looks at heartbeats and deadlines.
const TICK: Duration = Duration::from_millis(50);
/// Frame failures reported this soon after an epoch was configured are taken to belong to the
/// frames of the epoch before (daemon errors carry no epoch).
const ERROR_GRACE: Duration = Duration::from_millis(300);
/// A frame failure waits this long before the frames are requested again, so that the loss
/// behind it (which usually arrives at the same time) makes one re-plan, not two.
const RESET_DEBOUNCE: Duration = Duration::from_millis(300);
/// Re-plans in a row without a frame delivered before the run gives up.
const MAX_REPLANS_WITHOUT_PROGRESS: u32 = 8;
/// Sink warnings (stray connections) logged at most this often.
const WARNING_EVERY: Duration = Duration::from_secs(1);

/// One frame to render: its camera (`None`: the plan's) and the light colours in effect
/// (source light → colour; lights not named keep the scene's colour).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FrameSpec {
    pub camera: Option<WireCamera>,
    pub light_colors: Vec<(u32, [f32; 3])>,
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
}

struct InFlight {
    index: u64,
    spec: FrameSpec,
    wire: u64,
    sent_at: Instant,
    image: Option<SinkFrame>,
    stats: Vec<FrameStats>,
    slow_warned: bool,
}

/// Why establishing an epoch stopped.
enum Halt {
    /// A daemon of the new plan was lost: plan again.
    Interrupted,
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

/// The loop's state over one session.
pub struct Live<'s> {
    session: &'s mut Session,
    scene: &'s Scene,
    opts: PlanOptions,
    bytes: Vec<u8>,
    hash: [u8; 32],
    plan: Option<Plan>,
    /// The plan's daemons, compositors first.
    participants: Vec<String>,
    established_at: Instant,
    next_index: u64,
    queue: VecDeque<(u64, FrameSpec)>,
    inflight: Vec<InFlight>,
    done: BTreeMap<u64, FrameResult>,
    next_deliver: u64,
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
    pub summary: LiveSummary,
}

impl std::fmt::Debug for Live<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Live")
            .field("epoch", &self.plan.as_ref().map(|p| p.epoch))
            .field("queued", &self.queue.len())
            .field("in_flight", &self.inflight.len())
            .field("delivered", &self.summary.delivered)
            .finish_non_exhaustive()
    }
}

impl<'s> Live<'s> {
    pub fn new(
        session: &'s mut Session,
        scene: &'s Scene,
        opts: &PlanOptions,
    ) -> Result<Live<'s>, RunError> {
        let bytes = scene
            .to_bytes()
            .map_err(|e| RunError::Scene(e.to_string()))?;
        Ok(Live {
            session,
            scene,
            opts: opts.clone(),
            bytes,
            // Nodes decode what they receive and check it against this.
            hash: scene.content_hash(),
            plan: None,
            participants: Vec::new(),
            established_at: Instant::now(),
            next_index: 1,
            queue: VecDeque::new(),
            inflight: Vec::new(),
            done: BTreeMap::new(),
            next_deliver: 1,
            source_open: true,
            need_replan: None,
            pending_join: None,
            reset_at: None,
            just_lost: Vec::new(),
            lost: BTreeMap::new(),
            replans_without_progress: 0,
            last_ping: None,
            last_warning: None,
            summary: LiveSummary::default(),
        })
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
        let mut tick = tokio::time::interval(TICK);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        loop {
            self.collect();
            self.deliver(&mut on_frame);
            if let Some(reason) = self.due_replan() {
                self.replan(reason).await?;
                continue;
            }
            self.issue().await?;
            if !self.source_open && self.queue.is_empty() && self.inflight.is_empty() {
                self.deliver(&mut on_frame);
                return Ok(());
            }
            let lookahead = self.session.opts.frames_in_flight.max(1);
            let want = self.source_open && self.queue.len() < lookahead;
            tokio::select! {
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
                    Some(spec) => {
                        self.queue.push_back((self.next_index, spec));
                        self.next_index += 1;
                    }
                    None => self.source_open = false,
                },
                _ = tick.tick() => self.on_tick().await?,
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
                if let Some(f) = self.inflight.iter_mut().find(|f| f.wire == s.frame)
                    && !f.stats.iter().any(|x| x.daemon_id == s.daemon_id)
                {
                    f.stats.push(s);
                }
            }
            Message::FrameDone(_) => {} // of an older epoch
            Message::Error { code, message } => self.daemon_error(&id, code, &message),
            other => tracing::debug!(daemon = %id, "ignored {other:?}"),
        }
        Ok(())
    }

    fn daemon_error(&mut self, id: &str, code: ErrorCode, message: &str) {
        tracing::warn!(daemon = %id, ?code, "{message}");
        let frame_failure = matches!(
            code,
            ErrorCode::BandMismatch
                | ErrorCode::Timeout
                | ErrorCode::PeerLost
                | ErrorCode::RenderFailed
                | ErrorCode::Internal
        );
        if frame_failure
            && !self.inflight.is_empty()
            && self.established_at.elapsed() > ERROR_GRACE
            && self.reset_at.is_none()
        {
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
                if let Some(x) = self.inflight.iter_mut().find(|x| x.wire == f.frame) {
                    x.image = Some(f);
                }
            }
            SinkEvent::Frame(_) => {}
            SinkEvent::Failed { frame, reason } => {
                tracing::warn!(frame, "{reason}");
                if self.inflight.iter().any(|f| f.wire == frame) && self.reset_at.is_none() {
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
        self.session.admit(j);
        self.lost.remove(&id);
        self.summary.incidents.push(Incident {
            daemon: id.clone(),
            kind: IncidentKind::Rejoined,
            at: Instant::now(),
        });
        self.pending_join.get_or_insert(format!("{id} rejoined"));
    }

    /// Drops a daemon; a re-plan is due if the plan used it.
    fn lose(&mut self, id: &str, reason: String) {
        let Some(d) = self.session.lose(id) else {
            return;
        };
        let used = self.participants.iter().any(|p| p == id);
        tracing::warn!(daemon = %id, address = %d.address, in_plan = used, "lost: {reason}");
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
    }

    /// Sends heartbeats and judges silence; a heartbeat counts as unanswered only from when it
    /// was sent, so a loop that was busy never mistakes its own delay for a daemon's silence.
    async fn heartbeat(&mut self) {
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
            match self.session.send(&id, Message::Ping { seq: 0 }).await {
                Ok(()) => {
                    if let Some(d) = self.session.daemons.get_mut(&id) {
                        d.ping_pending.get_or_insert(now);
                    }
                }
                Err(e) => self.lose(&id, format!("cannot send to it: {e}")),
            }
        }
    }

    async fn on_tick(&mut self) -> Result<(), RunError> {
        self.heartbeat().await;
        let Some(plan) = &self.plan else {
            return Ok(());
        };
        let now = Instant::now();
        let opts = self.session.opts;
        let predicted = Duration::from_micros(plan.est_frame_us);
        let slow = predicted.mul_f64(opts.slow_factor).max(opts.slow_floor);
        let mut slow_frames = Vec::new();
        let mut hung = Vec::new();
        for f in &mut self.inflight {
            let waited = now.duration_since(f.sent_at);
            if waited > opts.frame {
                hung.push((f.index, waiting_on(plan, f)));
            } else if waited > slow && !f.slow_warned {
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
        if self.pending_join.is_some() && self.inflight.is_empty() {
            return self.pending_join.take();
        }
        None
    }

    /// Moves frames whose image and reports are all in to `done`.
    fn collect(&mut self) {
        let all = self.participants.len();
        let mut i = 0;
        while i < self.inflight.len() {
            let f = &self.inflight[i];
            if f.image.is_some() && f.stats.len() >= all {
                let f = self.inflight.remove(i);
                let later = self.inflight.iter().filter(|x| x.index > f.index).count();
                self.finish(f, later as u32);
            } else {
                i += 1;
            }
        }
    }

    fn finish(&mut self, f: InFlight, latency_frames: u32) {
        let Some(image) = f.image else {
            return;
        };
        self.done.insert(
            f.index,
            FrameResult {
                frame: f.index,
                wire_frame: f.wire,
                epoch: image.epoch,
                requested_at: f.sent_at,
                received_at: image.received_at,
                latency_frames,
                image: image.image,
                sink_bytes: image.bytes,
                stats: f.stats,
            },
        );
    }

    fn deliver(&mut self, on_frame: &mut impl FnMut(FrameResult)) {
        while let Some(r) = self.done.remove(&self.next_deliver) {
            self.next_deliver += 1;
            self.summary.delivered += 1;
            self.replans_without_progress = 0;
            on_frame(r);
        }
    }

    /// Sends frame requests up to the in-flight limit (none while a re-plan is due).
    async fn issue(&mut self) -> Result<(), RunError> {
        if self.pending_join.is_some() || self.need_replan.is_some() || self.reset_at.is_some() {
            return Ok(());
        }
        let Some(plan) = &self.plan else {
            return Ok(());
        };
        let limit = self.session.opts.frames_in_flight.max(1);
        let epoch = plan.epoch;
        while self.inflight.len() < limit {
            let Some((index, spec)) = self.queue.pop_front() else {
                break;
            };
            let Some(plan) = &self.plan else {
                break;
            };
            let wire = self.session.base + index;
            let params = frame_params(plan, &spec.light_colors, index)?;
            let mut failed = None;
            for id in &self.participants {
                let msg = Message::RenderFrame {
                    epoch,
                    frame: wire,
                    camera: spec.camera,
                    params: params.get(id).cloned().unwrap_or(FrameParams {
                        colors: Vec::new(),
                        scale: None,
                    }),
                };
                if let Err(e) = self.session.send(id, msg).await {
                    failed = Some((id.clone(), e));
                    break;
                }
            }
            if let Some((id, e)) = failed {
                self.queue.push_front((index, spec));
                self.lose(&id, format!("cannot send to it: {e}"));
                break;
            }
            self.inflight.push(InFlight {
                index,
                spec,
                wire,
                sent_at: Instant::now(),
                image: None,
                stats: Vec::new(),
                slow_warned: false,
            });
        }
        Ok(())
    }

    /// Keeps the frames in flight that reached the sink (their image is complete) and puts the
    /// others back at the head of the queue, in order.
    fn salvage(&mut self) {
        let mut again = Vec::new();
        for f in std::mem::take(&mut self.inflight) {
            if f.image.is_some() {
                self.finish(f, 0);
            } else {
                again.push((f.index, f.spec));
            }
        }
        self.summary.rerequested += again.len() as u64;
        for item in again.into_iter().rev() {
            self.queue.push_front(item);
        }
    }

    /// Plans a new epoch over the daemons connected now and configures it, planning again while
    /// daemons of the new plan are lost on the way.
    async fn replan(&mut self, reason: String) -> Result<(), RunError> {
        self.salvage();
        self.reset_at = None;
        self.need_replan = None;
        self.replans_without_progress += 1;
        if self.replans_without_progress > MAX_REPLANS_WITHOUT_PROGRESS {
            return Err(ControlError::Stuck(format!(
                "{MAX_REPLANS_WITHOUT_PROGRESS} re-plans in a row delivered no frame; the last: {reason}"
            ))
            .into());
        }
        let mut reason = reason;
        let mut waited_since: Option<Instant> = None;
        loop {
            let epoch = self.session.next_epoch();
            let mut o = self.opts.clone();
            o.epoch = epoch;
            let cluster = cluster_spec(self.session);
            let next = match &self.plan {
                Some(prev) => replan(self.scene, &cluster, &o, prev),
                None => plan(self.scene, &cluster, &o),
            };
            let next = match next {
                Ok(p) => p,
                Err(e) if too_few(&e) => {
                    let since = *waited_since.get_or_insert_with(Instant::now);
                    let left = self
                        .session
                        .opts
                        .wait_for_daemons
                        .saturating_sub(since.elapsed());
                    if left.is_zero() {
                        return Err(RunError::TooFewDaemons {
                            error: e,
                            lost: self.lost_list(),
                        });
                    }
                    tracing::warn!(
                        "no plan fits the daemons left ({e}); waiting up to {} s for lost daemons",
                        left.as_secs()
                    );
                    self.wait_for_join(Instant::now() + left).await?;
                    reason = format!("{reason}; then a daemon rejoined");
                    continue;
                }
                Err(e) => return Err(e.into()),
            };
            match self.establish(next, &reason).await {
                Ok(()) => return Ok(()),
                Err(Halt::Interrupted) => {
                    reason = format!("{reason}; then {} lost", self.just_lost.join(", "));
                    continue;
                }
                Err(Halt::Fatal(e)) => return Err(e),
            }
        }
    }

    fn lost_list(&self) -> String {
        if self.lost.is_empty() {
            return "none".to_string();
        }
        self.lost
            .iter()
            .map(|(id, why)| format!("{id} ({why})"))
            .collect::<Vec<_>>()
            .join("; ")
    }

    async fn wait_for_join(&mut self, deadline: Instant) -> Result<(), RunError> {
        let mut tick = tokio::time::interval(TICK);
        loop {
            tokio::select! {
                j = self.session.joined.recv() => if let Some(j) = j {
                    self.on_join(j);
                    self.pending_join = None;
                    return Ok(());
                },
                ev = self.session.events.recv() => if let Some(ev) = ev { self.accept(ev)?; },
                s = self.session.sink_events.recv() => if let Some(s) = s { self.on_sink(s) },
                _ = tick.tick() => self.heartbeat().await,
                _ = tokio::time::sleep_until(deadline.into()) => {
                    return Err(RunError::TooFewDaemons {
                        error: PlanError::NoNodes,
                        lost: self.lost_list(),
                    });
                }
            }
        }
    }

    /// Sends the scene to the plan's nodes that lack it and every configuration, and waits for
    /// each `Configured`.
    async fn establish(&mut self, next: Plan, reason: &str) -> Result<(), Halt> {
        let started = Instant::now();
        let deadline = started + self.session.opts.configure;
        let members: BTreeSet<String> = next
            .nodes
            .iter()
            .map(|n| n.node.clone())
            .chain(next.stages.iter().map(|s| s.compositor.clone()))
            .collect();
        self.just_lost.clear();
        let hash = self.hash;
        let needing: Vec<String> = next
            .nodes
            .iter()
            .map(|n| n.node.clone())
            .filter(|id| self.session.scenes.get(id) != Some(&hash))
            .collect();
        let mut offered: BTreeSet<String> = BTreeSet::new();
        for id in &needing {
            let size = self.bytes.len() as u64;
            self.send_or_lose(id, Message::SceneOffer { hash, size })
                .await;
            offered.insert(id.clone());
        }
        let mut loading: BTreeSet<String> = BTreeSet::new();
        while !offered.is_empty() || !loading.is_empty() {
            self.check_interrupted(&members)?;
            let pending: Vec<String> = offered.iter().chain(&loading).cloned().collect();
            let Some((id, m)) = self
                .wait_message(deadline, "the scene to load", &pending, &members)
                .await?
            else {
                continue;
            };
            match m {
                Message::SceneNeed { hash: h, need } if h == hash && offered.remove(&id) => {
                    if need {
                        self.send_scene(&id).await;
                        loading.insert(id);
                    } else {
                        self.session.scenes.insert(id, hash);
                    }
                }
                Message::SceneReady { hash: h, .. } if h == hash && loading.remove(&id) => {
                    self.session.scenes.insert(id, hash);
                }
                Message::Error { code, message } if pending.contains(&id) => {
                    return Err(Halt::Fatal(
                        ControlError::Remote {
                            address: self.session.address(&id),
                            id,
                            code,
                            message,
                        }
                        .into(),
                    ));
                }
                other => self.ignore(&id, other),
            }
        }
        let mut configs = Vec::new();
        for stage in &next.stages {
            let cfg = next
                .compositor_config(&stage.compositor)
                .ok_or_else(|| ControlError::UnknownDaemon(stage.compositor.clone()))?;
            configs.push((stage.compositor.clone(), Message::ConfigureCompositor(cfg)));
        }
        for node in &next.nodes {
            let cfg = next
                .node_config(&node.node)
                .ok_or_else(|| ControlError::UnknownDaemon(node.node.clone()))?;
            configs.push((node.node.clone(), Message::ConfigureNode(cfg)));
        }
        self.session.sink_geometry.send_replace(SinkGeometry {
            epoch: next.epoch,
            width: next.width,
            height: next.height,
            band_height: next.band_height,
        });
        let mut waiting: BTreeSet<String> = BTreeSet::new();
        for (id, msg) in configs {
            self.send_or_lose(&id, msg).await;
            waiting.insert(id);
        }
        while !waiting.is_empty() {
            self.check_interrupted(&members)?;
            let pending: Vec<String> = waiting.iter().cloned().collect();
            let Some((id, m)) = self
                .wait_message(deadline, "configurations to be applied", &pending, &members)
                .await?
            else {
                continue;
            };
            match m {
                Message::Configured { epoch } if epoch == next.epoch => {
                    waiting.remove(&id);
                }
                Message::Error { code, message }
                    if waiting.contains(&id) && refuses_configuration(code, &message) =>
                {
                    return Err(Halt::Fatal(
                        ControlError::Remote {
                            address: self.session.address(&id),
                            id,
                            code,
                            message,
                        }
                        .into(),
                    ));
                }
                other => self.ignore(&id, other),
            }
        }
        let moved = self.plan.as_ref().map_or(0, |p| lights_moved(p, &next));
        let record = EpochRecord {
            epoch: next.epoch,
            reason: reason.to_string(),
            at: Instant::now(),
            configure: started.elapsed(),
            nodes: next.nodes.len(),
            stages: next.stages.len(),
            k: next.k,
            lights_moved: moved,
        };
        tracing::info!(
            epoch = next.epoch,
            nodes = record.nodes,
            stages = record.stages,
            k = record.k,
            lights_moved = moved,
            configure_ms = record.configure.as_millis() as u64,
            "plan epoch configured ({reason})"
        );
        self.summary.epochs.push(record);
        self.participants = next
            .stages
            .iter()
            .map(|s| s.compositor.clone())
            .chain(next.nodes.iter().map(|n| n.node.clone()))
            .collect();
        self.summary.plan = Some(next.clone());
        self.plan = Some(next);
        self.established_at = Instant::now();
        Ok(())
    }

    fn check_interrupted(&self, members: &BTreeSet<String>) -> Result<(), Halt> {
        if self.just_lost.iter().any(|id| members.contains(id)) {
            Err(Halt::Interrupted)
        } else {
            Ok(())
        }
    }

    fn ignore(&mut self, id: &str, m: Message) {
        match m {
            Message::Error { code, message } => tracing::warn!(daemon = %id, ?code, "{message}"),
            other => tracing::debug!(daemon = %id, "ignored while configuring: {other:?}"),
        }
    }

    async fn send_or_lose(&mut self, id: &str, msg: Message) {
        if let Err(e) = self.session.send(id, msg).await {
            self.lose(id, format!("cannot send to it: {e}"));
        }
    }

    async fn send_scene(&mut self, id: &str) {
        const CHUNK: usize = super::session::SCENE_CHUNK;
        let hash = self.hash;
        let total = self.bytes.len();
        let chunks = total.div_ceil(CHUNK).max(1);
        for i in 0..chunks {
            let range = (i * CHUNK).min(total)..((i + 1) * CHUNK).min(total);
            let msg = Message::SceneChunk {
                hash,
                offset: range.start as u64,
                data: self.bytes[range].to_vec(),
                last: i + 1 == chunks,
            };
            if let Err(e) = self.session.send(id, msg).await {
                self.lose(id, format!("cannot send the scene: {e}"));
                return;
            }
        }
    }

    /// The next message for the configuring phase; `None` after an event it handled itself.
    /// Daemons of the new plan that do not answer by `deadline` are lost.
    async fn wait_message(
        &mut self,
        deadline: Instant,
        what: &str,
        pending: &[String],
        members: &BTreeSet<String>,
    ) -> Result<Option<(String, Message)>, Halt> {
        let mut tick = tokio::time::interval(TICK);
        tick.reset();
        tokio::select! {
            ev = self.session.events.recv() => match ev {
                Some(ev) => Ok(self.accept(ev)?),
                None => Err(ControlError::Sink("event channel closed".into()).into()),
            },
            s = self.session.sink_events.recv() => {
                if let Some(s) = s { self.on_sink(s) }
                Ok(None)
            }
            j = self.session.joined.recv() => {
                if let Some(j) = j { self.on_join(j) }
                Ok(None)
            }
            _ = tick.tick() => {
                self.heartbeat().await;
                self.check_interrupted(members)?;
                Ok(None)
            }
            _ = tokio::time::sleep_until(deadline.into()) => {
                let after = self.session.opts.configure;
                for id in pending {
                    self.lose(id, format!("did not answer within {} s while waiting for {what}", after.as_secs()));
                }
                Err(Halt::Interrupted)
            }
        }
    }
}

/// Whether a plan error means the cluster is too small (rather than a bad scene or options).
fn too_few(e: &PlanError) -> bool {
    matches!(
        e,
        PlanError::NoNodes | PlanError::NoCompositors | PlanError::NotEnoughNodes { .. }
    )
}

/// Whether an error answering a configuration refuses it (rather than reporting on a frame of
/// the epoch before).
fn refuses_configuration(code: ErrorCode, message: &str) -> bool {
    !message.starts_with("frame ")
        && matches!(
            code,
            ErrorCode::BadConfig
                | ErrorCode::UnknownScene
                | ErrorCode::UnsupportedFormat
                | ErrorCode::UnknownOperator
                | ErrorCode::RenderFailed
        )
}

/// The daemons frame `f` waits on: those of the plan that have not reported it while everything
/// upstream of them has (nodes have nothing upstream); the last stage when every daemon reported
/// and only the image is missing.
fn waiting_on(plan: &Plan, f: &InFlight) -> Vec<String> {
    let reported = |id: &str| f.stats.iter().any(|s| s.daemon_id == id);
    let mut out: Vec<String> = plan
        .nodes
        .iter()
        .map(|n| n.node.clone())
        .filter(|id| !reported(id))
        .collect();
    for s in &plan.stages {
        if reported(&s.compositor) {
            continue;
        }
        let upstream_done = s.inputs.iter().all(|i| match &i.source {
            Source::Node(n) | Source::Stage(n) => reported(n),
        });
        if upstream_done {
            out.push(s.compositor.clone());
        }
    }
    if out.is_empty()
        && let Some(last) = plan.stages.last()
    {
        out.push(format!(
            "{} (its link to the coordinator's sink)",
            last.compositor
        ));
    }
    out
}
