//! The f32 formats (`f32x6`, `f32x3`, `depth32`) bit for bit against the scalar code they replaced:
//! on a sweep through the whole f32 bit space, every pattern near a value the policy treats
//! specially, and saturating values scattered at every density, with whole and ragged blocks and
//! payloads that do not start on a 4-byte boundary. Pack must write the same bytes and count the
//! same saturated pixels; unpack must give the same bits.

use lightfold_protocol::PixelFormat;
use lightfold_protocol::format::{pack, unpack};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The scalar pack of the illumination formats as it was: the clamp value by value, then a second
/// pass counting the pixels with a channel above `f32::MAX`.
fn reference_pack_nonneg(src: &[f32], channels: usize) -> (Vec<u8>, u64) {
    let clamp = |v: f32| {
        let x = if v > 0.0 { v } else { 0.0 };
        if x < f32::MAX { x } else { f32::MAX }
    };
    let bytes = src.iter().flat_map(|&v| clamp(v).to_le_bytes()).collect();
    let saturated = src
        .chunks_exact(channels)
        .filter(|p| p.iter().any(|&v| v > f32::MAX))
        .count() as u64;
    (bytes, saturated)
}

/// The scalar depth clamp: NaN → 0, ±Inf → ±`f32::MAX`, everything else as it is.
fn reference_depth(v: f32) -> f32 {
    let x = if v.is_nan() { 0.0 } else { v };
    let x = if x > -f32::MAX { x } else { -f32::MAX };
    if x < f32::MAX { x } else { f32::MAX }
}

fn reference_pack(format: PixelFormat, src: &[f32]) -> (Vec<u8>, u64) {
    match format {
        PixelFormat::DepthF32 => (
            src.iter()
                .flat_map(|&v| reference_depth(v).to_le_bytes())
                .collect(),
            src.iter().filter(|v| v.is_infinite()).count() as u64,
        ),
        _ => reference_pack_nonneg(src, format.channels()),
    }
}

fn reference_unpack(format: PixelFormat, bits: u32) -> f32 {
    let v = f32::from_bits(bits);
    match format {
        PixelFormat::DepthF32 => reference_depth(v),
        _ => {
            let x = if v > 0.0 { v } else { 0.0 };
            if x < f32::MAX { x } else { f32::MAX }
        }
    }
}

const FORMATS: [PixelFormat; 3] = [
    PixelFormat::F32x6,
    PixelFormat::F32x3,
    PixelFormat::DepthF32,
];

/// Packs `src` into a buffer starting `offset` bytes into its allocation (so 0 and 1 give an
/// aligned and a misaligned payload) and compares with the reference; then unpacks the packed
/// bytes, also from `offset`, and compares with the reference reading of each pattern.
fn check(format: PixelFormat, src: &[f32], offset: usize, what: &str) {
    let (want, want_saturated) = reference_pack(format, src);
    let mut buf = vec![0xA5u8; offset + want.len()];
    let got = pack(format, src, 1.0, &mut buf[offset..]).unwrap();
    if let Some(k) = (0..want.len()).find(|&k| buf[offset + k] != want[k]) {
        let v = src[k / 4];
        panic!(
            "{format:?} {what}: pack of {v:e} ({:#010x}) differs at byte {k}",
            v.to_bits()
        );
    }
    assert_eq!(
        got.saturated, want_saturated,
        "{format:?} {what}: saturated"
    );
    // Unpack reads the input patterns themselves (any bytes are a valid payload).
    let raw: Vec<u8> = src.iter().flat_map(|v| v.to_bits().to_le_bytes()).collect();
    let mut inb = vec![0u8; offset];
    inb.extend_from_slice(&raw);
    let mut out = vec![f32::NAN; src.len()];
    unpack(format, &inb[offset..], 1.0, &mut out).unwrap();
    for (v, o) in src.iter().zip(&out) {
        let want = reference_unpack(format, v.to_bits());
        assert_eq!(
            o.to_bits(),
            want.to_bits(),
            "{format:?} {what}: unpack of {:#010x}",
            v.to_bits()
        );
    }
}

/// Values in whole pixels of `format` (the tail padded with 1.0).
fn whole_pixels(format: PixelFormat, mut v: Vec<f32>) -> Vec<f32> {
    v.resize(v.len().next_multiple_of(format.channels()), 1.0);
    v
}

/// One bit pattern in 255 (four interleaved passes with a stride of 1020), so each sign, exponent
/// and the NaN space are covered densely: 16.8 M patterns, in chunks of 1 M values.
#[test]
fn bit_space_sweep_matches_scalar() {
    for start in [0u64, 255, 510, 765] {
        let all: Vec<u32> = (start..=u64::from(u32::MAX))
            .step_by(1020)
            .map(|b| b as u32)
            .collect();
        for (n, chunk) in all.chunks(1 << 20).enumerate() {
            let vals: Vec<f32> = chunk.iter().map(|&b| f32::from_bits(b)).collect();
            for format in FORMATS {
                let v = whole_pixels(format, vals.clone());
                check(format, &v, n % 2, &format!("sweep from {start} chunk {n}"));
            }
        }
    }
}

/// Every pattern within 4096 of a boundary of the policy: ±0, the smallest subnormal and normal,
/// 1.0, ±`f32::MAX`, ±Inf and the edges of the NaN space, either sign.
#[test]
fn special_neighbourhoods_match_scalar() {
    let centres: [u32; 9] = [
        0x0000_0000,
        0x0000_0001,
        0x0080_0000,
        0x3F80_0000,
        0x7F7F_FFFF,
        0x7F80_0000,
        0x7FC0_0000,
        0x7FFF_FFFF,
        0x8000_0000,
    ];
    let mut vals = Vec::new();
    for c in centres {
        for sign in [0, 0x8000_0000u32] {
            let c = c ^ sign;
            vals.extend((c.saturating_sub(4096)..=c.saturating_add(4096)).map(f32::from_bits));
        }
    }
    vals.extend((u32::MAX - 4096..=u32::MAX).map(f32::from_bits));
    for format in FORMATS {
        let v = whole_pixels(format, vals.clone());
        check(format, &v, 0, "specials");
        check(format, &v, 3, "specials, misaligned");
    }
}

/// Saturating values (±Inf) at every density from none to all, among hostile values, in slices of
/// whole pixels from one pixel to several blocks with a ragged end: the per-block screen must count
/// exactly what the second pass counted.
#[test]
fn saturation_counts_match_scalar() {
    let mut r = ChaCha8Rng::seed_from_u64(0xF32);
    let specials = [
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::NAN,
        -f32::NAN,
        -0.0,
        f32::MAX,
        -f32::MAX,
        f32::MIN_POSITIVE / 2.0,
    ];
    for format in FORMATS {
        let ch = format.channels();
        for pixels in [1usize, 2, 255, 256, 257, 683, 4095, 4096, 4097, 9000] {
            for per_mille in [0u32, 1, 10, 100, 500, 1000] {
                let src: Vec<f32> = (0..pixels * ch)
                    .map(|_| {
                        if r.random_range(0..1000) < per_mille {
                            f32::INFINITY
                        } else if r.random_range(0..10) == 0 {
                            specials[r.random_range(0..specials.len())]
                        } else {
                            r.random_range(-4.0..4.0f32)
                        }
                    })
                    .collect();
                let what = format!("{pixels} px, {per_mille}‰ +Inf");
                check(format, &src, pixels % 4, &what);
                // The same with −Inf (saturates depth only) in place of +Inf.
                let neg: Vec<f32> = src
                    .iter()
                    .map(|&v| {
                        if v == f32::INFINITY {
                            f32::NEG_INFINITY
                        } else {
                            v
                        }
                    })
                    .collect();
                check(format, &neg, 0, &format!("{what} as -Inf"));
            }
        }
    }
}
