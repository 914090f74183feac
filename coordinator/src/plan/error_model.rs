//! The planner's error model: penumbra PSNR against the area-light truth by point samples per
//! area light, the screen-space penumbra filter's radius and the smallest shadow map
//! (`docs/planner.md` § Error model).
//!
//! Two sources. [`ErrorModel::balls`] is the sweep of the default scene at 400×300
//! (`docs/accuracy/balls`, `balls-penumbra`), what every plan used before a scene had its own.
//! [`ErrorModel`]s of a scene of its own come from a short calibration
//! (`lightfold_quality::calibrate`, `lightfold calibrate`): a few renders of that scene at a
//! reduced size against its area-light truth, one curve per shadow-map floor, cached by the
//! scene's content and size. With such a model an error target chooses the samples per area
//! light, the map floor and the filter together, at the least node-seconds the calibration
//! measured ([`ErrorModel::cheapest`]).

use serde::{Deserialize, Serialize};

/// Penumbra PSNR against samples per area light at one shadow-map floor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Curve {
    /// The smallest shadow map (side) the curve was measured with: the mismatch rule's floor
    /// raised to it. 0: the scene's own rule, whatever it is.
    pub map_floor: u32,
    /// `(samples per area light, penumbra PSNR dB)`, rising in samples, at least two points.
    pub unfiltered: Vec<(u32, f32)>,
    /// `(samples, filter radius, penumbra PSNR dB)` at the counts where a radius of the
    /// penumbra filter gained over none: the radius that gained most. Radii are for the plan's
    /// image size.
    #[serde(default)]
    pub filtered: Vec<(u32, u32, f32)>,
    /// Node-seconds a frame per sample per area light, as measured by the calibration (0:
    /// not measured; costs then go by samples × map side).
    #[serde(default)]
    pub seconds_per_sample: f64,
    /// `(samples, penumbra PSNR dB)` with the cell filter (each sample's shadow spread over
    /// its cell's, `ShadowFilter::Cell`) instead of the scene's own, at the counts where the
    /// calibration measured it gaining in the penumbra and losing nothing over the whole image;
    /// empty: never measured, or never a gain.
    #[serde(default)]
    pub cell: Vec<(u32, f32)>,
    /// Node-seconds a frame per sample with the cell filter (0: not measured).
    #[serde(default)]
    pub cell_seconds_per_sample: f64,
}

/// The planner's error model (module documentation).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ErrorModel {
    /// Where the figures come from, as the plan prints it.
    pub source: String,
    /// Measured on the planned scene itself (not the default scene's sweep).
    pub calibrated: bool,
    /// One curve per map floor, rising floors; at least one.
    pub curves: Vec<Curve>,
    /// The truth's own noise in the penumbra (its PSNR against a second seed, dB; 0: unknown):
    /// figures near it are as good as the truth can tell.
    #[serde(default)]
    pub truth_floor_db: f32,
    /// The calibration's cache key (scene content and image size; empty for the default
    /// scene's model), so a model given as a file can be checked against the planned scene.
    #[serde(default)]
    pub key: String,
}

/// One choice of an error target (`ErrorModel::cheapest`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Choice {
    pub samples: u32,
    /// The shadow-map floor (0: the scene's rule).
    pub map_floor: u32,
    /// The penumbra filter's radius (0: none).
    pub radius: u32,
    /// The cell filter instead of the scene's own shadow filter (never with a radius).
    pub cell: bool,
    /// The model's penumbra PSNR there.
    pub db: f32,
    /// Its relative cost (node-seconds where measured).
    pub cost: f64,
}

/// The balls sweep without the filter (grid pattern, 512² maps, PCF 2×2, 400×300):
/// 1 → 27.39, 4 → 37.34, 16 → 47.53, 64 → 55.51, 256 → 58.09 dB.
const BALLS: [(u32, f32); 5] = [
    (1, 27.39),
    (4, 37.34),
    (16, 47.53),
    (64, 55.51),
    (256, 58.09),
];

/// The same sweep with the filter at its best radius (`docs/accuracy/balls-penumbra`). From 32
/// samples on the filter measured no better than none (+0.5 dB at 32 for −2.7 dB over the whole
/// image, −2.5 dB at 64), so the model adds it up to 16 only.
const BALLS_FILTERED: [(u32, u32, f32); 5] = [
    (1, 4, 32.54),
    (2, 3, 35.57),
    (4, 2, 42.40),
    (8, 1, 44.21),
    (16, 1, 50.94),
];

impl Default for ErrorModel {
    fn default() -> Self {
        ErrorModel::balls()
    }
}

impl ErrorModel {
    /// The default scene's sweep at 400×300, for scenes without a calibration of their own.
    /// Only its differences carry to other scenes (their levels differ; `docs/planner.md`).
    pub fn balls() -> ErrorModel {
        ErrorModel {
            source: "the default scene's sweep (balls, 400×300); no calibration of this scene"
                .into(),
            calibrated: false,
            truth_floor_db: 56.73,
            key: String::new(),
            curves: vec![Curve {
                map_floor: 0,
                unfiltered: BALLS.to_vec(),
                filtered: BALLS_FILTERED.to_vec(),
                seconds_per_sample: 0.0,
                cell: Vec::new(),
                cell_seconds_per_sample: 0.0,
            }],
        }
    }

    /// Whether the model can be used: at least one curve, each with two or more rising counts and
    /// finite figures.
    pub fn check(&self) -> Result<(), String> {
        if self.curves.is_empty() {
            return Err("the error model has no curve".into());
        }
        for c in &self.curves {
            if c.unfiltered.len() < 2 {
                return Err("an error-model curve needs two sample counts or more".into());
            }
            let rising = c.unfiltered.windows(2).all(|w| w[0].0 < w[1].0)
                && c.filtered.windows(2).all(|w| w[0].0 < w[1].0)
                && c.cell.windows(2).all(|w| w[0].0 < w[1].0);
            let finite = c.unfiltered.iter().all(|p| p.1.is_finite() && p.0 > 0)
                && c.filtered.iter().all(|p| p.2.is_finite() && p.0 > 0)
                && c.cell.iter().all(|p| p.1.is_finite() && p.0 > 0)
                && [c.seconds_per_sample, c.cell_seconds_per_sample]
                    .iter()
                    .all(|s| s.is_finite() && *s >= 0.0);
            if !rising || !finite {
                return Err(
                    "an error-model curve's counts must rise and its figures be finite".into(),
                );
            }
        }
        Ok(())
    }

    /// The curve measured at `floor`, else the lowest floor's (the scene's own rule).
    pub fn curve(&self, floor: u32) -> &Curve {
        self.curves
            .iter()
            .find(|c| c.map_floor == floor)
            .unwrap_or(&self.curves[0])
    }

    /// The curve of the scene's own map rule (the lowest floor).
    pub fn base(&self) -> &Curve {
        &self.curves[0]
    }

    /// The cheapest `(samples, floor, radius or cell filter)` whose expected penumbra PSNR
    /// reaches `target_db`, among the counts a calibration measured (for the default scene's
    /// model: `from·2^k` or `from/2^k` up to the most it measured), every floor, the
    /// penumbra filter where `filter` allows it (`filter(curve, n)` gives the radius to use at
    /// `n` on that curve) and the cell filter at the counts where the curve measured it. When
    /// none reaches the target: the highest expected PSNR (cheapest among equals). Costs: the
    /// measured node-seconds per sample, else samples × (1 + map side / 512).
    pub fn cheapest(
        &self,
        target_db: f32,
        from: u32,
        filter: impl Fn(&Curve, u32) -> u32,
    ) -> Choice {
        self.cheapest_raised(target_db, from, filter, |_| 1.0)
    }

    /// [`ErrorModel::cheapest`] where a count `n` will be raised after the choice (glossy
    /// highlights, `plan::gloss`), so it costs `raised(n)` times what `n` samples cost: a few
    /// filtered samples that the highlights raise anyway save nothing.
    pub fn cheapest_raised(
        &self,
        target_db: f32,
        from: u32,
        filter: impl Fn(&Curve, u32) -> u32,
        raised: impl Fn(u32) -> f64,
    ) -> Choice {
        let mut all = Vec::new();
        for c in &self.curves {
            // A calibration's own counts (every area light takes the count chosen), so each
            // figure is one it measured; the default scene's model scales the scene's counts.
            let counts: Vec<u32> = if self.calibrated {
                c.unfiltered.iter().map(|p| p.0).collect()
            } else {
                let top = c.measured_up_to().max(from);
                let mut counts = vec![from.max(1)];
                let mut n = from.max(1);
                while n > 1 {
                    n /= 2;
                    counts.push(n);
                }
                let mut n = from.max(1);
                while n * 2 <= top {
                    n *= 2;
                    counts.push(n);
                }
                counts
            };
            for n in counts {
                let radius = filter(c, n);
                let factor = raised(n).max(1.0);
                let side = if c.map_floor == 0 { 512 } else { c.map_floor };
                let cost = factor
                    * if c.seconds_per_sample > 0.0 {
                        f64::from(n) * c.seconds_per_sample
                    } else {
                        f64::from(n) * (1.0 + f64::from(side) / 512.0)
                    };
                all.push(Choice {
                    samples: n,
                    map_floor: c.map_floor,
                    radius,
                    cell: false,
                    db: c.expected_db(n, radius),
                    cost,
                });
                if let Some(db) = c.cell_db(n)
                    && c.cell_seconds_per_sample > 0.0
                {
                    all.push(Choice {
                        samples: n,
                        map_floor: c.map_floor,
                        radius: 0,
                        cell: true,
                        db,
                        cost: factor * f64::from(n) * c.cell_seconds_per_sample,
                    });
                }
            }
        }
        let reaching = all.iter().filter(|c| c.db >= target_db);
        let best = reaching.min_by(|a, b| a.cost.total_cmp(&b.cost).then(b.db.total_cmp(&a.db)));
        match best {
            Some(c) => *c,
            None => *all
                .iter()
                .max_by(|a, b| a.db.total_cmp(&b.db).then(b.cost.total_cmp(&a.cost)))
                .expect("a model has a curve with points"),
        }
    }
}

impl Curve {
    /// The largest count the curve measured.
    pub fn measured_up_to(&self) -> u32 {
        self.unfiltered.last().map_or(1, |p| p.0)
    }

    /// Penumbra PSNR at `n` samples per area light without the filter: piecewise linear in
    /// log₂ n through the measured points, the end slopes beyond them.
    pub fn db(&self, n: u32) -> f32 {
        let pts: Vec<(f32, f32)> = self
            .unfiltered
            .iter()
            .map(|&(n, d)| (n as f32, d))
            .collect();
        through_log2(&pts, n)
    }

    /// The filter's radius the model expects to gain most at `n` (that of the nearest filtered
    /// count in log₂), 0 above the counts where it measured a gain.
    pub fn filter_radius(&self, n: u32) -> u32 {
        let Some(last) = self.filtered.last() else {
            return 0;
        };
        if n.max(1) > last.0 {
            return 0;
        }
        let x = (n.max(1) as f32).log2();
        self.filtered
            .iter()
            .min_by(|a, b| {
                ((a.0 as f32).log2() - x)
                    .abs()
                    .total_cmp(&((b.0 as f32).log2() - x).abs())
            })
            .map_or(0, |f| f.1)
    }

    /// Penumbra PSNR at `n` with the filter at [`Curve::filter_radius`]`(n)` (piecewise linear
    /// through the filtered points; one point: its gain over the unfiltered curve).
    pub fn filtered_db(&self, n: u32) -> f32 {
        if self.filter_radius(n) == 0 {
            return self.db(n);
        }
        if let [(m, _, d)] = self.filtered[..] {
            return self.db(n) + (d - self.db(m));
        }
        let pts: Vec<(f32, f32)> = self
            .filtered
            .iter()
            .map(|&(n, _, d)| (n as f32, d))
            .collect();
        through_log2(&pts, n)
    }

    /// Penumbra PSNR at `n` with the cell filter: the figure measured at that count, `None`
    /// where the curve has none (the cell filter is claimed only where it was measured).
    pub fn cell_db(&self, n: u32) -> Option<f32> {
        self.cell.iter().find(|p| p.0 == n).map(|p| p.1)
    }

    /// The figure at `n` samples with the filter at `radius`: the filtered figure where the
    /// radius is the model's own, else the unfiltered one (a radius it did not measure is not
    /// claimed).
    pub fn expected_db(&self, n: u32, radius: u32) -> f32 {
        if radius > 0 && radius == self.filter_radius(n) {
            self.filtered_db(n)
        } else {
            self.db(n)
        }
    }
}

/// Piecewise linear in log₂ of the count through `(count, dB)` points (at least two, in rising
/// order), the last slope beyond them and the first before.
fn through_log2(points: &[(f32, f32)], n: u32) -> f32 {
    let x = (n.max(1) as f32).log2();
    let pts: Vec<(f32, f32)> = points.iter().map(|&(n, db)| (n.log2(), db)).collect();
    if pts.len() < 2 {
        return pts.first().map_or(0.0, |p| p.1);
    }
    let seg = pts
        .windows(2)
        .find(|w| x <= w[1].0)
        .unwrap_or(&pts[pts.len() - 2..]);
    let (x0, y0) = seg[0];
    let (x1, y1) = seg[1];
    y0 + (x - x0) * (y1 - y0) / (x1 - x0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model() -> ErrorModel {
        ErrorModel {
            source: "test".into(),
            calibrated: true,
            truth_floor_db: 0.0,
            key: String::new(),
            curves: vec![
                Curve {
                    map_floor: 512,
                    unfiltered: vec![(4, 30.0), (16, 36.0), (64, 38.0)],
                    filtered: vec![(4, 2, 33.0), (16, 1, 37.0)],
                    seconds_per_sample: 0.01,
                    cell: vec![],
                    cell_seconds_per_sample: 0.0,
                },
                Curve {
                    map_floor: 2048,
                    unfiltered: vec![(4, 31.0), (16, 40.0), (64, 47.0)],
                    filtered: vec![],
                    seconds_per_sample: 0.03,
                    cell: vec![],
                    cell_seconds_per_sample: 0.0,
                },
            ],
        }
    }

    #[test]
    fn the_cheapest_choice_reaching_the_target_wins_across_floors_and_filters() {
        let m = model();
        assert!(m.check().is_ok());
        let any = |c: &Curve, n| c.filter_radius(n);
        // 36 dB: 16 samples at the small floor (0.16 s) beat 16 at 2048² (0.48 s); 4 filtered
        // reach 33 only.
        let c = m.cheapest(36.0, 16, any);
        assert_eq!((c.samples, c.map_floor), (16, 512), "{c:?}");
        // 45 dB only the large floor reaches, at 64 samples (model 47 dB at 64, 43.5 at 32).
        let c = m.cheapest(45.0, 16, any);
        assert_eq!((c.samples, c.map_floor, c.radius), (64, 2048, 0), "{c:?}");
        // Out of reach: the best there is, said by its figure.
        let c = m.cheapest(60.0, 16, any);
        assert_eq!((c.samples, c.map_floor), (64, 2048));
        assert!(c.db < 60.0);
        // The filter gives 33 dB at 4 samples where none gives 30: a 32 dB target takes 4
        // samples filtered, or 16 unfiltered when the filter is not allowed (a calibration's
        // choices are the counts it measured: no 8 between them).
        let c = m.cheapest(32.0, 16, any);
        assert_eq!((c.samples, c.radius), (4, 2), "{c:?}");
        let c = m.cheapest(32.0, 16, |_: &Curve, _| 0);
        assert_eq!((c.samples, c.radius, c.map_floor), (16, 0, 512), "{c:?}");
    }

    #[test]
    fn the_default_model_goes_through_the_sweep_and_rises_with_samples() {
        let balls = ErrorModel::balls();
        let c = balls.base();
        for (n, db) in BALLS {
            assert!((c.db(n) - db).abs() < 1e-4, "{n}");
        }
        let mut last = f32::MIN;
        for n in 1..=1024 {
            let db = c.db(n);
            assert!(db > last, "{n}: {db} after {last}");
            last = db;
        }
        // Halving 16 costs the 8 → 16 slope: about 5 dB.
        let d = c.db(8) - c.db(16);
        assert!((-5.2..=-5.0).contains(&d), "{d}");
    }

    #[test]
    fn the_default_filter_model_goes_through_its_sweep_and_stops_where_it_stopped_helping() {
        let balls = ErrorModel::balls();
        let c = balls.base();
        for (n, r, db) in BALLS_FILTERED {
            assert_eq!(c.filter_radius(n), r, "{n}");
            assert!((c.filtered_db(n) - db).abs() < 1e-4, "{n}");
            assert!(c.filtered_db(n) > c.db(n), "{n}");
        }
        for n in [17, 32, 64, 256] {
            assert_eq!(c.filter_radius(n), 0, "{n}");
            assert_eq!(c.filtered_db(n), c.db(n));
        }
        assert_eq!(c.filter_radius(3), 2);
        assert_eq!(c.filter_radius(12), 1);
        // A radius the model did not measure is not claimed.
        assert_eq!(c.expected_db(16, 3), c.db(16));
    }

    #[test]
    fn the_cell_filter_is_chosen_where_it_reaches_the_target_for_less() {
        let mut m = model();
        // At the small floor the cell filter gives 37 dB at 4 samples for 0.015 s a sample.
        m.curves[0].cell = vec![(4, 37.0), (16, 41.0)];
        m.curves[0].cell_seconds_per_sample = 0.015;
        assert!(m.check().is_ok());
        let any = |c: &Curve, n| c.filter_radius(n);
        // 36 dB: 4 samples with the cell filter (0.06 s) beat 16 unfiltered (0.16 s).
        let c = m.cheapest(36.0, 16, any);
        assert_eq!(
            (c.samples, c.map_floor, c.cell, c.radius),
            (4, 512, true, 0),
            "{c:?}"
        );
        assert_eq!(c.db, 37.0);
        // 40 dB: 16 with it (0.24 s) beat 64 at 2048² (1.92 s).
        let c = m.cheapest(40.0, 16, any);
        assert_eq!((c.samples, c.cell), (16, true), "{c:?}");
        // Where it was not measured it is not claimed: 32 dB goes to 4 with the penumbra
        // filter (0.04 s) rather than the cell filter (0.06 s), 45 dB to the large floor.
        let c = m.cheapest(32.0, 16, any);
        assert_eq!((c.samples, c.radius, c.cell), (4, 2, false), "{c:?}");
        let c = m.cheapest(45.0, 16, any);
        assert_eq!((c.samples, c.map_floor, c.cell), (64, 2048, false), "{c:?}");
        assert_eq!(m.curves[0].cell_db(8), None);
        // Where highlights raise 4 samples to 16 anyway (×4 the cost), 16 unfiltered (0.16 s,
        // not raised) beat the cell filter at 4 (0.24 s once raised).
        let c = m.cheapest_raised(
            36.0,
            16,
            any,
            |n| if n < 16 { 16.0 / n as f64 } else { 1.0 },
        );
        assert_eq!((c.samples, c.cell), (16, false), "{c:?}");
        // Unmeasured cost: not offered.
        m.curves[0].cell_seconds_per_sample = 0.0;
        assert!(!m.cheapest(36.0, 16, any).cell);
        // Falling counts are refused.
        m.curves[0].cell = vec![(16, 41.0), (4, 37.0)];
        assert!(m.check().is_err());
    }

    #[test]
    fn a_model_without_rising_counts_is_refused() {
        let mut m = model();
        m.curves[0].unfiltered = vec![(16, 30.0), (4, 31.0)];
        assert!(m.check().is_err());
        m.curves.clear();
        assert!(m.check().is_err());
        let mut m = model();
        m.curves[1].unfiltered[0].1 = f32::NAN;
        assert!(m.check().is_err());
    }
}
