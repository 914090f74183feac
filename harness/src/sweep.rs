//! Accuracy sweeps through a real cluster (`lightfold accuracy --cluster`): every point rendered
//! by an [`InProcessCluster`] — render nodes and compositors running the daemons' own code as
//! tasks, on loopback TCP links, and a coordinator session that plans, drives and collects — so
//! each image measured has been through every link (node → compositor, the compositor chain,
//! sink → coordinator), the material layers' link and the planner's own choices (map sizes,
//! formats, K), where the default sweep renders on one device and simulates only the node →
//! compositor link.

use crate::in_process::{ClusterOptions, InProcessCluster};
use anyhow::Context;
use lightfold_coordinator::control::{ControlOptions, Session};
use lightfold_coordinator::plan::MapSizing;
use lightfold_coordinator::run::RunOptions;
use lightfold_net::Timeouts;
use lightfold_quality::accuracy::{AccuracyError, Measured, Setting};
use lightfold_scene::Scene;
use std::time::Duration;

/// Deadline of a frame, a band and a configuration: generous, since frames of hundreds of
/// lights per node take long on a software rasteriser.
const DEADLINE: Duration = Duration::from_secs(600);

/// An in-process cluster on a runtime of its own and one coordinator session over it, for
/// callers that are not async.
#[derive(Debug)]
pub struct SweepCluster {
    rt: tokio::runtime::Runtime,
    session: Option<Session>,
    cluster: Option<InProcessCluster>,
    control: ControlOptions,
}

impl SweepCluster {
    /// Starts `nodes` render nodes and `compositors` compositors on loopback port 0 and
    /// connects a coordinator session to them.
    pub fn start(nodes: usize, compositors: usize) -> anyhow::Result<SweepCluster> {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .enable_all()
            .build()
            .context("cannot start the async runtime")?;
        let control = ControlOptions {
            link: Timeouts {
                send: DEADLINE,
                ..Timeouts::default()
            },
            register: Duration::from_secs(60),
            configure: DEADLINE,
            frame: DEADLINE,
            // A software-rendered frame keeps a node's device busy for seconds; a false loss
            // would re-plan in the middle of a measurement.
            heartbeat_timeout: Duration::from_secs(30),
            redial: Duration::ZERO,
            ..ControlOptions::default()
        };
        let options = ClusterOptions {
            input_timeout: Some(DEADLINE),
            token: Some(rand::random::<[u8; 32]>().to_vec()),
            ..ClusterOptions::default()
        };
        let cluster = rt.block_on(InProcessCluster::start_with(nodes, compositors, options))?;
        let session = rt.block_on(cluster.connect(control));
        let mut sweep = SweepCluster {
            rt,
            session: None,
            cluster: Some(cluster),
            control,
        };
        match session {
            Ok(s) => sweep.session = Some(s),
            Err(e) => {
                let _ = sweep.stop();
                return Err(e.context("cannot connect the in-process cluster"));
            }
        }
        Ok(sweep)
    }

    /// Renders each setting as one cluster run of `repeats` + 1 frames (the first warms up):
    /// the plan's own options (`MapSizing::Scene`, so the setting's map size; material and
    /// chain formats as planned) with K and the node link format from the setting. The image
    /// is the last frame's; each node's time is its fastest frame after the first, as reported
    /// by the node (`FrameStats::total_us`: shadow, eye, readback, pack and send).
    pub fn measure(
        &mut self,
        scene: &Scene,
        settings: &[Setting],
        repeats: u32,
    ) -> Result<Vec<Measured>, AccuracyError> {
        settings
            .iter()
            .map(|s| self.measure_one(scene, s, repeats))
            .collect()
    }

    fn measure_one(
        &mut self,
        scene: &Scene,
        s: &Setting,
        repeats: u32,
    ) -> Result<Measured, AccuracyError> {
        let err = |message: String| AccuracyError::Render {
            setting: s.to_string(),
            message,
        };
        let session = self
            .session
            .as_mut()
            .ok_or_else(|| err("the cluster is stopped".into()))?;
        let mut scene = scene.clone();
        s.apply(&mut scene);
        let mut opts = RunOptions {
            control: self.control,
            frames: repeats.max(1) + 1,
            ..RunOptions::default()
        };
        opts.plan.lights_per_node = s.k;
        opts.plan.formats.node = s.format;
        opts.plan.penumbra_filter = match s.penumbra {
            0 => lightfold_coordinator::plan::PenumbraFilter::Off,
            r => lightfold_coordinator::plan::PenumbraFilter::Radius(r),
        };
        opts.plan.map_sizing = MapSizing::Scene;
        let mut frames = Vec::new();
        let outcome = self.rt.block_on(lightfold_coordinator::run::render(
            session,
            &scene,
            &opts,
            |f| frames.push(f),
        ));
        if let Some(e) = outcome.error {
            return Err(err(format!(
                "{e} (incidents: {:?})",
                outcome.summary.incidents
            )));
        }
        let plan = outcome
            .summary
            .plan
            .ok_or_else(|| err("the run made no plan".into()))?;
        let (first, timed) = match frames.split_first() {
            Some((f, rest)) if !rest.is_empty() => (f, rest),
            Some((f, _)) => (f, std::slice::from_ref(f)),
            None => return Err(err("no frame arrived".into())),
        };
        // Each node's fastest timed frame: its time, and the pixel-bound share of it (eye pass,
        // readback, pack, send).
        let fastest: Vec<Option<&lightfold_protocol::FrameStats>> = plan
            .nodes
            .iter()
            .map(|n| {
                timed
                    .iter()
                    .filter_map(|f| f.stats.iter().find(|st| st.daemon_id == n.node))
                    .min_by_key(|st| st.total_us)
            })
            .collect();
        let seconds = |us: &dyn Fn(&lightfold_protocol::FrameStats) -> u64| -> Vec<f64> {
            fastest
                .iter()
                .map(|st| st.map_or(0.0, |st| us(st) as f64 / 1e6))
                .collect()
        };
        let node_seconds = seconds(&|st| st.total_us);
        let pixel_seconds = seconds(&|st| st.eye_us + st.readback_us + st.pack_us + st.send_us);
        let last = timed.last().unwrap_or(first);
        Ok(Measured {
            image: last.image.clone(),
            node_seconds,
            pixel_seconds,
            k_run: plan.k,
            lights: plan.active.len(),
        })
    }

    /// Ends the session and stops every daemon, waiting for each (with a deadline).
    pub fn stop(mut self) -> anyhow::Result<()> {
        if let Some(s) = self.session.take() {
            s.detach();
        }
        match self.cluster.take() {
            Some(c) => self.rt.block_on(c.stop()),
            None => Ok(()),
        }
    }
}
