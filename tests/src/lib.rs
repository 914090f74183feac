//! lightfold's integration tests: the in-process cluster harness (coordinator, render nodes and
//! compositors as tasks on `127.0.0.1:0` in one process), and the tests that use it. Every wait
//! has a deadline.

use anyhow::Context;
use lightfold_compositor::daemon::{self as stage, CompositorOptions};
use lightfold_coordinator::control::{ControlOptions, DaemonAddr, FrameResult, Session};
use lightfold_coordinator::plan::Plan;
use lightfold_coordinator::run::{RunOptions, apply, participants, requests};
use lightfold_net::{Identity, Timeouts};
use lightfold_node::daemon::{self as node, NodeOptions};
use lightfold_protocol::Role;
use lightfold_scene::Scene;
use std::time::Duration;
use tokio::net::TcpListener;
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;

/// Deadline for a whole in-process run (connect, plan, frames).
pub const RUN_DEADLINE: Duration = Duration::from_secs(300);

/// Daemons running as tasks of this process.
#[derive(Debug)]
pub struct InProcessCluster {
    pub nodes: Vec<String>,
    pub compositors: Vec<String>,
    pub token: Vec<u8>,
    pub stage_metrics: Vec<std::sync::Arc<lightfold_compositor::daemon::StageMetrics>>,
    cancel: CancellationToken,
    tasks: Vec<JoinHandle<anyhow::Result<()>>>,
}

/// What one coordinator run produced.
#[derive(Debug)]
pub struct RunOutput {
    pub plan: Plan,
    pub frames: Vec<FrameResult>,
}

impl InProcessCluster {
    /// Starts `nodes` render nodes and `compositors` compositors on loopback port 0.
    pub async fn start(nodes: usize, compositors: usize) -> anyhow::Result<Self> {
        let token = b"in-process cluster token".to_vec();
        let cancel = CancellationToken::new();
        let mut c = InProcessCluster {
            nodes: Vec::new(),
            compositors: Vec::new(),
            token: token.clone(),
            stage_metrics: Vec::new(),
            cancel: cancel.clone(),
            tasks: Vec::new(),
        };
        for i in 0..nodes {
            let listener = TcpListener::bind("127.0.0.1:0").await?;
            c.nodes.push(listener.local_addr()?.to_string());
            let opts = NodeOptions::new(format!("node-{i}"), &token);
            c.tasks.push(tokio::spawn(node::run(
                listener,
                opts,
                cancel.child_token(),
            )));
        }
        for i in 0..compositors {
            let listener = TcpListener::bind("127.0.0.1:0").await?;
            let addr = listener.local_addr()?.to_string();
            let opts = CompositorOptions::new(format!("comp-{i}"), addr.clone(), &token);
            c.stage_metrics.push(opts.metrics.clone());
            c.compositors.push(addr);
            c.tasks.push(tokio::spawn(stage::run(
                listener,
                opts,
                cancel.child_token(),
            )));
        }
        Ok(c)
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
        for t in self.tasks {
            tokio::time::timeout(Duration::from_secs(20), t)
                .await
                .context("a daemon did not stop within 20 s")???;
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
        let plan = apply(session, scene, &opts.plan).await?;
        let reqs = requests(&plan, opts, 1)?;
        let mut frames = Vec::new();
        session
            .drive(plan.epoch, &participants(&plan), &reqs, |f| frames.push(f))
            .await?;
        anyhow::Ok(RunOutput { plan, frames })
    };
    tokio::time::timeout(RUN_DEADLINE, work)
        .await
        .context("the run timed out")?
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
    }
}
