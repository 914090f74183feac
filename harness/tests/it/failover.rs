//! Failover in the in-process cluster (issue 18): a render node, a middle compositor and the sink
//! compositor each stop mid-run; every frame is still delivered, once, in order, equal to the
//! single-device render of its camera within the link formats' bound; the loss is detected
//! within a generous bound; a restarted daemon is folded back into the plan; a session left
//! behind by an aborted coordinator does not break the next one; a second coordinator is refused
//! while one holds the cluster, unless it takes over.

use lightfold_coordinator::control::{ControlError, IncidentKind, Live, LiveSummary};
use lightfold_coordinator::plan::MapSizing;
use lightfold_coordinator::run::{RunError, RunOptions, camera_at};
use lightfold_harness::{
    InProcessCluster, RunOutput, assert_close, orbit_options, single_device, small,
};
use lightfold_scene::Scene;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

const FRAMES: u32 = 6;

/// `balls` at 64×48 with 8 samples, K = 2: four render nodes and four stages in a chain.
fn setup() -> (Scene, RunOptions) {
    let scene = small("balls");
    let mut opts = orbit_options(FRAMES, 2);
    opts.plan.map_sizing = MapSizing::Fixed(scene.quality.shadow_map_size);
    (scene, opts)
}

/// Every frame of the run, in order, against the single-device render of its camera.
fn assert_every_frame(out: &RunOutput, scene: &Scene, opts: &RunOptions, what: &str) {
    let gpu = lightfold_harness::gpu();
    let numbers: Vec<u64> = out.frames.iter().map(|f| f.frame).collect();
    let want: Vec<u64> = (1..=u64::from(opts.frames)).collect();
    assert_eq!(numbers, want, "{what}: every frame once, in order");
    for f in &out.frames {
        let mut s = scene.clone();
        s.camera = camera_at(&scene.camera, opts.path, (f.frame - 1) as u32);
        let truth = single_device(&gpu, &s, false);
        assert_close(&f.image, &truth, &format!("{what}: frame {}", f.frame));
    }
}

/// When `id` was reported lost.
fn lost_at(summary: &LiveSummary, id: &str) -> Option<Instant> {
    summary
        .incidents
        .iter()
        .find(|i| i.daemon == id && matches!(i.kind, IncidentKind::Lost { .. }))
        .map(|i| i.at)
}

/// Renders the orbit on `cluster`, stopping daemon `victim` as frame `at` is delivered.
async fn run_losing(
    cluster: &InProcessCluster,
    scene: &Scene,
    opts: &RunOptions,
    victim: &str,
    at: u64,
) -> (RunOutput, Instant) {
    let stop = cluster.stop_token(victim).expect("victim exists");
    let killed: Arc<Mutex<Option<Instant>>> = Arc::default();
    let mut session = cluster.connect(opts.control).await.unwrap();
    let mut frames = Vec::new();
    let k = Arc::clone(&killed);
    let outcome = tokio::time::timeout(
        lightfold_harness::RUN_DEADLINE,
        lightfold_coordinator::run::render(&mut session, scene, opts, |f| {
            if f.frame == at {
                stop.cancel();
                *k.lock().unwrap() = Some(Instant::now());
            }
            frames.push(f);
        }),
    )
    .await
    .expect("the run timed out");
    session.detach();
    if let Some(e) = outcome.error {
        panic!(
            "the run failed after {} frames: {e}; incidents {:?}",
            frames.len(),
            outcome.summary.incidents
        );
    }
    let killed_at = killed.lock().unwrap().expect("the victim was stopped");
    let out = RunOutput {
        plan: outcome.summary.plan.clone().expect("a plan"),
        frames,
        summary: outcome.summary,
    };
    (out, killed_at)
}

async fn survives_losing(victim: &str) {
    let (scene, opts) = setup();
    let cluster = InProcessCluster::start(4, 4).await.unwrap();
    let (out, killed_at) = run_losing(&cluster, &scene, &opts, victim, 2).await;
    let first = &out.summary.epochs[0];
    assert_eq!(
        first.nodes, 4,
        "the first plan uses every node: epochs {:?}, incidents {:?}",
        out.summary.epochs, out.summary.incidents
    );
    let lost = lost_at(&out.summary, victim)
        .unwrap_or_else(|| panic!("{victim} was never reported lost: {:?}", out.summary));
    let detected = lost.saturating_duration_since(killed_at);
    eprintln!(
        "{victim}: lost detected after {detected:?}; epochs {:?}",
        out.summary.epochs
    );
    assert!(
        detected < Duration::from_secs(5),
        "{victim}: detection took {detected:?}"
    );
    assert!(out.summary.epochs.len() >= 2, "a re-plan happened");
    let uses = |id: &str| {
        out.plan.nodes.iter().any(|n| n.node == id)
            || out.plan.stages.iter().any(|s| s.compositor == id)
    };
    assert!(!uses(victim), "the final plan leaves {victim} out");
    assert_every_frame(&out, &scene, &opts, &format!("without {victim}"));
    cluster.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_lost_render_node_costs_no_frame() {
    survives_losing("node-1").await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_lost_middle_compositor_costs_no_frame() {
    survives_losing("comp-1").await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_lost_sink_compositor_costs_no_frame() {
    survives_losing("comp-3").await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_restarted_node_is_folded_back_in() {
    let (scene, mut opts) = setup();
    // Frames keep coming until node-2 renders again (or this many have been requested).
    opts.frames = 400;
    let specs = lightfold_coordinator::run::frame_specs(&scene, &opts);
    let mut cluster = InProcessCluster::start(4, 4).await.unwrap();
    let stop = cluster.stop_token("node-2").unwrap();
    let mut session = cluster.connect(opts.control).await.unwrap();
    let (killed_tx, mut killed_rx) = tokio::sync::mpsc::unbounded_channel::<()>();
    let back = Arc::new(std::sync::atomic::AtomicU64::new(0));
    let (req_tx, req_rx) = tokio::sync::mpsc::channel(1);
    let mut frames = Vec::new();
    let mut live = Live::new(&mut session, &scene, &opts.plan).unwrap();
    let seen_back = Arc::clone(&back);
    let render = live.run(req_rx, |f| {
        if f.frame == 2 {
            stop.cancel();
            let _ = killed_tx.send(());
        }
        let rendered_by_node_2 = f.stats.iter().any(|s| s.daemon_id == "node-2");
        if f.frame > 2 && rendered_by_node_2 && seen_back.load(Ordering::Relaxed) == 0 {
            seen_back.store(f.frame, Ordering::Relaxed);
        }
        frames.push(f);
    });
    let feed = async {
        for (i, spec) in specs.into_iter().enumerate() {
            let b = back.load(Ordering::Relaxed);
            if b > 0 && i as u64 >= b + 2 {
                break;
            }
            if req_tx.send(spec).await.is_err() {
                break;
            }
        }
        drop(req_tx);
    };
    let supervisor = async {
        // Like systemd restarting a crashed unit: the same id on the same address.
        killed_rx.recv().await;
        cluster.kill("node-2").await.unwrap();
        tokio::time::sleep(Duration::from_millis(500)).await;
        cluster.restart("node-2").await.unwrap();
    };
    let (result, (), ()) = tokio::time::timeout(lightfold_harness::RUN_DEADLINE, async {
        tokio::join!(render, feed, supervisor)
    })
    .await
    .expect("the run timed out");
    let summary = std::mem::take(&mut live.summary);
    drop(live);
    session.detach();
    assert!(result.is_ok(), "{result:?}");
    eprintln!(
        "epochs {:?}\nincidents {:?}",
        summary.epochs, summary.incidents
    );
    assert!(lost_at(&summary, "node-2").is_some(), "node-2 was lost");
    assert!(
        summary
            .incidents
            .iter()
            .any(|i| i.daemon == "node-2" && i.kind == IncidentKind::Rejoined),
        "node-2 rejoined"
    );
    let back = back.load(Ordering::Relaxed);
    assert!(
        back > 0,
        "node-2 never rendered again in {} frames",
        frames.len()
    );
    let plan = summary.plan.clone().unwrap();
    assert!(
        plan.nodes.iter().any(|n| n.node == "node-2"),
        "the final plan uses node-2 again"
    );
    assert_eq!(plan.nodes.len(), 4);
    opts.frames = frames.len() as u32;
    let out = RunOutput {
        plan,
        frames,
        summary,
    };
    assert_every_frame(&out, &scene, &opts, "with node-2 restarted");
    cluster.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn an_aborted_session_does_not_break_the_next() {
    let (scene, mut opts) = setup();
    let cluster = InProcessCluster::start(4, 4).await.unwrap();
    // A coordinator that dies with frames in flight: its bands stay in the pipeline.
    opts.frames = 100_000;
    let mut session = cluster.connect(opts.control).await.unwrap();
    // Aborted once frames flow (2 delivered), however long the first frames take on a loaded
    // machine: the run is dropped mid-stream with the next frames in flight.
    let seen = std::sync::atomic::AtomicUsize::new(0);
    let run = lightfold_coordinator::run::render(&mut session, &scene, &opts, |_| {
        seen.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
    });
    let flowing = async {
        while seen.load(std::sync::atomic::Ordering::SeqCst) < 2 {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    };
    let aborted = tokio::time::timeout(lightfold_harness::RUN_DEADLINE, async {
        tokio::select! {
            _ = run => false,
            () = flowing => true,
        }
    })
    .await;
    assert_eq!(
        aborted.ok(),
        Some(true),
        "frames were flowing before the coordinator went away, and the run outlasts its abort"
    );
    session.detach();
    // At once, a new coordinator: its epochs and frame ids are above the old session's.
    opts.frames = 3;
    let out = cluster.render(&scene, &opts).await.unwrap();
    assert_every_frame(&out, &scene, &opts, "after an aborted session");
    cluster.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_second_coordinator_is_refused_unless_it_takes_over() {
    let (scene, mut opts) = setup();
    opts.frames = 200;
    let cluster = InProcessCluster::start(4, 4).await.unwrap();
    let mut first = cluster.connect(opts.control).await.unwrap();
    let mut delivered = 0u64;
    let run = lightfold_coordinator::run::render(&mut first, &scene, &opts, |_| delivered += 1);
    let second = async {
        tokio::time::sleep(Duration::from_secs(2)).await;
        let refused = cluster.connect(opts.control).await.unwrap_err();
        let msg = format!("{refused:#}");
        assert!(msg.contains("take-over"), "{msg}");
        let mut control = opts.control;
        control.take_over = true;
        let mut second = cluster.connect(control).await.unwrap();
        let mut quick = opts.clone();
        quick.frames = 2;
        quick.control = control;
        let outcome = lightfold_coordinator::run::render(&mut second, &scene, &quick, |_| {}).await;
        second.detach();
        outcome
    };
    let (first_outcome, second_outcome) =
        tokio::time::timeout(lightfold_harness::RUN_DEADLINE, async {
            tokio::join!(run, second)
        })
        .await
        .expect("timed out");
    first.detach();
    assert!(second_outcome.error.is_none(), "{:?}", second_outcome.error);
    assert_eq!(second_outcome.summary.delivered, 2);
    match first_outcome.error {
        Some(RunError::Control(ControlError::TakenOver { .. })) => {}
        other => panic!("the first coordinator should be told it was taken over: {other:?}"),
    }
    cluster.stop().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn too_few_daemons_is_a_clear_error_unless_told_to_wait() {
    let (scene, mut opts) = setup();
    opts.plan.lights_per_node = 8;
    opts.control.redial = Duration::from_millis(200);
    // One stage only: losing it leaves no plan.
    let mut cluster = InProcessCluster::start(1, 1).await.unwrap();
    let (out, _) = {
        let stop = cluster.stop_token("comp-0").unwrap();
        let mut session = cluster.connect(opts.control).await.unwrap();
        let mut frames = Vec::new();
        let outcome = lightfold_coordinator::run::render(&mut session, &scene, &opts, |f| {
            if f.frame == 2 {
                stop.cancel();
            }
            frames.push(f);
        })
        .await;
        session.detach();
        (outcome, frames.len())
    };
    let msg = out.error.expect("the run cannot go on").to_string();
    assert!(
        msg.contains("no plan fits the daemons left") && msg.contains("comp-0"),
        "{msg}"
    );
    assert!(
        out.summary.delivered >= 2,
        "the frames before the loss were delivered"
    );
    cluster.kill("comp-0").await.unwrap();

    // Told to wait, the run picks the stage up again when it is restarted.
    cluster.restart("comp-0").await.unwrap();
    let stop = cluster.stop_token("comp-0").unwrap();
    opts.control.wait_for_daemons = Duration::from_secs(60);
    let mut session = cluster.connect(opts.control).await.unwrap();
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel::<()>();
    let mut frames = Vec::new();
    let run = lightfold_coordinator::run::render(&mut session, &scene, &opts, |f| {
        if f.frame == 2 {
            stop.cancel();
            let _ = tx.send(());
        }
        frames.push(f);
    });
    let supervisor = async {
        rx.recv().await;
        cluster.kill("comp-0").await.unwrap();
        tokio::time::sleep(Duration::from_millis(500)).await;
        cluster.restart("comp-0").await.unwrap();
    };
    let (outcome, ()) = tokio::time::timeout(lightfold_harness::RUN_DEADLINE, async {
        tokio::join!(run, supervisor)
    })
    .await
    .expect("timed out");
    session.detach();
    assert!(outcome.error.is_none(), "{:?}", outcome.error);
    assert_eq!(frames.len(), FRAMES as usize);
    cluster.stop().await.unwrap();
}

/// Seventy silent TCP connections to the coordinator's sink (no token, nothing sent), opened
/// under a coordinator that waits three minutes for its own dials (`demo`'s
/// `--connect-timeout`), then the sink compositor lost: the new last stage still gets its link to
/// the sink. The sink's handshake slots used to stay held for the coordinator's connect timeout,
/// so every re-plan failed to reach the sink and the run ended with frames never rendered.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn silent_connections_to_the_sink_do_not_keep_the_sink_stage_out() {
    let (scene, mut opts) = setup();
    opts.control.link.connect = Duration::from_secs(180);
    opts.control.link.handshake = Duration::from_secs(180);
    let cluster = InProcessCluster::start(4, 4).await.unwrap();
    let stop = cluster.stop_token("comp-3").unwrap();
    let mut session = cluster.connect(opts.control).await.unwrap();
    let mut silent = Vec::new();
    for _ in 0..70 {
        silent.push(
            tokio::net::TcpStream::connect(&session.sink_address)
                .await
                .unwrap(),
        );
    }
    let mut frames = Vec::new();
    let outcome = tokio::time::timeout(
        lightfold_harness::RUN_DEADLINE,
        lightfold_coordinator::run::render(&mut session, &scene, &opts, |f| {
            if f.frame == 2 {
                stop.cancel();
            }
            frames.push(f);
        }),
    )
    .await
    .expect("the run timed out");
    session.detach();
    drop(silent);
    assert!(
        outcome.error.is_none(),
        "{:?} after {} frames; epochs {:?}",
        outcome.error,
        frames.len(),
        outcome.summary.epochs
    );
    let out = RunOutput {
        plan: outcome.summary.plan.clone().expect("a plan"),
        frames,
        summary: outcome.summary,
    };
    assert!(
        !out.plan.stages.iter().any(|s| s.compositor == "comp-3"),
        "the final plan leaves the lost sink stage out"
    );
    assert_every_frame(&out, &scene, &opts, "with silent connections at the sink");
    cluster.stop().await.unwrap();
}

/// The live view's sequence that ended sessions: a saturated light colour (pure red, whose node
/// colour `[1, 0, 0]` render nodes refused), a frame budget set, then cleared — each a re-plan
/// over the red scene. Every frame is delivered, equal to the single-device render of its camera
/// under the colours it asked for.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_pure_red_light_and_a_budget_change_do_not_end_the_session() {
    let (scene, mut opts) = setup();
    let red = [1.0, 0.0, 0.0];
    opts.color_changes = vec![lightfold_coordinator::run::ColorChange {
        frame: 2,
        light: 0,
        color: red,
    }];
    let mut specs = lightfold_coordinator::run::frame_specs(&scene, &opts);
    // A budget the default plan fits (no concession changes the image), then none.
    specs[2].frame_budget_us = Some(Some(60_000_000));
    specs[4].frame_budget_us = Some(None);
    let cluster = InProcessCluster::start(4, 4).await.unwrap();
    let mut session = cluster.connect(opts.control).await.unwrap();
    let (req_tx, req_rx) = tokio::sync::mpsc::channel(1);
    let mut frames = Vec::new();
    let mut live = Live::new(&mut session, &scene, &opts.plan).unwrap();
    let notices = live.observe();
    let render = live.run(req_rx, |f| frames.push(f));
    let feed = async {
        for spec in specs {
            if req_tx.send(spec).await.is_err() {
                break;
            }
        }
        drop(req_tx);
    };
    let (result, ()) = tokio::time::timeout(lightfold_harness::RUN_DEADLINE, async {
        tokio::join!(render, feed)
    })
    .await
    .expect("the run timed out");
    let summary = std::mem::take(&mut live.summary);
    drop(live);
    session.detach();
    assert!(result.is_ok(), "{result:?}; epochs {:?}", summary.epochs);
    let reasons: Vec<&str> = summary.epochs.iter().map(|e| e.reason.as_str()).collect();
    eprintln!(
        "epochs: {reasons:?}; last notice {:?}",
        notices.borrow().notice
    );
    assert!(
        reasons.iter().any(|r| r.contains("colour group")),
        "the red light re-planned: {reasons:?}"
    );
    assert!(
        reasons.iter().any(|r| r.contains("no frame budget")),
        "clearing the budget re-planned: {reasons:?}"
    );
    assert!(
        !reasons.iter().any(|r| r.contains("refused")),
        "no daemon refused a plan: {reasons:?}"
    );
    let gpu = lightfold_harness::gpu();
    let numbers: Vec<u64> = frames.iter().map(|f| f.frame).collect();
    assert_eq!(numbers, (1..=u64::from(FRAMES)).collect::<Vec<_>>());
    for f in &frames {
        let mut s = scene.clone();
        s.camera = camera_at(&scene.camera, opts.path, (f.frame - 1) as u32);
        if f.frame >= 2 {
            s.lights[0].color = red;
        }
        let truth = lightfold_harness::single_device(&gpu, &s, false);
        lightfold_harness::assert_close(&f.image, &truth, &format!("frame {}", f.frame));
    }
    cluster.stop().await.unwrap();
}

/// A run resumed after its coordinator died (`--resume`): the frames already written are not
/// requested again, and the others arrive under their own numbers with their own cameras.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_resumed_run_renders_only_the_missing_frames() {
    let (scene, mut opts) = setup();
    opts.skip = vec![1, 2, 4];
    let cluster = InProcessCluster::start(4, 4).await.unwrap();
    let out = cluster.render(&scene, &opts).await.unwrap();
    let numbers: Vec<u64> = out.frames.iter().map(|f| f.frame).collect();
    assert_eq!(numbers, vec![3, 5, 6], "the missing frames, in order, once");
    let gpu = lightfold_harness::gpu();
    for f in &out.frames {
        let mut s = scene.clone();
        s.camera = camera_at(&scene.camera, opts.path, (f.frame - 1) as u32);
        let truth = lightfold_harness::single_device(&gpu, &s, false);
        lightfold_harness::assert_close(&f.image, &truth, &format!("resumed frame {}", f.frame));
    }
    cluster.stop().await.unwrap();
}

/// A render node dead while the coordinator connects (killed, or not up yet) does not fail the
/// start: the session starts with the daemons that answered, every frame is rendered, and the
/// node, once it is back on its address, is folded in.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_node_dead_at_the_start_is_folded_in_when_it_comes_back() {
    let (scene, mut opts) = setup();
    // Frames keep coming until node-1 renders one (or this many have been requested).
    opts.frames = 1000;
    let mut cluster = InProcessCluster::start(4, 4).await.unwrap();
    cluster.kill("node-1").await.unwrap();
    let started = Instant::now();
    let mut session = cluster.connect(opts.control).await.unwrap();
    let waited = started.elapsed();
    assert_eq!(session.unreachable.len(), 1, "{:?}", session.unreachable);
    assert_eq!(session.daemons.len(), 7);
    assert!(
        waited < Duration::from_secs(40),
        "the start waited {waited:?} for a dead node"
    );
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel::<()>();
    let mut frames = Vec::new();
    let stop = tokio_util::sync::CancellationToken::new();
    let enough = stop.clone();
    let run = lightfold_coordinator::run::render_until(&mut session, &scene, &opts, stop, |f| {
        if f.frame == 2 {
            let _ = tx.send(());
        }
        if f.stats.iter().any(|s| s.daemon_id == "node-1") {
            enough.cancel();
        }
        frames.push(f);
    });
    let supervisor = async {
        rx.recv().await;
        cluster.restart("node-1").await.unwrap();
    };
    let (outcome, ()) = tokio::time::timeout(lightfold_harness::RUN_DEADLINE, async {
        tokio::join!(run, supervisor)
    })
    .await
    .expect("the run timed out");
    session.detach();
    assert!(outcome.error.is_none(), "{:?}", outcome.error);
    assert_eq!(
        outcome.summary.epochs[0].nodes, 3,
        "the start plans without node-1"
    );
    assert!(
        outcome
            .summary
            .incidents
            .iter()
            .any(|i| i.daemon == "node-1" && i.kind == IncidentKind::Rejoined),
        "node-1 was folded in: {:?}",
        outcome.summary.epochs
    );
    assert!(
        frames
            .iter()
            .any(|f| f.stats.iter().any(|s| s.daemon_id == "node-1")),
        "node-1 never rendered in {} frames",
        frames.len()
    );
    opts.frames = frames.len() as u32;
    let out = RunOutput {
        plan: outcome.summary.plan.clone().expect("a plan"),
        frames,
        summary: outcome.summary,
    };
    assert_every_frame(&out, &scene, &opts, "with node-1 dead at the start");
    cluster.stop().await.unwrap();
}

/// The only render node slow to start (a loaded machine: it comes up after the compositor has
/// registered and the stragglers' grace has passed) is waited for until the register deadline,
/// not left behind: a session without a render node could plan nothing and would end at once.
/// The control: with a second render node up, the missing one is started without after the
/// grace.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn the_only_render_node_slow_to_start_is_waited_for() {
    let (scene, mut opts) = setup();
    opts.frames = 2;
    opts.control.stragglers = Duration::from_millis(500);
    opts.control.register = Duration::from_secs(60);
    for nodes in [1, 2] {
        let mut cluster = InProcessCluster::start(nodes, 1).await.unwrap();
        cluster.kill("node-0").await.unwrap();
        let (daemons, me) = (cluster.daemons(), cluster.identity());
        let sink = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let connect = lightfold_coordinator::control::Session::connect(
            &daemons,
            sink,
            None,
            me,
            opts.control,
        );
        // The control's node stays down: however slowly the others register, it cannot come
        // up inside their grace.
        let late_start = async {
            if nodes == 1 {
                tokio::time::sleep(Duration::from_secs(3)).await;
                cluster.restart("node-0").await.unwrap();
            }
        };
        let (session, ()) = tokio::time::timeout(lightfold_harness::RUN_DEADLINE, async {
            tokio::join!(connect, late_start)
        })
        .await
        .expect("connecting timed out");
        let mut session = session.unwrap();
        let unreachable: Vec<&str> = session
            .unreachable
            .iter()
            .map(|(a, _)| a.as_str())
            .collect();
        if nodes == 1 {
            assert!(unreachable.is_empty(), "left behind: {unreachable:?}");
            assert_eq!(session.daemons.len(), 2, "the node and the compositor");
            let out = lightfold_harness::render_on(&mut session, &scene, &opts)
                .await
                .unwrap();
            session.detach();
            assert_every_frame(&out, &scene, &opts, "with the only node late");
        } else {
            assert_eq!(unreachable.len(), 1, "control: node-0 is started without");
            assert_eq!(session.daemons.len(), 2, "node-1 and the compositor");
            session.detach();
        }
        cluster.stop().await.unwrap();
    }
}

/// Told to stop (Ctrl-C) while it waits for lost daemons to come back, the run stops at once with
/// what it delivered, instead of waiting out `--wait-for-daemons`.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_stop_ends_the_wait_for_lost_daemons() {
    let (scene, mut opts) = setup();
    opts.plan.lights_per_node = 8;
    opts.frames = 1000;
    opts.control.redial = Duration::from_millis(200);
    opts.control.wait_for_daemons = Duration::from_secs(120);
    // One stage only: losing it leaves no plan, and nothing brings it back.
    let cluster = InProcessCluster::start(1, 1).await.unwrap();
    let stage = cluster.stop_token("comp-0").unwrap();
    let mut session = cluster.connect(opts.control).await.unwrap();
    let stop = tokio_util::sync::CancellationToken::new();
    let ctrl_c = stop.clone();
    let (lost_tx, mut lost_rx) = tokio::sync::mpsc::unbounded_channel::<()>();
    let mut delivered = 0u64;
    let run = lightfold_coordinator::run::render_until(&mut session, &scene, &opts, stop, |f| {
        if f.frame == 2 {
            stage.cancel();
            let _ = lost_tx.send(());
        }
        delivered += 1;
    });
    let stopped_at = Arc::new(Mutex::new(None::<Instant>));
    let at = Arc::clone(&stopped_at);
    let user = async move {
        lost_rx.recv().await;
        // Well into the wait for lost daemons.
        tokio::time::sleep(Duration::from_secs(3)).await;
        *at.lock().unwrap() = Some(Instant::now());
        ctrl_c.cancel();
    };
    let (outcome, ()) = tokio::time::timeout(lightfold_harness::RUN_DEADLINE, async {
        tokio::join!(run, user)
    })
    .await
    .expect("the run timed out");
    let ended = stopped_at.lock().unwrap().expect("stopped").elapsed();
    session.detach();
    assert!(outcome.error.is_none(), "{:?}", outcome.error);
    assert!(delivered >= 2, "the frames before the loss were delivered");
    assert!(
        ended < Duration::from_secs(10),
        "the run went on {ended:?} after it was told to stop"
    );
    cluster.stop().await.unwrap();
}
