//! Issue 22's shadow-map cases with and without the fixes, and what the fixes cost on built-in
//! scenes, for docs/hard-cases.md:
//!
//! ```sh
//! cargo run --profile test -p lightfold-quality --example issue22 -- [--full] [--before | --no-ids] [--map N] [NAME...]
//! cargo run --profile test -p lightfold-quality --example issue22 -- --cost balls animal
//! ```
//!
//! `--before`: neither fix (one frustum per light, one bias for every caster); `--no-ids`: the
//! cascades without the object-ID test; `--map N`: N² maps instead of the scene's. `--cost`: per scene, the GPU renderer's shadow + eye time (median of 5 frames after a warm-up),
//! shadow passes and map sizes before the fixes, with the fixes at 512², at the default's per-light
//! sizes and at fixed 1024² and 2048², and each render's whole-image and penumbra PSNR
//! against the exact point sum of the same samples (penumbra: `reference::masks::penumbra`).
use lightfold_node::gpu::{Gpu, GpuOptions, LayerSet, RenderOptions, Renderer};
use lightfold_protocol::stats;
use lightfold_quality::hard::shadow_maps::{Fixes, run_with};
use lightfold_reference::metrics::error_stats;
use lightfold_reference::{PointSumOptions, masks, render_point_sum, render_point_sum_with};
use lightfold_scene::shadow_views::Mismatch;
use lightfold_scene::{MapSizing, defaults, sampling};

fn cost(name: &str) -> anyhow::Result<()> {
    let gpu = Gpu::new(&GpuOptions::default())?;
    let scene = lightfold_scene::builtin(name)?;
    let samples = sampling::direct_samples(&scene);
    let truth = render_point_sum(&scene, &samples, [1.0; 3]).radiance([1.0; 3], scene.ambient);
    let open = render_point_sum_with(
        &scene,
        &samples,
        [1.0; 3],
        PointSumOptions { shadows: false },
    )
    .radiance([1.0; 3], scene.ambient);
    let penumbra = masks::penumbra(&truth, &open);
    // (label, fixes, map rule): the state before issue 22, the two shading fixes at the old
    // default (every map 512²), the default now (the scene's rule: per-light sizes), and fixed
    // larger maps for the resolution curve.
    let fixed = |n| RenderOptions::from_quality(&scene.quality).fixed_maps(n);
    // Every map n² through the atlas, which halves the largest maps where a frame's maps pass the
    // device's budget (a fixed size above 512² refuses 32 lights of six views outright).
    let pinned = |n| RenderOptions {
        map_sizing: MapSizing::Mismatch(Mismatch {
            min: n,
            max: n,
            ..defaults::MAP_MISMATCH
        }),
        ..RenderOptions::from_quality(&scene.quality)
    };
    let configs = [
        ("before, 512²", Fixes::NONE, fixed(512)),
        ("fixes, 512²", Fixes::ALL, fixed(512)),
        (
            "default (per-light sizes)",
            Fixes::ALL,
            RenderOptions::from_quality(&scene.quality),
        ),
        ("fixes, every map 1024²", Fixes::ALL, pinned(1024)),
        ("fixes, every map 2048²", Fixes::ALL, pinned(2048)),
    ];
    let mut baseline = None;
    for (label, fixes, options) in configs {
        let mut r = Renderer::new(&gpu, &scene, options)?;
        r.set_cascades(fixes.cascades);
        r.set_object_ids(fixes.object_ids);
        let mut times = Vec::new();
        let mut last = None;
        for _ in 0..6 {
            let f = r.render(&gpu, &samples, None, [1.0; 3], LayerSet::all())?;
            times.push(f.stats.shadow_us + f.stats.eye_us);
            last = Some(f);
        }
        let f = last.expect("rendered");
        times.remove(0);
        let median = stats::median(&times).expect("timed frames") as f64 / 1e3;
        let base = *baseline.get_or_insert(median);
        let illum = f.illumination.clone().expect("illumination");
        let img = f.radiance(&illum, scene.ambient)?;
        let whole = error_stats(&img, &truth, scene.exposure, None)?;
        let pen = error_stats(&img, &truth, scene.exposure, Some(&penumbra))?;
        // LIGHTFOLD_HARD_DUMP=DIR: the render, the truth and 8× their absolute difference as PNG.
        if let Some(dir) = std::env::var_os("LIGHTFOLD_HARD_DUMP") {
            let dir = std::path::Path::new(&dir);
            std::fs::create_dir_all(dir)?;
            let tag = label.replace([' ', ',', '(', ')', '²'], "");
            img.write_png(&dir.join(format!("{name}-{tag}.png")), scene.exposure)?;
            truth.write_png(&dir.join(format!("{name}-truth.png")), scene.exposure)?;
            let mut diff = img.clone();
            for (d, t) in diff.data.iter_mut().zip(&truth.data) {
                *d = 8.0 * (*d - t).abs();
            }
            diff.write_png(&dir.join(format!("{name}-{tag}-diff8.png")), scene.exposure)?;
        }
        let (lo, hi) = f
            .stats
            .map_sides
            .iter()
            .fold((u32::MAX, 0), |(lo, hi), &s| (lo.min(s), hi.max(s)));
        println!(
            "{name} {label}: {} samples, {} shadow passes, maps {lo}²–{hi}² ({} halved), shadow+eye {median:.1} ms \
             (median of 5; ×{:.2} of the first line), PSNR whole {:.2} dB, penumbra {:.2} dB ({} px)",
            samples.len(),
            f.stats.passes_per_light.iter().sum::<u32>(),
            f.stats.maps_halved,
            median / base,
            whole.psnr,
            pen.psnr,
            pen.pixels
        );
    }
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let full = args.iter().any(|a| a == "--full");
    let map_size = args
        .iter()
        .position(|a| a == "--map")
        .map(|i| {
            args.get(i + 1)
                .and_then(|v| v.parse::<u32>().ok())
                .ok_or_else(|| anyhow::anyhow!("--map takes a map size"))
        })
        .transpose()?;
    let mut fixes = if args.iter().any(|a| a == "--before") {
        Fixes::NONE
    } else if args.iter().any(|a| a == "--no-ids") {
        Fixes {
            object_ids: false,
            ..Fixes::ALL
        }
    } else {
        Fixes::ALL
    };
    fixes.map_size = map_size;
    if args.iter().any(|a| a == "--no-plane") {
        fixes.receiver_plane = false;
    }
    let mut names: Vec<&str> = args
        .iter()
        .filter(|a| !a.starts_with("--") && a.parse::<u32>().is_err())
        .map(String::as_str)
        .collect();
    if args.iter().any(|a| a == "--cost") {
        for name in names {
            cost(name)?;
        }
        return Ok(());
    }
    if names.is_empty() {
        names = vec![
            "corner-leak",
            "grazing-fin",
            "deep-near",
            "thin-poles",
            "thin-house",
            "cornell-junction",
        ];
    }
    for name in names {
        let t = std::time::Instant::now();
        let r = run_with(name, full, fixes)
            .ok_or_else(|| anyhow::anyhow!("{name} is not one of issue 22's cases"))??;
        println!("{fixes:?}\n{r}\n  ({:.1} s)", t.elapsed().as_secs_f64());
    }
    Ok(())
}
