//! `lightfold calibrate`: a scene's own error model for the planner (`docs/planner.md` § Error
//! model), printed as the curves it measured and the setting it chooses for a target, and cached
//! where `plan`, `coordinator` and `demo` look for it.

use crate::model_args::{DEFAULT_TARGET_DB, ModelArgs, run_calibration};
use anyhow::Context;
use lightfold_telemetry::outln;

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Built-in scene name, `.toml` scene file or `.gltf`/`.glb`, `.obj`, `.ply` or USD
    /// (`.usda`, `.usdc`, `.usdz`) model.
    #[arg(long, default_value = lightfold_scene::defaults::DEFAULT_SCENE)]
    scene: String,
    /// Image size as WIDTHxHEIGHT the plans will render at (default: the scene's).
    #[arg(long)]
    size: Option<String>,
    /// The penumbra PSNR (dB) whose cheapest setting is printed.
    #[arg(long, default_value_t = DEFAULT_TARGET_DB)]
    target_db: f32,
    #[command(flatten)]
    model: ModelArgs,
}

pub(crate) fn run(args: Args) -> anyhow::Result<()> {
    let mut scene = lightfold_scene::load(&args.scene)
        .with_context(|| format!("cannot load scene {:?}", args.scene))?;
    if let Some(size) = &args.size {
        let (w, h) = crate::plan_args::parse_size(size)?;
        scene.camera.width = w;
        scene.camera.height = h;
    }
    let c = run_calibration(&scene, &args.model.cache())?;
    outln!("error model: {}", c.model.source);
    if c.model.truth_floor_db > 0.0 {
        outln!(
            "truth's noise floor in the penumbra: {:.2} dB (figures near it are as good as the \
             truth can tell)",
            c.model.truth_floor_db
        );
    }
    if c.from_cache {
        outln!("(from the cache, key {})", c.key);
    } else {
        outln!(
            "calibrated at {}×{} (1/{} of the image): truth {:.1} s, renders {:.1} s",
            c.size.0,
            c.size.1,
            c.divisor,
            c.truth_seconds,
            c.seconds
        );
    }
    let mut table = comfy_table::Table::new();
    table.load_style(comfy_table::presets::ASCII_MARKDOWN);
    table.set_header([
        "map floor",
        "samples/light",
        "penumbra PSNR",
        "filtered (radius)",
        "cell filter",
        "node-s/frame (full size, estimated)",
    ]);
    for curve in &c.model.curves {
        for &(n, db) in &curve.unfiltered {
            let filtered = curve
                .filtered
                .iter()
                .find(|f| f.0 == n)
                .map_or_else(|| "—".to_string(), |f| format!("{:.2} dB (r{})", f.2, f.1));
            let cell = curve.cell_db(n).map_or_else(
                || "—".to_string(),
                |db| {
                    format!(
                        "{db:.2} dB ({:.3} node-s)",
                        curve.cell_seconds_per_sample * f64::from(n)
                    )
                },
            );
            table.add_row([
                if curve.map_floor == 0 {
                    "the scene's".to_string()
                } else {
                    format!("{}²", curve.map_floor)
                },
                n.to_string(),
                format!("{db:.2} dB"),
                filtered,
                cell,
                format!("{:.3}", curve.seconds_per_sample * f64::from(n)),
            ]);
        }
    }
    outln!("{table}");
    match scene.area_samples() {
        None => outln!("the scene has no area light: no sample count to choose"),
        Some(from) => {
            // What a plan's default filter (`budget`) does where a target chooses the samples:
            // the radius the curve gains most with.
            let choice = c
                .model
                .cheapest(args.target_db, from, |curve, n| curve.filter_radius(n));
            outln!(
                "for {:.1} dB: {} samples per area light{}{}, expected {:.2} dB{} \
                 (`lightfold plan` and `lightfold demo` now choose it; \
                 `lightfold accuracy --planned` measures it)",
                args.target_db,
                choice.samples,
                if choice.map_floor == 0 {
                    String::new()
                } else {
                    format!(", shadow maps from {}²", choice.map_floor)
                },
                if choice.cell {
                    ", the cell filter".to_string()
                } else if choice.radius > 0 {
                    format!(", penumbra filter r{}", choice.radius)
                } else {
                    String::new()
                },
                choice.db,
                if choice.db >= args.target_db {
                    ""
                } else {
                    " — the most it measured: the target is out of reach"
                }
            );
        }
    }
    Ok(())
}
