//! The in-process cluster: render nodes and compositors running the daemons' own code as tasks of
//! this process on `127.0.0.1:0`, killed and restarted on their addresses as a supervisor would,
//! and a coordinator session over them. Every wait has a deadline.

use anyhow::Context;
use lightfold_compositor::daemon::{self as stage, CompositorOptions};
use lightfold_coordinator::control::{
    ControlOptions, DaemonAddr, FrameResult, LiveSummary, Session,
};
use lightfold_coordinator::plan::Plan;
use lightfold_coordinator::run::RunOptions;
use lightfold_net::Identity;
use lightfold_node::daemon::{self as node, NodeOptions};
use lightfold_protocol::Role;
use lightfold_scene::Scene;
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
    options: ClusterOptions,
}

/// What one coordinator run produced.
#[derive(Debug)]
pub struct RunOutput {
    pub plan: Plan,
    pub frames: Vec<FrameResult>,
    pub summary: LiveSummary,
}

/// How the daemons of an [`InProcessCluster`] are set up.
#[derive(Debug, Clone, Default)]
pub struct ClusterOptions {
    /// The memory render nodes report (`NodeOptions::memory_bytes`; `None`: the machine's).
    pub node_memory: Option<u64>,
    /// How long a compositor waits for an input band (`None`: its default).
    pub input_timeout: Option<Duration>,
    /// The shared secret (`None`: a fixed test token).
    pub token: Option<Vec<u8>>,
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
        let options = ClusterOptions {
            node_memory: memory,
            ..ClusterOptions::default()
        };
        Self::start_with(nodes, compositors, options).await
    }

    /// Starts `nodes` render nodes and `compositors` compositors set up as `options` says.
    pub async fn start_with(
        nodes: usize,
        compositors: usize,
        options: ClusterOptions,
    ) -> anyhow::Result<Self> {
        let token = options
            .token
            .clone()
            .unwrap_or_else(|| b"in-process cluster token".to_vec());
        let cancel = CancellationToken::new();
        let mut c = InProcessCluster {
            nodes: Vec::new(),
            compositors: Vec::new(),
            token,
            stage_metrics: Vec::new(),
            cancel: cancel.clone(),
            daemons: Vec::new(),
            options,
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
            opts.memory_bytes = self.options.node_memory;
            tokio::spawn(node::run(listener, opts, stop.clone()))
        } else {
            let mut opts = CompositorOptions::new(id.clone(), addr.clone(), &self.token);
            if let Some(t) = self.options.input_timeout {
                opts.input_timeout = t;
            }
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
