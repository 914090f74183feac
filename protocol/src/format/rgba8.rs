//! `rgba8` (linear) and `rgba8srgb`: three 8-bit channels in [0, 1] and a pad byte of 255 (opaque
//! alpha for anything that views the layer as RGBA). Linear rounds v·255 to nearest. sRGB picks the
//! code whose decoded **linear** value is nearest — the error that matters to the material stage,
//! which multiplies in linear space — via a 4096-bucket table and one threshold compare per channel
//! instead of `powf`.

use std::sync::LazyLock;

use super::{clamp_nonneg, count_saturated, round_u32};
use crate::srgb::srgb_to_linear_f64;

const BUCKETS: usize = 4096;
/// Values map to buckets by `round(x · SPAN)`.
const SPAN: f32 = (BUCKETS - 1) as f32;

struct Srgb {
    /// Linear value of each code.
    decode: [f32; 256],
    /// `threshold[c]`: midpoint between codes c and c+1; values at or above it encode above c.
    threshold: [f32; 256],
    /// Code at the lower edge of bucket `i`, the values that round to `i` in `x·4095`:
    /// [(i − ½)/4095, (i + ½)/4095], widened by 1e-6 for the rounding of the product. The smallest
    /// gap between codes (1/255/12.92 ≈ 3.0e-4) is wider than a bucket (2.4e-4 + 2e-6), so a
    /// bucket holds at most one threshold.
    start: [u8; BUCKETS],
}

static SRGB: LazyLock<Srgb> = LazyLock::new(|| {
    let exact: [f64; 256] = std::array::from_fn(|c| srgb_to_linear_f64(c as f64 / 255.0));
    let decode = exact.map(|v| v as f32);
    let threshold: [f32; 256] = std::array::from_fn(|c| match exact.get(c + 1) {
        Some(next) => ((exact[c] + next) / 2.0) as f32,
        None => f32::INFINITY,
    });
    let start = std::array::from_fn(|i| {
        let edge = ((i as f64 - 0.5) / f64::from(SPAN) - 1e-6).max(0.0) as f32;
        threshold.iter().take_while(|&&t| t <= edge).count() as u8
    });
    Srgb {
        decode,
        threshold,
        start,
    }
});

/// The sRGB encoder's tables, for kernels that must encode exactly as [`super::pack`] does (the
/// node's device pack): each code's upper threshold (`+∞` for 255) and, per bucket of
/// `round(x·4095)`, the first code whose threshold lies above the bucket's lower edge.
pub fn srgb_encode_tables() -> (&'static [f32; 256], &'static [u8; BUCKETS]) {
    let t = &*SRGB;
    (&t.threshold, &t.start)
}

#[inline(always)]
fn encode_srgb(t: &Srgb, v: f32) -> u8 {
    let x = clamp_nonneg(v, 1.0);
    // Rounding by the 2^23 trick keeps this free of float→int conversions.
    let bucket = (round_u32(x * SPAN) as usize).min(BUCKETS - 1);
    let c = t.start[bucket];
    c + u8::from(x >= t.threshold[usize::from(c)])
}

/// Quantisation bound of linear 8-bit: half a step plus the rounding of v·255 and c/255.
pub(super) fn bound_linear() -> f32 {
    1.0 / 510.0 + 1.0 / 4_194_304.0
}

/// Quantisation bound of sRGB 8-bit at `v` in [0, 1]: half the wider of the two gaps around the
/// code `v` encodes to (the farthest a value of that code's cell can lie), plus f32 rounding.
pub(super) fn bound_srgb(v: f32) -> f32 {
    let t = &*SRGB;
    let c = usize::from(encode_srgb(t, v));
    let below = if c == 0 {
        0.0
    } else {
        t.decode[c] - t.threshold[c - 1]
    };
    let above = if c == 255 {
        0.0
    } else {
        t.threshold[c] - t.decode[c]
    };
    below.max(above) + 1.0 / 16_777_216.0
}

fn pack_with(src: &[f32], dst: &mut [u8], encode: impl Fn(f32) -> u8) -> u64 {
    for (p, out) in src
        .as_chunks::<3>()
        .0
        .iter()
        .zip(dst.as_chunks_mut::<4>().0)
    {
        *out = [encode(p[0]), encode(p[1]), encode(p[2]), 255];
    }
    count_saturated::<3>(src, 1.0)
}

pub(super) fn pack_linear(src: &[f32], dst: &mut [u8]) -> u64 {
    pack_with(src, dst, |v| round_u32(clamp_nonneg(v, 1.0) * 255.0) as u8)
}

pub(super) fn pack_srgb(src: &[f32], dst: &mut [u8]) -> u64 {
    let t = &*SRGB;
    pack_with(src, dst, |v| encode_srgb(t, v))
}

pub(super) fn unpack_linear(src: &[u8], dst: &mut [f32]) {
    for (b, out) in src
        .as_chunks::<4>()
        .0
        .iter()
        .zip(dst.as_chunks_mut::<3>().0)
    {
        *out = [b[0], b[1], b[2]].map(|c| f32::from(c) / 255.0);
    }
}

pub(super) fn unpack_srgb(src: &[u8], dst: &mut [f32]) {
    let t = &*SRGB;
    for (b, out) in src
        .as_chunks::<4>()
        .0
        .iter()
        .zip(dst.as_chunks_mut::<3>().0)
    {
        *out = [b[0], b[1], b[2]].map(|c| t.decode[usize::from(c)]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bucketed encoder agrees with a brute-force nearest-code search everywhere, including
    /// on every threshold and its neighbours.
    #[test]
    fn srgb_encoder_is_nearest_code() {
        let t = &*SRGB;
        let brute = |x: f32| t.threshold.iter().take_while(|&&th| th <= x).count() as u8;
        let mut probes: Vec<f32> = (0..=200_000).map(|i| i as f32 / 200_000.0).collect();
        for &th in &t.threshold[..255] {
            probes.extend([th, th.next_down(), th.next_up()]);
        }
        for i in 0..=BUCKETS {
            let b = (i as f32 - 0.5) / SPAN;
            probes.extend([b, b.next_down(), b.next_up()]);
        }
        for x in probes.into_iter().filter(|x| (0.0..=1.0).contains(x)) {
            assert_eq!(encode_srgb(t, x), brute(x), "x = {x}");
        }
        for c in 0..=255u8 {
            assert_eq!(encode_srgb(t, t.decode[usize::from(c)]), c);
        }
    }
}
