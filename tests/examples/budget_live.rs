//! Frame budgets on a live in-process cluster (issue 30's table, `docs/planner.md` § Frame
//! budgets): for each budget, `balls` is run through the control loop (`control::Live`) on N render
//! nodes and N compositors from the nodes' registered costs; the table gives the first plan's
//! choices, the plan the loop settled on after checking the budget against measured frames, the
//! measured median frame time (the slowest node's own work) and frame interval over the last
//! frames, and the penumbra PSNR the accuracy sweep measured (`docs/accuracy/balls`) for the
//! chosen sample count, beside the error model's figure.
//!
//! `cargo run --profile test -p lightfold-tests --example budget_live [-- MS,MS,... NODES FRAMES]`

use lightfold_coordinator::control::{FrameSpec, Live};
use lightfold_coordinator::plan::{MapSizing, Plan, PlanOptions, expected_penumbra_db};
use lightfold_tests::{InProcessCluster, test_control};

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Samples per area light of a plan of balls (two area lights, no point lights).
fn per_light(p: &Plan) -> usize {
    p.samples.len() / 2
}

fn choices(p: &Plan) -> String {
    format!(
        "K {} · {} nodes · {} per light{}",
        p.k,
        p.nodes.len(),
        per_light(p),
        p.gave_up()
            .map(|g| format!(" · {}", g.trim_start_matches("gave up for the budget: ")))
            .unwrap_or_default()
    )
}

/// Penumbra PSNR `docs/accuracy/balls` measured at n samples per area light (grid, 512²),
/// where it measured it.
fn swept(n: usize) -> Option<f64> {
    match n {
        1 => Some(27.39),
        4 => Some(37.34),
        16 => Some(47.53),
        64 => Some(55.51),
        256 => Some(58.09),
        _ => None,
    }
}

#[tokio::main(flavor = "multi_thread", worker_threads = 4)]
async fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let budgets: Vec<f64> = args
        .first()
        .map_or("100,250,500".into(), |s| s.clone())
        .split(',')
        .map(|b| b.parse())
        .collect::<Result<_, _>>()?;
    let nodes: usize = args.get(1).map_or(Ok(8), |s| s.parse())?;
    let frames: usize = args.get(2).map_or(Ok(30), |s| s.parse())?;
    let mut scene = lightfold_scene::builtin("balls")?;
    scene.camera.width = 400;
    scene.camera.height = 300;
    println!(
        "balls 400×300, {nodes} render nodes + {nodes} compositors in one process, {frames} frames \
         per budget"
    );
    println!(
        "| budget | first plan | settled plan | epochs | measured frame (p50) | interval (p50) | \
         penumbra PSNR: sweep / model |"
    );
    println!("|---|---|---|---|---|---|---|");
    for budget in budgets {
        let cluster = InProcessCluster::start(nodes, nodes).await?;
        let mut session = cluster.connect(test_control()).await?;
        let opts = PlanOptions {
            frame_budget_us: Some((budget * 1e3) as u64),
            map_sizing: MapSizing::Scene,
            ..PlanOptions::default()
        };
        let (tx, rx) = tokio::sync::mpsc::channel(2);
        let mut live = Live::new(&mut session, &scene, &opts)?;
        let feed = async {
            for _ in 0..frames {
                if tx.send(FrameSpec::default()).await.is_err() {
                    break;
                }
            }
            drop(tx);
        };
        let mut first: Option<String> = None;
        let mut last_epoch = 0;
        let mut work = Vec::new();
        let mut done = Vec::new();
        let observer = live.observe();
        let (r, ()) = tokio::join!(
            live.run(rx, |f| {
                if first.is_none() {
                    first = observer.borrow().plan.as_deref().map(choices);
                }
                if f.epoch != last_epoch {
                    last_epoch = f.epoch;
                    work.clear();
                    done.clear();
                }
                let slowest = f
                    .stats
                    .iter()
                    .filter(|s| s.daemon_id.starts_with("node-"))
                    .map(|s| s.pose_us + s.shadow_us + s.eye_us + s.readback_us + s.pack_us)
                    .max()
                    .unwrap_or(0);
                work.push(slowest as f64 / 1e3);
                done.push(f.received_at);
            }),
            feed
        );
        r?;
        let plan = live.summary.plan.clone().expect("a plan");
        let epochs = live.summary.epochs.len();
        for e in &live.summary.epochs {
            eprintln!(
                "  {budget} ms · epoch K = {} on {} node(s): {}",
                e.k, e.nodes, e.reason
            );
        }
        drop(live);
        cluster.stop().await?;
        let intervals: Vec<f64> = done
            .windows(2)
            .map(|w| w[1].duration_since(w[0]).as_secs_f64() * 1e3)
            .collect();
        let n = per_light(&plan);
        println!(
            "| {budget} ms | {} | {} | {epochs} | {:.1} ms | {:.1} ms | {} / {:.1} dB |",
            first.unwrap_or_default(),
            choices(&plan),
            median(work),
            median(intervals),
            swept(n).map_or("–".into(), |d| format!("{d:.2}")),
            expected_penumbra_db(n as u32)
        );
    }
    Ok(())
}
