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

/// Pixels per block: the saturation pass re-reads a block while it is still in L1.
const BLOCK: usize = 512;

pub(super) fn pack(src: &[f32], scale: f32, dst: &mut [u8]) -> u64 {
    let kd = DMAX / scale;
    let ks = SMAX / scale;
    // v·k is NaN only for NaN input or an infinite k times 0; the clamp maps NaN to 0.
    let d = |v: f32| round_u32(clamp_nonneg(v * kd, DMAX));
    let s = |v: f32| round_u32(clamp_nonneg(v * ks, SMAX));
    let mut saturated = 0u64;
    let pixels = src.as_chunks::<6>().0;
    let words = dst.as_chunks_mut::<4>().0;
    for (block, out) in pixels.chunks(BLOCK).zip(words.chunks_mut(2 * BLOCK)) {
        // Two 32-bit halves per pixel keep every lane 32 bits wide, which vectorises across
        // pixels; diffuse blue straddles them (its top bit is bit 0 of the high half).
        for (p, o) in block.iter().zip(out.as_chunks_mut::<2>().0) {
            let (b, sr, sg, sb) = (d(p[2]), s(p[3]), s(p[4]), s(p[5]));
            let lo = d(p[0]) | d(p[1]) << 11 | b << 22;
            let hi = b >> 10 | sr << 1 | sg << 11 | sb << 21;
            *o = [lo.to_le_bytes(), hi.to_le_bytes()];
            let over = p.iter().fold(false, |acc, &v| acc | (v > scale));
            saturated += u64::from(over);
        }
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
