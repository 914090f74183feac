//! `seed64`, the paper's 64-bit network pixel: diffuse RGB as 3×11-bit and specular RGB as 3×10-bit
//! unsigned fixed point against a per-frame `scale` (code = round(v/scale·(2^bits−1))), bit 63
//! spare. Bits 0–10, 11–21, 22–32 hold diffuse R, G, B; 33–42, 43–52, 53–62 specular R, G, B;
//! stored little-endian.

use super::{clamp_nonneg, round_u32};

const DMAX: f32 = 2047.0;
const SMAX: f32 = 1023.0;

/// Quantisation bound of one channel: half a step, plus the f32 rounding of the two multiplies
/// on each side (under 2^-22·scale, so it never loosens the bound visibly).
pub(super) fn bound(channel: usize, scale: f32) -> f32 {
    let steps = if channel < 3 { DMAX } else { SMAX };
    scale / (2.0 * steps) + scale * (1.0 / 2_097_152.0)
}

pub(super) fn pack(src: &[f32], scale: f32, dst: &mut [u8]) -> u64 {
    let kd = DMAX / scale;
    let ks = SMAX / scale;
    // v·k is NaN only for NaN input or an infinite k times 0; the clamp maps NaN to 0.
    let d = |v: f32| u64::from(round_u32(clamp_nonneg(v * kd, DMAX)));
    let s = |v: f32| u64::from(round_u32(clamp_nonneg(v * ks, SMAX)));
    let mut saturated = 0u64;
    for (p, out) in src
        .as_chunks::<6>()
        .0
        .iter()
        .zip(dst.as_chunks_mut::<8>().0)
    {
        let word =
            d(p[0]) | d(p[1]) << 11 | d(p[2]) << 22 | s(p[3]) << 33 | s(p[4]) << 43 | s(p[5]) << 53;
        *out = word.to_le_bytes();
        let over = (p[0] > scale)
            | (p[1] > scale)
            | (p[2] > scale)
            | (p[3] > scale)
            | (p[4] > scale)
            | (p[5] > scale);
        saturated += u64::from(over);
    }
    saturated
}

pub(super) fn unpack(src: &[u8], scale: f32, dst: &mut [f32]) {
    let fd = scale / DMAX;
    let fs = scale / SMAX;
    for (b, out) in src
        .as_chunks::<8>()
        .0
        .iter()
        .zip(dst.as_chunks_mut::<6>().0)
    {
        let w = u64::from_le_bytes(*b);
        *out = [
            (w & 0x7FF) as f32 * fd,
            (w >> 11 & 0x7FF) as f32 * fd,
            (w >> 22 & 0x7FF) as f32 * fd,
            (w >> 33 & 0x3FF) as f32 * fs,
            (w >> 43 & 0x3FF) as f32 * fs,
            (w >> 53 & 0x3FF) as f32 * fs,
        ];
    }
}
