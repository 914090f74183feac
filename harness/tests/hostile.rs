//! Hostile peers change nothing (issue 19), each while the in-process cluster renders an orbit:
//! stray connections to the coordinator's sink, 200 MB frames sent before authenticating to every
//! daemon, and a second link claiming a live producer's id. Every frame still arrives, with no
//! re-plan, and the daemons' memory does not follow the hostile frames.
//!
//! Its own test binary (the crate's other tests are modules of `tests/it`): it measures this
//! process's peak memory and needs an undisturbed cluster, so no other test may share its
//! process.

use lightfold_coordinator::run::RunOptions;
use lightfold_harness::{InProcessCluster, RunOutput, orbit_options, small};
use lightfold_net::Identity;
use lightfold_protocol::Role;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;
use tokio::io::AsyncWriteExt;

const FRAMES: u32 = 30;

/// One hostile test at a time: each measures this process's memory, and runs its own cluster.
static ONE_AT_A_TIME: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

fn options() -> RunOptions {
    orbit_options(FRAMES, 2)
}

/// This process's peak resident memory (VmHWM), bytes.
fn peak_rss() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.split_whitespace().next()?.parse::<u64>().ok())
        .map_or(0, |kb| kb * 1024)
}

/// Renders the orbit while `attack(sink address, frames delivered so far)` runs beside it; the
/// run must be undisturbed.
async fn render_under<F, Fut>(cluster: &InProcessCluster, attack: F) -> RunOutput
where
    F: FnOnce(String, Arc<AtomicU64>) -> Fut,
    Fut: std::future::Future<Output = ()>,
{
    let scene = small("balls");
    let opts = options();
    let mut session = cluster.connect(opts.control).await.unwrap();
    let sink = session.sink_address.clone();
    let mut frames = Vec::new();
    let delivered = Arc::new(AtomicU64::new(0));
    let seen = Arc::clone(&delivered);
    let run = lightfold_coordinator::run::render(&mut session, &scene, &opts, |f| {
        seen.store(f.frame, Ordering::Relaxed);
        frames.push(f);
    });
    let (outcome, ()) = tokio::time::timeout(lightfold_harness::RUN_DEADLINE, async {
        tokio::join!(run, attack(sink, delivered))
    })
    .await
    .expect("the run timed out");
    session.detach();
    assert!(outcome.error.is_none(), "{:?}", outcome.error);
    let numbers: Vec<u64> = frames.iter().map(|f| f.frame).collect();
    assert_eq!(numbers, (1..=u64::from(FRAMES)).collect::<Vec<_>>());
    assert_eq!(
        outcome.summary.epochs.len(),
        1,
        "no re-plan: {:?}; incidents {:?}",
        outcome.summary.epochs,
        outcome.summary.incidents
    );
    RunOutput {
        plan: outcome.summary.plan.clone().unwrap(),
        frames,
        summary: outcome.summary,
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn stray_connections_to_the_sink_are_dropped() {
    let _one = ONE_AT_A_TIME.lock().await;
    let cluster = InProcessCluster::start(4, 4).await.unwrap();
    render_under(&cluster, |sink, _| async move {
        tokio::time::sleep(Duration::from_millis(300)).await;
        for i in 0..50 {
            // Connect and close (a port scanner, a health probe), or send junk.
            let mut s = tokio::net::TcpStream::connect(&sink).await.unwrap();
            if i % 2 == 1 {
                let _ = s.write_all(b"GET / HTTP/1.1\r\n\r\n").await;
            }
            drop(s);
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    })
    .await;
    cluster.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn huge_frames_before_the_handshake_are_refused_at_once() {
    const HUGE: u32 = 200_000_000;
    let _one = ONE_AT_A_TIME.lock().await;
    let cluster = InProcessCluster::start(4, 4).await.unwrap();
    let targets: Vec<String> = cluster
        .nodes
        .iter()
        .chain(&cluster.compositors)
        .cloned()
        .collect();
    // The cluster's own peak comes first: a quiet orbit sets the high-water mark, so what the
    // attacked orbit adds on top is the hostile frames' doing (rendering alone grows this
    // process's peak by some 300 MB on lavapipe).
    render_under(&cluster, |_, _| async {}).await;
    let before = peak_rss();
    let sent = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
    let counter = std::sync::Arc::clone(&sent);
    render_under(&cluster, |sink, _| async move {
        let mut all = targets.clone();
        all.push(sink);
        let mut tasks = Vec::new();
        for addr in all {
            let counter = std::sync::Arc::clone(&counter);
            tasks.push(tokio::spawn(async move {
                let mut s = tokio::net::TcpStream::connect(&addr).await.unwrap();
                // A band frame's prefix in place of a hello, then its 200 MB.
                let mut head = HUGE.to_be_bytes().to_vec();
                head.push(4);
                let _ = s.write_all(&head).await;
                let chunk = vec![0u8; 1 << 20];
                for _ in 0..(HUGE as usize >> 20) {
                    match tokio::time::timeout(Duration::from_secs(5), s.write_all(&chunk)).await {
                        Ok(Ok(())) => {
                            counter.fetch_add(
                                chunk.len() as u64,
                                std::sync::atomic::Ordering::Relaxed,
                            );
                        }
                        _ => return,
                    }
                }
            }));
        }
        for t in tasks {
            t.await.unwrap();
        }
    })
    .await;
    let grown = peak_rss().saturating_sub(before);
    let sent = sent.load(std::sync::atomic::Ordering::Relaxed);
    eprintln!(
        "9 hostile 200 MB frames: {} MB accepted by sockets before the close; peak RSS grew {} MB",
        sent >> 20,
        grown >> 20
    );
    assert!(
        sent < 9 * u64::from(HUGE) / 4,
        "the daemons kept reading: {sent} bytes"
    );
    assert!(grown < 300 << 20, "peak RSS grew by {grown} bytes");
    cluster.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_second_link_claiming_a_live_producer_is_refused() {
    let _one = ONE_AT_A_TIME.lock().await;
    let cluster = InProcessCluster::start(4, 4).await.unwrap();
    let compositors = cluster.compositors.clone();
    let token = cluster.token.clone();
    render_under(&cluster, |_, delivered| async move {
        // Live producers: every one has delivered frames (on a loaded machine the first frame
        // alone can take seconds; a claim made before it tests something else).
        let start = std::time::Instant::now();
        while delivered.load(Ordering::Relaxed) < 2 && start.elapsed() < Duration::from_secs(60) {
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        // With the token: claim to be node-1 (and node-0, node-2, node-3) at every stage.
        let mut held = Vec::new();
        for addr in &compositors {
            for n in 0..4 {
                let me = Identity::new(&token, Role::Node, format!("node-{n}"));
                let link = lightfold_net::dial(addr, &me, lightfold_net::Timeouts::default()).await;
                if let Ok(l) = link {
                    held.push(l);
                }
            }
        }
        // Hold them while frames keep flowing.
        tokio::time::sleep(Duration::from_secs(2)).await;
        drop(held);
    })
    .await;
    cluster.stop().await.unwrap();
}
