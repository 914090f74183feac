//! The coordinator's event loop, in two parts: the session core (`core::Core`, no I/O: the plan,
//! the membership, the frames in flight and the phase, changed by `handle(input, now)`, which
//! queues commands) and its driver (`Live::run`: one task, the only `select!`, over frame
//! requests (a scripted path or a viewer), daemon messages and the end of their control links,
//! the sink's frames, daemons that answer a redial, the stop token and a 50 ms tick for
//! heartbeats and deadlines; it carries out the core's commands through the `Session`, whose
//! per-daemon writer tasks never let a daemon hold the loop up) (`docs/failover.md`).
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

mod core;
mod epoch;
mod frames;
mod ledger;
#[cfg(test)]
mod tests;

use super::session::{ControlError, FrameResult, Session};
use super::sink::SinkFrame;
use crate::plan::{Plan, PlanOptions};
use crate::run::RunError;
use core::{Command, Core, CoreSetup, Input, Member};
pub use frames::{SEED64_HEADROOM, seed64_scale};
use lightfold_protocol::{ErrorCode, FrameStats, WireCamera};
use lightfold_scene::moves::MeshMove;
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
/// Sink warnings (stray connections) logged at most this often.
const WARNING_EVERY: Duration = Duration::from_secs(1);

/// One frame to render: its camera (`None`: the plan's) and the light colours in effect
/// (source light → colour; a light not named has its colour in the scene, also after an earlier
/// frame gave it another).
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
    /// Render this frame above the session's quality (the live view's refinement while its
    /// viewers are idle); `None`: at the session's quality, its frame budget's where it has one.
    /// A change re-plans before the frame is sent, as a budget does.
    pub refine: Option<Refine>,
    /// The scene's lights as the viewers edited them (moved, turned, resized, resampled, added,
    /// removed; their colour and power as the base the frame's `light_colors` scale), where they
    /// differ from the session's: the loop re-plans over them before sending the frame. Nodes
    /// keep their scene (a node's lights travel in its configuration), so in walkthrough mode a
    /// node draws again only the maps of lights that changed. `None`: the session's lights.
    pub lights: Option<Arc<Vec<lightfold_scene::Light>>>,
    /// The scene this frame shows, where a viewer opened another (`None`: the session's first).
    /// A newer one than the loop's is planned from this frame on, the nodes sent it as they are
    /// sent any scene they do not hold; one the cluster cannot plan is refused
    /// (`LiveStatus::scene_refused`) and the frame shows the loop's scene. A frame of an older
    /// scene (requested before the switch) shows the current one, without its light edits or
    /// colours.
    pub scene: Option<Arc<OpenScene>>,
    /// The scene's objects as the viewers moved them (every move, by mesh of the scene the
    /// frame shows), where they differ from the session's: the loop re-plans over the moved
    /// scene before sending the frame (culling, casters and virtual point lights follow the
    /// objects). Nodes keep their scene and are sent each moved mesh's matrix in their
    /// configuration (`NodeConfig::moves`), so in walkthrough mode a node draws again only the
    /// maps a moved object may reach. `None`: the session's moves.
    pub moves: Option<Arc<Vec<MeshMove>>>,
}

/// A scene a viewer opened in a live session (`FrameSpec::scene`).
#[derive(Debug)]
pub struct OpenScene {
    /// Counts the scenes opened in the session, from 1 (0 is the one it started with).
    pub id: u64,
    /// How the viewer named it.
    pub name: String,
    pub scene: lightfold_scene::Scene,
    /// The options to plan it with (the session's, with this scene's error model).
    pub options: PlanOptions,
}

impl PartialEq for OpenScene {
    fn eq(&self, other: &OpenScene) -> bool {
        self.id == other.id
    }
}

/// The id of the scene `spec` shows (0: the session's first).
pub(super) fn scene_id(spec: &FrameSpec) -> u64 {
    spec.scene.as_ref().map_or(0, |s| s.id)
}

/// Whether two light lists are the same lights but for their colours (which frames change as
/// `FrameSpec::light_colors`, and a re-plan may have recoloured).
pub(super) fn same_lights(a: &[lightfold_scene::Light], b: &[lightfold_scene::Light]) -> bool {
    a.len() == b.len()
        && a.iter().zip(b).all(|(x, y)| {
            x.name == y.name
                && x.shape == y.shape
                && x.power.to_bits() == y.power.to_bits()
                && x.range == y.range
                && x.samples == y.samples
        })
}

/// A frame rendered above the session's quality (`docs/live-view.md` § Refinement when idle):
/// planned with no frame budget or error target, every area light at `samples_per_area_light`
/// samples (the scene's quality override; each sample carries its share of the light's power, so
/// every light's energy is kept), at `supersample` × the camera's width and height, which the
/// sink box-resolves. A refinement the planner cannot plan (a camera too large at that factor,
/// say) is dropped: the frame renders at the session's quality, and the same refinement asked
/// for again is not tried again.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Refine {
    /// Samples per area light, every area light (0: the scene's counts).
    pub samples_per_area_light: u32,
    /// Antialiasing factor (`PlanOptions::supersample`); never below the session's.
    pub supersample: u32,
}

impl std::fmt::Display for Refine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.samples_per_area_light > 0 {
            write!(
                f,
                "{} samples per area light, ",
                self.samples_per_area_light
            )?;
        }
        write!(f, "antialiasing {}×", self.supersample.max(1))
    }
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
    /// Sort-first tiles: the rows of each tile at the end of the last epoch that had tiles, and
    /// the balancing steps taken over the run (`tiles::TileBalancer`).
    pub tile_rows: Vec<[u32; 2]>,
    pub tile_steps: u64,
}

/// Light colours by source light: (light, linear colour).
pub(super) type LightColors = Vec<(u32, [f32; 3])>;

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
    /// The lights the loop put back after an edit it could not plan (`FrameSpec::lights`),
    /// numbered from 1: whoever steers should take them as the lights again.
    pub lights_put_back: Option<(u64, Arc<Vec<lightfold_scene::Light>>)>,
    /// Light colours the loop put back after daemons refused the plan they needed (light →
    /// colour), numbered from 1: whoever steers should show them again.
    pub colors_put_back: Option<(u64, LightColors)>,
    /// The object moves the loop put back after a move it could not plan or make
    /// (`FrameSpec::moves`), numbered from 1: whoever steers should take them as the moves again.
    pub moves_put_back: Option<(u64, Arc<Vec<MeshMove>>)>,
    /// The id of the scene frames show now (`OpenScene::id`; 0: the session's first).
    pub scene: u64,
    /// A scene a viewer opened that the loop could not plan, and why: whoever steers should go
    /// back to the scene it had.
    pub scene_refused: Option<(u64, String)>,
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

/// The settings of an epoch every daemon took: what a refused configuration goes back to.
#[derive(Debug, Clone)]
struct Settings {
    epoch: u64,
    /// Each scene light's colour.
    colors: Vec<[f32; 3]>,
    opts: PlanOptions,
    refine: Option<Refine>,
    /// The scene's lights (`FrameSpec::lights`).
    lights: Vec<lightfold_scene::Light>,
    /// The objects' moves (`FrameSpec::moves`).
    moves: Arc<Vec<MeshMove>>,
}

/// Settings daemons refused: frame requests asking for them again are sent without them.
#[derive(Debug, Default)]
struct Refused {
    /// (scene light, colour) pairs.
    colors: Vec<(u32, [f32; 3])>,
    /// A frame budget (`FrameSpec::frame_budget_us`).
    budget: Option<Option<u64>>,
    /// A refinement (`FrameSpec::refine`).
    refine: Option<Option<Refine>>,
    /// An edit of the lights (`FrameSpec::lights`).
    lights: Option<Arc<Vec<lightfold_scene::Light>>>,
    /// A scene opened (`FrameSpec::scene`, by id): frames showing it show the loop's scene.
    scene: Option<u64>,
    /// Object moves (`FrameSpec::moves`).
    moves: Option<Arc<Vec<MeshMove>>>,
}

impl Refused {
    /// Takes out of `spec` what was refused: those lights keep their colour, the budget stays,
    /// and the refinement stays `current`.
    fn strip(&self, spec: &mut FrameSpec, current: Option<Refine>) {
        spec.light_colors.retain(|(l, c)| {
            !self
                .colors
                .iter()
                .any(|(rl, rc)| rl == l && rc.map(f32::to_bits) == c.map(f32::to_bits))
        });
        if spec.frame_budget_us.is_some() && spec.frame_budget_us == self.budget {
            spec.frame_budget_us = None;
        }
        if self.refine == Some(spec.refine) {
            spec.refine = current;
        }
        if let (Some(asked), Some(refused)) = (&spec.lights, &self.lights)
            && same_lights(asked, refused)
        {
            spec.lights = None;
        }
        if spec.moves.is_some() && spec.moves == self.moves {
            spec.moves = None;
        }
        if self.scene.is_some_and(|id| scene_id(spec) == id) {
            spec.scene = None;
            spec.lights = None;
            spec.moves = None;
            spec.light_colors.clear();
        }
    }
}

/// The scene and options a session plans from, for `cluster`: partitions resolved once (automatic
/// ones from the nodes' memory), meshes too large for a part split into chunks first, and the
/// camera at `--aa`'s factor (everything the cluster renders is N × the camera's size; the sink
/// resolves).
pub(super) fn prepare(
    scene: &lightfold_scene::Scene,
    cluster: &crate::plan::ClusterSpec,
    opts: &PlanOptions,
) -> Result<(lightfold_scene::Scene, PlanOptions), RunError> {
    let opts = PlanOptions {
        partitions: crate::plan::partitions_for(scene, cluster, opts),
        ..opts.clone()
    };
    let mut scene = crate::plan::scene_for(scene, cluster, &opts).into_owned();
    scene.camera = scene.camera.supersampled(opts.supersample)?;
    Ok((scene, opts))
}

/// The epochs one run may use (`Session::reserve_epochs`).
const EPOCHS_PER_RUN: u64 = 1 << 15;

/// The loop over one session: the core and the driver that feeds it.
pub struct Live<'s> {
    session: &'s mut Session,
    core: Core,
    /// One tick for every phase, so heartbeats go out however busy the event channels are.
    tick: tokio::time::Interval,
    /// Cancelled when the run is to stop (`stop_on`).
    stop: Option<CancellationToken>,
    pub summary: LiveSummary,
}

impl std::fmt::Debug for Live<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.core.fmt(f)
    }
}

impl<'s> Live<'s> {
    pub fn new(
        session: &'s mut Session,
        scene: &lightfold_scene::Scene,
        opts: &PlanOptions,
    ) -> Result<Live<'s>, RunError> {
        // `--aa N`: everything the cluster renders is N × the camera's size; the sink resolves.
        // Partitions resolved once for the run (automatic ones from the nodes' memory), and
        // meshes too large for a part split into chunks first.
        let cluster = crate::run::cluster_spec(session);
        let given = scene.meshes.len();
        let (scene, opts) = prepare(scene, &cluster, opts)?;
        let chunked = scene.meshes.len() != given;
        let now = Instant::now();
        let members = session
            .daemons
            .iter()
            .map(|(id, d)| {
                let m = Member::new(d.address.clone(), d.caps.clone(), d.link, now);
                (id.clone(), m)
            })
            .collect();
        let core = Core::new(CoreSetup {
            scene,
            chunked,
            opts,
            control: session.opts,
            members,
            // Daemons not reached while connecting are lost from the start (and redialled).
            unreachable: session.unreachable.clone(),
            sink_address: session.sink_address.clone(),
            base: session.base,
            first_epoch: session.reserve_epochs(EPOCHS_PER_RUN),
        })?;
        Ok(Live {
            session,
            core,
            tick: {
                let mut t = tokio::time::interval(TICK);
                t.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
                t
            },
            stop: None,
            summary: LiveSummary::default(),
        })
    }

    /// A watcher of the loop's state (plan, epochs, incidents, lost daemons, notices).
    pub fn observe(&self) -> watch::Receiver<LiveStatus> {
        self.core.observe()
    }

    /// The token that stops the run (Ctrl-C): once it is cancelled, daemons whose links end are
    /// stopping with the run, not lost (see the module docs). The caller still closes the
    /// request channel to stop new frames.
    pub fn stop_on(&mut self, stop: CancellationToken) {
        self.stop = Some(stop);
    }

    /// The plan in use.
    pub fn plan(&self) -> Option<&Plan> {
        self.core.plan()
    }

    /// Plans, configures and renders every frame `requests` yields until it closes, handing
    /// each finished frame to `on_frame` in order. On an error the frames delivered so far have
    /// been handed over and `summary` says what happened.
    pub async fn run(
        &mut self,
        requests: mpsc::Receiver<FrameSpec>,
        on_frame: impl FnMut(FrameResult),
    ) -> Result<(), RunError> {
        let result = self.drive(requests, on_frame).await;
        self.summary = std::mem::take(&mut self.core.summary);
        result
    }

    async fn drive(
        &mut self,
        mut requests: mpsc::Receiver<FrameSpec>,
        mut on_frame: impl FnMut(FrameResult),
    ) -> Result<(), RunError> {
        self.core.start(Instant::now())?;
        let stop = self.stop.clone().unwrap_or_default();
        let mut stop_seen = false;
        loop {
            self.execute(&mut on_frame)?;
            if self.core.finished() {
                return Ok(());
            }
            let want = self.core.wants_requests();
            let input = tokio::select! {
                () = stop.cancelled(), if !stop_seen && self.stop.is_some() => {
                    stop_seen = true;
                    Input::Stop
                }
                ev = self.session.events.recv() => match ev {
                    Some((id, link, at, msg)) => Input::Daemon { id, link, at, msg },
                    None => return Err(ControlError::Sink("event channel closed".into()).into()),
                },
                s = self.session.sink_events.recv() => match s {
                    Some(s) => Input::Sink(s),
                    None => return Err(ControlError::Sink("the sink stopped".into()).into()),
                },
                j = self.session.joined.recv() => match j {
                    Some(j) => {
                        let dialled = j.entry.address.clone();
                        let caps = j.caps.clone();
                        let (id, link) = self.session.admit(j);
                        Input::Joined { id, dialled, caps, link }
                    }
                    None => continue,
                },
                spec = requests.recv(), if want => match spec {
                    Some(spec) => Input::Request(spec),
                    None => Input::RequestsClosed,
                },
                _ = self.tick.tick() => {
                    // Every message already read goes to the core before it judges silence.
                    while let Ok((id, link, at, msg)) = self.session.events.try_recv() {
                        self.core.handle(Input::Daemon { id, link, at, msg }, Instant::now())?;
                        self.execute(&mut on_frame)?;
                    }
                    Input::Tick
                }
            };
            self.core.handle(input, Instant::now())?;
        }
    }

    /// Carries out the core's commands. None waits: sends are queued for the daemons' writer
    /// tasks, scenes go out from tasks of their own.
    fn execute(&mut self, on_frame: &mut impl FnMut(FrameResult)) -> Result<(), RunError> {
        while let Some(c) = self.core.poll_command() {
            match c {
                Command::Send { to, msg } => {
                    if let Err(e) = self.session.send(&to, msg) {
                        let why = e.to_string();
                        self.core
                            .handle(Input::Unsendable { id: to, why }, Instant::now())?;
                    }
                }
                Command::SendScene { to, hash, bytes } => self.session.send_scene(&to, hash, bytes),
                Command::Drop { id } => {
                    self.session.lose(&id);
                }
                Command::SinkGeometry(g) => {
                    self.session.sink_geometry.send_replace(g);
                }
                Command::Deliver(r) => on_frame(r),
            }
        }
        Ok(())
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

#[cfg(test)]
mod verdict_tests {
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
