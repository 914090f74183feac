//! lightfold's integration tests: the in-process cluster harness (coordinator, render nodes and
//! compositors as tasks on `127.0.0.1:0` in one process), and the tests that use it. Every wait
//! has a deadline.

use anyhow::Context;
use lightfold_compositor::daemon::{self as stage, CompositorOptions};
use lightfold_coordinator::control::{
    ControlOptions, DaemonAddr, FrameResult, LiveSummary, Session,
};
use lightfold_coordinator::plan::Plan;
use lightfold_coordinator::run::RunOptions;
use lightfold_net::{Identity, Timeouts};
use lightfold_node::daemon::{self as node, NodeOptions};
use lightfold_node::gpu::{Gpu, GpuOptions, LayerSet, RenderOptions, Renderer};
use lightfold_protocol::{Role, stats};
use lightfold_scene::shading::{MaterialLayers, compose_frame};
use lightfold_scene::{Image, Scene};
use std::time::Duration;
use tokio::net::TcpListener;
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;

/// Deadline for a whole in-process run (connect, plan, frames).
pub const RUN_DEADLINE: Duration = Duration::from_secs(300);

/// One daemon task: its id, address, its own stop token, and the task.
#[derive(Debug)]
struct Running {
    id: String,
    addr: String,
    node: bool,
    stop: CancellationToken,
    task: Option<JoinHandle<anyhow::Result<()>>>,
}

/// Daemons running as tasks of this process.
#[derive(Debug)]
pub struct InProcessCluster {
    pub nodes: Vec<String>,
    pub compositors: Vec<String>,
    pub token: Vec<u8>,
    pub stage_metrics: Vec<std::sync::Arc<lightfold_compositor::daemon::StageMetrics>>,
    cancel: CancellationToken,
    daemons: Vec<Running>,
    /// The memory render nodes report (`NodeOptions::memory_bytes`; `None`: the machine's).
    node_memory: Option<u64>,
}

/// What one coordinator run produced.
#[derive(Debug)]
pub struct RunOutput {
    pub plan: Plan,
    pub frames: Vec<FrameResult>,
    pub summary: LiveSummary,
}

impl InProcessCluster {
    /// Starts `nodes` render nodes and `compositors` compositors on loopback port 0.
    pub async fn start(nodes: usize, compositors: usize) -> anyhow::Result<Self> {
        Self::start_with_node_memory(nodes, compositors, None).await
    }

    /// [`InProcessCluster::start`] with render nodes that report `memory` bytes at
    /// registration (what automatic partitioning plans for).
    pub async fn start_with_node_memory(
        nodes: usize,
        compositors: usize,
        memory: Option<u64>,
    ) -> anyhow::Result<Self> {
        let token = b"in-process cluster token".to_vec();
        let cancel = CancellationToken::new();
        let mut c = InProcessCluster {
            nodes: Vec::new(),
            compositors: Vec::new(),
            token: token.clone(),
            stage_metrics: Vec::new(),
            cancel: cancel.clone(),
            daemons: Vec::new(),
            node_memory: memory,
        };
        for i in 0..nodes {
            let listener = TcpListener::bind("127.0.0.1:0").await?;
            let addr = listener.local_addr()?.to_string();
            c.nodes.push(addr.clone());
            c.spawn(format!("node-{i}"), addr, true, listener);
        }
        for i in 0..compositors {
            let listener = TcpListener::bind("127.0.0.1:0").await?;
            let addr = listener.local_addr()?.to_string();
            c.compositors.push(addr.clone());
            c.spawn(format!("comp-{i}"), addr, false, listener);
        }
        Ok(c)
    }

    fn spawn(&mut self, id: String, addr: String, node: bool, listener: TcpListener) {
        let stop = self.cancel.child_token();
        let task = if node {
            let mut opts = NodeOptions::new(id.clone(), &self.token);
            opts.memory_bytes = self.node_memory;
            tokio::spawn(node::run(listener, opts, stop.clone()))
        } else {
            let opts = CompositorOptions::new(id.clone(), addr.clone(), &self.token);
            self.stage_metrics.push(opts.metrics.clone());
            tokio::spawn(stage::run(listener, opts, stop.clone()))
        };
        self.daemons.retain(|d| d.id != id);
        self.daemons.push(Running {
            id,
            addr,
            node,
            stop,
            task: Some(task),
        });
    }

    /// A token that stops daemon `id` when cancelled (for tests that stop a daemon mid-run from
    /// another task).
    pub fn stop_token(&self, id: &str) -> Option<CancellationToken> {
        self.daemons
            .iter()
            .find(|d| d.id == id)
            .map(|d| d.stop.clone())
    }

    /// Stops daemon `id` at once: its links close as a killed process's would (the coordinator
    /// sees its control link end). Returns once it has stopped.
    pub async fn kill(&mut self, id: &str) -> anyhow::Result<()> {
        let d = self
            .daemons
            .iter_mut()
            .find(|d| d.id == id)
            .with_context(|| format!("no daemon {id}"))?;
        d.stop.cancel();
        if let Some(t) = d.task.take() {
            tokio::time::timeout(Duration::from_secs(20), t)
                .await
                .with_context(|| format!("{id} did not stop within 20 s"))???;
        }
        Ok(())
    }

    /// Starts daemon `id` again on its old address (after `kill`), as a supervisor restarting
    /// a crashed process would.
    pub async fn restart(&mut self, id: &str) -> anyhow::Result<()> {
        let d = self
            .daemons
            .iter()
            .find(|d| d.id == id)
            .with_context(|| format!("no daemon {id}"))?;
        let (addr, node) = (d.addr.clone(), d.node);
        let listener = TcpListener::bind(&addr)
            .await
            .with_context(|| format!("cannot bind {addr} again"))?;
        self.spawn(id.to_string(), addr, node, listener);
        Ok(())
    }

    pub fn daemons(&self) -> Vec<DaemonAddr> {
        DaemonAddr::list(&self.nodes, &self.compositors)
    }

    pub fn identity(&self) -> Identity {
        Identity::new(&self.token, Role::Coordinator, "coordinator")
    }

    /// Connects a coordinator session (nodes get time to open their devices).
    pub async fn connect(&self, control: ControlOptions) -> anyhow::Result<Session> {
        let sink = TcpListener::bind("127.0.0.1:0").await?;
        let session = tokio::time::timeout(
            RUN_DEADLINE,
            Session::connect(&self.daemons(), sink, None, self.identity(), control),
        )
        .await
        .context("connecting the cluster timed out")??;
        Ok(session)
    }

    /// Plans `scene`, configures the cluster and renders `opts.frames` frames.
    pub async fn render(&self, scene: &Scene, opts: &RunOptions) -> anyhow::Result<RunOutput> {
        let mut session = self.connect(opts.control).await?;
        let out = render_on(&mut session, scene, opts).await;
        session.detach();
        out
    }

    /// Stops every daemon and waits for them (with a deadline).
    pub async fn stop(self) -> anyhow::Result<()> {
        self.cancel.cancel();
        for d in self.daemons {
            if let Some(t) = d.task {
                tokio::time::timeout(Duration::from_secs(20), t)
                    .await
                    .with_context(|| format!("{} did not stop within 20 s", d.id))???;
            }
        }
        Ok(())
    }
}

/// Applies `scene` on a connected session and renders `opts.frames` frames, with a deadline.
pub async fn render_on(
    session: &mut Session,
    scene: &Scene,
    opts: &RunOptions,
) -> anyhow::Result<RunOutput> {
    let work = async {
        let mut frames = Vec::new();
        let outcome =
            lightfold_coordinator::run::render(session, scene, opts, |f| frames.push(f)).await;
        if let Some(e) = outcome.error {
            return Err(anyhow::Error::from(e).context(format!(
                "after {} frame(s); incidents: {:?}",
                frames.len(),
                outcome.summary.incidents
            )));
        }
        let plan = outcome.summary.plan.clone().context("no plan")?;
        anyhow::Ok(RunOutput {
            plan,
            frames,
            summary: outcome.summary,
        })
    };
    tokio::time::timeout(RUN_DEADLINE, work)
        .await
        .context("the run timed out")?
}

/// A small orbit (4° per frame) over `frames` frames at K = `k` with fixed-size shadow maps, so
/// re-plans that change K do not change the maps: the failover and hostile-peer runs.
pub fn orbit_options(frames: u32, k: u32) -> RunOptions {
    let mut opts = RunOptions {
        control: test_control(),
        frames,
        path: lightfold_coordinator::run::FramePath::Orbit { degrees: 4.0 },
        ..RunOptions::default()
    };
    opts.plan.lights_per_node = k;
    opts.plan.map_sizing =
        lightfold_coordinator::plan::MapSizing::Fixed(lightfold_scene::defaults::SHADOW_MAP_SIZE);
    opts
}

/// Control deadlines for tests: short enough to fail fast, long enough for lavapipe.
pub fn test_control() -> ControlOptions {
    ControlOptions {
        link: Timeouts {
            connect: Duration::from_secs(5),
            handshake: Duration::from_secs(5),
            send: Duration::from_secs(30),
            ..Timeouts::default()
        },
        register: Duration::from_secs(60),
        configure: Duration::from_secs(120),
        frame: Duration::from_secs(120),
        frames_in_flight: 2,
        // Generous: these machines are shared, and a false loss costs a re-plan, not a frame.
        heartbeat_timeout: Duration::from_secs(3),
        ..ControlOptions::default()
    }
}

/// The device, or a failed test that says why and what to install: GPU tests never skip, and CI
/// (no real GPU) runs them on lavapipe.
pub fn gpu() -> Gpu {
    Gpu::new(&GpuOptions::default()).unwrap_or_else(|e| {
        panic!("GPU tests need an adapter (CI installs mesa-vulkan-drivers for lavapipe): {e}")
    })
}

/// Small versions of built-in scenes: 2 area lights × 4 samples, 64×48.
pub fn small(name: &str) -> Scene {
    let mut s = lightfold_scene::builtin(name).unwrap();
    s.quality.samples_per_area_light = Some(4);
    s.camera.width = 64;
    s.camera.height = 48;
    s
}

/// `scenes/glass.toml` (coloured shadows, glass seen through: `docs/translucency.md`) small: 4
/// samples per area light, 64×48.
pub fn small_glass() -> Scene {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/glass.toml");
    let mut s = lightfold_scene::load(path).unwrap();
    s.quality.samples_per_area_light = Some(4);
    s.camera.width = 64;
    s.camera.height = 48;
    s
}

/// The Khronos FlightHelmet (glTF metallic-roughness with base-colour, metallic-roughness,
/// normal and occlusion textures, metal and dielectric parts) small: its framing light at 4
/// samples, 96×72.
pub fn small_helmet() -> Scene {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../assets/FlightHelmet/FlightHelmet.gltf"
    );
    let mut s = lightfold_scene::load(path).unwrap();
    s.quality.samples_per_area_light = Some(4);
    s.camera.width = 96;
    s.camera.height = 72;
    s
}

/// `d` in milliseconds.
pub fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// The median latency (request to complete image) and interval of the frames after the first,
/// in milliseconds (NaN where there are none): what the scaling examples report (`docs/scaling.md`).
pub fn latency_and_interval(frames: &[FrameResult]) -> (f64, f64) {
    let later = &frames[1.min(frames.len())..];
    let median = |v: Vec<f64>| stats::median(&v).unwrap_or(f64::NAN);
    let latency = median(
        later
            .iter()
            .map(|f| ms(f.received_at - f.requested_at))
            .collect(),
    );
    let interval = median(
        later
            .windows(2)
            .map(|w| ms(w[1].received_at - w[0].received_at))
            .collect(),
    );
    (latency, interval)
}

/// The silhouette scene of antialiasing (`scenes/silhouettes.toml`: lit objects against black,
/// thin poles) at `width × height`.
pub fn silhouettes(width: u32, height: u32) -> Scene {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes/silhouettes.toml");
    let mut s = lightfold_scene::load(path).unwrap();
    s.camera.width = width;
    s.camera.height = height;
    s
}

/// Final radiance of all the scene's samples rendered on one device (paper eq. 2). `walkthrough`
/// fits the shadow maps to every receiver, as walkthrough nodes must (their maps outlive camera
/// moves); otherwise to the receivers the camera sees. The two differ at shadow edges (other
/// texel grids: ≈ 0.4 % of channels of `small("balls")`, up to 0.025), so each cluster mode is
/// compared with the single-device render that fits its maps the same way.
pub fn single_device(gpu: &Gpu, scene: &Scene, walkthrough: bool) -> Image {
    single_device_filtered(gpu, scene, walkthrough, 0)
}

/// [`single_device`] with the penumbra filter of `radius` (0: none) on the summed illumination
/// before the material multiply, as a last stage planned with that radius applies it.
pub fn single_device_filtered(gpu: &Gpu, scene: &Scene, walkthrough: bool, radius: u32) -> Image {
    // Direct samples and, where the scene asks for indirect light, its VPLs (as the planner).
    let samples = lightfold_reference::indirect::frame_samples(scene);
    let mut r = Renderer::new(gpu, scene, RenderOptions::from_quality(&scene.quality)).unwrap();
    r.set_camera(&scene.camera);
    r.set_fit_to_camera(!walkthrough);
    let f = r
        .render(gpu, &samples, None, [1.0; 3], LayerSet::all())
        .unwrap();
    let (mut il, md, ms, ma, e) = (
        f.illumination.unwrap(),
        f.diffuse.unwrap(),
        f.specular.unwrap(),
        f.ambient.unwrap(),
        f.emissive.unwrap(),
    );
    let depth = f.depth.unwrap();
    if radius > 0 {
        il.data = lightfold_compositor::ops::penumbra::filter_frame(
            il.width,
            radius,
            scene.camera.fov_y_deg,
            &il.data,
            &depth.data,
        )
        .unwrap();
    }
    shade(scene, &il, [&md, &ms, &ma, &e], |i| depth.data[i] > 0.0)
}

/// The material stage on one device: paper eq. 2 (`compose_frame`), `e + m^a·c^a + m^d·I^d +
/// m^s·I^s` per pixel with the ambient `c^a` only where `covered`.
fn shade(
    scene: &Scene,
    il: &Image,
    [md, ms, ma, e]: [&Image; 4],
    covered: impl Fn(usize) -> bool,
) -> Image {
    let m = MaterialLayers {
        diffuse: md,
        specular: ms,
        ambient: ma,
        emissive: e,
    };
    compose_frame(il, [1.0; 3], m, scene.ambient, covered)
}

/// [`single_device`] over sort-last parts: each part's eye pass alone with its shadow maps
/// fitted to the part (as a sort-last node renders it), then per pixel every layer of the part whose surface is nearest (eye depth
/// above 0). Exact depth ties go to the lower part, or to the higher one with `ties_to_higher`
/// (a negative control of the compositor's rule).
pub fn single_device_parts(
    gpu: &Gpu,
    scene: &Scene,
    parts: &[Vec<u32>],
    ties_to_higher: bool,
) -> Image {
    let samples = lightfold_reference::indirect::frame_samples(scene);
    let mut r = Renderer::new(gpu, scene, RenderOptions::from_quality(&scene.quality)).unwrap();
    r.set_camera(&scene.camera);
    // Each part's maps fitted to the part, as a sort-last node fits them.
    r.set_fit_to_eye_meshes(true);
    let mut won: Vec<Option<(f32, usize)>> = Vec::new();
    let mut frames = Vec::new();
    for part in parts {
        r.set_eye_meshes(Some(part.clone()));
        let f = r
            .render(gpu, &samples, None, [1.0; 3], LayerSet::all())
            .unwrap();
        frames.push(f);
    }
    let depth = |p: usize| frames[p].depth.as_ref().unwrap();
    for i in 0..depth(0).pixel_count() {
        let mut best: Option<(f32, usize)> = None;
        for p in 0..parts.len() {
            let z = depth(p).data[i];
            let nearer = match best {
                None => true,
                Some((b, _)) => z < b || (ties_to_higher && z == b),
            };
            if z > 0.0 && z.is_finite() && nearer {
                best = Some((z, p));
            }
        }
        won.push(best);
    }
    let (w, h) = (scene.camera.width, scene.camera.height);
    let mut layers: Vec<Image> = (0..5)
        .map(|k| Image::new(w, h, if k == 0 { 6 } else { 3 }))
        .collect();
    for (i, winner) in won.iter().enumerate() {
        let Some((_, p)) = *winner else { continue };
        let f = &frames[p];
        let from = [
            f.illumination.as_ref(),
            f.diffuse.as_ref(),
            f.specular.as_ref(),
            f.ambient.as_ref(),
            f.emissive.as_ref(),
        ];
        for (dst, src) in layers.iter_mut().zip(from) {
            let c = dst.channels;
            dst.data[i * c..i * c + c].copy_from_slice(&src.unwrap().data[i * c..i * c + c]);
        }
    }
    shade(
        scene,
        &layers[0],
        [&layers[1], &layers[2], &layers[3], &layers[4]],
        |i| won[i].is_some(),
    )
}

/// [`single_device`] with `--aa factor`: rendered at `factor` × the camera's width and height,
/// the final radiance box-resolved to the camera's size (what `lightfold render --aa N` does, and
/// the cluster's sink). `factor = 1` is [`single_device`] itself.
pub fn single_device_aa(gpu: &Gpu, scene: &Scene, factor: u32) -> Image {
    let mut s = scene.clone();
    s.camera = s.camera.supersampled(factor).unwrap();
    single_device(gpu, &s, false).box_resolve(factor).unwrap()
}

/// Per-pixel agreement within the link formats' bound: rgb9e5x2 from nodes (2⁻⁹ relative),
/// f16 between stages (2⁻¹¹ per hop), material colours as planned (`f16x4` is exact; `rgba8srgb`,
/// when asked for, is ≤ 1.3 % relative at the dark end),
/// so 2.5 % relative + 1e-3 absolute; and mean energy within 1 %.
pub fn assert_close(test: &Image, want: &Image, what: &str) {
    assert_close_within(test, want, what, 1000);
}

/// As [`assert_close`], allowing one channel in `per` outside the bound.
pub fn assert_close_within(test: &Image, want: &Image, what: &str, per: usize) {
    assert_eq!(
        (test.width, test.height),
        (want.width, want.height),
        "{what}: size"
    );
    let mut bad = 0;
    for (a, b) in test.data.iter().zip(&want.data) {
        assert!(a.is_finite(), "{what}: non-finite pixel");
        if (a - b).abs() > 0.025 * b.abs() + 1e-3 {
            bad += 1;
        }
    }
    let (ea, eb): (f64, f64) = (
        test.data.iter().map(|&v| v as f64).sum(),
        want.data.iter().map(|&v| v as f64).sum(),
    );
    assert!(eb > 0.0, "{what}: reference is black");
    if bad > 0 {
        let worst = test
            .data
            .iter()
            .zip(&want.data)
            .map(|(a, b)| ((a - b).abs(), *b))
            .fold((0.0f32, 0.0f32), |m, x| if x.0 > m.0 { x } else { m });
        eprintln!(
            "{what}: {bad} channels outside; worst |diff| {} at value {}",
            worst.0, worst.1
        );
    }
    assert!(
        bad * per <= test.data.len(),
        "{what}: {bad} of {} channels outside the bound",
        test.data.len()
    );
    assert!((ea / eb - 1.0).abs() < 0.01, "{what}: energy {ea} vs {eb}");
}
