//! The compositor stage daemon (ARCHITECTURE §5–8, docs/cluster-protocol.md): one listener takes
//! the coordinator's control link and the producers' data links; configured inputs are matched by
//! authenticated daemon id; each frame is combined band by band as the bands arrive and streamed to
//! the downstream stage, with bounded queues (a stalled consumer blocks its producers through TCP),
//! a deadline on every wait, and a clean stop when the shutdown token fires.
//!
//! `run` follows mini-redis `server::run(listener, shutdown)`: the caller binds (tests bind port
//! 0) and owns the cancellation token (the CLI wires SIGTERM and Ctrl-C to it).

mod check;
mod compute;
mod control;
/// A stand-in coordinator, producer and sink for tests and benchmarks of stages.
mod engine;
mod inputs;
mod metrics;
mod output;
pub mod pixels;
mod stage_plan;

pub use check::{Expect, Mismatch, Verdict, judge};
pub use metrics::StageMetrics;
pub use stage_plan::{BAND_OVERHEAD, ConfigError, MAX_FRAMES_IN_FLIGHT, StagePlan};

use control::ControlHub;
use engine::Engine;
use inputs::{Registry, SlotContext};
use lightfold_net::{Identity, Link, Timeouts};
use lightfold_protocol::Role;
use std::sync::Arc;
use std::time::Duration;
use tokio::net::TcpListener;
use tokio::sync::{mpsc, watch};
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

/// Frame requests a stage queues ahead of the one it is combining.
pub const QUEUED_FRAMES: usize = 256;
/// How long `run` waits for its tasks after shutdown before giving up on them.
const SHUTDOWN_GRACE: Duration = Duration::from_secs(5);

/// How a stage runs. `token` is the shared cluster secret (never logged).
#[derive(Clone)]
pub struct CompositorOptions {
    /// This stage's daemon id: producers and the coordinator know it by this name.
    pub daemon_id: String,
    /// The address reported in `Register` for others to dial.
    pub advertise: String,
    pub token: Arc<[u8]>,
    /// Link deadlines (connect, handshake, each send) and the frame size limit.
    pub timeouts: Timeouts,
    /// Longest wait for any one input band once a frame is due (covers the producer's render
    /// time for the first band).
    pub input_timeout: Duration,
    /// How long to keep dialing the downstream before reporting it lost.
    pub dial_timeout: Duration,
    /// Counters the caller may read while the stage runs.
    pub metrics: Arc<StageMetrics>,
    /// A claimed control link that brings nothing (not even a keepalive) for this long is
    /// released, so a stopped or hung coordinator does not hold the stage. Zero: never.
    pub coordinator_silence: Duration,
    /// Threads that combine bands (a band is split across them). One by default: a stage's
    /// links need CPU too, and on a machine shared with other stages and nodes a second compute
    /// thread slowed the link benchmark (docs/compositor.md, "Link cost").
    pub compute_threads: usize,
}

impl std::fmt::Debug for CompositorOptions {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CompositorOptions")
            .field("daemon_id", &self.daemon_id)
            .field("advertise", &self.advertise)
            .field("timeouts", &self.timeouts)
            .field("input_timeout", &self.input_timeout)
            .field("dial_timeout", &self.dial_timeout)
            .field("compute_threads", &self.compute_threads)
            .field("coordinator_silence", &self.coordinator_silence)
            .finish_non_exhaustive()
    }
}

impl CompositorOptions {
    /// Options with the default deadlines: 30 s per input band, 10 s to reach the downstream.
    pub fn new(daemon_id: impl Into<String>, advertise: impl Into<String>, token: &[u8]) -> Self {
        CompositorOptions {
            daemon_id: daemon_id.into(),
            advertise: advertise.into(),
            token: Arc::from(token),
            timeouts: Timeouts::default(),
            input_timeout: Duration::from_secs(30),
            dial_timeout: Duration::from_secs(10),
            metrics: StageMetrics::new(),
            coordinator_silence: lightfold_net::claim::COORDINATOR_SILENCE,
            compute_threads: 1,
        }
    }
}

/// Runs a compositor stage on `listener` until `shutdown` is cancelled (or the coordinator sends
/// `Shutdown`, which cancels it). Returns once every task has stopped.
pub async fn run(
    listener: TcpListener,
    opts: CompositorOptions,
    shutdown: CancellationToken,
) -> anyhow::Result<()> {
    lightfold_protocol::handshake::check_daemon_id(&opts.daemon_id)
        .map_err(|e| anyhow::anyhow!("daemon id {:?}: {e}", opts.daemon_id))?;
    if opts.token.is_empty() {
        anyhow::bail!("the cluster token is empty");
    }
    let identity = Identity::new(&opts.token, Role::Compositor, opts.daemon_id.clone());
    let compute = rayon::ThreadPoolBuilder::new()
        .num_threads(opts.compute_threads.max(1))
        .thread_name(|i| format!("lightfold-compute-{i}"))
        .build()
        .map_err(|e| anyhow::anyhow!("cannot start the compute threads: {e}"))?;
    let tracker = TaskTracker::new();
    let (cmd_tx, cmd_rx) = mpsc::channel(QUEUED_FRAMES);
    let (gen_tx, gen_rx) = watch::channel(0u64);
    let (feed, out_rx, target_rx) = output::feed();
    let hub = Arc::new(ControlHub::new(
        cmd_tx,
        gen_tx,
        &opts.daemon_id,
        &opts.advertise,
        opts.timeouts.max_frame,
        opts.coordinator_silence,
    ));
    let registry = Arc::new(Registry::default());
    let ctx = SlotContext {
        registry: Arc::clone(&registry),
        metrics: Arc::clone(&opts.metrics),
        tracker: tracker.clone(),
        shutdown: shutdown.clone(),
    };
    let engine = Engine::new(
        ctx,
        hub.out(),
        feed,
        gen_rx,
        opts.input_timeout,
        opts.daemon_id.clone(),
        Arc::new(compute),
    );
    tracker.spawn(engine.run(cmd_rx));
    let settings = output::WriterSettings {
        identity: identity.clone(),
        timeouts: opts.timeouts,
        dial_timeout: opts.dial_timeout,
    };
    tracker.spawn(output::run(
        settings,
        hub.out(),
        Arc::clone(&opts.metrics),
        out_rx,
        target_rx,
        shutdown.clone(),
    ));
    match listener.local_addr() {
        Ok(addr) => tracing::info!(id = %opts.daemon_id, %addr, "compositor listening"),
        Err(e) => {
            tracing::info!(id = %opts.daemon_id, "compositor listening (address unknown: {e})")
        }
    }
    lightfold_telemetry::health::set_live(true);
    let conn = Connection {
        hub: Arc::clone(&hub),
        registry: Arc::clone(&registry),
        shutdown: shutdown.clone(),
    };
    lightfold_net::serve(
        &listener,
        &identity,
        opts.timeouts,
        &shutdown,
        &tracker,
        "handshakes",
        move |link| conn.clone().serve(link),
    )
    .await;
    lightfold_telemetry::health::set_live(false);
    drop(listener);
    tracker.close();
    if tokio::time::timeout(SHUTDOWN_GRACE, tracker.wait())
        .await
        .is_err()
    {
        tracing::warn!("some tasks did not stop within {SHUTDOWN_GRACE:?}");
    }
    tracing::info!(id = %opts.daemon_id, "compositor stopped");
    Ok(())
}

/// What serves an authenticated link: the control hub (coordinators) or the input registry
/// (producers).
#[derive(Clone)]
struct Connection {
    hub: Arc<ControlHub>,
    registry: Arc<Registry>,
    shutdown: CancellationToken,
}

impl Connection {
    async fn serve(self, link: Link) {
        match link.peer.role {
            Role::Coordinator => self.hub.session(link, &self.shutdown).await,
            Role::Node | Role::Compositor => {
                let peer = link.peer.daemon_id.clone();
                let addr = link.addr.clone();
                let (reader, writer) = link.split();
                let offer = self
                    .registry
                    .offer(peer.clone(), inputs::ProducerLink { reader, writer })
                    .await;
                match offer {
                    inputs::Offer::Parked => tracing::info!(%peer, %addr, "producer connected"),
                    inputs::Offer::Full => {
                        tracing::warn!(%peer, %addr, "refused a producer: too many unclaimed links")
                    }
                    inputs::Offer::Duplicate { live } => tracing::warn!(
                        %peer, %addr, live = %live,
                        "refused a second link claiming producer {peer}: its link from {live} is live"
                    ),
                }
            }
            Role::Viewer => {
                tracing::warn!(peer = %link.peer.daemon_id, "refused a viewer: a compositor serves none");
            }
        }
    }
}
