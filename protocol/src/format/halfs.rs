//! `f16x6` (six halves) and `f16x4` (three halves and a pad of 1.0, so a GPU reading it as RGBA
//! sees opaque alpha), little-endian. Values clamp to [0, 65504] first, so rounding (to nearest,
//! ties to even) never overflows to infinity; the conversion itself runs on `half`'s slice routines
//! (F16C when the CPU has it) over blocks that stay in L1.

use half::f16;
use half::slice::HalfFloatSliceExt;

use super::{F16_MAX, clamp_nonneg, count_saturated};

/// Pixels per block: small enough for the staging buffers to sit in L1.
const BLOCK: usize = 256;

/// Half an ulp of `v` in half precision: 2^(e−11) for `v` in [2^e, 2^(e+1)), e ≥ −14; 2^−25 in
/// the subnormal range. Exact.
pub(super) fn bound(v: f32) -> f32 {
    let e = ((v.to_bits() >> 23) as i32 - 127).max(-14);
    f32::from_bits(((e - 11 + 127) as u32) << 23)
}

/// Packs IN channels per pixel into OUT halves (OUT > IN pads with 1.0).
pub(super) fn pack<const IN: usize, const OUT: usize>(src: &[f32], dst: &mut [u8]) -> u64 {
    let mut staged = [0f32; BLOCK * 6];
    let mut halves = [f16::ZERO; BLOCK * 6];
    let mut saturated = 0u64;
    let pixels = src.as_chunks::<IN>().0;
    let packed = dst.as_chunks_mut::<2>().0;
    for (block, out) in pixels.chunks(BLOCK).zip(packed.chunks_mut(BLOCK * OUT)) {
        let n = block.len() * OUT;
        for (p, s) in block.iter().zip(staged.as_chunks_mut::<OUT>().0) {
            for c in 0..OUT {
                s[c] = if c < IN {
                    clamp_nonneg(p[c], F16_MAX)
                } else {
                    1.0
                };
            }
        }
        saturated += count_saturated::<IN>(block.as_flattened(), F16_MAX);
        halves[..n].convert_from_f32_slice(&staged[..n]);
        for (o, h) in out.iter_mut().zip(&halves[..n]) {
            *o = h.to_bits().to_le_bytes();
        }
    }
    saturated
}

/// Unpacks OUT halves per pixel into IN channels. Whatever the bytes, the result is finite and in
/// [0, 65504]: NaN → 0, negatives → 0, +Inf → 65504.
pub(super) fn unpack<const IN: usize, const OUT: usize>(src: &[u8], dst: &mut [f32]) {
    let mut halves = [f16::ZERO; BLOCK * 6];
    let mut staged = [0f32; BLOCK * 6];
    let packed = src.as_chunks::<2>().0;
    let pixels = dst.as_chunks_mut::<IN>().0;
    for (block, out) in packed.chunks(BLOCK * OUT).zip(pixels.chunks_mut(BLOCK)) {
        let n = block.len();
        for (h, b) in halves.iter_mut().zip(block) {
            *h = f16::from_bits(u16::from_le_bytes(*b));
        }
        halves[..n].convert_to_f32_slice(&mut staged[..n]);
        for (p, s) in out.iter_mut().zip(staged.as_chunks::<OUT>().0) {
            for c in 0..IN {
                p[c] = clamp_nonneg(s[c], F16_MAX);
            }
        }
    }
}
