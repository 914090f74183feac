//! A scene's own error model (`lightfold_quality::calibrate`): curves that fall with fewer
//! samples, a cache keyed by what the model depends on, bad cache files refused, and a plan's
//! choice that renders to the figure the model expected.

use lightfold_coordinator::plan::{ClusterSpec, ErrorModel, PlanOptions, plan};
use lightfold_node::gpu::{Gpu, GpuOptions};
use lightfold_quality::accuracy::{Setting, TruthOptions, load_or_render_truth, measure_prepared};
use lightfold_quality::calibrate::{
    CalibrationOptions, cached_model, calibrate, divisor, model_key, read_model,
};
use lightfold_scene::defaults::CELL_TAPS;
use lightfold_scene::{Scene, ShadowFilter};

fn small_balls() -> Scene {
    let mut scene = lightfold_scene::load("balls").unwrap();
    scene.camera.width = 120;
    scene.camera.height = 90;
    scene
}

fn options(dir: &std::path::Path) -> CalibrationOptions {
    CalibrationOptions {
        truth_samples: 32,
        truth_cache: Some(dir.join("truth")),
        model_cache: Some(dir.join("models")),
        counts: vec![1, 4, 16],
        floors: vec![512, 1024],
    }
}

#[test]
fn a_calibration_measures_each_floor_caches_and_predicts_what_its_plan_renders()
-> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let opts = options(dir.path());
    let scene = small_balls();
    let gpu = Gpu::new(&GpuOptions::default())?;
    let c = calibrate(&gpu, &scene, &opts)?;
    assert!(!c.from_cache && c.model.calibrated && c.divisor == 1);
    assert_eq!(c.model.key, model_key(&scene, &opts));
    assert_eq!(c.model.curves.len(), 2);
    for (curve, floor) in c.model.curves.iter().zip([512, 1024]) {
        assert_eq!(curve.map_floor, floor);
        let counts: Vec<u32> = curve.unfiltered.iter().map(|p| p.0).collect();
        assert_eq!(counts, [1, 4, 16]);
        // The point samples converge on the area light: each count gains on the one before.
        for w in curve.unfiltered.windows(2) {
            assert!(w[1].1 > w[0].1 + 3.0, "{:?}", curve.unfiltered);
        }
        assert!(curve.seconds_per_sample > 0.0);
        // The cell filter gains over the point samples at every count on balls (measured
        // +8 dB at 4 samples, 400×300), at a measured cost.
        let cell_counts: Vec<u32> = curve.cell.iter().map(|p| p.0).collect();
        assert!(!cell_counts.is_empty(), "{:?}", curve.cell);
        for &(n, db) in &curve.cell {
            assert!(db > curve.db(n), "{n}: cell {db} vs {}", curve.db(n));
        }
        assert!(curve.cell_seconds_per_sample > 0.0);
    }
    // Read back: the same model, from the cache.
    let again = calibrate(&gpu, &scene, &opts)?;
    assert!(again.from_cache);
    assert_eq!(again.model, c.model);
    assert_eq!(cached_model(&scene, &opts).as_ref(), Some(&c.model));

    // A plan aiming just under the 4-sample figure takes 4 samples (or fewer with the filter),
    // and rendering its choice gives the figure the model expected: the plan's samples, floor
    // and filter are the calibration's.
    let target = c.model.base().db(4) as f32 - 0.01;
    let p = plan(
        &scene,
        &ClusterSpec::local(64, 64),
        &PlanOptions {
            target_penumbra_db: Some(target),
            learned: lightfold_coordinator::plan::Learned {
                error_model: Some(c.model.clone()),
                ..Default::default()
            },
            ..PlanOptions::default()
        },
    )?;
    let t = p.target.clone().unwrap();
    assert!(t.calibrated && t.reachable && t.to <= 4, "{t:?}");
    let mut chosen = scene.clone();
    chosen.quality.samples_per_area_light = Some(t.to);
    if t.cell_filter {
        chosen.quality.filter = ShadowFilter::Cell { taps: CELL_TAPS };
    }
    let truth = load_or_render_truth(
        &scene,
        &TruthOptions {
            samples_per_light: 32,
            cache_dir: opts.truth_cache.clone(),
        },
    )?;
    assert!(
        truth.from_cache,
        "the calibration's truth is the accuracy sweep's"
    );
    let setting = Setting {
        samples: t.to,
        map_size: 2048,
        k: p.k,
        penumbra: p.penumbra_radius,
        ..Setting::defaults(&scene)
    };
    let m = measure_prepared(&gpu, &chosen, &[setting], 1)?;
    let got = truth.truth.compare(&m[0].image)?.penumbra.unwrap().psnr;
    assert!(
        (got - f64::from(t.expected_db)).abs() < 0.05,
        "measured {got} dB, the model expected {}",
        t.expected_db
    );
    assert!(got >= f64::from(target));

    // Where the cell filter is the cheaper way to a target the plan configures the nodes with
    // it, and its render gives the calibration's figure. (Made cheaper here: which one a
    // device finds cheaper is that device's measurement.)
    let mut model = c.model.clone();
    model.curves.truncate(1);
    for curve in &mut model.curves {
        curve.cell_seconds_per_sample = curve.seconds_per_sample / 8.0;
    }
    let &(n, db) = model.base().cell.first().expect("a cell figure");
    let p = plan(
        &scene,
        &ClusterSpec::local(64, 64),
        &PlanOptions {
            target_penumbra_db: Some(db - 0.01),
            learned: lightfold_coordinator::plan::Learned {
                error_model: Some(model),
                ..Default::default()
            },
            ..PlanOptions::default()
        },
    )?;
    let t = p.target.clone().unwrap();
    assert!(
        t.cell_filter && t.to == n && p.penumbra_radius == 0,
        "{t:?}"
    );
    assert!(p.target_line().unwrap().contains("cell filter"));
    let mut chosen = scene.clone();
    chosen.quality.samples_per_area_light = Some(n);
    chosen.quality.filter = ShadowFilter::Cell { taps: CELL_TAPS };
    let m = measure_prepared(
        &gpu,
        &chosen,
        &[Setting {
            samples: n,
            map_size: 2048,
            k: p.k,
            filter: chosen.quality.filter,
            ..Setting::defaults(&scene)
        }],
        1,
    )?;
    let got = truth.truth.compare(&m[0].image)?.penumbra.unwrap().psnr;
    assert!(
        (got - f64::from(db)).abs() < 0.05,
        "measured {got} dB with the cell filter, the model expected {db}"
    );
    Ok(())
}

#[test]
fn a_scene_without_area_lights_is_refused_before_any_render() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let opts = options(dir.path());
    let mut scene = small_balls();
    scene.lights.retain(|l| !l.is_area());
    let gpu = Gpu::new(&GpuOptions::default())?;
    let e = calibrate(&gpu, &scene, &opts).expect_err("no area light");
    assert!(e.to_string().contains("no area light"), "{e}");
    assert!(!dir.path().join("truth").exists(), "nothing rendered");
    Ok(())
}

#[test]
fn the_cache_key_follows_what_the_model_depends_on() {
    let dir = std::path::Path::new("/nonexistent");
    let opts = options(dir);
    let scene = small_balls();
    let key = model_key(&scene, &opts);
    // Sample counts, K and map sizes are what the model chooses, not what it depends on.
    let mut same = scene.clone();
    same.quality.samples_per_area_light = Some(64);
    same.quality.lights_per_node = 8;
    for l in same.lights.iter_mut().filter(|l| l.is_area()) {
        l.samples = 9;
    }
    assert_eq!(model_key(&same, &opts), key);
    // The light, the image size and the calibration's counts are.
    let mut moved = scene.clone();
    moved.lights[0].power *= 2.0;
    let mut bigger = scene.clone();
    bigger.camera.width = 160;
    let mut fewer = opts.clone();
    fewer.counts = vec![1, 4];
    for other in [
        model_key(&moved, &opts),
        model_key(&bigger, &opts),
        model_key(&scene, &fewer),
    ] {
        assert_ne!(other, key);
    }
    assert_eq!(divisor(400, 300), 1);
    assert_eq!(divisor(800, 600), 2);
    assert_eq!(divisor(1920, 1080), 5);
}

#[test]
fn a_broken_huge_or_meaningless_model_file_is_refused() -> anyhow::Result<()> {
    let dir = tempfile::tempdir()?;
    let write = |name: &str, bytes: &[u8]| {
        let p = dir.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    };
    let good = serde_json::to_string(&ErrorModel::balls())?;
    assert!(read_model(&write("good.json", good.as_bytes())).is_ok());
    let cases = [
        write("truncated.json", &good.as_bytes()[..good.len() / 2]),
        write("huge.json", &vec![b' '; 2 << 20]),
        write("empty-curves.json", br#"{"source":"x","calibrated":true,"curves":[]}"#),
        write(
            "falling.json",
            br#"{"source":"x","calibrated":true,"curves":[{"map_floor":0,"unfiltered":[[16,30.0],[4,31.0]]}]}"#,
        ),
    ];
    for path in cases {
        let e = read_model(&path).expect_err(&path.display().to_string());
        assert!(!e.is_empty());
    }
    assert!(read_model(&dir.path().join("missing.json")).is_err());
    Ok(())
}
