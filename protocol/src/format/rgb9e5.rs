//! `rgb9e5x2`: two shared-exponent RGB triples (diffuse, specular), each packed as in
//! GL_EXT_texture_shared_exponent (9-bit mantissas R, G, B in bits 0–26, 5-bit exponent in 27–31,
//! bias 15), diffuse in the low 32 bits; stored little-endian. Mantissas round to nearest (ties to
//! even); the exponent comes from the f32 bits of the largest channel, not `log2`.

use super::{clamp_nonneg, count_saturated, round_u32};

/// Largest representable value, 511/512 · 2^16.
pub const MAX: f32 = 65408.0;

/// Smallest value with its own exponent: below it the exponent is 0 and the step 2^-24.
const FLOOR: f32 = 1.0 / 65536.0;

/// The biased shared exponent (0..=31) for a triple whose largest clamped channel is `m`: the
/// smallest that holds `m` after rounding to 9 bits. Adding half a 9-bit step (bit 14) to the f32
/// bits carries into the exponent field exactly when the mantissa would round up to 512, so the
/// exponent field of the sum is already the answer (`m = 1.f·2^e` → `e + 16`, or `e + 17` on a
/// carry); clamping `m` to 2^-16 first gives exponent 0 to everything smaller.
#[inline(always)]
fn shared_exponent(m: f32) -> u32 {
    let m = if m > FLOOR { m } else { FLOOR };
    ((m.to_bits() + 0x4000) >> 23) - 111
}

#[inline(always)]
fn encode(r: f32, g: f32, b: f32) -> u32 {
    let (r, g, b) = (
        clamp_nonneg(r, MAX),
        clamp_nonneg(g, MAX),
        clamp_nonneg(b, MAX),
    );
    let m = if r > g { r } else { g };
    let m = if m > b { m } else { b };
    let es = shared_exponent(m);
    // 2^(24 − es): scaling by a power of two is exact, so only the rounding loses anything.
    let f = f32::from_bits((151 - es) << 23);
    round_u32(r * f) | round_u32(g * f) << 9 | round_u32(b * f) << 18 | es << 27
}

#[inline(always)]
fn decode(w: u32) -> [f32; 3] {
    let f = f32::from_bits(((w >> 27) + 103) << 23);
    [
        (w & 511) as f32 * f,
        (w >> 9 & 511) as f32 * f,
        (w >> 18 & 511) as f32 * f,
    ]
}

/// Half a mantissa step at the exponent chosen for a triple whose largest clamped channel is `m`;
/// exact (the arithmetic adds no rounding of its own).
pub(super) fn bound(m: f32) -> f32 {
    f32::from_bits((shared_exponent(m) + 102) << 23)
}

/// Pixels per block: the saturation pass re-reads a block while it is still in L1.
const BLOCK: usize = 512;

pub(super) fn pack(src: &[f32], dst: &mut [u8]) -> u64 {
    // Diffuse and specular words are consecutive little-endian u32s, so the hot loop runs over
    // triples (one u32 each), which the compiler vectorises across triples.
    let triples = src.as_chunks::<3>().0;
    let words = dst.as_chunks_mut::<4>().0;
    let mut saturated = 0u64;
    for (t, w) in triples.chunks(2 * BLOCK).zip(words.chunks_mut(2 * BLOCK)) {
        for (t, w) in t.iter().zip(w.iter_mut()) {
            *w = encode(t[0], t[1], t[2]).to_le_bytes();
        }
        saturated += count_saturated::<6>(t.as_flattened(), MAX);
    }
    saturated
}

pub(super) fn unpack(src: &[u8], dst: &mut [f32]) {
    for (w, out) in src
        .as_chunks::<4>()
        .0
        .iter()
        .zip(dst.as_chunks_mut::<3>().0)
    {
        *out = decode(u32::from_le_bytes(*w));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// GL_EXT_texture_shared_exponent's encoder written out in f64 with `log2`, as the spec
    /// states it (rounding ties to even, as ours does).
    fn reference(rgb: [f32; 3]) -> u32 {
        let c = rgb.map(|v| f64::from(clamp_nonneg(v, MAX)));
        let m = c[0].max(c[1]).max(c[2]);
        let mut es = m.log2().floor().max(-16.0) as i32 + 16;
        let mut denom = 2f64.powi(es - 24);
        if (m / denom).round_ties_even() == 512.0 {
            es += 1;
            denom *= 2.0;
        }
        let q = c.map(|v| (v / denom).round_ties_even() as u32);
        q[0] | q[1] << 9 | q[2] << 18 | (es as u32) << 27
    }

    #[test]
    fn matches_the_extension_reference() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        for _ in 0..200_000 {
            let rgb: [f32; 3] = std::array::from_fn(|_| match rng.random_range(0..4) {
                0 => f32::from_bits(rng.random::<u32>() & 0x7FFF_FFFF),
                1 => rng.random_range(-1.0..70_000.0),
                // Just under a power of two, where the mantissa carries into the exponent.
                2 => 2f32.powi(rng.random_range(-20..17)) * rng.random_range(0.998..1.0),
                _ => 2f32.powi(rng.random_range(-30..17)) * rng.random_range(0.0..1.0),
            });
            assert_eq!(encode(rgb[0], rgb[1], rgb[2]), reference(rgb), "{rgb:?}");
        }
        assert_eq!(decode(encode(MAX, 0.0, 1.0)), [MAX, 0.0, 0.0]);
    }
}
