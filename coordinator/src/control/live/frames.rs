//! The frames of the loop: sending requests, collecting images and reports, delivering in
//! order, and putting back what a re-plan interrupts.

use super::core::{Command, Core};
use super::{InFlight, ledger};
use crate::plan::{Plan, Source};
use crate::run::{RunError, frame_params};
use lightfold_protocol::{FrameParams, Message, WireCamera};
use std::sync::Arc;
use std::time::Instant;

/// A frame's camera (at the delivered size) as the nodes render it under `--aa factor`.
fn supersampled(mut c: WireCamera, factor: u32) -> WireCamera {
    let n = factor.max(1);
    (c.width, c.height) = (c.width.saturating_mul(n), c.height.saturating_mul(n));
    c
}

impl Core {
    /// Moves frames whose image and reports are all in to the ledger's complete frames.
    pub(super) fn collect(&mut self) {
        for (f, later) in self.frames.complete(self.participants.len()) {
            self.finish(f, later);
        }
    }

    pub(super) fn finish(&mut self, f: InFlight, latency_frames: u32) {
        let warming = f.warming;
        let Some(r) = ledger::result(f, latency_frames) else {
            return;
        };
        // Refined frames are planned with no budget: they would mislead the budget's cost model.
        if !warming
            && self.refine.is_none()
            && self.plan.as_ref().is_some_and(|p| p.epoch == r.epoch)
        {
            self.adapt.measure(&self.opts, &r.stats);
        }
        self.frames.finished(r);
    }

    pub(super) fn deliver(&mut self) {
        for r in self.frames.deliverable() {
            self.summary.delivered += 1;
            self.replans_without_progress = 0;
            self.command(Command::Deliver(r));
        }
    }

    /// Sends frame requests up to the in-flight limit (none while a re-plan is due).
    pub(super) fn issue(&mut self, now: Instant) -> Result<(), RunError> {
        if self.pending_join.is_some()
            || self.pending_steer.is_some()
            || self.need_replan.is_some()
            || self.reset_at.is_some()
        {
            return Ok(());
        }
        let Some(plan) = &self.plan else {
            return Ok(());
        };
        let limit = self.control.frames_in_flight.max(1);
        let epoch = plan.epoch;
        while self.frames.inflight.len() < limit {
            let Some((index, mut spec)) = self.frames.queue.pop_front() else {
                break;
            };
            self.refused.strip(&mut spec, self.refine);
            let shows = super::scene_id(&spec);
            if shows < self.scene_id {
                // Requested before a scene was opened: it shows the new one as it is.
                spec.scene = None;
                spec.lights = None;
                spec.moves = None;
                spec.light_colors.clear();
            } else if let Some(open) = spec.scene.clone().filter(|_| shows > self.scene_id) {
                self.frames.queue.push_front((index, spec));
                match self.open_scene(&open) {
                    Ok(()) => {
                        let why =
                            format!("scene {:?} opened at frame {index}: planning", open.name);
                        self.notice(why.clone());
                        self.pending_steer = Some(why);
                        self.publish();
                        break;
                    }
                    Err(e) => {
                        let why = format!("cannot open scene {:?}: {e}", open.name);
                        self.notice(why.clone());
                        self.refused.scene = Some(open.id);
                        self.observer
                            .send_modify(|s| s.scene_refused = Some((open.id, why.clone())));
                        // Sent again without it, as the loop's scene.
                        continue;
                    }
                }
            }
            // A light the request names no colour for has the scene's, also after a re-plan
            // recoloured it.
            for (l, (now, given)) in self.scene.lights.iter().zip(&self.scene_colors).enumerate() {
                let named = spec.light_colors.iter().any(|(x, _)| *x as usize == l);
                if !named && now.color.map(f32::to_bits) != given.map(f32::to_bits) {
                    spec.light_colors.push((l as u32, *given));
                }
            }
            self.refuse_moves_it_cannot_make(&mut spec);
            let Some(spec) = self.replan_for_steering(index, spec) else {
                break;
            };
            let Some(plan) = &self.plan else {
                break;
            };
            let wire = self.base + index;
            let params = match frame_params(plan, &spec.light_colors, index, self.recoloured) {
                Ok(p) => p,
                Err(RunError::ColorSplit { node, .. }) => {
                    // The nodes must render with the new colours themselves: re-plan over a
                    // recoloured scene, then send this frame under the new epoch.
                    self.recolour(&spec.light_colors)?;
                    self.frames.queue.push_front((index, spec));
                    let why = format!(
                        "new light colours at frame {index} split the colour group of {node}: re-planning"
                    );
                    self.notice(why.clone());
                    self.pending_steer = Some(why);
                    break;
                }
                Err(e) => return Err(e),
            };
            self.recoloured |= !params.is_empty();
            let bounce = spec.time.and_then(|t| bounce_at(plan, &self.scene, t));
            let mut sends = Vec::with_capacity(self.participants.len());
            for id in &self.participants {
                let mut frame_params = params.get(id).cloned().unwrap_or(FrameParams {
                    colors: Vec::new(),
                    scale: None,
                    time: None,
                    lights: Vec::new(),
                    rows: None,
                });
                frame_params.time = spec.time;
                if let Some(moved) = self.light_frames.get(id) {
                    frame_params.lights = moved.clone();
                }
                if let (Some((first, vpls)), Some(node)) =
                    (&bounce, plan.nodes.iter().find(|n| n.node == *id))
                {
                    frame_params.lights = node
                        .lights
                        .iter()
                        .filter_map(|&i| {
                            let s = vpls.get(i.checked_sub(*first)?)?;
                            Some(lightfold_scene::wire::light_to_wire(s, i as u32))
                        })
                        .collect();
                }
                if let Some(b) = &mut self.tiles {
                    frame_params.rows = b.requested(wire, id);
                }
                if let Some(s) = seed64_node(plan, id).and_then(|_| self.peaks.get(id)) {
                    frame_params.scale = seed64_scale(*s);
                }
                let msg = Message::RenderFrame {
                    epoch,
                    frame: wire,
                    camera: spec.camera.map(|c| supersampled(c, self.supersample())),
                    params: frame_params,
                };
                sends.push(Command::Send {
                    to: id.clone(),
                    msg,
                });
            }
            // A send that fails comes back as a loss, which re-plans and requests this frame
            // again.
            sends.into_iter().for_each(|c| self.command(c));
            self.sent_in_epoch += 1;
            self.frames.inflight.push(InFlight {
                index,
                spec,
                wire,
                sent_at: now,
                image: None,
                stats: Vec::new(),
                slow_warned: false,
                warming: self.sent_in_epoch <= limit as u64,
            });
        }
        Ok(())
    }

    /// Makes `open` the session's scene, once a plan for it fits the daemons connected now: the
    /// next epoch plans it afresh and offers every node its bytes (nodes know a scene by its
    /// hash). What belonged to the scene before goes: light edits and colours, refinement, what
    /// was refused, the settings to go back to, the cost model learned under a budget, and the
    /// `seed64` peaks. The frame budget the viewers set stays.
    pub(super) fn open_scene(&mut self, open: &super::OpenScene) -> Result<(), String> {
        let cluster = self.cluster();
        let options = crate::plan::PlanOptions {
            frame_budget_us: self.opts.frame_budget_us,
            ..open.options.clone()
        };
        let (scene, opts) =
            super::prepare(&open.scene, &cluster, &options).map_err(|e| e.to_string())?;
        crate::plan::plan(&scene, &cluster, &opts).map_err(|e| e.to_string())?;
        let bytes = scene.to_bytes().map_err(|e| e.to_string())?;
        self.hash = scene.content_hash();
        self.bytes = std::sync::Arc::new(bytes);
        self.scene_colors = scene.lights.iter().map(|l| l.color).collect();
        self.chunked = scene.meshes.len() != open.scene.meshes.len();
        self.moves = Arc::new(Vec::new());
        self.scene = scene;
        self.opts = opts;
        self.scene_id = open.id;
        self.fresh_plan = true;
        self.subsets.clear();
        self.refine = None;
        self.target_samples = None;
        self.good = None;
        self.refused = super::Refused::default();
        self.adapt = Default::default();
        self.peaks.clear();
        self.recoloured = false;
        Ok(())
    }

    /// Takes out of `spec` a move list the loop cannot make (`Core::check_moves`): a notice,
    /// frames asking for it again sent without it, and the moves rendered published for the
    /// viewers to take back.
    fn refuse_moves_it_cannot_make(&mut self, spec: &mut super::FrameSpec) {
        if let Some(moves) = spec.moves.clone().filter(|m| **m != *self.moves)
            && let Err(e) = self.check_moves(&moves)
        {
            self.notice(format!(
                "cannot move the objects ({e}): they stay where they are"
            ));
            self.refused.moves = Some(moves);
            spec.moves = None;
            self.publish_moves_put_back();
        }
    }

    /// Frame `index` as requested: `Some(spec)` to send it under the plan there is, or `None`
    /// when it asks for a budget, refinement, light edit or move the plan lacks — the settings
    /// are taken, the frame is put back at the head of the queue and a re-plan is due once the
    /// frames in flight are done (one re-plan for all of them).
    fn replan_for_steering(
        &mut self,
        index: u64,
        spec: super::FrameSpec,
    ) -> Option<super::FrameSpec> {
        let budget = spec
            .frame_budget_us
            .filter(|b| *b != self.opts.frame_budget_us);
        let edit = spec
            .lights
            .clone()
            .filter(|l| !super::same_lights(l, &self.scene.lights));
        let moved = spec.moves.clone().filter(|m| **m != *self.moves);
        if budget.is_some() || spec.refine != self.refine || edit.is_some() || moved.is_some() {
            // Plan under the new budget or refinement (one re-plan for both), then send this
            // frame under the new epoch.
            let mut why = Vec::new();
            if let Some(budget) = budget {
                self.opts.frame_budget_us = budget;
                self.adapt.budget_changed();
                let text = match budget {
                    Some(us) => format!(
                        "frame budget {:.1} ms from frame {index}: re-planning",
                        us as f64 / 1e3
                    ),
                    None => format!("no frame budget from frame {index}: re-planning"),
                };
                self.notice(text.clone());
                why.push(text);
            }
            if let Some(lights) = edit {
                self.edit_lights(&lights);
                let alone = budget.is_none() && spec.refine == self.refine && moved.is_none();
                if alone && self.light_edit_in_place() {
                    tracing::debug!("lights edited at frame {index}: sent with the frames");
                    return Some(spec);
                }
                let text = format!(
                    "lights edited at frame {index} ({} light(s)): re-planning",
                    lights.len()
                );
                tracing::info!("{text}");
                why.push(text);
            }
            if let Some(moves) = moved {
                let text = format!(
                    "objects moved at frame {index} ({} moved): re-planning",
                    moves.iter().filter(|m| !m.is_identity()).count()
                );
                tracing::info!("{text}");
                self.moves = moves;
                why.push(text);
            }
            if spec.refine != self.refine {
                // Each refinement step re-plans: told in the log and the epoch's reason,
                // not as a notice (the page would show one every step).
                let text = match spec.refine {
                    Some(r) => format!("refining from frame {index} ({r}): re-planning"),
                    None => {
                        format!("back to the session's quality from frame {index}: re-planning")
                    }
                };
                tracing::info!("{text}");
                self.refine = spec.refine;
                why.push(text);
            }
            self.frames.queue.push_front((index, spec));
            self.pending_steer = Some(why.join("; "));
            self.publish();
            return None;
        }
        Some(spec)
    }

    /// Tells whoever steers the moves the loop renders after refusing others
    /// (`LiveStatus::moves_put_back`, numbered from 1).
    pub(super) fn publish_moves_put_back(&self) {
        let back = Arc::clone(&self.moves);
        self.observer.send_modify(|s| {
            let n = s.moves_put_back.as_ref().map_or(1, |(n, _)| n + 1);
            s.moves_put_back = Some((n, back));
        });
    }

    /// Makes `lights` the scene's: the next plan renders them, each with its base colour. Nodes
    /// keep the scene bytes they hold (and sort-last parts theirs): a node's lights reach it in
    /// its configuration, so its renderer, and the maps of lights that did not change, stay.
    pub(super) fn edit_lights(&mut self, lights: &[lightfold_scene::Light]) {
        self.scene.lights = lights.to_vec();
        self.scene_colors = lights.iter().map(|l| l.color).collect();
    }

    /// Whether the scene's lights, as just edited, can be rendered without a new epoch: planned
    /// again over the current plan, every daemon's configuration is the same but for where its
    /// lights are and how strong (the same samples, kinds, colours, groups, casters and map
    /// sizes, the same stages). Then the moved lights go to their nodes with every frame
    /// (`Core::light_frames`) and nodes redraw only their maps. Not for an animated scene
    /// (nodes pose its lights), a refinement or moved objects (planned from other scenes).
    fn light_edit_in_place(&mut self) -> bool {
        let Some(old) = self.plan.as_ref() else {
            return false;
        };
        if self.scene.is_animated() || self.refine.is_some() || self.moved_scene().is_some() {
            return false;
        }
        let mut o = self.opts.clone();
        o.epoch = old.epoch;
        let Ok(new) = crate::plan::replan(&self.scene, &self.cluster(), &o, old) else {
            return false;
        };
        match moved_lights(old, &new) {
            Some(mut frames) => {
                // A node whose lights are all back where its configuration has them is sent
                // them so (a frame without lights keeps the last frame's).
                for node in self.light_frames.keys() {
                    if !frames.contains_key(node)
                        && let Some(c) = old.node_config(node)
                    {
                        frames.insert(node.clone(), c.lights);
                    }
                }
                self.light_frames = frames;
                true
            }
            None => false,
        }
    }

    /// Gives the scene's lights the colours of `colors` (source light → colour), as the next plan
    /// and the nodes will have them.
    pub(super) fn recolour(&mut self, colors: &[(u32, [f32; 3])]) -> Result<(), RunError> {
        for &(light, color) in colors {
            if let Some(l) = self.scene.lights.get_mut(light as usize) {
                l.color = color;
            }
        }
        self.bytes = std::sync::Arc::new(
            self.scene
                .to_bytes()
                .map_err(|e| RunError::Scene(e.to_string()))?,
        );
        self.hash = self.scene.content_hash();
        self.subsets.clear();
        Ok(())
    }

    /// Keeps the frames in flight that reached the sink (their image is complete) and puts the
    /// others back at the head of the queue, in order.
    pub(super) fn salvage(&mut self) {
        let (kept, again) = self.frames.salvage();
        for f in kept {
            self.finish(f, 0);
        }
        self.summary.rerequested += again;
    }
}

/// The daemons frame `f` waits on: those of the plan that have not reported it while everything
/// upstream of them has (nodes have nothing upstream); the last stage when every daemon reported
/// and only the image is missing.
pub(super) fn waiting_on(plan: &Plan, f: &InFlight) -> Vec<String> {
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

/// How far above the latest measured maximum a `seed64` link's next scale is set: room for a
/// scene that brightens by up to 25 % between the measured frame and the next (with frames in
/// flight the measurement is that many frames old), at a cost of 1.25× the quantisation step.
pub const SEED64_HEADROOM: f32 = 1.25;

/// The `seed64` scale a link gets after a frame whose illumination peaked at `peak`
/// (`FrameStats::peak`): `peak × SEED64_HEADROOM`; `None` (keep the current scale) for a black
/// or non-finite peak.
pub fn seed64_scale(peak: f32) -> Option<f32> {
    let s = peak * SEED64_HEADROOM;
    (s.is_finite() && s > 0.0).then_some(s)
}

/// Whether node `id` sends a `seed64` layer in `plan`.
fn seed64_node(plan: &crate::plan::Plan, id: &str) -> Option<()> {
    plan.nodes
        .iter()
        .find(|n| n.node == id)
        .filter(|n| {
            n.layers
                .iter()
                .any(|(_, f)| *f == lightfold_protocol::PixelFormat::Seed64)
        })
        .map(|_| ())
}

/// An animated scene's virtual point lights at time `t` for `plan` (planned from `scene`, or
/// from it with other samples per light): the index of its first VPL and the VPLs traced
/// again at `t` from its direct samples, slot for slot with the plan's. `None` for a still scene,
/// one without VPLs, or a plan whose VPL slots the scene does not give.
fn bounce_at(
    plan: &crate::plan::Plan,
    scene: &lightfold_scene::Scene,
    t: f32,
) -> Option<(usize, Vec<lightfold_scene::LightSample>)> {
    if !scene.is_animated() || scene.quality.indirect == 0 {
        return None;
    }
    let bounce = |s: &lightfold_scene::LightSample| {
        matches!(s.kind, lightfold_scene::SampleKind::Bounce { .. })
    };
    let first = plan.samples.iter().position(bounce)?;
    let vpls = lightfold_scene::vpl::vpls_at(scene, &plan.samples[..first], t);
    (vpls.len() == plan.samples.len() - first && plan.samples[first..].iter().all(bounce))
        .then_some((first, vpls))
}

/// Per node, its lights in `new` that differ from `old`, when every daemon's configuration under
/// `new` is the one under `old` but for where its lights are and how strong; `None` otherwise.
fn moved_lights(
    old: &Plan,
    new: &Plan,
) -> Option<std::collections::HashMap<String, Vec<lightfold_protocol::WireLight>>> {
    let same_sample = |a: &lightfold_scene::LightSample, b: &lightfold_scene::LightSample| {
        std::mem::discriminant(&a.kind) == std::mem::discriminant(&b.kind)
            && a.color == b.color
            && a.range == b.range
            && a.light == b.light
            && a.area.is_some() == b.area.is_some()
    };
    if old.samples.len() != new.samples.len()
        || old.nodes.len() != new.nodes.len()
        || old.stages.len() != new.stages.len()
        || !old
            .samples
            .iter()
            .zip(&new.samples)
            .all(|(a, b)| same_sample(a, b))
    {
        return None;
    }
    let mut probe = new.clone();
    probe.epoch = old.epoch;
    probe.scene_hash = old.scene_hash;
    for (p, o) in probe.nodes.iter_mut().zip(&old.nodes) {
        p.scene = o.scene;
    }
    let mut frames = std::collections::HashMap::new();
    for n in &old.nodes {
        let (was, now) = (old.node_config(&n.node)?, probe.node_config(&n.node)?);
        let unmoved = lightfold_protocol::NodeConfig {
            lights: was.lights.clone(),
            ..now.clone()
        };
        if unmoved != was {
            return None;
        }
        let moved: Vec<_> = now
            .lights
            .iter()
            .zip(&was.lights)
            .filter(|(a, b)| a != b)
            .map(|(a, _)| *a)
            .collect();
        if !moved.is_empty() {
            frames.insert(n.node.clone(), moved);
        }
    }
    let same_stages = old
        .stages
        .iter()
        .all(|s| old.compositor_config(&s.compositor) == probe.compositor_config(&s.compositor));
    same_stages.then_some(frames)
}

#[cfg(test)]
mod tests {
    use super::moved_lights;
    use crate::plan::{ClusterSpec, PlanOptions, plan, replan};
    use lightfold_scene::LightShape;

    /// A light nudged keeps every configuration but its own lights: they go to the nodes that
    /// hold its samples and nowhere else. A light added, recoloured or moved where its casters
    /// change needs a new epoch (the controls).
    #[test]
    fn a_nudged_light_rides_with_the_frames_and_other_edits_re_plan() {
        let mut scene = lightfold_scene::builtin("balls").unwrap();
        scene.quality.samples_per_area_light = Some(4);
        scene.camera.width = 64;
        scene.camera.height = 48;
        let cluster = ClusterSpec::local(8, 8);
        let opts = PlanOptions {
            lights_per_node: 4,
            walkthrough: true,
            ..PlanOptions::default()
        };
        let old = plan(&scene, &cluster, &opts).unwrap();
        let edited = |f: &dyn Fn(&mut lightfold_scene::Scene)| {
            let mut s = scene.clone();
            f(&mut s);
            replan(&s, &cluster, &opts, &old).unwrap()
        };
        let shift = |s: &mut lightfold_scene::Scene, d: f32| match &mut s.lights[0].shape {
            LightShape::Rect { center, .. }
            | LightShape::Disk { center, .. }
            | LightShape::Sphere { center, .. } => center[0] += d,
            other => panic!("{other:?}"),
        };
        let nudged = edited(&|s| shift(s, 0.01));
        let frames = moved_lights(&old, &nudged).expect("a nudge keeps the plan");
        let holders: Vec<&str> = old
            .nodes
            .iter()
            .filter(|n| n.lights.iter().any(|&i| old.samples[i].light == 0))
            .map(|n| n.node.as_str())
            .collect();
        let mut sent: Vec<&str> = frames.keys().map(String::as_str).collect();
        sent.sort_unstable();
        let mut want = holders.clone();
        want.sort_unstable();
        assert_eq!(sent, want, "only the nodes holding light 0's samples");
        for lights in frames.values() {
            for w in lights {
                assert_eq!(old.samples[w.sample as usize].light, 0);
            }
        }
        // The controls.
        let mut added = scene.clone();
        added.lights.push(added.lights[0].clone());
        let added = replan(&added, &cluster, &opts, &old).unwrap();
        assert!(moved_lights(&old, &added).is_none(), "a light added");
        let recoloured = edited(&|s| s.lights[0].color = [1.0, 0.2, 0.2]);
        assert!(
            moved_lights(&old, &recoloured).is_none(),
            "a light recoloured"
        );
        assert!(moved_lights(&old, &old).is_some_and(|f| f.is_empty()));
    }
}
