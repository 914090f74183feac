//! A frame budget in a live session is checked against measured frames: a cost model that is
//! 1000× too optimistic plans the scene at full quality, the loop measures the frames, corrects
//! the model and re-plans at the quality the budget allows, and then stays (no oscillation: the
//! last frames all come from one epoch); one 1000× too pessimistic starts at the lowest quality
//! and is raised to full quality. Without a budget the same wrong model changes nothing.

use lightfold_coordinator::control::{FrameSpec, Live, LiveSummary};
use lightfold_coordinator::plan::{CostScale, Knob, MapSizing, PlanOptions};
use lightfold_harness::{InProcessCluster, small, test_control};

/// Runs `frames` frames of small balls (two area lights of 4 samples) on three nodes; the
/// summary, and the epoch of each delivered frame.
async fn run(opts: PlanOptions, frames: usize) -> (LiveSummary, Vec<u64>) {
    let scene = small("balls");
    let cluster = InProcessCluster::start(3, 3).await.unwrap();
    let mut session = cluster.connect(test_control()).await.unwrap();
    let (tx, rx) = tokio::sync::mpsc::channel(2);
    let mut live = Live::new(&mut session, &scene, &opts).unwrap();
    let feed = async {
        for _ in 0..frames {
            if tx.send(FrameSpec::default()).await.is_err() {
                break;
            }
        }
        drop(tx);
    };
    let mut delivered = Vec::new();
    let (r, ()) = tokio::time::timeout(lightfold_harness::RUN_DEADLINE, async {
        tokio::join!(live.run(rx, |f| delivered.push(f.epoch)), feed)
    })
    .await
    .expect("the run timed out");
    r.unwrap();
    assert_eq!(delivered.len(), frames);
    let summary = std::mem::take(&mut live.summary);
    drop(live);
    cluster.stop().await.unwrap();
    (summary, delivered)
}

/// A re-plan or two from measured frames (a first correction may be refined by the next
/// window), every one said to be for the budget, and the last 12 frames from one epoch.
fn settled(s: &LiveSummary, epochs: &[u64], budget: &str) {
    let reasons: Vec<&str> = s.epochs.iter().map(|e| e.reason.as_str()).collect();
    eprintln!("epochs: {reasons:?}");
    assert!((2..=3).contains(&reasons.len()), "{reasons:?}");
    for r in &reasons[1..] {
        assert!(
            r.contains("measured frames") && r.contains(budget),
            "{reasons:?}"
        );
    }
    let last = &epochs[epochs.len() - 12..];
    assert!(last.iter().all(|&e| e == last[0]), "{epochs:?}");
    assert_eq!(Some(last[0]), s.plan.as_ref().map(|p| p.epoch));
}

/// The model believes the nodes 1000× faster than they are.
fn options(budget_us: Option<u64>) -> PlanOptions {
    PlanOptions {
        frame_budget_us: budget_us,
        map_sizing: MapSizing::Fixed(512),
        learned: lightfold_coordinator::plan::Learned {
            cost_scale: CostScale::uniform(1e-3),
            ..Default::default()
        },
        ..PlanOptions::default()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn measured_frames_correct_the_cost_model_and_the_plan_stays() {
    // 1 ms: met by the wrong model at full quality, by no plan once the model is corrected.
    let (s, epochs) = run(options(Some(1000)), 40).await;
    settled(&s, &epochs, "1.0 ms budget");
    let first = &s.epochs[0];
    let plan = s.plan.as_ref().unwrap();
    assert!(plan.k < first.k || plan.samples.len() < 8, "{plan}");
    let given: Vec<(Knob, &str)> = plan
        .concessions
        .iter()
        .map(|c| (c.knob, c.to.as_str()))
        .collect();
    // One sample per area light (with the penumbra filter where the last stage can afford it).
    assert!(
        given.iter().any(|(k, to)| *k == Knob::SamplesPerAreaLight
            && (*to == "1" || to.starts_with("1 + penumbra filter"))),
        "{given:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn without_a_budget_measured_frames_change_nothing() {
    let (s, _) = run(options(None), 20).await;
    assert_eq!(s.epochs.len(), 1, "{:?}", s.epochs);
    assert!(s.plan.unwrap().concessions.is_empty());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_pessimistic_model_starts_low_and_measured_frames_raise_the_quality() {
    // 10 s: missed by every plan of a model 1000× too slow, met at full quality by the frames.
    let o = PlanOptions {
        learned: lightfold_coordinator::plan::Learned {
            cost_scale: CostScale::uniform(1e3),
            ..Default::default()
        },
        ..options(Some(10_000_000))
    };
    let (s, epochs) = run(o, 40).await;
    settled(&s, &epochs, "10000.0 ms budget");
    let plan = s.plan.as_ref().unwrap();
    assert!(plan.concessions.is_empty(), "{plan}");
    assert_eq!(plan.samples.len(), 8);
}
