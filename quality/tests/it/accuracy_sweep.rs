//! The sweep end to end on a tiny image: three points (defaults, another sample count, another
//! link format) against a coarse truth, the CSV columns, the frontier flags and the outputs; then
//! the pattern knob alone and its table.

use lightfold_node::gpu::{Gpu, GpuOptions};
use lightfold_quality::accuracy::{
    CSV_COLUMNS, Knob, SweepPlan, TruthOptions, load_or_render_truth, report, run_sweep,
};
use lightfold_scene::SamplePattern;

#[test]
fn a_tiny_sweep_runs_and_writes_the_expected_columns() -> anyhow::Result<()> {
    let mut scene = lightfold_scene::load("balls")?;
    scene.camera.width = 64;
    scene.camera.height = 48;
    let dir = std::env::temp_dir().join(format!("lightfold-accuracy-test-{}", std::process::id()));
    let truth = load_or_render_truth(
        &scene,
        &TruthOptions {
            samples_per_light: 16,
            cache_dir: Some(dir.join("cache")),
        },
    )?;
    assert!(!truth.from_cache);
    // A second load hits the cache and gives the same floor.
    let again = load_or_render_truth(
        &scene,
        &TruthOptions {
            samples_per_light: 16,
            cache_dir: Some(dir.join("cache")),
        },
    )?;
    assert!(again.from_cache);
    assert_eq!(again.truth.penumbra, truth.truth.penumbra);
    assert_eq!(again.floor.whole.rmse, truth.floor.whole.rmse);

    let gpu = Gpu::new(&GpuOptions::default())?;
    let mut calls = 0;
    let points = run_sweep(&gpu, &scene, &truth, &SweepPlan::tiny(), 1, |_, _| {
        calls += 1
    })?;
    assert_eq!(points.len(), 3, "defaults, samples=2, f16x6");
    assert!(calls >= 2);
    assert_eq!(points[0].knob, Knob::Default);
    assert_eq!(points[0].setting.samples, 16);
    for p in &points {
        assert!(p.node_seconds > 0.0 && p.frame_seconds <= p.node_seconds);
        assert_eq!(p.nodes, p.lights.div_ceil(p.k_run as usize));
        assert!(p.metrics.whole.psnr.is_finite() && p.metrics.whole.non_finite == 0);
    }
    // Two samples per light cost fewer lights than sixteen.
    let two = points
        .iter()
        .find(|p| p.knob == Knob::Samples)
        .expect("samples point");
    assert!(two.lights < points[0].lights);
    assert!(points.iter().any(|p| p.pareto));

    let csv = report::csv(&points);
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    assert_eq!(header, CSV_COLUMNS);
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 3);
    let cost_col = CSV_COLUMNS
        .iter()
        .position(|&c| c == "node_seconds")
        .expect("node_seconds column");
    for r in &rows {
        assert_eq!(r.len(), CSV_COLUMNS.len());
        assert_eq!(r[2], "grid", "the default pattern");
        let cost: f64 = r[cost_col].parse()?;
        assert!(cost > 0.0);
    }
    // The pattern knob: the default (grid) beside jittered at the default count, tabled.
    let plan = SweepPlan {
        patterns: vec![SamplePattern::Grid, SamplePattern::Jittered],
        ..SweepPlan::tiny().only(&[Knob::Pattern])
    };
    let pts = run_sweep(&gpu, &scene, &truth, &plan, 1, |_, _| {})?;
    assert_eq!(pts.len(), 2, "defaults, jittered");
    assert_eq!(pts[1].knob, Knob::Pattern);
    assert_eq!(pts[1].setting.pattern, SamplePattern::Jittered);
    assert_eq!(pts[1].lights, pts[0].lights);
    assert_ne!(pts[1].metrics.whole.rmse, pts[0].metrics.whole.rmse);
    let table = report::pattern_table(&pts);
    assert!(table.contains("| samples | grid | jittered |"), "{table}");
    assert!(table.contains("| 16 | "), "{table}");
    assert!(!table.contains('–'), "a cell is missing: {table}");

    std::fs::create_dir_all(&dir)?;
    report::write_svg(&dir.join("frontier.svg"), "test", &truth, &points)?;
    let svg = std::fs::read_to_string(dir.join("frontier.svg"))?;
    assert!(svg.contains("<svg") && svg.contains("circle"));
    let md = report::markdown("test", "cmd", &truth, &points, 45.0);
    assert!(md.contains("Default (n=16 map=512 pcf2x2"));
    std::fs::remove_dir_all(&dir)?;
    Ok(())
}
