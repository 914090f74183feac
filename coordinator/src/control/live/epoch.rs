//! Plan epochs: planning over the daemons connected now, sending the scene and the
//! configurations, and waiting for every daemon of the new plan to apply them.

use super::{EpochRecord, Halt, Live, MAX_REPLANS_WITHOUT_PROGRESS, SceneBytes, Settings};
use crate::control::session::{ControlError, SCENE_CHUNK};
use crate::control::sink::SinkGeometry;
use crate::plan::{Plan, PlanError, lights_moved, plan, replan};
use crate::run::{RunError, cluster_spec};
use lightfold_protocol::{ErrorCode, Message};
use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;
use std::time::Instant;

impl Live<'_> {
    /// Plans a new epoch over the daemons connected now and configures it, planning again while
    /// daemons of the new plan are lost on the way.
    pub(super) async fn replan(&mut self, reason: String) -> Result<(), RunError> {
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
        self.publish(true);
        let mut reason = reason;
        let mut waited_since: Option<Instant> = None;
        loop {
            if self.abandon {
                // Daemons stopped with the run: nothing more is rendered.
                return Ok(());
            }
            let epoch = self.session.next_epoch();
            let mut o = self.opts.clone();
            o.epoch = epoch;
            let cluster = cluster_spec(self.session);
            let next = match &self.plan {
                Some(prev) => replan(&self.scene, &cluster, &o, prev),
                None => plan(&self.scene, &cluster, &o),
            };
            let next = match next {
                Ok(p) => p,
                Err(_) if self.stopping() => {
                    // Stopping anyway: waiting for lost daemons would only delay it.
                    self.abandon = true;
                    return Ok(());
                }
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
                Ok(()) => {
                    self.publish(false);
                    return Ok(());
                }
                Err(Halt::Interrupted) => {
                    reason = format!("{reason}; then {} lost", self.just_lost.join(", "));
                    continue;
                }
                Err(Halt::Refused { id, code, message }) => {
                    reason = self.absorb_refusal(&id, code, &message)?;
                    continue;
                }
                Err(Halt::Fatal(e)) => return Err(e),
            }
        }
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

    pub(super) async fn wait_for_join(&mut self, deadline: Instant) -> Result<(), RunError> {
        loop {
            let stopped = self.stopped();
            tokio::select! {
                j = self.session.joined.recv() => if let Some(j) = j {
                    self.on_join(j);
                    self.pending_join = None;
                    return Ok(());
                },
                ev = self.session.events.recv() => if let Some(ev) = ev { self.accept(ev)?; },
                s = self.session.sink_events.recv() => if let Some(s) = s { self.on_sink(s) },
                _ = self.tick.tick() => self.heartbeat(),
                () = stopped => {
                    // Told to stop while waiting for daemons: nothing more can be rendered.
                    self.abandon = true;
                    return Ok(());
                }
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
    pub(super) async fn establish(&mut self, mut next: Plan, reason: &str) -> Result<(), Halt> {
        let started = Instant::now();
        // Nodes know the scene by the hash of the bytes they are sent.
        next.scene_hash = self.hash;
        let deadline = started + self.session.opts.configure;
        let members: BTreeSet<String> = next
            .nodes
            .iter()
            .map(|n| n.node.clone())
            .chain(next.stages.iter().map(|s| s.compositor.clone()))
            .collect();
        self.just_lost.clear();
        // What each node is sent: the scene, or with partitions only what it draws.
        let mut wants: BTreeMap<String, SceneBytes> = BTreeMap::new();
        for i in 0..next.nodes.len() {
            let (hash, bytes) = self
                .node_scene(&next, i)
                .map_err(|e| Halt::Fatal(RunError::Scene(e)))?;
            next.nodes[i].scene = (hash != self.hash).then_some(hash);
            wants.insert(next.nodes[i].node.clone(), (hash, bytes));
        }
        let mut offered: BTreeSet<String> = BTreeSet::new();
        for (id, (hash, bytes)) in &wants {
            if self.session.scenes.get(id) == Some(hash) {
                continue;
            }
            let (hash, size) = (*hash, bytes.len() as u64);
            self.send_or_lose(id, Message::SceneOffer { hash, size });
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
            let wanted = wants.get(&id).map(|w| w.0);
            match m {
                Message::SceneNeed { hash: h, need }
                    if Some(h) == wanted && offered.remove(&id) =>
                {
                    if need {
                        let bytes = Arc::clone(&wants[&id].1);
                        self.send_scene(&id, h, &bytes).await;
                        loading.insert(id);
                    } else {
                        self.session.scenes.insert(id, h);
                    }
                }
                Message::SceneReady { hash: h, .. } if Some(h) == wanted && loading.remove(&id) => {
                    self.session.scenes.insert(id, h);
                }
                // A refusal of the scene (no frame; scene errors name no epoch): a frame's error of
                // the epoch before is not one.
                Message::Error {
                    code,
                    message,
                    epoch,
                    frame: None,
                } if pending.contains(&id) && epoch.is_none_or(|e| e == next.epoch) => {
                    return Err(Halt::Refused { id, code, message });
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
            supersample: self.opts.supersample.max(1),
        });
        let mut waiting: BTreeSet<String> = BTreeSet::new();
        for (id, msg) in configs {
            self.send_or_lose(&id, msg);
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
                Message::Error {
                    code,
                    message,
                    epoch: Some(e),
                    frame: None,
                } if e == next.epoch && waiting.contains(&id) => {
                    return Err(Halt::Refused { id, code, message });
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
        lightfold_ops::record::plan_epoch(next.epoch);
        if self.summary.epochs.len() > 1 {
            lightfold_ops::record::replanned();
        }
        // Daemons the new plan leaves out drop what they hold of the old epoch (a stage would
        // otherwise wait out its input deadline on a frame that can no longer come).
        let left_out: Vec<String> = self
            .participants
            .iter()
            .filter(|p| !members.contains(*p) && self.session.daemons.contains_key(*p))
            .cloned()
            .collect();
        for id in left_out {
            self.send_or_lose(&id, Message::Release { epoch: next.epoch });
        }
        self.participants = next
            .stages
            .iter()
            .map(|s| s.compositor.clone())
            .chain(next.nodes.iter().map(|n| n.node.clone()))
            .collect();
        self.summary.plan = Some(next.clone());
        self.set_model(&next);
        self.plan_scale = self.opts.cost_scale;
        self.good = Some(Settings {
            epoch: next.epoch,
            colors: self.scene.lights.iter().map(|l| l.color).collect(),
            opts: self.opts.clone(),
        });
        self.refusals = 0;
        self.plan = Some(next);
        self.measured.clear();
        self.scales.clear();
        self.sent_in_epoch = 0;
        Ok(())
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
    ) -> Result<String, RunError> {
        let Some(good) = self.good.clone() else {
            return Err(ControlError::Remote {
                address: self.session.address(id),
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

    pub(super) fn check_interrupted(&self, members: &BTreeSet<String>) -> Result<(), Halt> {
        if self.abandon || self.just_lost.iter().any(|id| members.contains(id)) {
            Err(Halt::Interrupted)
        } else {
            Ok(())
        }
    }

    pub(super) fn ignore(&mut self, id: &str, m: Message) {
        match m {
            Message::Error {
                code,
                message,
                epoch,
                frame,
            } => tracing::warn!(daemon = %id, ?code, ?epoch, ?frame, "{message}"),
            other => tracing::debug!(daemon = %id, "ignored while configuring: {other:?}"),
        }
    }

    /// Puts back the settings of an epoch every daemon took; what changed is named in the
    /// returned list (empty: nothing had changed) and remembered as refused
    /// (`Refused::strip`).
    fn restore(&mut self, good: &Settings) -> Result<Vec<String>, RunError> {
        let mut undone = Vec::new();
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
        }
        if self.opts.frame_budget_us != good.opts.frame_budget_us {
            self.refused.budget = Some(self.opts.frame_budget_us);
            undone.push(match good.opts.frame_budget_us {
                Some(us) => format!("the frame budget ({:.1} ms)", us as f64 / 1e3),
                None => "no frame budget".to_string(),
            });
        }
        if self.opts.cost_scale != good.opts.cost_scale {
            undone.push("the cost model".to_string());
        }
        if !undone.is_empty() {
            self.opts = good.opts.clone();
        }
        Ok(undone)
    }

    pub(super) fn send_or_lose(&mut self, id: &str, msg: Message) {
        if let Err(e) = self.session.send(id, msg) {
            self.lose(id, format!("cannot send to it: {e}"));
        }
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

    pub(super) async fn send_scene(&mut self, id: &str, hash: [u8; 32], bytes: &[u8]) {
        const CHUNK: usize = SCENE_CHUNK;
        let total = bytes.len();
        let chunks = total.div_ceil(CHUNK).max(1);
        for i in 0..chunks {
            let range = (i * CHUNK).min(total)..((i + 1) * CHUNK).min(total);
            let msg = Message::SceneChunk {
                hash,
                offset: range.start as u64,
                data: bytes[range].to_vec(),
                last: i + 1 == chunks,
            };
            if let Err(e) = self.session.send_bulk(id, msg).await {
                self.lose(id, format!("cannot send the scene: {e}"));
                return;
            }
        }
    }

    /// The next message for the configuring phase; `None` after an event it handled itself.
    /// Daemons of the new plan that do not answer by `deadline` are lost.
    pub(super) async fn wait_message(
        &mut self,
        deadline: Instant,
        what: &str,
        pending: &[String],
        members: &BTreeSet<String>,
    ) -> Result<Option<(String, Message)>, Halt> {
        let stopped = self.stopped();
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
            _ = self.tick.tick() => {
                self.heartbeat();
                self.check_interrupted(members)?;
                Ok(None)
            }
            () = stopped => {
                // Told to stop while configuring: the frames of the old epoch were put back,
                // so what is not delivered is abandoned.
                self.abandon = true;
                Err(Halt::Interrupted)
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
