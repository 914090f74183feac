//! Plan epochs: planning over the daemons connected now, sending the scene and the
//! configurations, and taking the answers of every daemon of the new plan — a phase of the
//! session core (`Phase::Configuring`), advanced by each input like any other: a loss of one of
//! the new plan's daemons plans again, a refusal is absorbed (`Core::absorb_refusal`), and frame
//! requests, joins and heartbeats go on meanwhile.

use super::core::{Command, Core, Phase, SceneBytes};
use super::{EpochRecord, MAX_REPLANS_WITHOUT_PROGRESS, Refine, Settings};
use crate::control::session::ControlError;
use crate::control::sink::SinkGeometry;
use crate::plan::{Plan, PlanError, PlanOptions, lights_moved, plan, replan};
use crate::run::RunError;
use lightfold_protocol::{ErrorCode, Message};
use lightfold_scene::Scene;
use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;
use std::time::Instant;

/// A new epoch being configured.
#[derive(Debug)]
pub(in crate::control) struct Establishing {
    next: Plan,
    /// Why it was planned (the re-plans it took on the way included).
    reason: String,
    started: Instant,
    /// Daemons of the plan that have not answered by then are lost.
    deadline: Instant,
    /// The plan's daemons.
    members: BTreeSet<String>,
    /// What each node is sent: the scene, or with partitions only what it draws.
    wants: BTreeMap<String, SceneBytes>,
    /// Nodes offered their scene (no answer yet), and those loading it.
    offered: BTreeSet<String>,
    loading: BTreeSet<String>,
    /// Configurations sent (once every node holds its scene), and the daemons yet to apply them.
    configs_sent: bool,
    waiting: BTreeSet<String>,
}

impl Establishing {
    /// The daemons it waits on now, and for what.
    fn pending(&self) -> (Vec<String>, &'static str) {
        if self.configs_sent {
            (
                self.waiting.iter().cloned().collect(),
                "configurations to be applied",
            )
        } else {
            (
                self.offered.iter().chain(&self.loading).cloned().collect(),
                "the scene to load",
            )
        }
    }
}

impl Core {
    /// Plans a new epoch over the daemons connected now and starts configuring it; the frames in
    /// flight that had not reached the sink are put back to be requested under it. Re-plans for
    /// a `failure` with no frame delivered since the last one are counted: past
    /// `MAX_REPLANS_WITHOUT_PROGRESS` the cluster cannot go on (a daemon that fails every plan);
    /// those for a change (a daemon joined, the user steered, the cost model) are not.
    pub(super) fn replan(
        &mut self,
        reason: String,
        failure: bool,
        now: Instant,
    ) -> Result<(), RunError> {
        self.salvage();
        self.reset_at = None;
        self.need_replan = None;
        self.pending_steer = None;
        self.waited_since = None;
        self.replans_without_progress += u32::from(failure);
        if self.replans_without_progress > MAX_REPLANS_WITHOUT_PROGRESS {
            return Err(ControlError::Stuck(format!(
                "{MAX_REPLANS_WITHOUT_PROGRESS} re-plans in a row delivered no frame; the last: {reason}"
            ))
            .into());
        }
        self.plan_next(reason, now)
    }

    /// Plans an epoch over the daemons connected now and sends what it needs; with too few
    /// daemons for any plan, waits for lost ones (`Phase::Waiting`) up to
    /// `ControlOptions::wait_for_daemons` from the first failed attempt.
    pub(super) fn plan_next(&mut self, reason: String, now: Instant) -> Result<(), RunError> {
        self.phase = Phase::Running;
        if self.abandon {
            // Daemons stopped with the run: nothing more is rendered.
            return Ok(());
        }
        if self.epochs_used >= super::EPOCHS_PER_RUN {
            return Err(ControlError::Stuck(format!(
                "{} plan epochs in one run; the last: {reason}",
                super::EPOCHS_PER_RUN
            ))
            .into());
        }
        self.epochs_used += 1;
        let mut o = self.opts.clone();
        o.epoch = self.first_epoch + self.epochs_used;
        let cluster = self.cluster();
        let prev = self.plan.as_ref().filter(|_| !self.fresh_plan);
        let plan_for = |scene: &Scene, o: &PlanOptions| match prev {
            Some(prev) => replan(scene, &cluster, o, prev),
            None => plan(scene, &cluster, o),
        };
        // A refinement that cannot be planned (too many samples for the nodes there are, say)
        // is dropped, and the session's quality planned instead.
        // So is one whose estimated frame is far over the session's own: a step's frame is not
        // cancelled by an input, so its length is how long an input may wait.
        // The session's own plan is the bound's measure, and the plan when the step is dropped.
        // The planner sees the objects where viewers moved them; nodes move their own copies.
        let planned = self.moved_scene();
        let scene = planned.as_ref().unwrap_or(&self.scene);
        let mut session = self.refine.map(|_| plan_for(scene, &o));
        let refined = self.refine.map(|r| {
            refined(scene, r, self.target_samples, &o)
                .and_then(|(scene, ro)| plan_for(&scene, &ro).map_err(|e| e.to_string()))
                .and_then(|p| {
                    let bound = refine_bound_us(session.as_ref().and_then(|s| s.as_ref().ok()));
                    if p.est_frame_us > bound {
                        Err(format!(
                            "its estimated frame ({:.0} ms) is over {:.0} ms, {REFINE_SLOWDOWN}× \
                             the session's or {} ms at least",
                            p.est_frame_us as f64 / 1e3,
                            bound as f64 / 1e3,
                            REFINE_MIN_BOUND_US / 1000
                        ))
                    } else {
                        Ok(p)
                    }
                })
        });
        let next = match refined {
            None => plan_for(scene, &o),
            Some(Ok(next)) => Ok(next),
            Some(Err(why)) => {
                // Not to be tried again: frames asking for it get the session's quality.
                tracing::warn!(
                    "the refinement ({}) cannot be planned: {why}; rendering at the session's \
                     quality",
                    self.refine.map(|r| r.to_string()).unwrap_or_default()
                );
                let next = session.take().unwrap_or_else(|| plan_for(scene, &o));
                self.refused.refine = Some(self.refine.take());
                next
            }
        };
        let next = match next {
            Err(e) if !self.stopping => {
                // What the user changed since the last epoch every daemon took (a light edit, a
                // budget) may be what cannot be planned: put it back and plan again, rather than
                // wait for daemons or end the session.
                // Only a change a user made counts (not the cost model the loop learns).
                let user_changed = self.good.as_ref().is_some_and(|good| {
                    !super::same_lights(&self.scene.lights, &good.lights)
                        || self.opts.frame_budget_us != good.opts.frame_budget_us
                        || *self.moves != *good.moves
                });
                match self.good.clone().filter(|_| user_changed) {
                    Some(good) => {
                        let undone = self.restore(&good)?;
                        if undone.is_empty() {
                            Err(e)
                        } else {
                            let why = format!(
                                "cannot plan the change ({e}): {} kept as in epoch {}, \
                                 re-planning",
                                undone.join(", "),
                                good.epoch
                            );
                            self.notice(why.clone());
                            return self.plan_next(why, now);
                        }
                    }
                    None => Err(e),
                }
            }
            next => next,
        };
        match next {
            Ok(next) => self.begin(next, reason, now),
            Err(_) if self.stopping => {
                // Stopping anyway: waiting for lost daemons would only delay it.
                self.abandon = true;
                Ok(())
            }
            Err(e) if too_few(&e) => {
                let since = *self.waited_since.get_or_insert(now);
                let left = self
                    .control
                    .wait_for_daemons
                    .saturating_sub(now.saturating_duration_since(since));
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
                self.phase = Phase::Waiting {
                    reason,
                    deadline: now + left,
                };
                self.publish();
                Ok(())
            }
            Err(e) => Err(e.into()),
        }
    }

    /// Offers each node of `next` the scene it needs (nodes holding it already skip it).
    fn begin(&mut self, mut next: Plan, reason: String, now: Instant) -> Result<(), RunError> {
        // Nodes know the scene by the hash of the bytes they are sent.
        next.scene_hash = self.hash;
        // The new configurations carry the lights where they are.
        self.light_frames.clear();
        let members: BTreeSet<String> = next
            .nodes
            .iter()
            .map(|n| n.node.clone())
            .chain(next.stages.iter().map(|s| s.compositor.clone()))
            .collect();
        self.just_lost.clear();
        let mut wants: BTreeMap<String, SceneBytes> = BTreeMap::new();
        for i in 0..next.nodes.len() {
            let (hash, bytes) = self.node_scene(&next, i).map_err(RunError::Scene)?;
            next.nodes[i].scene = (hash != self.hash).then_some(hash);
            wants.insert(next.nodes[i].node.clone(), (hash, bytes));
        }
        let mut offered = BTreeSet::new();
        for (id, (hash, bytes)) in &wants {
            if self.members.get(id).and_then(|m| m.scene) == Some(*hash) {
                continue;
            }
            let (hash, size) = (*hash, bytes.len() as u64);
            self.send(id, Message::SceneOffer { hash, size });
            offered.insert(id.clone());
        }
        self.phase = Phase::Configuring(Box::new(Establishing {
            next,
            reason,
            started: now,
            deadline: now + self.control.configure,
            members,
            wants,
            offered,
            loading: BTreeSet::new(),
            configs_sent: false,
            waiting: BTreeSet::new(),
        }));
        self.publish();
        Ok(())
    }

    /// Moves the epoch being configured on: plans again when one of its daemons was lost, sends
    /// the configurations once every node holds its scene, and makes it the plan once every
    /// daemon applied its configuration. Returns whether it changed anything.
    pub(super) fn advance(&mut self, now: Instant) -> Result<bool, RunError> {
        let supersample = self.supersample();
        let moves = self.wire_moves();
        let Phase::Configuring(est) = &mut self.phase else {
            return Ok(false);
        };
        if self.abandon {
            self.phase = Phase::Running;
            return Ok(true);
        }
        let lost: Vec<&String> = self
            .just_lost
            .iter()
            .filter(|id| est.members.contains(*id))
            .collect();
        if !lost.is_empty() {
            let names: Vec<&str> = self.just_lost.iter().map(String::as_str).collect();
            let reason = format!("{}; then {} lost", est.reason, names.join(", "));
            self.plan_next(reason, now)?;
            return Ok(true);
        }
        if !est.configs_sent && est.offered.is_empty() && est.loading.is_empty() {
            let next = &est.next;
            let mut configs = Vec::new();
            for stage in &next.stages {
                let cfg = next
                    .compositor_config(&stage.compositor)
                    .ok_or_else(|| ControlError::UnknownDaemon(stage.compositor.clone()))?;
                configs.push((stage.compositor.clone(), Message::ConfigureCompositor(cfg)));
            }
            for node in &next.nodes {
                let mut cfg = next
                    .node_config(&node.node)
                    .ok_or_else(|| ControlError::UnknownDaemon(node.node.clone()))?;
                cfg.moves = moves.clone();
                configs.push((node.node.clone(), Message::ConfigureNode(cfg)));
            }
            let geometry = SinkGeometry {
                epoch: next.epoch,
                width: next.width,
                height: next.height,
                band_height: next.band_height,
                supersample,
            };
            est.configs_sent = true;
            est.waiting = configs.iter().map(|(id, _)| id.clone()).collect();
            self.command(Command::SinkGeometry(geometry));
            for (id, msg) in configs {
                self.send(&id, msg);
            }
            return Ok(true);
        }
        if est.configs_sent && est.waiting.is_empty() {
            let Phase::Configuring(est) = std::mem::replace(&mut self.phase, Phase::Running) else {
                return Ok(false);
            };
            self.complete(*est, now);
            return Ok(true);
        }
        Ok(false)
    }

    /// A daemon's message while an epoch is configured.
    pub(super) fn configuring_message(
        &mut self,
        id: &str,
        m: Message,
        now: Instant,
    ) -> Result<(), RunError> {
        let Phase::Configuring(est) = &mut self.phase else {
            return Ok(());
        };
        let wanted = est.wants.get(id).map(|w| w.0);
        let scene_phase = est.offered.contains(id) || est.loading.contains(id);
        let refusal = match m {
            Message::SceneNeed { hash, need } if Some(hash) == wanted && est.offered.remove(id) => {
                if need {
                    let bytes = Arc::clone(&est.wants[id].1);
                    est.loading.insert(id.to_string());
                    self.command(Command::SendScene {
                        to: id.to_string(),
                        hash,
                        bytes,
                    });
                } else if let Some(m) = self.members.get_mut(id) {
                    m.scene = Some(hash);
                }
                None
            }
            Message::SceneReady { hash, .. } if Some(hash) == wanted && est.loading.remove(id) => {
                if let Some(m) = self.members.get_mut(id) {
                    m.scene = Some(hash);
                }
                None
            }
            Message::Configured { epoch } if epoch == est.next.epoch => {
                est.waiting.remove(id);
                None
            }
            // A refusal of the scene (no frame; scene errors name no epoch), or of the
            // configuration (this epoch, no frame): a frame's error of the epoch before is not
            // one.
            Message::Error {
                code,
                message,
                epoch,
                frame: None,
            } if (scene_phase && epoch.is_none_or(|e| e == est.next.epoch))
                || (epoch == Some(est.next.epoch) && est.waiting.contains(id)) =>
            {
                Some((code, message))
            }
            Message::Error {
                code,
                message,
                epoch,
                frame,
            } => {
                tracing::warn!(daemon = %id, ?code, ?epoch, ?frame, "{message}");
                None
            }
            other => {
                tracing::debug!(daemon = %id, "ignored while configuring: {other:?}");
                None
            }
        };
        if let Some((code, message)) = refusal {
            let reason = self.absorb_refusal(id, code, &message, now)?;
            return self.plan_next(reason, now);
        }
        Ok(())
    }

    /// The configuring phase's deadline: daemons of the new plan that have not answered by then
    /// are lost (and the epoch planned again without them).
    pub(super) fn configuring_tick(&mut self, now: Instant) -> Result<(), RunError> {
        let Phase::Configuring(est) = &self.phase else {
            return Ok(());
        };
        if now < est.deadline {
            return Ok(());
        }
        let (pending, what) = est.pending();
        let after = self.control.configure.as_secs();
        for id in pending {
            self.lose(
                &id,
                format!("did not answer within {after} s while waiting for {what}"),
                now,
            );
        }
        Ok(())
    }

    /// Every daemon of the new plan applied it: it is the plan from now on.
    fn complete(&mut self, est: Establishing, now: Instant) {
        let Establishing {
            next,
            reason,
            started,
            members,
            ..
        } = est;
        let moved = self.plan.as_ref().map_or(0, |p| lights_moved(p, &next));
        let record = EpochRecord {
            epoch: next.epoch,
            reason: reason.clone(),
            at: now,
            configure: now.saturating_duration_since(started),
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
        lightfold_telemetry::record::plan_epoch(next.epoch);
        if self.summary.epochs.len() > 1 {
            lightfold_telemetry::record::replanned();
        }
        // Daemons the new plan leaves out drop what they hold of the old epoch (a stage would
        // otherwise wait out its input deadline on a frame that can no longer come).
        let left_out: Vec<String> = self
            .participants
            .iter()
            .filter(|p| !members.contains(*p) && self.members.contains_key(*p))
            .cloned()
            .collect();
        for id in left_out {
            self.send(&id, Message::Release { epoch: next.epoch });
        }
        self.participants = next
            .stages
            .iter()
            .map(|s| s.compositor.clone())
            .chain(next.nodes.iter().map(|n| n.node.clone()))
            .collect();
        self.summary.plan = Some(next.clone());
        let cluster = self.cluster();
        self.adapt.epoch(&next, &cluster, &self.opts);
        if self.refine.is_none() {
            self.target_samples = next.target.as_ref().map(|t| t.to);
        }
        self.good = Some(Settings {
            epoch: next.epoch,
            colors: self.scene.lights.iter().map(|l| l.color).collect(),
            opts: self.opts.clone(),
            refine: self.refine,
            lights: self.scene.lights.clone(),
            moves: Arc::clone(&self.moves),
        });
        self.refusals = 0;
        let previous = self.tiles.take();
        self.tiles = crate::tiles::TileBalancer::of(&next).map(|mut b| {
            if let Some(p) = &previous {
                b.carry(p);
            }
            b
        });
        if let Some(b) = &self.tiles {
            self.summary.tile_rows = b.rows().to_vec();
        }
        self.plan = Some(next);
        self.fresh_plan = false;
        self.sent_in_epoch = 0;
        self.recoloured = false;
        self.publish();
    }

    /// A daemon refused the scene or configuration of a new epoch. The coordinator planned what
    /// the daemon's own checks refuse, which is the coordinator's to absorb: the settings that
    /// changed since the last epoch every daemon took (light colours, the frame budget, the
    /// cost model) go back to what they were, the viewers are told why, and frames asking for
    /// the refused settings again are sent without them. Where nothing changed, the daemon cannot
    /// take its part under settings that worked: it is left out (lost). Only a refusal of the
    /// very first plan ends the run: nothing has worked yet to go back to. Returns the reason of
    /// the next plan.
    ///
    /// A daemon left out is redialled like any lost one; when it answers it is folded in at the
    /// next re-plan something else causes, not at once, so a daemon that refuses every plan
    /// costs one re-plan per other event rather than a loop.
    fn absorb_refusal(
        &mut self,
        id: &str,
        code: ErrorCode,
        message: &str,
        now: Instant,
    ) -> Result<String, RunError> {
        let Some(good) = self.good.clone() else {
            return Err(ControlError::Remote {
                address: self.address(id),
                id: id.to_string(),
                code,
                message: message.to_string(),
            }
            .into());
        };
        self.refusals += 1;
        if self.refusals > MAX_REPLANS_WITHOUT_PROGRESS {
            return Err(ControlError::Stuck(format!(
                "{MAX_REPLANS_WITHOUT_PROGRESS} configurations in a row were refused; the last: \
                 {id} reported {code:?}: {message}"
            ))
            .into());
        }
        let undone = self.restore(&good)?;
        let why = if undone.is_empty() {
            self.lose(
                id,
                format!("refused its configuration ({code:?}: {message})"),
                now,
            );
            self.shunned.insert(id.to_string());
            format!(
                "{id} refused its part of the plan ({code:?}: {message}): re-planning without it"
            )
        } else {
            format!(
                "{id} refused the new configuration ({code:?}: {message}): {} kept as in epoch \
                 {}, re-planning",
                undone.join(", "),
                good.epoch
            )
        };
        self.notice(why.clone());
        Ok(why)
    }

    /// Puts back the settings of an epoch every daemon took; what changed is named in the
    /// returned list (empty: nothing had changed) and remembered as refused
    /// (`Refused::strip`).
    fn restore(&mut self, good: &Settings) -> Result<Vec<String>, RunError> {
        let mut undone = Vec::new();
        if !super::same_lights(&self.scene.lights, &good.lights) {
            self.refused.lights = Some(Arc::new(self.scene.lights.clone()));
            undone.push("the lights as they were (the edit is dropped)".to_string());
            self.edit_lights(&good.lights);
            let lights = Arc::new(good.lights.clone());
            self.observer.send_modify(|s| {
                let n = s.lights_put_back.as_ref().map_or(1, |(n, _)| n + 1);
                s.lights_put_back = Some((n, lights));
            });
        }
        let back: Vec<(u32, [f32; 3])> = self
            .scene
            .lights
            .iter()
            .zip(&good.colors)
            .enumerate()
            .filter(|(_, (l, c))| l.color.map(f32::to_bits) != c.map(f32::to_bits))
            .map(|(i, (l, c))| {
                self.refused.colors.push((i as u32, l.color));
                (i as u32, *c)
            })
            .collect();
        if !back.is_empty() {
            undone.push(format!(
                "the colours of light(s) {:?}",
                back.iter().map(|b| b.0).collect::<Vec<_>>()
            ));
            self.recolour(&back)?;
            self.observer.send_modify(|s| {
                let n = s.colors_put_back.as_ref().map_or(1, |(n, _)| n + 1);
                s.colors_put_back = Some((n, back.clone()));
            });
        }
        if *self.moves != *good.moves {
            self.refused.moves = Some(Arc::clone(&self.moves));
            undone.push("the objects where they were (the move is dropped)".to_string());
            self.moves = Arc::clone(&good.moves);
            self.publish_moves_put_back();
        }
        if self.opts.frame_budget_us != good.opts.frame_budget_us {
            self.refused.budget = Some(self.opts.frame_budget_us);
            undone.push(match good.opts.frame_budget_us {
                Some(us) => format!("the frame budget ({:.1} ms)", us as f64 / 1e3),
                None => "no frame budget".to_string(),
            });
        }
        if self.opts.learned.cost_scale != good.opts.learned.cost_scale {
            undone.push("the cost model".to_string());
        }
        if self.refine != good.refine {
            self.refused.refine = Some(self.refine);
            undone.push(match good.refine {
                Some(r) => format!("the refinement ({r})"),
                None => "the session's quality (no refinement)".to_string(),
            });
            self.refine = good.refine;
        }
        if !undone.is_empty() {
            self.opts = good.opts.clone();
        }
        Ok(undone)
    }

    /// The scene bytes node `next.nodes[i]` is sent, and their content hash: the whole scene,
    /// or with sort-last partitions (of a still scene) its part, its lights' casters and every
    /// glass mesh whole and the other meshes as stand-ins (`scene::partition::keep_meshes`).
    fn node_scene(&mut self, next: &Plan, i: usize) -> Result<SceneBytes, String> {
        let whole = (self.hash, Arc::clone(&self.bytes));
        let n = &next.nodes[i];
        let Some(part) = n.part.and_then(|p| next.partitions.get(p)) else {
            return Ok(whole);
        };
        if self.scene.animation.is_some() {
            // Posing moves every mesh; stand-ins would not follow their meshes' bounds.
            return Ok(whole);
        }
        let scene = &self.scene;
        let mut keep = vec![false; scene.meshes.len()];
        let mut mark = |m: u32| {
            if let Some(k) = keep.get_mut(m as usize) {
                *k = true;
            }
        };
        part.iter().copied().for_each(&mut mark);
        n.shadows
            .iter()
            .flat_map(|s| s.casters.iter().copied())
            .for_each(&mut mark);
        for (m, mesh) in scene.meshes.iter().enumerate() {
            if scene
                .materials
                .get(mesh.material)
                .is_some_and(|mat| mat.is_filter())
            {
                keep[m] = true;
            }
        }
        if keep.iter().all(|&k| k) {
            return Ok(whole);
        }
        let kept: Vec<u32> = (0..keep.len() as u32)
            .filter(|&m| keep[m as usize])
            .collect();
        if let Some(hit) = self.subsets.get(&kept) {
            return Ok(hit.clone());
        }
        // Encoding a large scene takes seconds: on a multi-threaded runtime the loop's other
        // tasks (the sink, the live view) move to other workers meanwhile.
        let encode = || -> Result<SceneBytes, String> {
            let sub = lightfold_scene::partition::keep_meshes(scene, &keep);
            let bytes = Arc::new(sub.to_bytes().map_err(|e| e.to_string())?);
            Ok((sub.content_hash(), bytes))
        };
        let entry = match tokio::runtime::Handle::try_current().map(|h| h.runtime_flavor()) {
            Ok(tokio::runtime::RuntimeFlavor::MultiThread) => tokio::task::block_in_place(encode)?,
            _ => encode()?,
        };
        self.subsets.insert(kept, entry.clone());
        Ok(entry)
    }
}

/// A refinement step's estimated frame may be at most this many times the session's own ...
pub(super) const REFINE_SLOWDOWN: u64 = 4;
/// ... or this long (µs), whichever is more.
pub(super) const REFINE_MIN_BOUND_US: u64 = 1_000_000;

/// The longest estimated frame a refinement step may have, given the session's plan at its own
/// quality (when it could be planned).
pub(super) fn refine_bound_us(session: Option<&Plan>) -> u64 {
    session
        .map_or(0, |p| p.est_frame_us.saturating_mul(REFINE_SLOWDOWN))
        .max(REFINE_MIN_BOUND_US)
}

/// The scene and options refinement `r` plans from the nodes' `scene` (at the session's
/// antialiasing factor, `options.supersample`) and the session's `options`: every area light at
/// the refinement's samples (at least the `target_samples` an error target of the session chose),
/// the camera at its factor, no frame budget or error target. The nodes keep the scene they hold:
/// the samples and the camera travel in the configurations.
fn refined(
    scene: &Scene,
    r: Refine,
    target_samples: Option<u32>,
    options: &PlanOptions,
) -> Result<(Scene, PlanOptions), String> {
    let session = options.supersample.max(1);
    let factor = r.supersample.max(session);
    let mut s = scene.clone();
    if r.samples_per_area_light > 0 && s.lights.iter().any(|l| l.is_area()) {
        let n = r.samples_per_area_light.max(target_samples.unwrap_or(0));
        lightfold_scene::limits::check_samples_per_area_light(
            "the refinement's samples per area light",
            n,
        )
        .map_err(|e| e.to_string())?;
        s.quality.samples_per_area_light = Some(n);
    }
    // The scene's camera is the session's factor × the frames' size.
    let mut camera = s.camera;
    (camera.width, camera.height) = (camera.width / session, camera.height / session);
    s.camera = camera.supersampled(factor).map_err(|e| e.to_string())?;
    let o = PlanOptions {
        frame_budget_us: None,
        target_penumbra_db: None,
        supersample: factor,
        ..options.clone()
    };
    Ok((s, o))
}

/// Whether a plan error means the cluster is too small (rather than a bad scene or options).
fn too_few(e: &PlanError) -> bool {
    matches!(
        e,
        PlanError::NoNodes | PlanError::NoCompositors | PlanError::NotEnoughNodes { .. }
    )
}
