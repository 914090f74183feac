//! `lightfold accuracy`: the speed-against-error sweep of one scene (CSV, Markdown, SVG under
//! `--out`), on one device or with `--cluster` through an in-process cluster, or with `--hard`
//! the full-size hard cases of numerical stability.

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use lightfold_node::gpu::{Gpu, GpuOptions};
use lightfold_quality::accuracy::{
    self, CachedTruth, SweepPlan, TruthOptions, load_or_render_truth, planned, report, run_sweep,
    run_sweep_with,
};
use lightfold_telemetry::outln;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Built-in scene name, `.toml` scene file or `.gltf`/`.glb`, `.obj`, `.ply` or USD
    /// (`.usda`, `.usdc`, `.usdz`) model.
    #[arg(long, default_value = lightfold_scene::defaults::DEFAULT_SCENE)]
    scene: String,
    /// Run the hard cases of numerical stability at full size instead of the sweep.
    #[arg(long)]
    hard: bool,
    /// Image size as WIDTHxHEIGHT.
    #[arg(long, default_value = "400x300")]
    size: String,
    /// Output folder (default: lightfold-accuracy/<scene>, or lightfold-accuracy/hard, in the
    /// current directory; the committed results live in docs/accuracy/ and are rewritten only
    /// when named here).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Points per area light per pixel of the ground truth.
    #[arg(long, default_value_t = 256)]
    truth_samples: u32,
    /// Sweep: `full`, `reduced` (samples ≤ 64, maps ≤ 2048, fewer K) or `tiny`.
    #[arg(long, default_value = "full")]
    sweep: String,
    /// Vary only these knobs of the sweep, comma-separated: samples, pattern, map, filter,
    /// format, K, grid, penumbra (default: all).
    #[arg(long, value_delimiter = ',')]
    knobs: Vec<String>,
    /// Where ground truths are cached by scene hash (default: the user's cache folder,
    /// e.g. ~/.cache/lightfold/accuracy).
    #[arg(long)]
    cache_dir: Option<PathBuf>,
    /// Timed frames per point (each node's fastest counts).
    #[arg(long, default_value_t = 2)]
    repeats: u32,
    /// The penumbra PSNR the report looks for the cheapest setting to reach.
    #[arg(long, default_value_t = 45.0)]
    target_db: f64,
    /// Render every point through a cluster in this process (render nodes, compositors and a
    /// coordinator on loopback links: every link format, the material layers and the planner's
    /// choices) instead of one device with the node link simulated.
    #[arg(long)]
    cluster: bool,
    /// `--cluster`: render nodes (the planner raises K where a point needs more).
    #[arg(long, default_value_t = 8, requires = "cluster")]
    cluster_nodes: usize,
    /// `--cluster`: compositors.
    #[arg(long, default_value_t = 8, requires = "cluster")]
    cluster_compositors: usize,
    /// Instead of the sweep, measure what the planner chooses for the scene by default (with its
    /// calibration, made first when the cache has none) beside the scene as it asks (the
    /// previous default), both against the area-light truth; one Markdown row each.
    #[arg(long, conflicts_with_all = ["hard", "cluster"])]
    planned: bool,
    #[command(flatten)]
    model: crate::model_args::ModelArgs,
}

/// Where results go unless `--out` says otherwise: a folder of their own in the current
/// directory.
const DEFAULT_OUT: &str = "lightfold-accuracy";

/// The truth cache: `--cache-dir`, else the user's cache folder, else beside the results.
fn cache_dir(args: &Args) -> PathBuf {
    args.cache_dir.clone().unwrap_or_else(|| {
        dirs::cache_dir().map_or_else(
            || PathBuf::from(DEFAULT_OUT).join("truth-cache"),
            |d| d.join("lightfold").join("accuracy"),
        )
    })
}

fn scene_label(scene: &str) -> String {
    let stem = std::path::Path::new(scene)
        .file_stem()
        .map_or_else(|| scene.to_string(), |s| s.to_string_lossy().into_owned());
    stem.to_ascii_lowercase()
}

/// Runs `lightfold accuracy`: the hard cases, the planned comparison, or the sweep of the
/// scene's settings against its ground truth, written as CSV, Markdown and SVG under the
/// output folder with the report's headline printed.
pub(crate) fn run(args: Args) -> anyhow::Result<()> {
    if args.hard {
        return run_hard(&args);
    }
    if args.planned {
        return run_planned(&args);
    }
    let plan = SweepPlan::named(&args.sweep, &args.knobs).map_err(anyhow::Error::msg)?;
    let mut scene = lightfold_scene::load(&args.scene)
        .with_context(|| format!("cannot load scene {:?}", args.scene))?;
    let (w, h) = crate::plan_args::parse_size(&args.size)?;
    scene.camera.width = w;
    scene.camera.height = h;
    let label = scene_label(&args.scene);
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(DEFAULT_OUT).join(&label));
    std::fs::create_dir_all(&out).with_context(|| format!("cannot create {}", out.display()))?;
    let truth = truth_for(&args, &scene)?;

    let gpu = Gpu::new(&GpuOptions::default()).context("no usable GPU")?;
    let points = plan.points(accuracy::Setting::defaults(&scene));
    let bar = ProgressBar::new(points.len() as u64);
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} points, {elapsed} {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let progress = |done: usize, what: &str| {
        bar.set_position(done as u64);
        bar.set_message(what.to_string());
    };
    let points = if args.cluster {
        let mut c = lightfold_harness::sweep::SweepCluster::start(
            args.cluster_nodes,
            args.cluster_compositors,
        )?;
        let points = run_sweep_with(&scene, &truth, &plan, progress, |scene, settings| {
            c.measure(scene, settings, args.repeats)
        });
        c.stop()?;
        points?
    } else {
        run_sweep(&gpu, &scene, &truth, &plan, args.repeats, progress)?
    };
    bar.finish_and_clear();

    let command = command_line(&args, &out);
    let title = sweep_title(&args, &label, (w, h), &gpu.info.name);
    report::write_csv(&out.join("sweep.csv"), &points)?;
    report::write_markdown(
        &out.join("README.md"),
        &title,
        &command,
        &truth,
        &points,
        args.target_db,
    )?;
    report::write_svg(&out.join("frontier.svg"), &title, &truth, &points)?;
    let md = report::markdown(&title, &command, &truth, &points, args.target_db);
    // The headline paragraphs and the pattern table (everything before the table of points).
    for line in md.lines().take_while(|l| !l.starts_with("| knob")) {
        outln!("{line}");
    }
    outln!(
        "wrote {}/{{sweep.csv,README.md,frontier.svg}}",
        out.display()
    );
    Ok(())
}

/// Loads the scene's ground truth from the cache or renders it, saying on stderr which and
/// what it is worth (the floor of the penumbra PSNR, the tie pixels left out).
fn truth_for(args: &Args, scene: &lightfold_scene::Scene) -> anyhow::Result<CachedTruth> {
    eprintln!(
        "truth: {}x{}, {} points per area light per pixel…",
        scene.camera.width, scene.camera.height, args.truth_samples
    );
    let truth = load_or_render_truth(
        scene,
        &TruthOptions {
            samples_per_light: args.truth_samples,
            cache_dir: Some(cache_dir(args)),
        },
    )?;
    eprintln!(
        "truth {} ({}; {:.1} s); floor penumbra PSNR {:.2} dB; {} tie pixels left out",
        truth.key,
        if truth.from_cache {
            "cached"
        } else {
            "rendered"
        },
        truth.render_seconds,
        truth.floor.penumbra.map_or(f64::NAN, |p| p.psnr),
        truth.truth.tie_pixels()
    );
    Ok(truth)
}

/// The command that repeats this sweep, as the report quotes it.
fn command_line(args: &Args, out: &std::path::Path) -> String {
    let threads = std::env::var("LP_NUM_THREADS")
        .map(|t| format!("LP_NUM_THREADS={t} "))
        .unwrap_or_default();
    format!(
        "{threads}NODEVICE_SELECT=1 lightfold accuracy --scene {} --size {} \
         --truth-samples {} --sweep {}{}{} --repeats {} --out {}",
        args.scene,
        args.size,
        args.truth_samples,
        args.sweep,
        if args.knobs.is_empty() {
            String::new()
        } else {
            format!(" --knobs {}", args.knobs.join(","))
        },
        if args.cluster {
            format!(
                " --cluster --cluster-nodes {} --cluster-compositors {}",
                args.cluster_nodes, args.cluster_compositors
            )
        } else {
            String::new()
        },
        args.repeats,
        out.display()
    )
}

/// The report's title: the scene, image size, sweep and knobs, and what rendered it.
fn sweep_title(args: &Args, label: &str, (w, h): (u32, u32), device: &str) -> String {
    let knobs = if args.knobs.is_empty() {
        String::new()
    } else {
        format!(" ({})", args.knobs.join(", "))
    };
    let path = if args.cluster {
        format!(
            ", through a cluster of {} nodes and {} compositors",
            args.cluster_nodes, args.cluster_compositors
        )
    } else {
        String::new()
    };
    format!("{label} ({w}×{h}, {}{knobs}{path} on {device})", args.sweep)
}

/// `--planned`: the planner's default choice (with this scene's calibration) against the scene
/// as it asks, rendered on this device as the sweep renders a point, both against the truth.
fn run_planned(args: &Args) -> anyhow::Result<()> {
    let mut scene = lightfold_scene::load(&args.scene)
        .with_context(|| format!("cannot load scene {:?}", args.scene))?;
    let (w, h) = crate::plan_args::parse_size(&args.size)?;
    scene.camera.width = w;
    scene.camera.height = h;
    let cache = args.model.cache();
    let calibration = crate::model_args::run_calibration(&scene, &cache)?;
    let model = (args.model.error_model != "default").then(|| calibration.model.clone());
    let truth = load_or_render_truth(
        &scene,
        &TruthOptions {
            samples_per_light: args.truth_samples,
            cache_dir: cache.truth_cache.clone(),
        },
    )?;
    let gpu = Gpu::new(&GpuOptions::default()).context("no usable GPU")?;
    let rows = planned::measure(
        &gpu,
        &scene,
        args.target_db as f32,
        model,
        &truth,
        args.repeats,
    )?;
    outln!(
        "| scene | setting | samples/light | map floor | filter | penumbra PSNR (expected) | whole PSNR | node-s | truth floor |"
    );
    outln!("|---|---|---:|---:|---:|---:|---:|---:|---:|");
    for r in rows {
        outln!(
            "| {} | {} | {} | {} | {} | {:.2} dB{} | {:.2} dB | {:.3} | {:.2} dB |",
            scene_label(&args.scene),
            r.what,
            r.samples,
            r.floor,
            r.filter,
            r.penumbra_db,
            r.expected_db
                .map_or_else(String::new, |e| format!(" ({e:.2})")),
            r.whole_db,
            r.node_seconds,
            truth.floor.penumbra.map_or(f64::NAN, |e| e.psnr),
        );
    }
    Ok(())
}

fn run_hard(args: &Args) -> anyhow::Result<()> {
    use lightfold_quality::hard::{case_names, run_case};
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(DEFAULT_OUT).join("hard"));
    std::fs::create_dir_all(&out).with_context(|| format!("cannot create {}", out.display()))?;
    let mut text = String::from(
        "# Hard cases at full size\n\nReproduce: `lightfold accuracy --hard`\n\n```\n",
    );
    let mut failed = Vec::new();
    for name in case_names() {
        let report = run_case(name, true).with_context(|| format!("hard case {name}"))?;
        outln!("{report}");
        text.push_str(&format!("{report}\n"));
        if !report.passes() {
            failed.push(name);
        }
    }
    text.push_str("```\n");
    let path = out.join("README.md");
    std::fs::write(&path, text).with_context(|| format!("cannot write {}", path.display()))?;
    if failed.is_empty() {
        Ok(())
    } else {
        anyhow::bail!("hard cases failed: {}", failed.join(", "))
    }
}
