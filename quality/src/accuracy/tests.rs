//! Sweep plan tests: which points each knob adds and how `--knobs` narrows a plan.

use super::*;

fn base() -> Setting {
    Setting {
        samples: 16,
        pattern: SamplePattern::Grid,
        map_size: 512,
        filter: ShadowFilter::Pcf2x2,
        format: PixelFormat::F16x6,
        k: 4,
        penumbra: 0,
    }
}

#[test]
fn the_pattern_knob_puts_every_pattern_at_three_sample_counts() {
    let points = SweepPlan::full().points(base());
    let pattern_points: Vec<Setting> = points
        .iter()
        .filter(|(k, _)| *k == Knob::Pattern)
        .map(|(_, s)| *s)
        .collect();
    // Grid at 16 is the default and grid at 4 and 64 are samples points already.
    assert_eq!(pattern_points.len(), 6);
    for n in [4, 16, 64] {
        for pattern in [
            SamplePattern::Grid,
            SamplePattern::Jittered,
            SamplePattern::Halton,
        ] {
            let want = Setting {
                samples: n,
                pattern,
                ..base()
            };
            assert_eq!(
                points.iter().filter(|(_, s)| *s == want).count(),
                1,
                "{want}"
            );
        }
    }
    // Other knobs keep the default pattern.
    assert!(
        points
            .iter()
            .filter(|(k, _)| *k != Knob::Pattern)
            .all(|(_, s)| s.pattern == SamplePattern::Grid)
    );
}

#[test]
fn a_plan_can_vary_only_some_knobs() {
    let plan = SweepPlan::full().only(&[Knob::Samples, Knob::Pattern]);
    let points = plan.points(base());
    assert!(
        points
            .iter()
            .all(|(k, _)| matches!(k, Knob::Default | Knob::Samples | Knob::Pattern))
    );
    // Defaults, samples 1, 4, 64, 256 and the six pattern points.
    assert_eq!(points.len(), 1 + 4 + 6);
    assert_eq!(SweepPlan::full().only(&[]).points(base()).len(), 1);
    for knob in Knob::SWEPT {
        assert_eq!(Knob::from_name(knob.name()), Some(knob));
    }
    assert_eq!(Knob::from_name(" Pattern"), Some(Knob::Pattern));
    assert_eq!(Knob::from_name("default"), None);
}

#[test]
fn the_penumbra_knob_shares_renders_with_the_unfiltered_points() {
    let points = SweepPlan::full()
        .only(&[Knob::Samples, Knob::Penumbra])
        .points(base());
    let filtered: Vec<Setting> = points
        .iter()
        .filter(|(k, _)| *k == Knob::Penumbra)
        .map(|(_, s)| *s)
        .collect();
    // Radii 1, 2, 4 at 16 (the default), 1, 4 and 64 samples.
    assert_eq!(filtered.len(), 12);
    for group in render_groups(&points) {
        let samples = points[group[0]].1.samples;
        assert!(group.iter().all(|&i| points[i].1.samples == samples));
    }
    // Each filtered point renders with the unfiltered point of its sample count.
    let groups = render_groups(&points);
    for s in &filtered {
        let unfiltered = Setting { penumbra: 0, ..*s };
        assert!(groups.iter().any(|g| {
            g.iter().any(|&i| points[i].1 == *s) && g.iter().any(|&i| points[i].1 == unfiltered)
        }));
    }
}
