//! Speed against error of one-bounce indirect light (issue 25) for `docs/accuracy/indirect/`:
//!
//! ```sh
//! LP_NUM_THREADS=2 NODEVICE_SELECT=1 cargo run --profile test -p lightfold-quality \
//!     --example indirect_sweep -- --out docs/accuracy/indirect [--size 160x120] [--paths 256]
//! ```
//!
//! Per scene (`cornell`, and the Fox on its floor, posed at rest), the truth is the exact sum of
//! the direct samples plus the path-traced one bounce of those samples
//! (`reference::indirect::render_one_bounce`, `--paths` per pixel), and its noise is measured
//! against a second truth of another seed. For M = 0, 64, 256, 1024 VPLs (and, at 256, clamps of
//! 0, ½× and 2× the default), it renders every sample on the GPU in batches of K = 16 (the
//! node-seconds of the frame: the sum of the batches' wall times) and reports the total error
//! against the truth, split into the VPL error (the CPU's exact VPL sum against the truth) and
//! the shadow-map error (the GPU against that exact sum).
use lightfold_node::gpu::{Gpu, GpuOptions};
use lightfold_quality::gpu_radiance;
use lightfold_reference::indirect::OneBounceOptions;
use lightfold_reference::metrics::error_stats;
use lightfold_reference::{render_one_bounce, render_point_sum};
use lightfold_scene::vpl::{self, default_clamp};
use lightfold_scene::{Image, SampleKind, Scene, sampling};
use plotters::prelude::*;
use std::path::{Path, PathBuf};
use std::time::Instant;

struct Row {
    scene: String,
    vpls_asked: u32,
    vpls: usize,
    clamp: f32,
    node_seconds: f64,
    psnr: f64,
    energy_bias: f64,
    vpl_psnr: f64,
    vpl_bias: f64,
    map_psnr: f64,
    /// A point of the M series at the default clamp (the plotted line).
    series: bool,
}

fn add(a: &Image, b: &Image) -> Image {
    let mut out = a.clone();
    for (o, v) in out.data.iter_mut().zip(&b.data) {
        *o += v;
    }
    out
}

fn sweep(
    gpu: &Gpu,
    name: &str,
    mut scene: Scene,
    paths: u32,
    rows: &mut Vec<Row>,
) -> anyhow::Result<()> {
    scene.animation = None;
    let direct = sampling::direct_samples(&scene);
    let t = Instant::now();
    let direct_img = render_point_sum(&scene, &direct, [1.0; 3]).radiance([1.0; 3], scene.ambient);
    let bounce = |seed| {
        render_one_bounce(&scene, &direct, &OneBounceOptions { paths, seed })
            .radiance([1.0; 3], [0.0; 3])
    };
    let truth = add(&direct_img, &bounce(1));
    let second = add(&direct_img, &bounce(2));
    let floor = error_stats(&second, &truth, scene.exposure, None)?;
    eprintln!(
        "{name}: truth ({} direct samples, {paths} paths/px) in {:.1} s; two seeds differ by PSNR {:.2} dB",
        direct.len(),
        t.elapsed().as_secs_f64(),
        floor.psnr
    );
    let clamp0 = default_clamp(&scene);
    let mut points: Vec<(u32, f32)> = [0, 64, 256, 1024].iter().map(|&m| (m, clamp0)).collect();
    points.extend([(256, 0.0), (256, 0.5 * clamp0), (256, 2.0 * clamp0)]);
    for (k, (m, clamp)) in points.into_iter().enumerate() {
        let mut s = scene.clone();
        s.quality.indirect = m;
        s.quality.indirect_clamp = Some(clamp);
        let samples = vpl::frame_samples(&s);
        let vpls = samples
            .iter()
            .filter(|x| matches!(x.kind, SampleKind::Bounce { .. }))
            .count();
        let exact = render_point_sum(&s, &samples, [1.0; 3]).radiance([1.0; 3], s.ambient);
        // The faster of two frames: these machines are shared.
        let (img, first) = gpu_radiance(gpu, &s, &samples)?;
        let (_, second) = gpu_radiance(gpu, &s, &samples)?;
        let seconds = first.min(second);
        let total = error_stats(&img, &truth, s.exposure, None)?;
        let vpl = error_stats(&exact, &truth, s.exposure, None)?;
        let map = error_stats(&img, &exact, s.exposure, None)?;
        eprintln!(
            "{name} M={m} clamp={clamp:.3}: {vpls} VPLs, {seconds:.2} node-s, PSNR {:.2} dB (bias {:+.4}); VPL {:.2} dB, maps {:.2} dB",
            total.psnr, total.energy_bias, vpl.psnr, map.psnr
        );
        rows.push(Row {
            scene: name.to_string(),
            vpls_asked: m,
            vpls,
            clamp,
            node_seconds: seconds,
            psnr: total.psnr,
            energy_bias: total.energy_bias,
            vpl_psnr: vpl.psnr,
            vpl_bias: vpl.energy_bias,
            map_psnr: map.psnr,
            series: k < 4,
        });
    }
    rows.push(Row {
        scene: format!("{name} (truth noise)"),
        vpls_asked: 0,
        vpls: 0,
        clamp: 0.0,
        node_seconds: 0.0,
        psnr: floor.psnr,
        energy_bias: floor.energy_bias,
        vpl_psnr: f64::NAN,
        vpl_bias: f64::NAN,
        map_psnr: f64::NAN,
        series: false,
    });
    Ok(())
}

fn write_csv(path: &Path, rows: &[Row]) -> anyhow::Result<()> {
    let mut w = csv::Writer::from_path(path)?;
    w.write_record([
        "scene",
        "vpls_asked",
        "vpls",
        "clamp_m",
        "node_seconds",
        "psnr_db",
        "energy_bias",
        "vpl_psnr_db",
        "vpl_energy_bias",
        "shadow_map_psnr_db",
    ])?;
    for r in rows {
        w.write_record([
            r.scene.clone(),
            r.vpls_asked.to_string(),
            r.vpls.to_string(),
            format!("{:.4}", r.clamp),
            format!("{:.4}", r.node_seconds),
            format!("{:.3}", r.psnr),
            format!("{:.5}", r.energy_bias),
            format!("{:.3}", r.vpl_psnr),
            format!("{:.5}", r.vpl_bias),
            format!("{:.3}", r.map_psnr),
        ])?;
    }
    w.flush()?;
    Ok(())
}

fn write_svg(path: &Path, rows: &[Row]) -> anyhow::Result<()> {
    let pts: Vec<&Row> = rows
        .iter()
        .filter(|r| r.node_seconds > 0.0 && r.psnr.is_finite())
        .collect();
    let x0 = pts
        .iter()
        .map(|r| r.node_seconds)
        .fold(f64::INFINITY, f64::min);
    let x1 = pts.iter().map(|r| r.node_seconds).fold(0.0, f64::max);
    let y0 = pts.iter().map(|r| r.psnr).fold(f64::INFINITY, f64::min);
    let y1 = pts.iter().map(|r| r.psnr).fold(f64::NEG_INFINITY, f64::max);
    let draw = || -> Result<(), Box<dyn std::error::Error>> {
        let root = SVGBackend::new(path, (900, 600)).into_drawing_area();
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                "one-bounce indirect light: PSNR vs node-seconds (default clamp)",
                ("sans-serif", 20),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(
                (x0 / 1.3..x1 * 1.3).log_scale(),
                (y0 - 2.0).floor()..(y1 + 2.0).ceil(),
            )?;
        chart
            .configure_mesh()
            .x_desc("node-seconds per frame (log), K = 16")
            .y_desc("whole-image PSNR vs one-bounce truth (dB)")
            .draw()?;
        let scenes: Vec<String> = {
            let mut v: Vec<String> = pts.iter().map(|r| r.scene.clone()).collect();
            v.dedup();
            v
        };
        for (i, name) in scenes.iter().enumerate() {
            let colour = Palette99::pick(i).to_rgba();
            let line: Vec<(f64, f64)> = pts
                .iter()
                .filter(|r| &r.scene == name && r.series)
                .map(|r| (r.node_seconds, r.psnr))
                .collect();
            chart
                .draw_series(LineSeries::new(line.clone(), colour.stroke_width(2)))?
                .label(name.as_str())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour));
            chart.draw_series(line.iter().map(|&p| Circle::new(p, 4, colour.filled())))?;
            let labels = pts.iter().filter(|r| &r.scene == name);
            chart.draw_series(labels.map(|r| {
                Text::new(
                    format!("M={} c={:.2}", r.vpls_asked, r.clamp),
                    (r.node_seconds, r.psnr + 0.3),
                    ("sans-serif", 11),
                )
            }))?;
        }
        chart
            .configure_series_labels()
            .border_style(BLACK)
            .background_style(WHITE)
            .draw()?;
        root.present()?;
        Ok(())
    };
    draw().map_err(|e| anyhow::anyhow!("plot: {e}"))
}

fn write_markdown(path: &Path, rows: &[Row], command: &str, adapter: &str) -> anyhow::Result<()> {
    let mut s = String::new();
    s.push_str("# One-bounce indirect light: speed against error\n\n");
    s.push_str("Generated by `quality/examples/indirect_sweep.rs`; see `docs/indirect.md` for the method.\n\n");
    s.push_str(&format!("```\n{command}\n```\n\nAdapter: {adapter}.\n\n"));
    s.push_str("| scene | VPLs asked | VPLs | clamp (m) | node-s | PSNR vs truth | energy bias | VPL-only PSNR | VPL bias | shadow-map PSNR |\n");
    s.push_str("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    for r in rows {
        let f = |v: f64, d: usize| {
            if v.is_finite() {
                format!("{v:.d$}")
            } else {
                "–".to_string()
            }
        };
        s.push_str(&format!(
            "| {} | {} | {} | {:.3} | {} | {} dB | {:+.2} % | {} | {} | {} |\n",
            r.scene,
            r.vpls_asked,
            r.vpls,
            r.clamp,
            f(r.node_seconds, 2),
            f(r.psnr, 2),
            r.energy_bias * 100.0,
            f(r.vpl_psnr, 2),
            if r.vpl_bias.is_finite() {
                format!("{:+.2} %", r.vpl_bias * 100.0)
            } else {
                "–".into()
            },
            f(r.map_psnr, 2),
        ));
    }
    s.push_str(
        "\n`PSNR vs truth`: the GPU render of the direct samples and the VPLs against the exact direct \
         sum plus the path-traced one bounce. `VPL-only`: the CPU's exact sum over the same samples \
         (ray-traced visibility) against that truth — the VPL sampling and clamp error alone. \
         `shadow-map`: the GPU against that exact sum — the shadow maps' error alone. The \
         `(truth noise)` row compares two truths of different seeds.\n\n![frontier](frontier.svg)\n",
    );
    std::fs::write(path, s)?;
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let value = |flag: &str| {
        args.iter()
            .position(|a| a == flag)
            .and_then(|i| args.get(i + 1))
            .cloned()
    };
    let out = PathBuf::from(value("--out").unwrap_or_else(|| "docs/accuracy/indirect".into()));
    let size = value("--size").unwrap_or_else(|| "160x120".into());
    let (w, h) =
        lightfold_scene::limits::parse_image_size(&size).map_err(|e| anyhow::anyhow!(e))?;
    let paths: u32 = value("--paths").map_or(Ok(256), |p| p.parse())?;
    std::fs::create_dir_all(&out)?;
    let gpu = Gpu::new(&GpuOptions::default())?;
    let adapter = format!("{} ({:?})", gpu.info.name, gpu.info.backend);
    eprintln!("adapter {adapter}");
    let mut rows = Vec::new();
    for (name, source) in [("cornell", "cornell"), ("fox", "assets/fox.toml")] {
        let mut scene = lightfold_scene::load(source)?;
        scene.camera.width = w;
        scene.camera.height = h;
        sweep(&gpu, name, scene, paths, &mut rows)?;
    }
    let command = format!(
        "LP_NUM_THREADS=2 NODEVICE_SELECT=1 cargo run --profile test -p lightfold-quality --example indirect_sweep -- --out {} --size {size} --paths {paths}",
        out.display()
    );
    write_csv(&out.join("sweep.csv"), &rows)?;
    write_svg(&out.join("frontier.svg"), &rows)?;
    write_markdown(&out.join("README.md"), &rows, &command, &adapter)?;
    eprintln!("wrote {}", out.display());
    Ok(())
}
