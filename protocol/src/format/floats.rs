//! `f32x6`, `f32x3` (non-negative illumination and radiance) and `depth32`, little-endian f32.
//! Finite values in range travel exactly. Illumination/radiance: NaN and negatives → 0, +Inf →
//! `f32::MAX` (saturated). Depth keeps every finite value, sign included; NaN → 0, ±Inf → ±`f32::MAX`
//! (saturated). Every loop is a single pass of selects (vector compare, min and max, no branch per
//! value) that also gathers, in a register, whether a value saturated: the count reads the values
//! again only for a block holding an infinity, while that block is still in L1. Before, the count
//! was a second pass over the whole slice, which cost as much as the copy itself.

use super::{clamp_nonneg, count_saturated};

/// Pixels per block of the saturation screen: a block of six-channel pixels (6 KB) stays in L1
/// for the rare recount.
const BLOCK: usize = 256;

/// Depth values per block: one u32 counter per block cannot overflow.
const DEPTH_BLOCK: usize = 4096;

pub(super) fn clamp_depth(v: f32) -> f32 {
    let x = if v.is_nan() { 0.0 } else { v };
    let x = if x > -f32::MAX { x } else { -f32::MAX };
    if x < f32::MAX { x } else { f32::MAX }
}

pub(super) fn pack_nonneg<const C: usize>(src: &[f32], dst: &mut [u8]) -> u64 {
    let out = dst.as_chunks_mut::<4>().0;
    let mut saturated = 0;
    for (s, o) in src.chunks(BLOCK * C).zip(out.chunks_mut(BLOCK * C)) {
        // A flat OR of comparisons (`any` would exit early and stop the vectorisation). Only +Inf
        // lies above `f32::MAX`; NaN compares false.
        let mut inf = 0u32;
        for (&v, o) in s.iter().zip(o) {
            *o = clamp_nonneg(v, f32::MAX).to_le_bytes();
            inf |= u32::from(v > f32::MAX);
        }
        // Blocks hold whole pixels (the slice does: `pack` checked), so counting per block counts
        // every pixel once.
        if inf != 0 {
            saturated += count_saturated::<C>(s, f32::MAX);
        }
    }
    saturated
}

pub(super) fn unpack_nonneg(src: &[u8], dst: &mut [f32]) {
    for (b, out) in src.as_chunks::<4>().0.iter().zip(dst) {
        *out = clamp_nonneg(f32::from_le_bytes(*b), f32::MAX);
    }
}

pub(super) fn pack_depth(src: &[f32], dst: &mut [u8]) -> u64 {
    let out = dst.as_chunks_mut::<4>().0;
    let mut saturated = 0;
    for (s, o) in src.chunks(DEPTH_BLOCK).zip(out.chunks_mut(DEPTH_BLOCK)) {
        // One channel per pixel, and −Inf saturates too: the count is the pixel count.
        let mut inf = 0u32;
        for (&v, o) in s.iter().zip(o) {
            *o = clamp_depth(v).to_le_bytes();
            inf += u32::from(v.is_infinite());
        }
        saturated += u64::from(inf);
    }
    saturated
}

pub(super) fn unpack_depth(src: &[u8], dst: &mut [f32]) {
    for (b, out) in src.as_chunks::<4>().0.iter().zip(dst) {
        *out = clamp_depth(f32::from_le_bytes(*b));
    }
}
