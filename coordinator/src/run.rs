//! One coordinator run: connect the cluster, plan the scene, send it, configure every daemon,
//! drive the frames and collect the images with their per-frame reports.

use crate::control::{
    ControlError, ControlOptions, FrameRequest, Participants, Session, SinkGeometry,
};
use crate::plan::{ClusterSpec, DaemonSpec, Plan, PlanError, PlanOptions, plan};
use lightfold_protocol::{FrameParams, Message, Role};
use lightfold_scene::{Camera, Scene};
use std::collections::HashMap;

/// The frames to render.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FramePath {
    /// The scene's camera, every frame.
    Still,
    /// The camera orbits its target about the up axis by `degrees` per frame.
    Orbit { degrees: f32 },
}

/// A change of light colour at a frame: every sample of source light `light` gets `color`.
#[derive(Debug, Clone, PartialEq)]
pub struct ColorChange {
    pub frame: u64,
    pub light: u32,
    pub color: [f32; 3],
}

#[derive(Debug, Clone)]
pub struct RunOptions {
    pub plan: PlanOptions,
    pub frames: u32,
    pub path: FramePath,
    pub color_changes: Vec<ColorChange>,
    pub control: ControlOptions,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            plan: PlanOptions::default(),
            frames: 1,
            path: FramePath::Still,
            color_changes: Vec::new(),
            control: ControlOptions::default(),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error(transparent)]
    Control(#[from] ControlError),
    #[error("planning failed: {0}")]
    Plan(#[from] PlanError),
    #[error("cannot encode the scene: {0}")]
    Scene(String),
    #[error(
        "light colour change at frame {frame} splits the colour group of node {node}: re-plan needed"
    )]
    ColorSplit { frame: u64, node: String },
}

/// The cluster spec of a connected session.
pub fn cluster_spec(session: &Session) -> ClusterSpec {
    let spec = |role: Role| -> Vec<DaemonSpec> {
        session
            .daemons
            .iter()
            .filter(|(_, d)| d.caps.role == role)
            .map(|(id, d)| DaemonSpec {
                id: id.clone(),
                address: d.address.clone(),
                capabilities: Some(d.caps.clone()),
            })
            .collect()
    };
    ClusterSpec {
        nodes: spec(Role::Node),
        compositors: spec(Role::Compositor),
        sink: session.sink_address.clone(),
    }
}

/// Plans `scene` for the connected cluster, sends it and configures every daemon the plan uses.
pub async fn apply(
    session: &mut Session,
    scene: &Scene,
    opts: &PlanOptions,
) -> Result<Plan, RunError> {
    let spec = cluster_spec(session);
    let mut plan = plan(scene, &spec, opts)?;
    let bytes = scene
        .to_bytes()
        .map_err(|e| RunError::Scene(e.to_string()))?;
    // Nodes decode what they receive and check it against this.
    let hash = scene.content_hash();
    plan.scene_hash = hash;
    let nodes: Vec<String> = plan.nodes.iter().map(|n| n.node.clone()).collect();
    session.distribute_scene(&nodes, hash, &bytes).await?;
    let mut configs = Vec::new();
    for stage in &plan.stages {
        let cfg = plan
            .compositor_config(&stage.compositor)
            .ok_or_else(|| ControlError::UnknownDaemon(stage.compositor.clone()))?;
        configs.push((stage.compositor.clone(), Message::ConfigureCompositor(cfg)));
    }
    for node in &plan.nodes {
        let cfg = plan
            .node_config(&node.node)
            .ok_or_else(|| ControlError::UnknownDaemon(node.node.clone()))?;
        configs.push((node.node.clone(), Message::ConfigureNode(cfg)));
    }
    let geometry = SinkGeometry {
        epoch: plan.epoch,
        width: plan.width,
        height: plan.height,
        band_height: plan.band_height,
    };
    session.configure(configs, plan.epoch, geometry).await?;
    Ok(plan)
}

/// The daemons `plan` uses.
pub fn participants(plan: &Plan) -> Participants {
    Participants {
        compositors: plan.stages.iter().map(|s| s.compositor.clone()).collect(),
        nodes: plan.nodes.iter().map(|n| n.node.clone()).collect(),
    }
}

/// The camera of frame `i` along `path`.
pub fn camera_at(base: &Camera, path: FramePath, i: u32) -> Camera {
    match path {
        FramePath::Still => *base,
        FramePath::Orbit { degrees } => base.orbited(degrees * i as f32),
    }
}

/// Frame requests for a plan: cameras along the path, and per-frame colour overrides for the
/// stages whose inputs' node colours change.
pub fn requests(
    plan: &Plan,
    opts: &RunOptions,
    first_frame: u64,
) -> Result<Vec<FrameRequest>, RunError> {
    let mut colors: Vec<[f32; 3]> = plan.samples.iter().map(|s| s.color).collect();
    let mut out = Vec::new();
    for i in 0..opts.frames {
        let frame = first_frame + i as u64;
        let mut changed = false;
        for ch in opts.color_changes.iter().filter(|c| c.frame == frame) {
            for (k, s) in plan.samples.iter().enumerate() {
                if s.light == ch.light {
                    colors[k] = ch.color;
                    changed = true;
                }
            }
        }
        let mut params: HashMap<String, FrameParams> = HashMap::new();
        if changed || opts.color_changes.iter().any(|c| c.frame < frame) {
            for node in plan.nodes.iter().filter(|n| !n.lights.is_empty()) {
                let new_c =
                    group_color(plan, node, &colors).ok_or_else(|| RunError::ColorSplit {
                        frame,
                        node: node.node.clone(),
                    })?;
                params
                    .entry(node.downstream.clone())
                    .or_insert_with(|| FrameParams {
                        colors: Vec::new(),
                        scale: None,
                    })
                    .colors
                    .push((node.input_index, new_c));
            }
        }
        let camera = (opts.path != FramePath::Still)
            .then(|| lightfold_scene::wire::camera_to_wire(&camera_at(&plan.camera, opts.path, i)));
        out.push(FrameRequest {
            frame,
            camera,
            params,
        });
    }
    Ok(out)
}

/// The node colour that keeps the node's output unchanged under new light colours: the new
/// colours must be the old ones scaled by one common factor per channel.
fn group_color(plan: &Plan, node: &crate::plan::NodePlan, colors: &[[f32; 3]]) -> Option<[f32; 3]> {
    let mut factor: Option<[f32; 3]> = None;
    for &l in &node.lights {
        let old = plan.samples[l].color;
        let new = colors[l];
        let mut f = [0.0f32; 3];
        for c in 0..3 {
            f[c] = if old[c] != 0.0 {
                new[c] / old[c]
            } else if new[c] == 0.0 {
                factor.map_or(0.0, |x| x[c])
            } else {
                return None;
            };
        }
        match factor {
            None => factor = Some(f),
            Some(prev) => {
                if (0..3).any(|c| (prev[c] - f[c]).abs() > 1e-6 * prev[c].abs().max(1.0)) {
                    return None;
                }
            }
        }
    }
    let f = factor.unwrap_or([1.0; 3]);
    Some([
        node.color[0] * f[0],
        node.color[1] * f[1],
        node.color[2] * f[2],
    ])
}
