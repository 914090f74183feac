//! The session core driven directly, on virtual time, with no socket: a simulated cluster
//! answers the core's commands the way the daemons' protocol does (offers, scene transfers,
//! configurations, frame reports, the sink's images, pongs) with a delay, and the tests kill,
//! restart, stall and refuse. Every frame requested must be delivered exactly once, in order.

use super::core::{Command, Core, CoreSetup, Input, Member, Phase};
use super::{FrameSpec, IncidentKind};
use crate::control::session::ControlOptions;
use crate::control::sink::{SinkEvent, SinkFrame};
use crate::plan::{MapSizing, PlanOptions};
use crate::run::RunError;
use lightfold_net::NetError;
use lightfold_protocol::{Capabilities, ErrorCode, FrameStats, Message, Role};
use proptest::prelude::*;
use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;
use std::time::{Duration, Instant};

const TICK: Duration = super::TICK;
/// How long a simulated daemon takes to answer, and a lost one to answer its redial.
const ANSWER: Duration = Duration::from_millis(5);
const REDIAL: Duration = Duration::from_millis(500);

fn caps(id: &str, role: Role) -> Capabilities {
    Capabilities {
        advertise: format!("{id}:7300"),
        adapter: "sim".into(),
        backend: "sim".into(),
        // Two lights a node: the 4 samples of the scene take two nodes.
        max_lights: if role == Role::Node { 2 } else { 0 },
        max_texture_size: 4096,
        threads: 1,
        ..Capabilities::unmeasured(role, id)
    }
}

#[derive(Debug)]
struct SimDaemon {
    role: Role,
    /// Running (not killed).
    up: bool,
    /// Stopped (SIGSTOP): reads nothing, answers nothing, its socket stays open.
    mute: bool,
    link: u64,
    /// The core dropped its link: it answers a redial once up and not mute.
    dropped: bool,
    rejoin_scheduled: bool,
    scene: Option<[u8; 32]>,
    /// Epochs whose configuration it refuses (its own checks say no).
    refuse: BTreeSet<u64>,
    /// Refuse the next configuration it is sent.
    refuse_next: bool,
    /// What reached it while it was stopped, read when it resumes.
    inbox: Vec<Message>,
}

/// Light colours as a frame request carries them (stage input or light → colour).
type Colours = Vec<(u32, [f32; 3])>;

/// A simulated cluster around one core.
struct Sim {
    core: Core,
    now: Instant,
    next_tick: Instant,
    daemons: BTreeMap<String, SimDaemon>,
    /// Inputs due at a time (ties in order of scheduling).
    due: BTreeMap<(Instant, u64), Input>,
    seq: u64,
    delivered: Vec<u64>,
    /// Per epoch, the daemons configured for it; per (epoch, wire frame), those that got it.
    configured: BTreeMap<u64, BTreeSet<String>>,
    got: BTreeMap<(u64, u64), BTreeSet<String>>,
    /// The newest configuration each node was sent.
    node_configs: BTreeMap<String, lightfold_protocol::NodeConfig>,
    /// Pings sent, per daemon (heartbeats while the loop configures).
    pings: BTreeMap<String, u32>,
    requested: u64,
    /// Per wire frame, the light colours each daemon was sent with it.
    colours: BTreeMap<u64, Vec<(String, Colours)>>,
    /// Per wire frame, the camera size its nodes were sent; the sink's newest antialiasing factor.
    sizes: BTreeMap<u64, (u32, u32)>,
    sink_supersample: u32,
    error: Option<RunError>,
    /// Per tiled node, the rows it renders now (its configuration's, moved by `FrameParams`),
    /// and every move it was sent: (wire frame, node, rows).
    rows: BTreeMap<String, [u32; 2]>,
    moved_rows: Vec<(u64, String, [u32; 2])>,
    /// The rows each tiled node rendered its first frame of each epoch with.
    first_rows: BTreeMap<(u64, String), [u32; 2]>,
    /// A tiled node reports this many µs of eye pass per row at `y` (none: 0).
    row_cost: Option<fn(u32) -> u64>,
}

fn control() -> ControlOptions {
    ControlOptions {
        configure: Duration::from_secs(20),
        frame: Duration::from_secs(20),
        wait_for_daemons: Duration::from_secs(120),
        ..ControlOptions::default()
    }
}

impl Sim {
    /// `nodes` render nodes and `compositors` compositors; those in `unreached` were not reached
    /// at the start (lost, redialled). Started: the first plan is being configured.
    fn new(nodes: usize, compositors: usize, unreached: &[&str]) -> Sim {
        let mut sim = Sim::build(nodes, compositors, unreached);
        sim.start();
        sim
    }

    fn start(&mut self) {
        self.core.start(self.now).unwrap();
        self.pump();
    }

    fn build(nodes: usize, compositors: usize, unreached: &[&str]) -> Sim {
        Sim::build_with(nodes, compositors, unreached, |_| {}, 4)
    }

    /// [`Sim::build`] with every daemon's capabilities changed by `tweak`, planning `k` lights
    /// a node.
    fn build_with(
        nodes: usize,
        compositors: usize,
        unreached: &[&str],
        tweak: impl Fn(&mut Capabilities),
        k: u32,
    ) -> Sim {
        let mut scene = lightfold_scene::builtin("cornell").unwrap();
        scene.quality.samples_per_area_light = Some(4);
        scene.camera.width = 64;
        scene.camera.height = 48;
        // A pure-red light: a node colour with zero channels, which any colour with green or
        // blue in it splits (a re-plan over the recoloured scene).
        scene.lights[0].color = [1.0, 0.0, 0.0];
        let opts = PlanOptions {
            map_sizing: MapSizing::Fixed(256),
            lights_per_node: k,
            ..PlanOptions::default()
        };
        let now = Instant::now();
        let mut daemons = BTreeMap::new();
        let ids = (0..nodes)
            .map(|i| (format!("node-{i}"), Role::Node))
            .chain((0..compositors).map(|i| (format!("comp-{i}"), Role::Compositor)));
        let mut members = BTreeMap::new();
        let mut unreachable = Vec::new();
        for (id, role) in ids {
            let reached = !unreached.contains(&id.as_str());
            if reached {
                let mut c = caps(&id, role);
                tweak(&mut c);
                let m = Member::new(format!("{id}:7300"), c, 1, now);
                members.insert(id.clone(), m);
            } else {
                unreachable.push((format!("{id}:7300"), "not reached".to_string()));
            }
            daemons.insert(
                id,
                SimDaemon {
                    role,
                    up: true,
                    mute: false,
                    link: 1,
                    dropped: !reached,
                    rejoin_scheduled: false,
                    scene: None,
                    refuse: BTreeSet::new(),
                    refuse_next: false,
                    inbox: Vec::new(),
                },
            );
        }
        let core = Core::new(CoreSetup {
            scene,
            chunked: false,
            opts,
            control: control(),
            members,
            unreachable,
            sink_address: "sink:7400".into(),
            base: 1 << 20,
            first_epoch: 100,
        })
        .unwrap();
        let mut sim = Sim {
            core,
            now,
            next_tick: now + TICK,
            daemons,
            due: BTreeMap::new(),
            seq: 0,
            delivered: Vec::new(),
            configured: BTreeMap::new(),
            node_configs: BTreeMap::new(),
            got: BTreeMap::new(),
            pings: BTreeMap::new(),
            requested: 0,
            colours: BTreeMap::new(),
            sizes: BTreeMap::new(),
            sink_supersample: 0,
            error: None,
            rows: BTreeMap::new(),
            moved_rows: Vec::new(),
            first_rows: BTreeMap::new(),
            row_cost: None,
        };
        let ids: Vec<String> = sim.daemons.keys().cloned().collect();
        for id in ids {
            sim.maybe_rejoin(&id, Duration::ZERO);
        }
        sim
    }

    fn at(&mut self, after: Duration, input: Input) {
        self.seq += 1;
        self.due.insert((self.now + after, self.seq), input);
    }

    fn answer(&mut self, id: &str, msg: Message) {
        let link = self.daemons[id].link;
        let input = Input::Daemon {
            id: id.to_string(),
            link,
            at: self.now + ANSWER,
            msg: Ok(msg),
        };
        self.at(ANSWER, input);
    }

    /// A dropped daemon that is up answers its redial.
    fn maybe_rejoin(&mut self, id: &str, after: Duration) {
        let d = self.daemons.get_mut(id).unwrap();
        if !(d.dropped && d.up && !d.mute) || d.rejoin_scheduled {
            return;
        }
        d.rejoin_scheduled = true;
        d.link += 1;
        d.scene = None;
        d.inbox.clear();
        let (link, role) = (d.link, d.role);
        let input = Input::Joined {
            id: id.to_string(),
            dialled: format!("{id}:7300"),
            caps: caps(id, role),
            link,
        };
        self.at(after, input);
    }

    /// Carries out the core's commands as the cluster would.
    fn pump(&mut self) {
        while let Some(c) = self.core.poll_command() {
            match c {
                Command::Send { to, msg } => self.daemon_gets(&to, msg),
                Command::SendScene { to, hash, .. } => {
                    let last = Message::SceneChunk {
                        hash,
                        offset: 0,
                        data: Vec::new(),
                        last: true,
                    };
                    self.daemon_gets(&to, last);
                }
                Command::Drop { id } => {
                    let d = self.daemons.get_mut(&id).unwrap();
                    d.dropped = true;
                    d.rejoin_scheduled = false;
                    self.maybe_rejoin(&id, REDIAL);
                }
                Command::SinkGeometry(g) => self.sink_supersample = g.supersample,
                Command::Deliver(r) => self.delivered.push(r.frame),
            }
        }
    }

    fn daemon_gets(&mut self, to: &str, msg: Message) {
        let d = self.daemons.get_mut(to).unwrap();
        if d.dropped || !d.up {
            return; // a killed daemon's link end was reported when it died
        }
        if d.mute {
            d.inbox.push(msg);
            return;
        }
        if let Message::ConfigureNode(c) = &msg {
            self.node_configs.insert(to.to_string(), c.clone());
            match c.rows {
                Some(r) => self.rows.insert(to.to_string(), r),
                None => self.rows.remove(to),
            };
        }
        let d = &self.daemons[to];
        match msg {
            Message::SceneChunk { hash, .. } => {
                self.daemons.get_mut(to).unwrap().scene = Some(hash);
                self.answer(to, Message::SceneReady { hash, triangles: 1 });
            }
            Message::Ping { seq } => {
                *self.pings.entry(to.to_string()).or_default() += 1;
                self.answer(to, Message::Pong { seq });
            }
            Message::SceneOffer { hash, .. } => {
                let need = d.scene != Some(hash);
                self.answer(to, Message::SceneNeed { hash, need });
            }
            Message::ConfigureNode(lightfold_protocol::NodeConfig { epoch, .. })
            | Message::ConfigureCompositor(lightfold_protocol::CompositorConfig {
                epoch, ..
            }) => {
                let d = self.daemons.get_mut(to).unwrap();
                if d.refuse.contains(&epoch) || std::mem::take(&mut d.refuse_next) {
                    let refusal = Message::epoch_error(
                        epoch,
                        ErrorCode::BadConfig,
                        "node colour [1.0, 0.0, 0.0] must be finite and positive",
                    );
                    self.answer(to, refusal);
                } else {
                    self.configured
                        .entry(epoch)
                        .or_default()
                        .insert(to.to_string());
                    self.answer(to, Message::Configured { epoch });
                }
            }
            Message::RenderFrame {
                epoch,
                frame,
                params,
                camera,
            } => {
                if let Some(c) = camera {
                    self.sizes.insert(frame, (c.width, c.height));
                }
                if let Some(r) = params.rows {
                    self.rows.insert(to.to_string(), r);
                    self.moved_rows.push((frame, to.to_string(), r));
                }
                if let Some(&r) = self.rows.get(to) {
                    self.first_rows.entry((epoch, to.to_string())).or_insert(r);
                }
                let eye_us = match (self.row_cost, self.rows.get(to)) {
                    (Some(cost), Some(r)) => (r[0]..r[1]).map(cost).sum(),
                    _ => 0,
                };
                let sent = (to.to_string(), params.colors);
                self.colours.entry(frame).or_default().push(sent);
                let stats = FrameStats {
                    epoch,
                    frame,
                    daemon_id: to.to_string(),
                    eye_us,
                    ..FrameStats::default()
                };
                self.answer(to, Message::FrameDone(stats));
                let got = self.got.entry((epoch, frame)).or_default();
                got.insert(to.to_string());
                if self.configured.get(&epoch) == Some(got) {
                    let image = SinkFrame {
                        epoch,
                        frame,
                        image: lightfold_scene::Image::new(1, 1, 3),
                        bytes: 12,
                        received_at: self.now,
                    };
                    self.at(ANSWER * 2, Input::Sink(SinkEvent::Frame(image)));
                }
            }
            _ => {}
        }
    }

    fn input(&mut self, input: Input) {
        if self.error.is_some() {
            return;
        }
        if let Err(e) = self.core.handle(input, self.now) {
            self.error = Some(e);
        }
        self.pump();
    }

    /// Runs the cluster for `span` of virtual time, requesting frames as the core takes them
    /// (`spec` makes request i).
    fn run(&mut self, span: Duration, frames: u64, spec: &mut impl FnMut(u64) -> FrameSpec) {
        let end = self.now + span;
        while self.now < end && self.error.is_none() && !self.core.finished() {
            while self.core.wants_requests() && self.requested < frames {
                self.requested += 1;
                let s = spec(self.requested);
                self.input(Input::Request(s));
            }
            let next_due = self.due.keys().next().copied();
            match next_due {
                Some((t, seq)) if t <= self.next_tick => {
                    self.now = self.now.max(t);
                    let input = self.due.remove(&(t, seq)).unwrap();
                    // Inputs of a link the daemon no longer has never arrive.
                    if let Input::Daemon { id, link, .. } = &input
                        && self.daemons[id].link != *link
                    {
                        continue;
                    }
                    // A redial is answered only by a daemon that is up and not stopped.
                    if let Input::Joined { id, .. } = &input {
                        let d = self.daemons.get_mut(id).unwrap();
                        d.rejoin_scheduled = false;
                        if !d.up || d.mute {
                            continue;
                        }
                        d.dropped = false;
                    }
                    self.input(input);
                }
                _ => {
                    self.now = self.next_tick;
                    self.next_tick += TICK;
                    self.input(Input::Tick);
                }
            }
        }
    }

    fn run_plain(&mut self, span: Duration, frames: u64) {
        self.run(span, frames, &mut |_| FrameSpec::default());
    }

    /// SIGKILL: the link ends at once.
    fn kill(&mut self, id: &str) {
        let d = self.daemons.get_mut(id).unwrap();
        d.up = false;
        d.scene = None;
        d.inbox.clear();
        let link = d.link;
        let input = Input::Daemon {
            id: id.to_string(),
            link,
            at: self.now,
            msg: Err(NetError::Closed {
                addr: format!("{id}:7300"),
            }),
        };
        self.at(Duration::ZERO, input);
    }

    /// SIGCONT: it reads what reached it meanwhile.
    fn resume(&mut self, id: &str) {
        let d = self.daemons.get_mut(id).unwrap();
        d.mute = false;
        for m in std::mem::take(&mut d.inbox) {
            self.daemon_gets(id, m);
        }
        self.pump();
        self.maybe_rejoin(id, REDIAL);
    }

    fn restart(&mut self, id: &str) {
        self.daemons.get_mut(id).unwrap().up = true;
        self.maybe_rejoin(id, REDIAL);
    }

    fn epoch(&self) -> u64 {
        self.core.plan().map_or(0, |p| p.epoch)
    }

    fn in_plan(&self, id: &str) -> bool {
        self.core.participants.iter().any(|p| p == id)
    }

    fn assert_all_delivered(&self, frames: u64) {
        assert!(self.error.is_none(), "the session ended: {:?}", self.error);
        let want: Vec<u64> = (1..=frames).collect();
        assert_eq!(self.delivered, want, "every frame once, in order");
    }
}

#[test]
fn the_simulated_cluster_renders_every_frame() {
    let mut sim = Sim::new(3, 2, &[]);
    sim.run_plain(Duration::from_secs(5), 20);
    sim.input(Input::RequestsClosed);
    sim.run_plain(Duration::from_secs(1), 20);
    sim.assert_all_delivered(20);
    assert!(sim.core.finished());
    assert_eq!(sim.core.summary.epochs.len(), 1);
}

/// Render nodes that report one GPU are planned as one node; when it is lost, another node of
/// that GPU takes all the lights and no frame is lost.
#[test]
fn nodes_sharing_a_gpu_run_as_one_and_fail_over_to_another() {
    // K = 2: the ordinary plan would run two nodes, one after the other on the GPU.
    let mut sim = Sim::build_with(
        3,
        2,
        &[],
        |c| {
            if c.role == Role::Node {
                c.max_lights = 8;
                c.device = "host/0000:01:00.0/sim".into();
            }
        },
        2,
    );
    sim.start();
    sim.run_plain(Duration::from_secs(3), 6);
    let plan = sim.core.plan().expect("planned").clone();
    assert_eq!(plan.nodes.len(), 1, "one node for the shared GPU");
    assert!(plan.shared_devices.is_some());
    let first = plan.nodes[0].node.clone();
    sim.kill(&first);
    sim.run_plain(Duration::from_secs(5), 12);
    let after = sim.core.plan().expect("re-planned");
    assert_eq!(after.nodes.len(), 1);
    assert_ne!(
        after.nodes[0].node, first,
        "another node of the GPU took over"
    );
    sim.input(Input::RequestsClosed);
    sim.run_plain(Duration::from_secs(2), 12);
    sim.assert_all_delivered(12);
}

#[test]
fn a_stale_timeout_after_a_re_plan_does_not_re_plan() {
    let mut sim = Sim::new(3, 3, &[]);
    sim.run_plain(Duration::from_secs(1), 1000);
    let old = sim.epoch();
    let old_frame = sim.core.base + 3;
    // A node dies: one re-plan.
    sim.kill("node-1");
    sim.run_plain(Duration::from_secs(1), 1000);
    let new = sim.epoch();
    assert!(new > old, "the loss re-planned");
    let epochs = sim.core.summary.epochs.len();
    // 30 s later, a compositor reports the old epoch's frame timed out.
    sim.answer_error("comp-0", ErrorCode::Timeout, old, Some(old_frame));
    sim.answer_error("comp-1", ErrorCode::PeerLost, old, None);
    sim.run_plain(Duration::from_secs(2), 1000);
    assert_eq!(
        sim.core.summary.epochs.len(),
        epochs,
        "no re-plan for history"
    );
    assert_eq!(sim.epoch(), new);
    // Negative control: the same report about the current epoch's frame in flight re-plans
    // (a stage of the plan holds the frames up meanwhile, for less than the heartbeat timeout).
    let stage = sim.core.participants[0].clone();
    sim.daemons.get_mut(&stage).unwrap().mute = true;
    sim.run_plain(Duration::from_millis(200), 1000);
    let inflight = sim.core.frames.inflight.first().map(|f| f.wire);
    assert!(inflight.is_some());
    sim.answer_error(&stage, ErrorCode::Timeout, new, inflight);
    sim.run_plain(Duration::from_millis(500), 1000);
    sim.resume(&stage);
    sim.run_plain(Duration::from_secs(1), 1000);
    assert_eq!(sim.core.summary.epochs.len(), epochs + 1);
    let last = &sim.core.summary.epochs[epochs].reason;
    assert!(
        last.contains(&format!("{stage} reported Timeout")),
        "{last}"
    );
    assert!(sim.error.is_none());
    let n = sim.delivered.len() as u64;
    assert_eq!(sim.delivered, (1..=n).collect::<Vec<_>>());
}

impl Sim {
    fn answer_error(&mut self, id: &str, code: ErrorCode, epoch: u64, frame: Option<u64>) {
        let msg = match frame {
            Some(f) => Message::frame_error(epoch, f, code, "input 0 delivered no band"),
            None => Message::epoch_error(epoch, code, "no link to the downstream stage"),
        };
        self.answer(id, msg);
    }
}

#[test]
fn a_refused_configuration_does_not_end_the_session() {
    let mut sim = Sim::new(3, 2, &[]);
    sim.run_plain(Duration::from_secs(1), 10);
    // Frame 11 sets a budget; node-0 refuses the epoch planned for it.
    sim.daemons.get_mut("node-0").unwrap().refuse_next = true;
    let mut spec = |i: u64| FrameSpec {
        frame_budget_us: (i == 11).then_some(Some(20_000)),
        ..FrameSpec::default()
    };
    let status = sim.core.observe();
    sim.run(Duration::from_secs(5), 30, &mut spec);
    sim.input(Input::RequestsClosed);
    sim.run_plain(Duration::from_secs(1), 30);
    sim.assert_all_delivered(30);
    // The budget went back; the viewers were told.
    assert_eq!(sim.core.opts.frame_budget_us, None);
    let notice = status.borrow().notice.clone().unwrap().1;
    assert!(notice.contains("refused"), "{notice}");
    assert!(
        sim.in_plan("node-0"),
        "the daemon stays: the change went back"
    );
    // A daemon that refuses under unchanged settings is left out, and the session goes on.
    let mut sim = Sim::new(3, 2, &[]);
    sim.run_plain(Duration::from_secs(1), 40);
    let epoch = sim.epoch();
    sim.daemons
        .get_mut("node-2")
        .unwrap()
        .refuse
        .extend(epoch + 1..epoch + 100);
    sim.kill("comp-1");
    sim.run_plain(Duration::from_secs(5), 40);
    sim.input(Input::RequestsClosed);
    sim.run_plain(Duration::from_secs(1), 40);
    sim.assert_all_delivered(40);
    assert!(!sim.in_plan("node-2"));
    // Negative control: a refusal of the very first plan ends the run (nothing to go back to).
    let mut sim = Sim::build(3, 2, &[]);
    let first = sim.core.first_epoch + 1;
    sim.daemons.get_mut("node-1").unwrap().refuse.insert(first);
    sim.start();
    sim.run_plain(Duration::from_secs(1), 5);
    assert!(
        matches!(sim.error, Some(RunError::Control(_))),
        "{:?}",
        sim.error
    );
}

#[test]
fn a_loss_during_configure_plans_again_without_it() {
    let mut sim = Sim::new(3, 2, &[]);
    assert!(matches!(sim.core.phase, Phase::Configuring(_)));
    // node-2 dies before it answers anything of the first plan.
    sim.due
        .retain(|_, i| !matches!(i, Input::Daemon { id, .. } if id == "node-1"));
    sim.kill("node-1");
    sim.daemons.get_mut("node-1").unwrap().up = false;
    sim.run_plain(Duration::from_secs(2), 20);
    assert!(sim.epoch() > sim.core.first_epoch + 1, "planned again");
    assert!(!sim.in_plan("node-1"));
    sim.input(Input::RequestsClosed);
    sim.run_plain(Duration::from_secs(2), 20);
    sim.assert_all_delivered(20);
    let lost = sim.core.summary.incidents.iter().any(|i| {
        i.daemon == "node-1"
            && matches!(&i.kind, IncidentKind::Lost { reason } if reason.contains("link ended"))
    });
    assert!(lost);
}

#[test]
fn a_daemon_joining_late_is_folded_in() {
    let mut sim = Sim::new(3, 2, &["node-2"]);
    // Not reached at the start: lost under its address, and the plan does without it.
    assert!(sim.core.lost.contains_key("node-2:7300"));
    sim.daemons.get_mut("node-2").unwrap().up = false;
    sim.run_plain(Duration::from_secs(1), 60);
    assert!(!sim.in_plan("node-2"));
    let epochs = sim.core.summary.epochs.len();
    sim.restart("node-2");
    sim.run_plain(Duration::from_secs(2), 60);
    assert!(sim.core.members.contains_key("node-2"));
    assert_eq!(sim.core.summary.epochs.len(), epochs + 1);
    let last = &sim.core.summary.epochs[epochs].reason;
    assert!(
        last.contains("node-2 rejoined"),
        "folded into the next epoch: {last}"
    );
    assert!(sim.core.lost.is_empty(), "{:?}", sim.core.lost);
    sim.input(Input::RequestsClosed);
    sim.run_plain(Duration::from_secs(2), 60);
    sim.assert_all_delivered(60);
}

#[test]
fn heartbeats_and_requests_go_on_while_a_scene_loads() {
    let mut sim = Sim::new(3, 2, &[]);
    // node-1 takes 3 s over its scene: nothing waits on it but the epoch.
    let slow: Vec<(Instant, u64)> = sim
        .due
        .iter()
        .filter(|(_, i)| matches!(i, Input::Daemon { id, msg: Ok(Message::SceneNeed { .. }), .. } if id == "node-1"))
        .map(|(k, _)| *k)
        .collect();
    assert_eq!(slow.len(), 1, "node-1 was offered the scene");
    let input = sim.due.remove(&slow[0]).unwrap();
    let (t, seq) = slow[0];
    sim.due.insert((t + Duration::from_secs(3), seq), input);
    sim.pings.clear();
    sim.run_plain(Duration::from_millis(2500), 4);
    assert!(matches!(sim.core.phase, Phase::Configuring(_)));
    // Heartbeats every 250 ms to every daemon, the slow one included, and no loss.
    for id in sim.daemons.keys() {
        assert!(
            sim.pings.get(id).copied().unwrap_or(0) >= 8,
            "{id}: {:?}",
            sim.pings
        );
    }
    assert!(sim.core.lost.is_empty());
    // Requests are taken while configuring (up to the lookahead).
    assert_eq!(sim.core.frames.queue.len(), 2);
    sim.run_plain(Duration::from_secs(2), 4);
    assert!(matches!(sim.core.phase, Phase::Running));
    sim.input(Input::RequestsClosed);
    sim.run_plain(Duration::from_secs(1), 4);
    sim.assert_all_delivered(4);
    // A daemon that stops answering while configuring is lost by its heartbeats (1 s), not
    // waited for until the configure deadline.
    let mut sim = Sim::new(3, 2, &[]);
    sim.due
        .retain(|_, i| !matches!(i, Input::Daemon { id, .. } if id == "node-0"));
    sim.daemons.get_mut("node-0").unwrap().mute = true;
    let start = sim.now;
    sim.run_plain(Duration::from_secs(3), 4);
    let lost = sim
        .core
        .summary
        .incidents
        .iter()
        .find(|i| i.daemon == "node-0");
    let lost = lost.expect("node-0 lost");
    assert!(lost.at.duration_since(start) < Duration::from_secs(2));
    assert!(!sim.in_plan("node-0"));
}

#[test]
fn frames_of_alternating_colours_do_not_re_plan_each_other_for_ever() {
    // Pure red, then pure green: each frame's colours split the node's colour group of the
    // frame before (a zero channel where the other has light): every frame
    // re-plans once, after the frame before it is done (re-planning at once put the frame in
    // flight back under the new colours, where it split the group again, for ever).
    let mut sim = Sim::new(3, 2, &[]);
    let mut flicker = |i: u64| FrameSpec {
        light_colors: vec![(0, [(i % 2) as f32, 1.0 - (i % 2) as f32, 0.0])],
        ..FrameSpec::default()
    };
    sim.run(Duration::from_secs(10), 12, &mut flicker);
    sim.input(Input::RequestsClosed);
    sim.run_plain(Duration::from_secs(1), 12);
    sim.assert_all_delivered(12);
    let epochs = sim.core.summary.epochs.len();
    assert!(epochs <= 13, "{epochs} epochs for 12 frames");
}

#[test]
fn a_light_no_longer_named_goes_back_to_the_scene_colour() {
    let mut sim = Sim::new(3, 2, &[]);
    // Green splits the red light's group (a re-plan over a green scene); frames that name no
    // colour again have the scene's red, which splits it back.
    let mut spec = |i: u64| FrameSpec {
        light_colors: if i <= 3 {
            vec![(0, [0.0, 1.0, 0.0])]
        } else {
            Vec::new()
        },
        ..FrameSpec::default()
    };
    sim.run(Duration::from_secs(2), 3, &mut spec);
    assert_eq!(sim.core.scene.lights[0].color, [0.0, 1.0, 0.0]);
    sim.run(Duration::from_secs(2), 6, &mut spec);
    sim.input(Input::RequestsClosed);
    sim.run_plain(Duration::from_secs(1), 6);
    sim.assert_all_delivered(6);
    assert_eq!(sim.core.scene.lights[0].color, [1.0, 0.0, 0.0]);
}

#[test]
fn a_frame_after_a_colour_change_names_the_colours_the_stages_keep() {
    // Stages keep the colours the last frame gave them: a brighter red (a scaling, no re-plan)
    // on frame 1, then frames that name none must set the scene's red back.
    let mut sim = Sim::new(3, 2, &[]);
    let mut spec = |i: u64| FrameSpec {
        light_colors: if i == 1 {
            vec![(0, [2.0, 0.0, 0.0])]
        } else {
            Vec::new()
        },
        ..FrameSpec::default()
    };
    sim.run(Duration::from_secs(2), 3, &mut spec);
    sim.input(Input::RequestsClosed);
    sim.run_plain(Duration::from_secs(1), 3);
    sim.assert_all_delivered(3);
    assert_eq!(
        sim.core.summary.epochs.len(),
        1,
        "a scaling re-plans nothing"
    );
    let base = sim.core.base;
    let stages = |frame: u64| -> Vec<Colours> {
        sim.colours[&(base + frame)]
            .iter()
            .filter(|(to, _)| to.starts_with("comp-"))
            .map(|(_, c)| c.clone())
            .collect()
    };
    assert!(
        stages(1)
            .iter()
            .any(|c| c.iter().any(|(_, rgb)| rgb[0] == 2.0))
    );
    for frame in [2, 3] {
        let set = stages(frame);
        assert!(set.iter().any(|c| !c.is_empty()), "frame {frame}: {set:?}");
        assert!(
            set.iter().flatten().all(|(_, rgb)| rgb[0] == 1.0),
            "frame {frame}: {set:?}"
        );
    }
}

#[test]
fn a_stop_while_waiting_for_daemons_ends_the_run() {
    let mut sim = Sim::new(1, 1, &[]);
    sim.run_plain(Duration::from_secs(1), 100);
    sim.kill("node-0");
    sim.run_plain(Duration::from_secs(1), 100);
    assert!(
        matches!(sim.core.phase, Phase::Waiting { .. }),
        "{:?}",
        sim.core.phase
    );
    // Requests still come in meanwhile (up to the lookahead) and nothing is lost.
    sim.input(Input::Stop);
    sim.run_plain(Duration::from_secs(1), 100);
    assert!(sim.core.finished());
    assert!(sim.error.is_none());
    let n = sim.delivered.len() as u64;
    assert_eq!(sim.delivered, (1..=n).collect::<Vec<_>>());
}

/// Ordinary events of a live session.
#[derive(Debug, Clone)]
enum Ev {
    /// Nothing happens for a while.
    Wait(u16),
    /// A daemon dies, and comes back after a while.
    Kill(usize, u16),
    /// A daemon stops (SIGSTOP) for a while.
    Stall(usize, u16),
    /// A daemon reports a timeout of the epoch before (history).
    Stale(usize),
    /// The user steers: a colour, a budget, no budget, a camera.
    Colour(u8),
    Budget(u16),
    NoBudget,
    /// Consecutive frames of different colours (a colour picker dragged), for a while.
    Flicker(u16),
}

fn ev() -> impl Strategy<Value = Ev> {
    prop_oneof![
        3 => (50u16..1500).prop_map(Ev::Wait),
        2 => (0usize..6, 100u16..3000).prop_map(|(d, t)| Ev::Kill(d, t)),
        1 => (0usize..6, 100u16..3000).prop_map(|(d, t)| Ev::Stall(d, t)),
        1 => (0usize..6).prop_map(Ev::Stale),
        1 => (0u8..8).prop_map(Ev::Colour),
        1 => (5u16..100).prop_map(Ev::Budget),
        1 => Just(Ev::NoBudget),
        1 => (50u16..1500).prop_map(Ev::Flicker),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// Whatever ordinary events happen, in whatever order, every frame requested is delivered
    /// exactly once, in order, and the session does not end.
    #[test]
    fn ordinary_events_never_lose_or_repeat_a_frame(events in prop::collection::vec(ev(), 1..14)) {
        let mut sim = Sim::new(4, 2, &[]);
        let ids: Vec<String> = sim.daemons.keys().cloned().collect();
        let mut steer = FrameSpec::default();
        let mut last_epoch = sim.epoch();
        let frames = 400;
        let mut restarts: Vec<(Instant, String)> = Vec::new();
        for e in events {
            let mut spec = {
                let s = steer.clone();
                move |_| s.clone()
            };
            match e {
                Ev::Wait(ms) => sim.run(Duration::from_millis(ms.into()), frames, &mut spec),
                Ev::Kill(d, ms) => {
                    let id = &ids[d % ids.len()];
                    if sim.daemons[id].up {
                        sim.kill(id);
                        restarts.push((sim.now + Duration::from_millis(ms.into()), id.clone()));
                    }
                }
                Ev::Stall(d, ms) => {
                    let id = ids[d % ids.len()].clone();
                    sim.daemons.get_mut(&id).unwrap().mute = true;
                    sim.run(Duration::from_millis(ms.into()), frames, &mut spec);
                    sim.resume(&id);
                }
                Ev::Stale(d) => {
                    let id = ids[d % ids.len()].clone();
                    if last_epoch < sim.epoch() && sim.daemons[&id].up {
                        sim.answer_error(&id, ErrorCode::Timeout, last_epoch, Some(sim.core.base + 1));
                    }
                }
                Ev::Colour(c) => {
                    let colour = [1.0, f32::from(c & 1), f32::from(c & 2) / 2.0];
                    steer.light_colors = vec![(0, colour)];
                    steer.frame_budget_us = None;
                }
                Ev::Budget(ms) => steer.frame_budget_us = Some(Some(u64::from(ms) * 1000)),
                Ev::NoBudget => steer.frame_budget_us = Some(None),
                Ev::Flicker(ms) => {
                    let mut flicker = |i: u64| FrameSpec {
                        light_colors: vec![(0, [(i % 2) as f32, 1.0 - (i % 2) as f32, 0.0])],
                        ..FrameSpec::default()
                    };
                    sim.run(Duration::from_millis(ms.into()), frames, &mut flicker);
                }
            }
            last_epoch = last_epoch.max(sim.epoch().saturating_sub(1));
            for (t, id) in std::mem::take(&mut restarts) {
                if sim.now >= t {
                    sim.restart(&id);
                } else {
                    restarts.push((t, id));
                }
            }
            prop_assert!(sim.error.is_none(), "the session ended: {:?}", sim.error);
        }
        for (_, id) in std::mem::take(&mut restarts) {
            sim.restart(&id);
        }
        sim.run_plain(Duration::from_secs(3), frames);
        sim.input(Input::RequestsClosed);
        sim.run_plain(Duration::from_secs(120), frames);
        prop_assert!(sim.error.is_none(), "the session ended: {:?}", sim.error);
        prop_assert!(sim.core.finished(), "{:?} {:?}", sim.core.phase, sim.core);
        let want: Vec<u64> = (1..=sim.requested).collect();
        prop_assert_eq!(&sim.delivered, &want);
    }
}

/// Idle refinement (`FrameSpec::refine`): each step re-plans above the budget's quality (more
/// samples per area light, then a larger camera the sink resolves), with no budget; a frame
/// without it re-plans back to the budget's plan; a refinement that cannot be planned is
/// dropped (the frame renders at the session's quality) and not tried again.
#[test]
fn refinement_re_plans_above_the_budget_s_quality_and_back() {
    let mut sim = Sim::build_with(3, 2, &[], |c| c.max_lights = 64, 4);
    sim.start();
    let scene = sim.core.scene.clone();
    let area = scene.lights.iter().filter(|l| l.is_area()).count();
    let other = scene.lights.len() - area;
    assert!(area > 0, "the scene has area lights");
    let (w, h) = (scene.camera.width, scene.camera.height);
    let camera = lightfold_scene::wire::camera_to_wire(&scene.camera);
    let refine = |samples, supersample| {
        Some(super::Refine {
            samples_per_area_light: samples,
            supersample,
        })
    };
    // Frames 1–5 under a 1 µs budget (no plan meets it: fewer samples per area light); 6–10 at 8
    // samples, 11–15 at 16 samples and 2× antialiasing, 16–20 back at the budget's, 21–30 asking
    // for a factor no camera takes.
    let mut spec = |i: u64| FrameSpec {
        camera: Some(camera),
        frame_budget_us: (i == 1).then_some(Some(1)),
        refine: match i {
            6..=10 => refine(8, 1),
            11..=15 => refine(16, 2),
            21.. => refine(16, 1 << 20),
            _ => None,
        },
        ..FrameSpec::default()
    };
    let samples = |sim: &Sim| sim.core.plan().unwrap().samples.len();
    sim.run(Duration::from_secs(3), 5, &mut spec);
    let budget = samples(&sim);
    assert!(budget < 4 * area + other, "the budget lowered the samples");
    assert_eq!(sim.core.plan().unwrap().frame_budget_us, Some(1));
    sim.run(Duration::from_secs(3), 10, &mut spec);
    assert_eq!(samples(&sim), 8 * area + other);
    assert_eq!(sim.core.plan().unwrap().frame_budget_us, None, "no budget");
    sim.run(Duration::from_secs(3), 15, &mut spec);
    assert_eq!(samples(&sim), 16 * area + other);
    assert_eq!(sim.core.plan().unwrap().width, 2 * w);
    assert_eq!(sim.sink_supersample, 2, "the sink resolves 2 × 2");
    let base = sim.core.base;
    let wire = |frame: u64| base + frame;
    assert_eq!(sim.sizes[&wire(15)], (2 * w, 2 * h));
    assert_eq!(sim.sizes[&wire(10)], (w, h));
    sim.run(Duration::from_secs(3), 20, &mut spec);
    assert_eq!(samples(&sim), budget, "back to the budget's quality");
    assert_eq!(sim.core.plan().unwrap().frame_budget_us, Some(1));
    assert_eq!(sim.sink_supersample, 1);
    assert_eq!(sim.sizes[&wire(16)], (w, h));
    let epochs = sim.core.summary.epochs.len();
    sim.run(Duration::from_secs(3), 30, &mut spec);
    sim.input(Input::RequestsClosed);
    sim.run_plain(Duration::from_secs(2), 30);
    sim.assert_all_delivered(30);
    assert_eq!(samples(&sim), budget, "the refinement was dropped");
    assert_eq!(sim.sizes[&wire(30)], (w, h));
    assert!(
        sim.core.summary.epochs.len() <= epochs + 1,
        "a refinement that cannot be planned re-planned again"
    );
    let reasons: Vec<&str> = sim
        .core
        .summary
        .epochs
        .iter()
        .map(|e| e.reason.as_str())
        .collect();
    assert!(
        reasons.iter().any(|r| r.contains("refining from frame 6")),
        "{reasons:?}"
    );
}

/// A daemon that refuses a refinement's configuration: the refinement goes back (the frames render
/// at the session's quality), the daemon stays, and frames asking for it again re-plan nothing.
#[test]
fn a_refused_refinement_goes_back_and_is_not_asked_again() {
    let mut sim = Sim::build_with(3, 2, &[], |c| c.max_lights = 64, 4);
    sim.start();
    sim.run_plain(Duration::from_secs(1), 5);
    let before = sim.core.plan().unwrap().samples.len();
    sim.daemons.get_mut("node-0").unwrap().refuse_next = true;
    let mut spec = |i: u64| FrameSpec {
        refine: (i > 5).then_some(super::Refine {
            samples_per_area_light: 8,
            supersample: 1,
        }),
        ..FrameSpec::default()
    };
    sim.run(Duration::from_secs(3), 10, &mut spec);
    let epochs = sim.core.summary.epochs.len();
    sim.run(Duration::from_secs(3), 20, &mut spec);
    sim.input(Input::RequestsClosed);
    sim.run_plain(Duration::from_secs(1), 20);
    sim.assert_all_delivered(20);
    assert_eq!(sim.core.refine, None);
    assert_eq!(sim.core.plan().unwrap().samples.len(), before);
    assert_eq!(
        sim.core.summary.epochs.len(),
        epochs,
        "asked again, planned again"
    );
    assert!(
        sim.in_plan("node-0"),
        "the daemon stays: the change went back"
    );
}

/// Under an error target that chose more samples than a refinement step asks for, the step
/// plans the target's count (a refinement never renders fewer samples than the session).
#[test]
fn a_refinement_never_plans_fewer_samples_than_the_error_target_chose() {
    let mut sim = Sim::build_with(3, 2, &[], |c| c.max_lights = 64, 4);
    sim.core.opts.target_penumbra_db = Some(50.0);
    sim.start();
    sim.run_plain(Duration::from_secs(1), 5);
    let chosen = sim.core.plan().unwrap().target.as_ref().unwrap().to;
    assert!(
        chosen > 8,
        "the target chose {chosen} samples per area light"
    );
    let session = sim.core.plan().unwrap().samples.len();
    let mut spec = |i: u64| FrameSpec {
        refine: (i > 5).then_some(super::Refine {
            samples_per_area_light: 8,
            supersample: 1,
        }),
        ..FrameSpec::default()
    };
    sim.run(Duration::from_secs(3), 10, &mut spec);
    sim.input(Input::RequestsClosed);
    sim.run_plain(Duration::from_secs(1), 10);
    sim.assert_all_delivered(10);
    assert_eq!(sim.core.refine.map(|r| r.samples_per_area_light), Some(8));
    assert_eq!(sim.core.plan().unwrap().samples.len(), session);
    assert!(sim.core.plan().unwrap().target.is_none(), "no target");
}

/// A refinement whose estimated frame is far over the session's (64 samples per area light on
/// nodes that take 100 ms a light, against the scene's 4) is dropped like one that cannot be
/// planned: an input would wait for its frame. The control, 8 samples, is taken.
#[test]
fn a_refinement_far_slower_than_the_sessions_frame_is_dropped() {
    let mut sim = Sim::build_with(
        3,
        2,
        &[],
        |c| {
            c.max_lights = 64;
            c.cost_per_light_us = 100_000;
        },
        4,
    );
    sim.start();
    let scene = sim.core.scene.clone();
    let camera = lightfold_scene::wire::camera_to_wire(&scene.camera);
    let area = scene.lights.iter().filter(|l| l.is_area()).count();
    let other = scene.lights.len() - area;
    sim.run_plain(Duration::from_secs(3), 2);
    let session = sim.core.plan().unwrap().clone();
    assert_eq!(session.samples.len(), 4 * area + other);
    let bound = super::epoch::refine_bound_us(Some(&session));
    let mut spec = |i: u64| FrameSpec {
        camera: Some(camera),
        refine: Some(super::Refine {
            samples_per_area_light: if i <= 6 { 8 } else { 64 },
            supersample: 1,
        }),
        ..FrameSpec::default()
    };
    sim.run(Duration::from_secs(3), 6, &mut spec);
    let taken = sim.core.plan().unwrap().clone();
    assert_eq!(
        taken.samples.len(),
        8 * area + other,
        "the control step is taken"
    );
    assert!(taken.est_frame_us <= bound);
    sim.run(Duration::from_secs(3), 12, &mut spec);
    sim.input(Input::RequestsClosed);
    sim.run_plain(Duration::from_secs(2), 12);
    sim.assert_all_delivered(12);
    let p = sim.core.plan().unwrap();
    assert_eq!(
        p.samples.len(),
        4 * area + other,
        "the 64-sample step was dropped"
    );
    // It was dropped for its estimate: planned, it is over the bound.
    let mut slow = scene.clone();
    slow.quality.samples_per_area_light = Some(64);
    let would = crate::plan::plan(&slow, &sim.core.cluster(), &sim.core.opts).unwrap();
    assert!(
        would.est_frame_us > bound,
        "{} ≤ {bound}",
        would.est_frame_us
    );
}

/// A light edit the cluster cannot take (twenty point lights at K = 4 on three nodes whose
/// devices take 4 lights each) is put back — the session goes on with the lights it had, told
/// why — and frames asking for the same edit again re-plan nothing; an edit that fits is
/// planned. (Before, the plan error ended the session.)
#[test]
fn a_light_edit_no_plan_fits_is_put_back_and_the_session_goes_on() {
    let mut sim = Sim::build_with(3, 2, &[], |c| c.max_lights = 4, 4);
    sim.start();
    sim.run_plain(Duration::from_secs(1), 3);
    let lights = sim.core.scene.lights.clone();
    let before = sim.core.plan().unwrap().samples.len();
    let mut many = lights.clone();
    for i in 0..20 {
        many.push(lightfold_scene::Light {
            name: format!("extra {i}"),
            shape: lightfold_scene::LightShape::Point {
                position: [i as f32 * 0.01, 0.5, 0.0],
            },
            color: [1.0, 1.0, 1.0],
            power: 1.0,
            range: None,
            samples: 1,
        });
    }
    let many = Arc::new(many);
    let mut spec = |i: u64| FrameSpec {
        lights: (i > 3).then(|| Arc::clone(&many)),
        ..FrameSpec::default()
    };
    sim.run(Duration::from_secs(3), 10, &mut spec);
    sim.assert_all_delivered(10);
    assert_eq!(sim.core.scene.lights, lights, "the edit was put back");
    assert_eq!(sim.core.plan().unwrap().samples.len(), before);
    let notice = sim
        .core
        .observe()
        .borrow()
        .notice
        .clone()
        .expect("a notice");
    assert!(notice.1.contains("cannot plan"), "{notice:?}");
    // Whoever steers is told which lights are rendered again.
    let put_back = sim.core.observe().borrow().lights_put_back.clone();
    assert_eq!(
        put_back.map(|(n, l)| (n, l.as_ref().clone())),
        Some((1, lights.clone()))
    );
    let epochs = sim.core.summary.epochs.len();
    sim.run(Duration::from_secs(2), 15, &mut spec);
    assert_eq!(
        sim.core.summary.epochs.len(),
        epochs,
        "the refused edit was planned again"
    );
    // One more light fits.
    let mut one = lights.clone();
    one.push(many[lights.len()].clone());
    let one = Arc::new(one);
    let mut spec = |_: u64| FrameSpec {
        lights: Some(Arc::clone(&one)),
        ..FrameSpec::default()
    };
    sim.run(Duration::from_secs(3), 20, &mut spec);
    sim.input(Input::RequestsClosed);
    sim.run_plain(Duration::from_secs(2), 20);
    sim.assert_all_delivered(20);
    assert_eq!(sim.core.scene.lights.len(), lights.len() + 1);
    assert_eq!(sim.core.plan().unwrap().samples.len(), before + 1);
}

/// Light edits survive failover: a node lost after an edit is planned around with the edited
/// lights (moved and added), not the scene's.
#[test]
fn light_edits_survive_a_lost_node() {
    let mut sim = Sim::build_with(4, 2, &[], |c| c.max_lights = 64, 4);
    sim.start();
    sim.run_plain(Duration::from_secs(1), 3);
    let before = sim.core.plan().unwrap().samples.len();
    let mut edited = sim.core.scene.lights.clone();
    if let lightfold_scene::LightShape::Rect { center, .. }
    | lightfold_scene::LightShape::Sphere { center, .. }
    | lightfold_scene::LightShape::Disk { center, .. } = &mut edited[0].shape
    {
        center[0] += 0.2;
    }
    edited.push(lightfold_scene::Light {
        name: "added".into(),
        shape: lightfold_scene::LightShape::Point {
            position: [0.1, 0.6, 0.2],
        },
        color: [1.0, 1.0, 1.0],
        power: 1.0,
        range: None,
        samples: 1,
    });
    let edited = Arc::new(edited);
    let mut spec = |_: u64| FrameSpec {
        lights: Some(Arc::clone(&edited)),
        ..FrameSpec::default()
    };
    sim.run(Duration::from_secs(3), 8, &mut spec);
    assert_eq!(sim.core.plan().unwrap().samples.len(), before + 1);
    let epochs = sim.core.summary.epochs.len();
    let victim = sim.core.plan().unwrap().nodes[0].node.clone();
    sim.kill(&victim);
    sim.run(Duration::from_secs(5), 14, &mut spec);
    sim.input(Input::RequestsClosed);
    sim.run_plain(Duration::from_secs(2), 14);
    sim.assert_all_delivered(14);
    let plan = sim.core.plan().unwrap();
    assert!(
        sim.core.summary.epochs.len() > epochs,
        "the loss re-planned"
    );
    assert!(plan.nodes.iter().all(|n| n.node != victim));
    assert_eq!(
        plan.samples.len(),
        before + 1,
        "the added light is still planned"
    );
    assert_eq!(
        sim.core.scene.lights, *edited,
        "the edited lights are the scene's"
    );
    assert!(
        plan.samples
            .iter()
            .any(|s| s.light == edited.len() as u32 - 1),
        "the plan renders the added light"
    );
}

/// A colour whose re-plan a daemon refuses goes back, and the colours put back are published
/// for whoever steers (the live view shows them again instead of the refused one).
#[test]
fn a_refused_colour_is_published_as_put_back() {
    let mut sim = Sim::new(3, 2, &[]);
    sim.run_plain(Duration::from_secs(1), 5);
    let red = sim.core.scene.lights[0].color;
    // White on the pure-red light splits its node's colour group: a re-plan, which the nodes
    // refuse (each the next configuration it is sent).
    for d in ["node-0", "node-1", "node-2"] {
        sim.daemons.get_mut(d).unwrap().refuse_next = true;
    }
    let mut spec = |i: u64| FrameSpec {
        light_colors: if i > 5 {
            vec![(0, [1.0, 1.0, 1.0])]
        } else {
            Vec::new()
        },
        ..FrameSpec::default()
    };
    sim.run(Duration::from_secs(5), 15, &mut spec);
    sim.input(Input::RequestsClosed);
    sim.run_plain(Duration::from_secs(1), 15);
    sim.assert_all_delivered(15);
    let back = sim.core.observe().borrow().colors_put_back.clone();
    assert_eq!(back, Some((1, vec![(0, red)])), "{back:?}");
    assert_eq!(sim.core.scene.lights[0].color, red);
}

/// A viewer opens another scene: from the frame that carries it on, the plan is the new scene's
/// and every node holds its bytes; frames requested before it show it too. One the cluster cannot
/// plan is refused and said, and the session goes on with the scene it had.
#[test]
fn a_scene_opened_live_is_planned_and_sent_to_every_node() {
    let mut sim = Sim::build_with(3, 2, &[], |c| c.max_lights = 4, 4);
    sim.start();
    sim.run_plain(Duration::from_secs(1), 3);
    let first = sim.core.hash;
    let small = |samples: u32| {
        let mut s = lightfold_scene::builtin("balls").unwrap();
        s.quality.samples_per_area_light = Some(samples);
        s.camera.width = 64;
        s.camera.height = 48;
        s
    };
    // Too many samples for three nodes of four lights: refused.
    let too_big = Arc::new(super::OpenScene {
        id: 1,
        name: "balls at 64 samples".into(),
        scene: small(64),
        options: sim.core.opts.clone(),
    });
    let mut spec = |i: u64| FrameSpec {
        scene: (i > 3).then(|| Arc::clone(&too_big)),
        ..FrameSpec::default()
    };
    sim.run(Duration::from_secs(3), 10, &mut spec);
    sim.assert_all_delivered(10);
    assert_eq!(sim.core.scene_id, 0);
    assert_eq!(sim.core.hash, first);
    let refused = sim.core.observe().borrow().scene_refused.clone();
    assert!(
        refused
            .as_ref()
            .is_some_and(|(id, why)| *id == 1 && why.contains("cannot open")),
        "{refused:?}"
    );
    // One that fits.
    let epochs = sim.core.summary.epochs.len();
    let balls = Arc::new(super::OpenScene {
        id: 2,
        name: "balls".into(),
        scene: small(2),
        options: sim.core.opts.clone(),
    });
    let mut spec = |i: u64| FrameSpec {
        scene: (i > 12).then(|| Arc::clone(&balls)),
        ..FrameSpec::default()
    };
    sim.run(Duration::from_secs(3), 20, &mut spec);
    sim.input(Input::RequestsClosed);
    sim.run_plain(Duration::from_secs(2), 20);
    sim.assert_all_delivered(20);
    assert_eq!(sim.core.scene_id, 2);
    assert_eq!(sim.core.scene.name, "balls");
    assert_ne!(sim.core.hash, first);
    assert_eq!(sim.core.summary.epochs.len(), epochs + 1, "one plan for it");
    let plan = sim.core.plan().unwrap();
    assert_eq!(plan.scene_hash, sim.core.hash);
    for n in &plan.nodes {
        assert_eq!(
            sim.daemons[&n.node].scene,
            Some(sim.core.hash),
            "{} holds the new scene",
            n.node
        );
    }
    assert_eq!(sim.core.observe().borrow().scene, 2);
}

/// Objects moved reach every node of each plan as matrices (the nodes keep their scene), also
/// after a lost node re-plans; the planner sees them moved; a move the loop cannot make is put
/// back, published, and not tried again.
#[test]
fn object_moves_reach_every_node_and_survive_a_lost_node() {
    use lightfold_scene::moves::MeshMove;
    let mut sim = Sim::build_with(4, 2, &[], |c| c.max_lights = 64, 4);
    sim.start();
    sim.run_plain(Duration::from_secs(1), 3);
    let hash = sim.core.hash;
    let mesh = sim.core.scene.meshes.len() as u32 - 1;
    let moved = MeshMove {
        translate: [0.1, 0.0, -0.1],
        rotate: [0.0, 20.0, 0.0],
        ..MeshMove::identity(mesh)
    };
    let moves = Arc::new(vec![moved]);
    let want = sim.core.scene.move_matrices(&moves)[0].1.to_cols_array();
    let carried = |sim: &Sim| {
        let plan = sim.core.plan().unwrap();
        plan.nodes.iter().all(|n| {
            let c = &sim.node_configs[&n.node];
            c.epoch == plan.epoch
                && c.moves.len() == 1
                && c.moves[0].mesh == mesh
                && c.moves[0].matrix == want
        })
    };
    assert!(!carried(&sim), "the control: no move before");
    let mut spec = |_: u64| FrameSpec {
        moves: Some(Arc::clone(&moves)),
        ..FrameSpec::default()
    };
    sim.run(Duration::from_secs(3), 8, &mut spec);
    assert!(carried(&sim), "every node of the plan is sent the move");
    assert_eq!(sim.core.hash, hash, "the nodes keep their scene");
    let victim = sim.core.plan().unwrap().nodes[0].node.clone();
    sim.kill(&victim);
    sim.run(Duration::from_secs(5), 14, &mut spec);
    assert!(
        sim.core
            .plan()
            .unwrap()
            .nodes
            .iter()
            .all(|n| n.node != victim)
    );
    assert!(carried(&sim), "the move survives the loss");

    // A move of a mesh the scene lacks: put back, published, frames asking again stripped.
    let status = sim.core.observe();
    let epochs = sim.core.summary.epochs.len();
    let bad = Arc::new(vec![moved, MeshMove::identity(9999)]);
    let mut spec = |_: u64| FrameSpec {
        moves: Some(Arc::clone(&bad)),
        ..FrameSpec::default()
    };
    sim.run(Duration::from_secs(3), 20, &mut spec);
    sim.input(Input::RequestsClosed);
    sim.run_plain(Duration::from_secs(2), 20);
    sim.assert_all_delivered(20);
    assert_eq!(sim.core.moves, moves, "the good moves stay");
    assert_eq!(sim.core.summary.epochs.len(), epochs, "nothing re-planned");
    let back = status.borrow().moves_put_back.clone();
    assert_eq!(back.map(|(_, m)| m), Some(Arc::clone(&moves)));
    let notice = status.borrow().notice.clone().unwrap().1;
    assert!(notice.contains("cannot move"), "{notice}");
}

/// Sort-first tiles: rows in the top quarter of the image cost 9 times those below. The core
/// moves rows from the top tile to the bottom one frame by frame, in `FrameParams::rows` to the
/// nodes whose rows changed, until the tiles cost about the same; every frame is still
/// delivered. Untiled, no rows are ever sent (the control).
#[test]
fn tiles_give_the_heavy_tile_fewer_rows_frame_by_frame() {
    for tiles in [2, 0] {
        let mut sim = Sim::build(4, 2, &[]);
        sim.core.opts.tiles = tiles;
        sim.core.opts.band_height = 4;
        sim.row_cost = Some(|y| if y < 12 { 900 } else { 100 });
        sim.start();
        sim.run_plain(Duration::from_secs(5), 40);
        sim.input(Input::RequestsClosed);
        sim.run_plain(Duration::from_secs(1), 40);
        sim.assert_all_delivered(40);
        let plan = sim.core.summary.plan.clone().unwrap();
        if tiles == 0 {
            assert!(plan.tiles.is_empty());
            assert!(sim.moved_rows.is_empty(), "{:?}", sim.moved_rows);
            assert_eq!(sim.core.summary.tile_steps, 0);
            continue;
        }
        assert_eq!(plan.tiles, vec![[0, 24], [24, 48]], "rows start even");
        assert_eq!(plan.nodes.len(), 4, "2 tiles × 2 light groups");
        let rows = sim.core.summary.tile_rows.clone();
        let cost = |r: [u32; 2]| -> u64 { (r[0]..r[1]).map(sim.row_cost.unwrap()).sum() };
        assert!(rows[0][1] < 24, "the heavy top tile shrank: {rows:?}");
        let (a, b) = (cost(rows[0]), cost(rows[1]));
        assert!(
            a.abs_diff(b) <= 2 * 4 * 900,
            "the tiles cost {a} and {b} µs, within a boundary band: {rows:?}"
        );
        assert!(sim.core.summary.tile_steps >= 10);
        // Both nodes of a tile render the same rows, and every node was told.
        for n in &plan.nodes {
            let t = n.tile.unwrap();
            assert_eq!(sim.rows[&n.node], rows[t], "{}", n.node);
        }
        assert!(!sim.moved_rows.is_empty());
    }
}

/// A re-plan keeps the tiles' balance: with two idle nodes, losing a tiled node re-plans the
/// same 2 × 2 grid, and the first frame of the new epoch is sent the rows the old one reached,
/// not the even split its configuration carries.
#[test]
fn a_re_plan_keeps_the_tiles_rows() {
    let mut sim = Sim::build(6, 2, &[]);
    sim.core.opts.tiles = 2;
    sim.core.opts.band_height = 4;
    sim.row_cost = Some(|y| if y < 12 { 900 } else { 100 });
    sim.start();
    sim.run_plain(Duration::from_secs(5), 30);
    let before = sim.core.summary.tile_rows.clone();
    assert!(before[0][1] < 24, "balanced: {before:?}");
    let epoch = sim.epoch();
    let tiled = sim.core.summary.plan.clone().unwrap().nodes[0].node.clone();
    sim.kill(&tiled);
    sim.run_plain(Duration::from_secs(5), 60);
    sim.input(Input::RequestsClosed);
    sim.run_plain(Duration::from_secs(1), 60);
    sim.assert_all_delivered(60);
    assert!(sim.epoch() > epoch, "re-planned");
    let plan = sim.core.summary.plan.clone().unwrap();
    assert_eq!(plan.tiles, vec![[0, 24], [24, 48]], "configured even");
    assert!(!plan.nodes.iter().any(|n| n.node == tiled));
    // The new epoch's first frame: every node renders the rows the old epoch reached, not the
    // even ones it was configured with (without the carry it would start even).
    for n in &plan.nodes {
        let first = sim.first_rows[&(plan.epoch, n.node.clone())];
        assert_eq!(
            first,
            before[n.tile.unwrap()],
            "{}'s first frame after the re-plan (configured {:?})",
            n.node,
            plan.tiles
        );
    }
}
