//! The summary statistics every crate reports with (timings, latencies, errors, the planner's
//! measured frame times): one definition of each, so a `p95` means the same in the soak, the
//! coordinator's report and the view probe. Here because `protocol` is the one crate all the others
//! already depend on; nothing here touches the wire.
//!
//! - [`median`]: the element at index `n / 2` of the sorted values — the middle one for odd `n`,
//!   the upper of the two middle ones for even `n`. Always one of the inputs (never an average),
//!   so it is defined for integers and durations too.
//! - [`percentile_nearest_rank`]: the nearest-rank `p`-quantile, `p` in [0, 1]: the smallest value
//!   with at least a fraction `p` of the values at or below it (rank `⌈p·n⌉`, at least 1). Also
//!   always one of the inputs. For even `n`, `p = 0.5` is the *lower* middle value, so a `p50` and
//!   a [`median`] of the same even-length values can differ by one rank.
//! - [`mean`]: the arithmetic mean, summed in order.
//!
//! Empty input gives `None`. Floats are ordered by `total_cmp`, so NaN has a place instead of
//! poisoning the sort: a (positive) NaN sorts above +∞, a negative NaN below −∞; NaNs are kept, not
//! dropped, so a NaN can be a median or a maximum. A NaN in [`mean`]'s input makes the mean NaN.

use std::cmp::Ordering;
use std::time::Duration;

/// A value the statistics can sort: floats by `total_cmp`, integers and durations by `Ord`.
pub trait Sample: Copy {
    /// The total order the statistics sort by.
    fn order(&self, other: &Self) -> Ordering;
}

macro_rules! by_ord {
    ($($t:ty),*) => {$(
        impl Sample for $t {
            fn order(&self, other: &Self) -> Ordering {
                self.cmp(other)
            }
        }
    )*};
}
by_ord!(u32, u64, usize, i64, Duration);

impl Sample for f64 {
    fn order(&self, other: &Self) -> Ordering {
        self.total_cmp(other)
    }
}

impl Sample for f32 {
    fn order(&self, other: &Self) -> Ordering {
        self.total_cmp(other)
    }
}

/// `v` in ascending order (see [`Sample`]).
pub fn sorted<T: Sample>(v: &[T]) -> Vec<T> {
    let mut s = v.to_vec();
    s.sort_by(T::order);
    s
}

/// The median as this module defines it: the element at index `n / 2` of the sorted values (the
/// upper middle one for even `n`); `None` when empty.
pub fn median<T: Sample>(v: &[T]) -> Option<T> {
    sorted(v).get(v.len() / 2).copied()
}

/// The nearest-rank `p`-quantile of `v`, `p` in [0, 1] (`0.95` for a p95): the value of rank
/// `⌈p·n⌉` (ranks from 1) in ascending order, rank 1 when that is 0. `p` at or below 0 (or NaN)
/// gives the least value, at or above 1 the largest. `None` when empty.
pub fn percentile_nearest_rank<T: Sample>(v: &[T], p: f64) -> Option<T> {
    if v.is_empty() {
        return None;
    }
    let s = sorted(v);
    Some(s[nearest_rank(s.len(), p) - 1])
}

/// The rank (from 1) of the nearest-rank `p`-quantile among `n > 0` values.
fn nearest_rank(n: usize, p: f64) -> usize {
    // `as` saturates: NaN and negatives to 0, +∞ to usize::MAX.
    ((p * n as f64).ceil() as usize).clamp(1, n)
}

/// The arithmetic mean of `v`; `None` when empty.
pub fn mean(v: &[f64]) -> Option<f64> {
    (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_is_the_middle_element_upper_for_even_lengths() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&[4.0, 1.0, 3.0, 2.0]), Some(3.0));
        assert_eq!(median(&[7u64]), Some(7));
        assert_eq!(median(&[10u64, 40, 20, 30]), Some(30));
        assert_eq!(median::<f64>(&[]), None);
        let ms = Duration::from_millis;
        assert_eq!(median(&[ms(5), ms(1), ms(9)]), Some(ms(5)));
    }

    #[test]
    fn nearest_rank_percentiles_by_hand() {
        let v: Vec<f64> = (1..=20).map(f64::from).collect();
        // ⌈0.5·20⌉ = 10, ⌈0.95·20⌉ = 19, ⌈0.05·20⌉ = 1, ⌈0.06·20⌉ = ⌈1.2⌉ = 2.
        assert_eq!(percentile_nearest_rank(&v, 0.5), Some(10.0));
        assert_eq!(percentile_nearest_rank(&v, 0.95), Some(19.0));
        assert_eq!(percentile_nearest_rank(&v, 0.05), Some(1.0));
        assert_eq!(percentile_nearest_rank(&v, 0.06), Some(2.0));
        assert_eq!(percentile_nearest_rank(&v, 1.0), Some(20.0));
        // Out of range or NaN p: the ends.
        assert_eq!(percentile_nearest_rank(&v, 0.0), Some(1.0));
        assert_eq!(percentile_nearest_rank(&v, -1.0), Some(1.0));
        assert_eq!(percentile_nearest_rank(&v, f64::NAN), Some(1.0));
        assert_eq!(percentile_nearest_rank(&v, 2.0), Some(20.0));
        // One value is every percentile; none has none.
        assert_eq!(percentile_nearest_rank(&[3.0], 0.95), Some(3.0));
        assert_eq!(percentile_nearest_rank::<f64>(&[], 0.5), None);
        // Unsorted input; p50 of an even count is the lower middle, the median the upper one.
        let w = [40u64, 10, 30, 20];
        assert_eq!(percentile_nearest_rank(&w, 0.5), Some(20));
        assert_eq!(median(&w), Some(30));
    }

    #[test]
    fn nan_sorts_by_total_order_and_is_kept() {
        let v = [1.0, f64::NAN, 3.0, f64::INFINITY, 2.0];
        let s = sorted(&v);
        assert_eq!(&s[..4], &[1.0, 2.0, 3.0, f64::INFINITY]);
        assert!(s[4].is_nan());
        assert_eq!(median(&v), Some(3.0));
        assert!(percentile_nearest_rank(&v, 1.0).unwrap().is_nan());
        assert_eq!(
            sorted(&[0.5, -f64::NAN, f64::NEG_INFINITY])[1],
            f64::NEG_INFINITY
        );
        assert!(mean(&v).unwrap().is_nan());
        let z = sorted(&[2.0f32, 0.0, -0.0, -1.0]);
        assert_eq!(z, [-1.0, 0.0, 0.0, 2.0]);
        assert!(z[1].is_sign_negative() && z[2].is_sign_positive());
    }

    #[test]
    fn mean_by_hand() {
        assert_eq!(mean(&[1.0, 2.0, 6.0]), Some(3.0));
        assert_eq!(mean(&[0.5]), Some(0.5));
        assert_eq!(mean(&[]), None);
    }
}
