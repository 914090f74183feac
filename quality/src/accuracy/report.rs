//! The sweep's outputs: CSV (one row per point), a Markdown table with the headline figures, and
//! an SVG plot of penumbra PSNR against node-seconds with the Pareto frontier drawn through.

use super::{AccuracyError, CachedTruth, Knob, Point, filter_name, pattern_name};
use plotters::prelude::*;
use std::fmt::Write as _;
use std::path::Path;

/// The CSV header, in order.
pub const CSV_COLUMNS: [&str; 21] = [
    "knob",
    "samples",
    "pattern",
    "map_size",
    "filter",
    "format",
    "k",
    "k_run",
    "penumbra_filter",
    "lights",
    "nodes",
    "node_seconds",
    "frame_seconds",
    "rmse",
    "psnr_db",
    "flip",
    "penumbra_rmse",
    "penumbra_psnr_db",
    "penumbra_flip",
    "at_floor",
    "pareto",
];

fn out_err(path: &Path, e: impl ToString) -> AccuracyError {
    AccuracyError::Output {
        path: path.display().to_string(),
        message: e.to_string(),
    }
}

/// The CSV text of `points`.
pub fn csv(points: &[Point]) -> String {
    let mut w = csv::Writer::from_writer(Vec::new());
    let _ = w.write_record(CSV_COLUMNS);
    for p in points {
        let st = &p.setting;
        let _ = w.write_record([
            p.knob.name().to_string(),
            st.samples.to_string(),
            pattern_name(st.pattern).to_string(),
            st.map_size.to_string(),
            filter_name(st.filter).to_string(),
            st.format.name().to_string(),
            st.k.to_string(),
            p.k_run.to_string(),
            st.penumbra.to_string(),
            p.lights.to_string(),
            p.nodes.to_string(),
            format!("{:.6}", p.node_seconds),
            format!("{:.6}", p.frame_seconds),
            format!("{:.6e}", p.metrics.whole.rmse),
            format!("{:.3}", p.metrics.whole.psnr),
            format!("{:.5}", p.metrics.flip),
            format!("{:.6e}", p.penumbra_rmse()),
            format!("{:.3}", p.penumbra_psnr()),
            format!("{:.5}", p.penumbra_flip()),
            p.at_floor.to_string(),
            p.pareto.to_string(),
        ]);
    }
    let bytes = w.into_inner().unwrap_or_default();
    String::from_utf8(bytes).unwrap_or_default()
}

pub fn write_csv(path: &Path, points: &[Point]) -> Result<(), AccuracyError> {
    std::fs::write(path, csv(points)).map_err(|e| out_err(path, e))
}

/// The headline: the default point and the cheapest point reaching `target_db` penumbra PSNR.
#[derive(Debug, Clone, Copy)]
pub struct Headline<'a> {
    pub default: Option<&'a Point>,
    pub cheapest_at_target: Option<&'a Point>,
    /// The best penumbra PSNR of the sweep.
    pub best: Option<&'a Point>,
}

pub fn headline(points: &[Point], target_db: f64) -> Headline<'_> {
    let by_cost = |a: &&Point, b: &&Point| a.node_seconds.total_cmp(&b.node_seconds);
    Headline {
        default: points.iter().find(|p| p.knob == Knob::Default),
        cheapest_at_target: points
            .iter()
            .filter(|p| p.penumbra_psnr() >= target_db)
            .min_by(by_cost),
        best: points
            .iter()
            .max_by(|a, b| a.penumbra_psnr().total_cmp(&b.penumbra_psnr())),
    }
}

/// The Markdown report: truth and floor, the headline, and a table of every point.
pub fn markdown(
    title: &str,
    command: &str,
    truth: &CachedTruth,
    points: &[Point],
    target_db: f64,
) -> String {
    let mut s = String::new();
    let t = &truth.truth;
    let floor_pen = truth.floor.penumbra.map_or(f64::NAN, |p| p.psnr);
    let _ = writeln!(s, "# Speed against error: {title}\n");
    let _ = writeln!(s, "Reproduce: `{command}`\n");
    let _ = writeln!(
        s,
        "Truth: {}×{}, {} points per area light per pixel (cache key `{}`), {} penumbra pixels, {} \
         pixels left out as ties (a pixel centre on a boundary between two surfaces). Noise floor (truth against a second seed): whole PSNR {:.2} dB, penumbra PSNR {:.2} dB, \
         FLIP {:.4}. \"at floor\" = RMSE within 10× the floor's (whole and penumbra): such points \
         are as good as this truth can tell.\n",
        t.radiance.width,
        t.radiance.height,
        t.options.samples_per_light,
        truth.key,
        t.penumbra_pixels(),
        t.tie_pixels(),
        truth.floor.whole.psnr,
        floor_pen,
        truth.floor.flip
    );
    let h = headline(points, target_db);
    if let Some(d) = h.default {
        let _ = writeln!(
            s,
            "Default ({}): penumbra PSNR {:.2} dB, penumbra FLIP {:.4}, whole PSNR {:.2} dB, \
             FLIP {:.4}; {:.3} node-s per frame over {} nodes, slowest node {:.3} s.\n",
            d.setting,
            d.penumbra_psnr(),
            d.penumbra_flip(),
            d.metrics.whole.psnr,
            d.metrics.flip,
            d.node_seconds,
            d.nodes,
            d.frame_seconds
        );
        match (h.cheapest_at_target, h.best) {
            (Some(c), _) => {
                let _ = writeln!(
                    s,
                    "Cheapest setting with penumbra PSNR ≥ {target_db} dB: {} ({:.2} dB, FLIP \
                     {:.4}) at {:.3} node-s, {:.2}× the default's cost.\n",
                    c.setting,
                    c.penumbra_psnr(),
                    c.penumbra_flip(),
                    c.node_seconds,
                    c.node_seconds / d.node_seconds
                );
            }
            (None, Some(b)) => {
                let _ = writeln!(
                    s,
                    "No setting in this sweep reaches penumbra PSNR ≥ {target_db} dB; the best is \
                     {} with {:.2} dB at {:.3} node-s ({:.2}× the default's cost).\n",
                    b.setting,
                    b.penumbra_psnr(),
                    b.node_seconds,
                    b.node_seconds / d.node_seconds
                );
            }
            (None, None) => {}
        }
    }
    s.push_str(&pattern_table(points));
    s.push_str(
        "| knob | samples | pattern | map | filter | format | K (run) | lights | nodes | node-s \
         | frame s | PSNR dB | FLIP | pen. RMSE | pen. PSNR dB | pen. FLIP | at floor | Pareto |\n",
    );
    s.push_str(
        "|---|---:|---|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---|\n",
    );
    for p in points {
        let st = &p.setting;
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {} | {} | {} ({}) | {} | {} | {:.3} | {:.3} | {:.2} | {:.4} | \
             {:.3e} | {:.2} | {:.4} | {} | {} |",
            p.knob.name(),
            st.samples,
            pattern_name(st.pattern),
            st.map_size,
            shadow_filters(st),
            st.format.name(),
            st.k,
            p.k_run,
            p.lights,
            p.nodes,
            p.node_seconds,
            p.frame_seconds,
            p.metrics.whole.psnr,
            p.metrics.flip,
            p.penumbra_rmse(),
            p.penumbra_psnr(),
            p.penumbra_flip(),
            if p.at_floor { "at floor" } else { "" },
            if p.pareto { "★" } else { "" }
        );
    }
    s
}

/// The patterns side by side: one row per sample count at which the sweep has more than one
/// pattern (all other knobs at their defaults), penumbra PSNR / penumbra FLIP / node-seconds per
/// pattern. Empty when the sweep compared no patterns.
pub fn pattern_table(points: &[Point]) -> String {
    let Some(base) = points.iter().find(|p| p.knob == Knob::Default) else {
        return String::new();
    };
    let b = base.setting;
    let around: Vec<&Point> = points
        .iter()
        .filter(|p| {
            let s = p.setting;
            (s.map_size, s.filter, s.format, s.k) == (b.map_size, b.filter, b.format, b.k)
        })
        .collect();
    // The default pattern's points belong to other knobs (default, samples): the column is
    // filled from whichever knob measured them.
    let mut patterns = vec![b.pattern];
    let mut counts = Vec::new();
    for p in around.iter().filter(|p| p.knob == Knob::Pattern) {
        if !patterns.contains(&p.setting.pattern) {
            patterns.push(p.setting.pattern);
        }
        if !counts.contains(&p.setting.samples) {
            counts.push(p.setting.samples);
        }
    }
    if patterns.len() < 2 {
        return String::new();
    }
    counts.sort_unstable();
    let mut s = String::from(
        "Sample patterns (other knobs at their defaults): penumbra PSNR dB / penumbra FLIP / \
         node-s.\n\n| samples |",
    );
    for &pat in &patterns {
        let _ = write!(s, " {} |", pattern_name(pat));
    }
    s.push_str("\n|---:|");
    s.push_str(&"---|".repeat(patterns.len()));
    s.push('\n');
    for &n in &counts {
        let _ = write!(s, "| {n} |");
        for &pat in &patterns {
            match around
                .iter()
                .find(|p| p.setting.samples == n && p.setting.pattern == pat)
            {
                Some(p) => {
                    let _ = write!(
                        s,
                        " {:.2} / {:.4} / {:.3} |",
                        p.penumbra_psnr(),
                        p.penumbra_flip(),
                        p.node_seconds
                    );
                }
                None => s.push_str(" – |"),
            }
        }
        s.push('\n');
    }
    s.push('\n');
    s
}

pub fn write_markdown(
    path: &Path,
    title: &str,
    command: &str,
    truth: &CachedTruth,
    points: &[Point],
    target_db: f64,
) -> Result<(), AccuracyError> {
    std::fs::write(path, markdown(title, command, truth, points, target_db))
        .map_err(|e| out_err(path, e))
}

/// The shadow-map filter, and the screen-space penumbra filter where there is one.
fn shadow_filters(st: &super::Setting) -> String {
    if st.penumbra > 0 {
        format!("{} + penumbra r{}", filter_name(st.filter), st.penumbra)
    } else {
        filter_name(st.filter)
    }
}

fn knob_color(k: Knob) -> RGBColor {
    match k {
        Knob::Default => BLACK,
        Knob::Samples => RGBColor(0x1f, 0x77, 0xb4),
        Knob::Pattern => RGBColor(0xe3, 0x77, 0xc2),
        Knob::MapSize => RGBColor(0xff, 0x7f, 0x0e),
        Knob::Filter => RGBColor(0x2c, 0xa0, 0x2c),
        Knob::Format => RGBColor(0xd6, 0x27, 0x28),
        Knob::K => RGBColor(0x94, 0x67, 0xbd),
        Knob::Grid => RGBColor(0x8c, 0x56, 0x4b),
        Knob::Penumbra => RGBColor(0x17, 0xbe, 0xcf),
    }
}

/// An axis tick without float noise: at most three significant digits.
fn tick(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let digits = (2 - v.abs().log10().floor() as i32).max(0) as usize;
    let s = format!("{v:.digits$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// What a point varies, as a chart label.
fn point_label(p: &Point) -> String {
    let st = &p.setting;
    match p.knob {
        Knob::Default => "default".to_string(),
        Knob::Samples => format!("{} samples", st.samples),
        Knob::Pattern => format!("{} ×{}", pattern_name(st.pattern), st.samples),
        Knob::MapSize => format!("map {}", st.map_size),
        Knob::Filter => filter_name(st.filter).to_string(),
        Knob::Format => st.format.name().to_string(),
        Knob::K => format!("K {}", st.k),
        Knob::Grid => format!(
            "{} × {} {}",
            st.samples,
            st.map_size,
            filter_name(st.filter)
        ),
        Knob::Penumbra => format!("{} + filter r{}", st.samples, st.penumbra),
    }
}

/// Penumbra PSNR against node-seconds (log scale), one colour per knob, the Pareto frontier as a
/// line, the floor's PSNR as a dashed-looking grey line.
pub fn write_svg(
    path: &Path,
    title: &str,
    truth: &CachedTruth,
    points: &[Point],
) -> Result<(), AccuracyError> {
    let finite: Vec<&Point> = points
        .iter()
        .filter(|p| p.node_seconds > 0.0 && p.penumbra_psnr().is_finite())
        .collect();
    let (mut x0, mut x1) = (f64::INFINITY, 0.0f64);
    let (mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY);
    for p in &finite {
        x0 = x0.min(p.node_seconds);
        x1 = x1.max(p.node_seconds);
        y0 = y0.min(p.penumbra_psnr());
        y1 = y1.max(p.penumbra_psnr());
    }
    let floor_db = truth.floor.penumbra.map_or(f64::NAN, |p| p.psnr);
    if floor_db.is_finite() {
        y1 = y1.max(floor_db);
    }
    if finite.is_empty() {
        (x0, x1, y0, y1) = (0.01, 1.0, 0.0, 50.0);
    }
    let draw = || -> Result<(), Box<dyn std::error::Error>> {
        let root = SVGBackend::new(path, (900, 600)).into_drawing_area();
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(
                (x0 / 1.3..x1 * 1.3).log_scale(),
                (y0 - 2.0).floor()..(y1 + 2.0).ceil(),
            )?;
        chart
            .configure_mesh()
            .x_desc("node-seconds per frame (log)")
            .y_desc("penumbra PSNR vs truth (dB)")
            .x_label_formatter(&|v| tick(*v))
            .y_label_formatter(&|v| format!("{v:.0}"))
            .draw()?;
        if floor_db.is_finite() {
            chart
                .draw_series(LineSeries::new(
                    [(x0 / 1.3, floor_db), (x1 * 1.3, floor_db)],
                    RGBColor(0xaa, 0xaa, 0xaa).stroke_width(1),
                ))?
                .label("truth noise floor")
                .legend(|(x, y)| {
                    PathElement::new([(x, y), (x + 16, y)], RGBColor(0xaa, 0xaa, 0xaa))
                });
        }
        let mut front: Vec<&Point> = finite.iter().copied().filter(|p| p.pareto).collect();
        front.sort_by(|a, b| a.node_seconds.total_cmp(&b.node_seconds));
        chart
            .draw_series(LineSeries::new(
                front.iter().map(|p| (p.node_seconds, p.penumbra_psnr())),
                BLACK.stroke_width(2),
            ))?
            .label("Pareto frontier")
            .legend(|(x, y)| PathElement::new([(x, y), (x + 16, y)], BLACK.stroke_width(2)));
        for knob in std::iter::once(Knob::Default).chain(Knob::SWEPT) {
            let c = knob_color(knob);
            let pts: Vec<(f64, f64)> = finite
                .iter()
                .filter(|p| p.knob == knob)
                .map(|p| (p.node_seconds, p.penumbra_psnr()))
                .collect();
            if pts.is_empty() {
                continue;
            }
            let size = if knob == Knob::Default { 7 } else { 4 };
            chart
                .draw_series(pts.into_iter().map(|xy| Circle::new(xy, size, c.filled())))?
                .label(knob.name())
                .legend(move |(x, y)| Circle::new((x + 8, y), 4, c.filled()));
        }
        // Frontier points ringed and labelled with their setting, so they read without the
        // legend.
        chart.draw_series(front.iter().map(|p| {
            Circle::new(
                (p.node_seconds, p.penumbra_psnr()),
                8,
                BLACK.stroke_width(1),
            )
        }))?;
        chart.draw_series(front.iter().map(|p| {
            Text::new(
                point_label(p),
                (p.node_seconds * 1.04, p.penumbra_psnr() + 0.6),
                ("sans-serif", 12),
            )
        }))?;
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
        root.present()?;
        Ok(())
    };
    draw().map_err(|e| out_err(path, e))
}
