//! The sRGB transfer and its 8-bit encoding, the one copy every crate uses (images written as PNG,
//! the sink's tone map, the live view's JPEG frames). `srgb8` is the reference: the transfer in
//! f32, then round to nearest. `encode8` gives the same byte for every f32 (NaN, ±∞ and negatives
//! included) from two table reads, no `powf`: a bucket table gives the code at the bucket's lower
//! edge, and one comparison with the next code's exact threshold (found from the reference itself)
//! finishes it. Here rather than in `scene` so the compositor, which must not depend on `scene`,
//! shares it; the wire's own `rgba8srgb` format rounds in the linear domain and is `format`'s
//! (its tables are built from [`srgb_to_linear_f64`], the same curve in f64).
//!
//! Out-of-range input, one rule in both directions: NaN and −∞ read as 0, +∞ as 1, and anything
//! else is clamped to [0, 1] before the curve, so no transfer here returns a value outside [0, 1]
//! or a NaN.

use std::sync::OnceLock;

/// The sRGB transfer of a linear value; NaN and values outside [0, 1] are clamped first (NaN and
/// −∞ to 0, +∞ to 1).
pub fn linear_to_srgb(x: f32) -> f32 {
    let x = if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) };
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// The inverse sRGB transfer (an encoded value to linear); NaN and values outside [0, 1] are
/// clamped first, as [`linear_to_srgb`] clamps them.
pub fn srgb_to_linear(x: f32) -> f32 {
    let x = if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) };
    if x <= 0.040_45 {
        x / 12.92
    } else {
        ((x + 0.055) / 1.055).powf(2.4)
    }
}

/// [`srgb_to_linear`] in f64, for tables that must hold the curve closer than f32 rounds it (the
/// `rgba8srgb` format's code midpoints).
pub fn srgb_to_linear_f64(x: f64) -> f64 {
    let x = if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) };
    if x <= 0.040_45 {
        x / 12.92
    } else {
        ((x + 0.055) / 1.055).powf(2.4)
    }
}

/// The reference 8-bit code of a linear value (round to nearest).
pub fn srgb8(x: f32) -> u8 {
    (linear_to_srgb(x) * 255.0 + 0.5) as u8
}

/// Buckets of the fast encoder's first guess over [0, 1].
const BUCKETS: usize = 4096;

struct Tables {
    /// `thresholds[k]`: the smallest non-negative f32 whose reference code is at least `k`
    /// (`thresholds[256]` is +Inf, so code 255 never steps further).
    thresholds: [f32; 257],
    /// The code at each bucket's lower edge, a lower bound for every value in the bucket.
    start: [u8; BUCKETS + 1],
}

fn tables() -> &'static Tables {
    static T: OnceLock<Tables> = OnceLock::new();
    T.get_or_init(|| {
        let mut thresholds = [f32::INFINITY; 257];
        for (k, t) in thresholds.iter_mut().enumerate().take(256).skip(1) {
            // Non-negative floats order like their bit patterns: bisect on the bits.
            let (mut lo, mut hi) = (0u32, 1.0f32.to_bits());
            while lo < hi {
                let mid = lo + (hi - lo) / 2;
                if usize::from(srgb8(f32::from_bits(mid))) >= k {
                    hi = mid;
                } else {
                    lo = mid + 1;
                }
            }
            *t = f32::from_bits(lo);
        }
        let start = std::array::from_fn(|b| srgb8(b as f32 / BUCKETS as f32));
        Tables { thresholds, start }
    })
}

/// The fast encoder: the code at the bucket's lower edge, plus one if `v` is past the next
/// exact threshold. A bucket holds at most one threshold: the steepest part of the curve,
/// 12.92·255 codes per unit, moves 0.8 codes per bucket.
#[inline(always)]
fn encode_with(t: &Tables, v: f32) -> u8 {
    // Selects, so NaN and −∞ read as 0 and +∞ as 1, as the reference clamps them.
    let v = if v > 0.0 { v } else { 0.0 };
    let v = if v < 1.0 { v } else { 1.0 };
    // Multiplying by a power of two is exact, so the bucket's edge is at or below `v`; 1.0 falls
    // in the extra last bucket.
    let c = t.start[(v * BUCKETS as f32) as i32 as usize];
    c + u8::from(v >= t.thresholds[usize::from(c) + 1])
}

/// [`srgb8`] of `v`, by table (the same byte for every f32).
#[inline]
pub fn encode8(v: f32) -> u8 {
    encode_with(tables(), v)
}

/// Encodes `values` scaled by `exposure` into `out`: `out[k] = srgb8(exposure · values[k])`.
/// Stops at the shorter of the two.
pub fn encode8_slice(values: &[f32], exposure: f32, out: &mut [u8]) {
    let t = tables();
    for (o, v) in out.iter_mut().zip(values) {
        *o = encode_with(t, exposure * *v);
    }
}

/// The first three channels of each `channels`-channel pixel of `values`, scaled by `exposure`,
/// as 8-bit sRGB RGB appended to `out`.
pub fn encode_rgb8(values: &[f32], channels: usize, exposure: f32, out: &mut Vec<u8>) {
    let t = tables();
    if channels == 3 {
        let start = out.len();
        out.resize(start + values.len() - values.len() % 3, 0);
        encode8_slice(values, exposure, &mut out[start..]);
        return;
    }
    out.reserve(values.len() / channels.max(1) * 3);
    for px in values.chunks_exact(channels.max(3)) {
        for &v in &px[..3] {
            out.push(encode_with(t, exposure * v));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_table_encoder_is_the_reference_everywhere() {
        // Every code boundary and its neighbourhood, then a sweep of bit patterns.
        let mut xs: Vec<f32> = Vec::new();
        for k in 1..256 {
            let b = tables().thresholds[k].to_bits();
            xs.extend((b.saturating_sub(300)..b + 300).map(f32::from_bits));
        }
        xs.extend((0..u32::MAX).step_by(4099).map(f32::from_bits));
        xs.extend([f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -0.0, 1.0, 2.0]);
        for x in xs {
            assert_eq!(encode8(x), srgb8(x), "{x:e}");
        }
        assert_eq!(encode8(f32::INFINITY), 255);
        assert_eq!(encode8(f32::NAN), 0);
    }

    #[test]
    fn out_of_range_reads_as_the_nearest_end_both_ways() {
        for (x, end) in [
            (f32::NAN, 0.0),
            (f32::NEG_INFINITY, 0.0),
            (-1.0, 0.0),
            (-0.0, 0.0),
            (f32::INFINITY, 1.0),
            (2.0, 1.0),
        ] {
            assert_eq!(linear_to_srgb(x), linear_to_srgb(end), "{x}");
            assert_eq!(srgb_to_linear(x), srgb_to_linear(end), "{x}");
            let wide = f64::from(x);
            assert_eq!(
                srgb_to_linear_f64(wide),
                srgb_to_linear_f64(f64::from(end)),
                "{x}"
            );
        }
        assert_eq!(srgb8(f32::INFINITY), 255);
        assert_eq!(srgb8(f32::NEG_INFINITY), 0);
        assert_eq!((srgb_to_linear(0.0), srgb_to_linear_f64(1.0)), (0.0, 1.0));
        // By hand: the linear piece below the knee, the power piece above it.
        assert_eq!(srgb_to_linear(0.04), 0.04 / 12.92);
        assert!((srgb_to_linear(0.5) - 0.214_041_14).abs() < 1e-7);
        assert!((srgb_to_linear_f64(0.5) - 0.214_041_140_482_232_5).abs() < 1e-15);
        assert!((linear_to_srgb(0.214_041_14) - 0.5).abs() < 1e-6);
        // Every code decodes to within f32 rounding of the f64 curve, and back to itself.
        for c in 0..=255u8 {
            let s = f32::from(c) / 255.0;
            let (lin, wide) = (srgb_to_linear(s), srgb_to_linear_f64(f64::from(c) / 255.0));
            assert!(
                (f64::from(lin) - wide).abs() <= 1e-6 * wide.max(1e-3),
                "{c}"
            );
            assert_eq!(srgb8(lin), c);
        }
    }

    #[test]
    fn rgb_of_wider_pixels() {
        let mut out = Vec::new();
        encode_rgb8(&[0.5, 1.0, 0.0, 7.0, 0.0, 0.25, 2.0, 9.0], 4, 1.0, &mut out);
        assert_eq!(out, [srgb8(0.5), 255, 0, 0, srgb8(0.25), 255]);
        let mut three = Vec::new();
        encode_rgb8(&[0.5, 1.0, 0.0, 0.1], 3, 2.0, &mut three);
        assert_eq!(three, [255, 255, 0]);
    }
}
