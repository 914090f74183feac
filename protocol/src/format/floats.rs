//! `f32x6`, `f32x3` (non-negative illumination and radiance) and `depth32`, little-endian f32.
//! Finite values in range travel exactly. Illumination/radiance: NaN and negatives → 0, +Inf →
//! `f32::MAX` (saturated). Depth keeps every finite value, sign included; NaN → 0, ±Inf → ±`f32::MAX`
//! (saturated).

use super::{clamp_nonneg, count_saturated};

pub(super) fn clamp_depth(v: f32) -> f32 {
    let x = if v.is_nan() { 0.0 } else { v };
    let x = if x > -f32::MAX { x } else { -f32::MAX };
    if x < f32::MAX { x } else { f32::MAX }
}

pub(super) fn pack_nonneg<const C: usize>(src: &[f32], dst: &mut [u8]) -> u64 {
    for (&v, out) in src.iter().zip(dst.as_chunks_mut::<4>().0) {
        *out = clamp_nonneg(v, f32::MAX).to_le_bytes();
    }
    count_saturated::<C>(src, f32::MAX)
}

pub(super) fn unpack_nonneg(src: &[u8], dst: &mut [f32]) {
    for (b, out) in src.as_chunks::<4>().0.iter().zip(dst) {
        *out = clamp_nonneg(f32::from_le_bytes(*b), f32::MAX);
    }
}

pub(super) fn pack_depth(src: &[f32], dst: &mut [u8]) -> u64 {
    for (&v, out) in src.iter().zip(dst.as_chunks_mut::<4>().0) {
        *out = clamp_depth(v).to_le_bytes();
    }
    // One channel per pixel, and −Inf saturates too.
    src.iter().filter(|v| v.is_infinite()).count() as u64
}

pub(super) fn unpack_depth(src: &[u8], dst: &mut [f32]) {
    for (b, out) in src.as_chunks::<4>().0.iter().zip(dst) {
        *out = clamp_depth(f32::from_le_bytes(*b));
    }
}
