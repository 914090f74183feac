//! What a coordinator run is made of: its options and errors, the cluster spec of a session, and
//! the frame requests of a scripted run (a camera path, light colour changes) with the per-frame
//! parameters they need under a plan. The event loop that runs them is `control::live`.

use crate::control::{
    ControlError, ControlOptions, FrameResult, FrameSpec, Live, LiveSummary, Session,
};
use crate::plan::{ClusterSpec, DaemonSpec, Plan, PlanError, PlanOptions};
use lightfold_protocol::{FrameParams, Role};
use lightfold_scene::{Camera, Scene};
use std::collections::HashMap;
use tokio_util::sync::CancellationToken;

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
    /// Scene time of the first frame (seconds); `None` with no `fps`: the rest pose.
    pub time: Option<f32>,
    /// Animation frames per second: frame `i` is at `time + i / fps`.
    pub fps: Option<f32>,
    /// Frames of the path (numbered from 1) already done, not rendered again: a run resumed
    /// after its coordinator died (`--resume`). The others keep their numbers, cameras and
    /// scene times.
    pub skip: Vec<u64>,
}

impl RunOptions {
    /// The scene time of frame `i` (0-based), `None` for the rest pose.
    pub fn time_of(&self, i: u32) -> Option<f32> {
        match (self.time, self.fps) {
            (None, None) => None,
            (t, None) => t,
            (t, Some(fps)) => Some(t.unwrap_or(0.0) + i as f32 / fps),
        }
    }
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            plan: PlanOptions::default(),
            frames: 1,
            path: FramePath::Still,
            color_changes: Vec::new(),
            control: ControlOptions::default(),
            time: None,
            fps: None,
            skip: Vec::new(),
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
    #[error(transparent)]
    Supersample(#[from] lightfold_scene::supersample::SupersampleError),
    #[error("no plan fits the daemons left ({error}); lost: {lost}")]
    TooFewDaemons { error: PlanError, lost: String },
}

/// The cluster spec of a connected session.
pub fn cluster_spec(session: &Session) -> ClusterSpec {
    cluster_of(
        session
            .daemons
            .iter()
            .map(|(id, d)| (id.as_str(), d.address.as_str(), &d.caps)),
        &session.sink_address,
    )
}

/// The cluster spec of registered daemons (id, dialled address, capabilities) and a sink address.
pub fn cluster_of<'a>(
    daemons: impl IntoIterator<Item = (&'a str, &'a str, &'a lightfold_protocol::Capabilities)>,
    sink: &str,
) -> ClusterSpec {
    let (mut nodes, mut compositors) = (Vec::new(), Vec::new());
    for (id, address, caps) in daemons {
        let spec = DaemonSpec {
            id: id.to_string(),
            address: address.to_string(),
            capabilities: Some(caps.clone()),
        };
        match caps.role {
            Role::Node => nodes.push(spec),
            Role::Compositor => compositors.push(spec),
            _ => {}
        }
    }
    ClusterSpec {
        nodes,
        compositors,
        sink: sink.to_string(),
    }
}

/// The camera of frame `i` along `path`.
pub fn camera_at(base: &Camera, path: FramePath, i: u32) -> Camera {
    match path {
        FramePath::Still => *base,
        FramePath::Orbit { degrees } => base.orbited(degrees * i as f32),
    }
}

/// The frame requests of a scripted run: cameras along the path (frame `i` of `opts.frames`
/// at `camera_at(.., i)`), and the light colours in effect at each frame (a change stays until
/// changed again). Frame numbers start at 1, like `FrameResult::frame`.
pub fn frame_specs(scene: &Scene, opts: &RunOptions) -> Vec<FrameSpec> {
    let mut colors: Vec<(u32, [f32; 3])> = Vec::new();
    (0..opts.frames)
        .map(|i| {
            let frame = u64::from(i) + 1;
            for ch in opts.color_changes.iter().filter(|c| c.frame == frame) {
                colors.retain(|(l, _)| *l != ch.light);
                colors.push((ch.light, ch.color));
            }
            let camera = (opts.path != FramePath::Still).then(|| {
                lightfold_scene::wire::camera_to_wire(&camera_at(&scene.camera, opts.path, i))
            });
            FrameSpec {
                camera,
                light_colors: colors.clone(),
                time: opts.time_of(i),
                frame_budget_us: None,
                refine: None,
                lights: None,
                scene: None,
                moves: None,
            }
        })
        .collect()
}

/// Per-daemon frame parameters for light colours `colors` (source light → colour) under
/// `plan`: for every stage input whose node's colour changes, the new `c_n`. Empty when no colour
/// differs from the plan's, unless `reset`: a stage keeps the colours the last frame that set
/// any gave it (they are operator parameters) until its next configuration, so once a frame of
/// an epoch changed colours, every later frame of it names every node's colour (`reset`), those
/// of the plan included.
pub fn frame_params(
    plan: &Plan,
    colors: &[(u32, [f32; 3])],
    frame: u64,
    reset: bool,
) -> Result<HashMap<String, FrameParams>, RunError> {
    let mut params: HashMap<String, FrameParams> = HashMap::new();
    let mut per_sample: Vec<[f32; 3]> = plan.samples.iter().map(|s| s.color).collect();
    let mut changed = false;
    let bounce = |s: &lightfold_scene::LightSample| {
        matches!(s.kind, lightfold_scene::SampleKind::Bounce { .. })
    };
    // Per changed light: its new colour and its colour in the plan (that of its direct samples),
    // looked up once.
    let changes: Vec<(u32, [f32; 3], [f32; 3])> = colors
        .iter()
        .map(|&(l, c)| {
            let source = plan
                .samples
                .iter()
                .find(|d| d.light == l && !bounce(d))
                .map_or([1.0; 3], |d| d.color);
            (l, c, source)
        })
        .collect();
    for (k, s) in plan.samples.iter().enumerate() {
        if let Some(&(_, c, source)) = changes.iter().find(|(l, _, _)| *l == s.light) {
            // A virtual point light's colour is its source's times the albedo it bounced off:
            // it changes by the source's ratio.
            let new = if bounce(s) {
                std::array::from_fn(|i| {
                    if source[i] != 0.0 {
                        s.color[i] * c[i] / source[i]
                    } else {
                        0.0
                    }
                })
            } else {
                c
            };
            changed |= new.map(f32::to_bits) != s.color.map(f32::to_bits);
            per_sample[k] = new;
        }
    }
    if !changed && !reset {
        return Ok(params);
    }
    for node in plan.nodes.iter().filter(|n| !n.lights.is_empty()) {
        let new_c = group_color(plan, node, &per_sample).ok_or_else(|| RunError::ColorSplit {
            frame,
            node: node.node.clone(),
        })?;
        params
            .entry(node.downstream.clone())
            .or_insert_with(|| FrameParams {
                colors: Vec::new(),
                scale: None,
                time: None,
                lights: Vec::new(),
                rows: None,
            })
            .colors
            .push((node.input_index, new_c));
    }
    Ok(params)
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

/// What a run produced: the summary, and the error that ended it early, if any (the frames
/// delivered before it were handed over).
#[derive(Debug)]
pub struct RunOutcome {
    pub summary: LiveSummary,
    pub error: Option<RunError>,
}

/// Renders the frames of `opts` (a camera path, colour changes) on a connected session through
/// the event loop, handing each finished frame to `on_frame` in order.
pub async fn render(
    session: &mut Session,
    scene: &Scene,
    opts: &RunOptions,
    on_frame: impl FnMut(FrameResult),
) -> RunOutcome {
    render_until(session, scene, opts, CancellationToken::new(), on_frame).await
}

/// As `render`, but when `stop` is cancelled (Ctrl-C) no further frame is requested: the frames
/// in flight are finished and handed over, and the run ends early without an error.
pub async fn render_until(
    session: &mut Session,
    scene: &Scene,
    opts: &RunOptions,
    stop: CancellationToken,
    mut on_frame: impl FnMut(FrameResult),
) -> RunOutcome {
    // Frames of `opts.skip` are not requested; the loop numbers what it delivers 1, 2, …, which
    // is put back to the path's numbers here.
    let skip: std::collections::HashSet<u64> = opts.skip.iter().copied().collect();
    let (numbers, specs): (Vec<u64>, Vec<FrameSpec>) = frame_specs(scene, opts)
        .into_iter()
        .zip(1u64..)
        .filter(|(_, n)| !skip.contains(n))
        .map(|(s, n)| (n, s))
        .unzip();
    let on_frame = move |mut f: FrameResult| {
        if let Some(&n) = f
            .frame
            .checked_sub(1)
            .and_then(|i| usize::try_from(i).ok())
            .and_then(|i| numbers.get(i))
        {
            f.frame = n;
        }
        on_frame(f)
    };
    let (tx, rx) = tokio::sync::mpsc::channel(opts.control.frames_in_flight.max(1));
    let stopped = stop.clone();
    let feeder = tokio::spawn(async move {
        for s in specs {
            tokio::select! {
                _ = stop.cancelled() => return,
                r = tx.send(s) => if r.is_err() { return },
            }
        }
    });
    let mut live = match Live::new(session, scene, &opts.plan) {
        Ok(l) => l,
        Err(e) => {
            feeder.abort();
            return RunOutcome {
                summary: LiveSummary::default(),
                error: Some(e),
            };
        }
    };
    live.stop_on(stopped);
    let error = live.run(rx, on_frame).await.err();
    feeder.abort();
    RunOutcome {
        summary: std::mem::take(&mut live.summary),
        error,
    }
}
