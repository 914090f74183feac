//! `f16x6` (six halves) and `f16x4` (three halves and a pad of 1.0, so a GPU reading it as RGBA
//! sees opaque alpha), little-endian. Values clamp to [0, 65504] first, so rounding (to nearest,
//! ties to even) never overflows to infinity. Packing runs on `half`'s slice conversion (F16C when
//! the CPU has it) block by block; a block whose values are all in range already (one vectorised
//! test of the bits) is converted straight into the output, and only a block holding a negative,
//! NaN, infinite or too large value is clamped into a staging buffer first. Unpacking decodes the
//! bits directly (exact: a shift and one multiplication by 2^112), which vectorises and needs no
//! alignment of the packed bytes.

use half::f16;
use half::slice::HalfFloatSliceExt;

use super::{F16_MAX, clamp_nonneg, count_saturated};

/// Pixels per block: small enough for the block and its staging buffers to sit in L1, so the
/// range test and the conversion read the values from memory once.
const BLOCK: usize = 384;

/// Pixels per block of the padded formats (measured best for `f16x4`).
const PADDED_BLOCK: usize = 256;

/// Bits of `F16_MAX`. Compared as unsigned integers, exactly the values the clamp would change
/// lie above it: negatives (−0 included, the sign bit makes them huge), NaN, +Inf and everything
/// beyond 65504.
const MAX_BITS: u32 = 0x477F_E000;

/// Half an ulp of `v` in half precision: 2^(e−11) for `v` in [2^e, 2^(e+1)), e ≥ −14; 2^−25 in
/// the subnormal range. Exact.
pub(super) fn bound(v: f32) -> f32 {
    let e = ((v.to_bits() >> 23) as i32 - 127).max(-14);
    f32::from_bits(((e - 11 + 127) as u32) << 23)
}

/// Packs IN channels per pixel into OUT halves (OUT > IN pads with 1.0).
pub(super) fn pack<const IN: usize, const OUT: usize>(src: &[f32], dst: &mut [u8]) -> u64 {
    if IN != OUT {
        return pack_padded::<IN, OUT>(src, dst);
    }
    // Straight into the output when it can be viewed as halves (little-endian, 2-byte aligned:
    // pooled payload buffers and their pixel-aligned splits are), else through an L1 buffer.
    #[cfg(target_endian = "little")]
    if let Ok(halves) = bytemuck::try_cast_slice_mut::<u8, f16>(dst) {
        return src
            .chunks(BLOCK * IN)
            .zip(halves.chunks_mut(BLOCK * IN))
            .map(|(s, o)| pack_block::<IN>(s, o))
            .sum();
    }
    let mut staged = [f16::ZERO; BLOCK * 6];
    let mut saturated = 0;
    for (s, out) in src.chunks(BLOCK * IN).zip(dst.chunks_mut(BLOCK * IN * 2)) {
        let halves = &mut staged[..s.len()];
        saturated += pack_block::<IN>(s, halves);
        store_le(halves, out);
    }
    saturated
}

/// Converts one block of whole pixels; returns its saturated pixels.
#[inline]
fn pack_block<const C: usize>(src: &[f32], out: &mut [f16]) -> u64 {
    // A flat OR of comparisons (not `any`, whose early exit would stop the vectorisation).
    let outside = src
        .iter()
        .fold(0u32, |acc, v| acc | u32::from(v.to_bits() > MAX_BITS));
    if outside == 0 {
        out.convert_from_f32_slice(src);
        return 0;
    }
    let mut staged = [0f32; BLOCK * 6];
    let clamped = &mut staged[..src.len()];
    for (c, &v) in clamped.iter_mut().zip(src) {
        *c = clamp_nonneg(v, F16_MAX);
    }
    out.convert_from_f32_slice(clamped);
    count_saturated::<C>(src, F16_MAX)
}

/// Writes `halves` little-endian into `out` (as long).
fn store_le(halves: &[f16], out: &mut [u8]) {
    if cfg!(target_endian = "little") {
        out.copy_from_slice(bytemuck::cast_slice(halves));
    } else {
        for (o, h) in out.as_chunks_mut::<2>().0.iter_mut().zip(halves) {
            *o = h.to_bits().to_le_bytes();
        }
    }
}

/// The padded formats: clamp and interleave the pad into a staging block, then convert.
fn pack_padded<const IN: usize, const OUT: usize>(src: &[f32], dst: &mut [u8]) -> u64 {
    let mut staged = [0f32; PADDED_BLOCK * 6];
    let mut halves = [f16::ZERO; PADDED_BLOCK * 6];
    let mut saturated = 0u64;
    let pixels = src.as_chunks::<IN>().0;
    for (block, out) in pixels
        .chunks(PADDED_BLOCK)
        .zip(dst.chunks_mut(PADDED_BLOCK * OUT * 2))
    {
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
        store_le(&halves[..n], out);
    }
    saturated
}

/// The half nearest `v` (ties to even) as bits, for `v` in [0, 65504] (what `pack` clamps to):
/// integer arithmetic and one f32 addition, no branch and no table, so a kernel's loop compiled
/// for any instruction set vectorises it. Gives F16C's bits for every such `v`
/// (`tests/halfs.rs` checks all of them). Normal results round by adding 0xFFF plus the kept
/// mantissa's lowest bit below the cut; subnormal ones by adding 0.5, whose exponent puts the
/// f32 rounding point at the half's last subnormal bit.
#[inline(always)]
pub fn encode(v: f32) -> u16 {
    const HALF_MIN_NORMAL: u32 = 113 << 23;
    const REBIAS: u32 = ((15 - 127i32) << 23) as u32;
    const SUBNORMAL_MAGIC: u32 = 126 << 23;
    let u = v.to_bits();
    let odd = (u >> 13) & 1;
    let normal = u.wrapping_add(REBIAS).wrapping_add(0xFFF + odd) >> 13;
    let subnormal = (v + f32::from_bits(SUBNORMAL_MAGIC))
        .to_bits()
        .wrapping_sub(SUBNORMAL_MAGIC);
    (if u < HALF_MIN_NORMAL {
        subnormal
    } else {
        normal
    }) as u16
}

/// One half (its bits) as the clamped f32 unpack yields: finite positive values exactly, +Inf →
/// 65504, NaN and everything with the sign bit (−0 included) → 0.
#[inline(always)]
pub fn decode(bits: u16) -> f32 {
    let h = u32::from(bits);
    // Exponent and mantissa moved to the f32 positions: the value is then 2^−112 of the half's,
    // subnormals included (they become f32 subnormals), and the multiplication is exact.
    let v = f32::from_bits(h << 13) * f32::from_bits((127 + 112) << 23);
    if h < 0x7C00 {
        v
    } else if h == 0x7C00 {
        F16_MAX
    } else {
        0.0
    }
}

/// Unpacks OUT halves per pixel into IN channels. Whatever the bytes, the result is finite and in
/// [0, 65504]: NaN → 0, negatives → 0, +Inf → 65504.
pub(super) fn unpack<const IN: usize, const OUT: usize>(src: &[u8], dst: &mut [f32]) {
    let halves = src.as_chunks::<2>().0;
    if IN == OUT {
        for (o, h) in dst.iter_mut().zip(halves) {
            *o = decode(u16::from_le_bytes(*h));
        }
        return;
    }
    for (p, o) in halves.chunks_exact(OUT).zip(dst.as_chunks_mut::<IN>().0) {
        for c in 0..IN {
            o[c] = decode(u16::from_le_bytes(p[c]));
        }
    }
}
