//! Frame budgets on a live in-process cluster (issue 30's table, `docs/planner.md` § Frame
//! budgets): for each budget, `balls` is run through the control loop (`control::Live`) on N render
//! nodes and N compositors from the nodes' registered costs; the table gives the first plan's
//! choices, the plan the loop settled on after checking the budget against measured frames, the
//! measured median frame time (the slowest node's own work) and frame interval over the last
//! frames, the penumbra PSNR of the last frame against the area-light truth (256 points per area
//! light per pixel, from the accuracy sweep's cache or rendered), and the best penumbra PSNR any
//! point of the committed sweeps (`docs/accuracy/balls`, `docs/accuracy/balls-penumbra`) measured
//! on at most as many nodes with its slowest node within the budget.
//!
//! `cargo run --profile test -p lightfold-harness --example budget_live [-- MS,MS,... NODES FRAMES]`

use lightfold_coordinator::control::{FrameSpec, Live};
use lightfold_coordinator::plan::{MapSizing, Plan, PlanOptions};
use lightfold_harness::{InProcessCluster, test_control};
use lightfold_protocol::stats;
use lightfold_quality::accuracy::{TruthOptions, load_or_render_truth};

/// The best point of the committed `balls` sweeps whose slowest node took at most `budget_ms` on
/// at most `nodes` nodes: (its description, penumbra PSNR, frame ms). The sweep times each node's
/// batch on one device in turn, so its frame is what that many nodes of their own would take.
fn best_swept(budget_ms: f64, nodes: usize) -> anyhow::Result<Option<(String, f64, f64)>> {
    let mut best: Option<(String, f64, f64)> = None;
    for dir in ["balls", "balls-penumbra"] {
        let path = format!(
            "{}/../docs/accuracy/{dir}/sweep.csv",
            env!("CARGO_MANIFEST_DIR")
        );
        let mut r = csv::Reader::from_path(&path)?;
        let head = r.headers()?.clone();
        let col = |name: &str| head.iter().position(|h| h == name);
        let (Some(frame), Some(db), Some(used)) =
            (col("frame_seconds"), col("penumbra_psnr_db"), col("nodes"))
        else {
            anyhow::bail!("{path}: no frame_seconds, penumbra_psnr_db or nodes column");
        };
        for row in r.records() {
            let row = row?;
            let (ms, psnr): (f64, f64) = (row[frame].parse::<f64>()? * 1e3, row[db].parse()?);
            let used: usize = row[used].parse()?;
            if ms > budget_ms || used > nodes || best.as_ref().is_some_and(|b| b.1 >= psnr) {
                continue;
            }
            let get = |n: &str| col(n).map_or("?", |i| &row[i]).to_string();
            let filter = match get("penumbra_filter").as_str() {
                "0" | "?" => String::new(),
                r => format!(" + penumbra r{r}"),
            };
            let what = format!(
                "{} per light{filter}, map {}, {}, K {}, {used} nodes",
                get("samples"),
                get("map_size"),
                get("filter"),
                get("k")
            );
            best = Some((what, psnr, ms));
        }
    }
    Ok(best)
}

fn median(v: &[f64]) -> f64 {
    stats::median(v).unwrap_or(f64::NAN)
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
    // The accuracy sweep's truth (and its cache, so a committed sweep's truth is reused).
    let truth = load_or_render_truth(
        &scene,
        &TruthOptions {
            samples_per_light: 256,
            cache_dir: dirs::cache_dir().map(|d| d.join("lightfold").join("accuracy")),
        },
    )?;
    println!(
        "balls 400×300, {nodes} render nodes + {nodes} compositors in one process, {frames} frames \
         per budget"
    );
    println!(
        "| budget | first plan | settled plan | epochs | measured frame (p50) | interval (p50) | \
         penumbra PSNR of the last frame | best sweep point within the budget |"
    );
    println!("|---|---|---|---|---|---|---|---|");
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
        let mut last = None;
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
                last = Some(f.image);
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
        let measured = match &last {
            Some(image) => truth
                .truth
                .compare(image)?
                .penumbra
                .map_or(f64::NAN, |p| p.psnr),
            None => f64::NAN,
        };
        let best = best_swept(budget, nodes)?.map_or("none".to_string(), |(what, db, ms)| {
            format!("{db:.2} dB ({what}; {ms:.0} ms)")
        });
        println!(
            "| {budget} ms | {} | {} | {epochs} | {:.1} ms | {:.1} ms | {measured:.2} dB | {best} |",
            first.unwrap_or_default(),
            choices(&plan),
            median(&work),
            median(&intervals),
        );
    }
    Ok(())
}
