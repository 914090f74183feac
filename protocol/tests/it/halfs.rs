//! The half-float formats bit for bit: every half decodes to the value the policy says, and packing
//! rounds exactly as `half`'s scalar conversion of the clamped value, whether a block takes the
//! straight conversion (all values in range) or the clamping one (one value out of range), and
//! whether or not the output buffer can be viewed as halves.

use half::f16;
use lightfold_protocol::PixelFormat;
use lightfold_protocol::format::{F16_MAX, pack, unpack};

/// What unpack must give for a half: finite non-negative values exactly, +Inf → 65504, NaN and
/// anything with the sign bit → 0.
fn policy(bits: u16) -> f32 {
    let v = f16::from_bits(bits).to_f32();
    if v.is_nan() || v.is_sign_negative() {
        0.0
    } else {
        v.min(F16_MAX)
    }
}

/// What pack must write for a value: the clamped value rounded by `half`'s scalar conversion.
fn reference(v: f32) -> u16 {
    let clamped = if v > 0.0 { v.min(F16_MAX) } else { 0.0 };
    f16::from_f32(clamped).to_bits()
}

#[test]
fn every_half_unpacks_by_the_policy() {
    let all: Vec<u16> = (0..=u16::MAX).collect();
    // f16x6: 65536 halves are 10922 whole pixels and 4 halves; pad with zeros.
    let mut bytes: Vec<u8> = all.iter().flat_map(|h| h.to_le_bytes()).collect();
    bytes.resize(bytes.len().next_multiple_of(12), 0);
    let mut out = vec![f32::NAN; bytes.len() / 2];
    unpack(PixelFormat::F16x6, &bytes, 1.0, &mut out).unwrap();
    for (&h, &o) in all.iter().zip(&out) {
        assert_eq!(o.to_bits(), policy(h).to_bits(), "f16x6 {h:#06x} -> {o:e}");
    }
    // f16x4: three halves per pixel, the fourth (pad) ignored.
    let mut bytes = Vec::new();
    for chunk in all.chunks(3) {
        for c in 0..4 {
            let h = chunk.get(c).copied().unwrap_or(0x7E00);
            bytes.extend_from_slice(&h.to_le_bytes());
        }
    }
    let mut out = vec![f32::NAN; bytes.len() / 8 * 3];
    unpack(PixelFormat::F16x4, &bytes, 1.0, &mut out).unwrap();
    for (&h, &o) in all.iter().zip(&out) {
        assert_eq!(o.to_bits(), policy(h).to_bits(), "f16x4 {h:#06x} -> {o:e}");
    }
}

/// Every finite positive half, the midpoint to the next one (a tie) and one f32 step either side
/// of it: all the rounding decisions there are.
fn rounding_cases() -> Vec<f32> {
    let mut v = Vec::new();
    for bits in 0..0x7BFFu16 {
        let (lo, hi) = (
            f64::from(f16::from_bits(bits).to_f32()),
            f64::from(f16::from_bits(bits + 1).to_f32()),
        );
        let mid = ((lo + hi) / 2.0) as f32;
        v.extend([lo as f32, mid, mid.next_down(), mid.next_up()]);
    }
    v.extend([F16_MAX, 65503.99, 0.0, f32::MIN_POSITIVE, 1e-45, 1e-40]);
    v.resize(v.len().next_multiple_of(6), 1.0);
    v
}

/// Packs `src` as f16x6 into an aligned and into a misaligned buffer; checks both against the
/// reference and returns the saturated count.
fn pack_checked(src: &[f32], what: &str) -> u64 {
    let n = src.len() * 2;
    let mut aligned = vec![0u8; n];
    let stats = pack(PixelFormat::F16x6, src, 1.0, &mut aligned).unwrap();
    let mut shifted = vec![0u8; n + 1];
    let again = pack(PixelFormat::F16x6, src, 1.0, &mut shifted[1..]).unwrap();
    assert_eq!(
        stats, again,
        "{what}: saturation differs with a misaligned buffer"
    );
    assert_eq!(
        aligned[..],
        shifted[1..],
        "{what}: misaligned buffer differs"
    );
    for (i, (&v, b)) in src.iter().zip(aligned.as_chunks::<2>().0).enumerate() {
        let got = u16::from_le_bytes(*b);
        assert_eq!(
            got,
            reference(v),
            "{what}: value {i} = {v:e} packed {got:#06x}"
        );
    }
    stats.saturated
}

#[test]
fn packing_rounds_like_the_scalar_conversion() {
    let cases = rounding_cases();
    assert_eq!(pack_checked(&cases, "in range"), 0);
    // One value out of range in a block sends that block down the clamping path: the block's
    // in-range values must come out the same, and only its pixel counts as saturated.
    let outside: [(f32, bool); 8] = [
        (-0.0, false),
        (-1.0, false),
        (f32::NAN, false),
        (-f32::NAN, false),
        (f32::NEG_INFINITY, false),
        (f32::INFINITY, true),
        (65504.01, true),
        (1e30, true),
    ];
    for (k, &(bad, saturates)) in outside.iter().enumerate() {
        let mut src = cases.clone();
        // Different places in different blocks, including a block's first and last value.
        let spots = [0, 2303, 2304, 5000 + k * 97, src.len() - 1];
        for &i in &spots {
            src[i] = bad;
        }
        let expected = if saturates { spots.len() as u64 } else { 0 };
        assert_eq!(pack_checked(&src, &format!("{bad:e} inside")), expected);
    }
}

#[test]
fn padded_halves_round_the_same_and_pad_with_one() {
    let mut cases = rounding_cases();
    cases.truncate(cases.len() / 3 * 3);
    cases[7] = f32::NAN;
    cases[8] = f32::INFINITY;
    let mut bytes = vec![0u8; cases.len() / 3 * 8];
    let stats = pack(PixelFormat::F16x4, &cases, 1.0, &mut bytes).unwrap();
    assert_eq!(stats.saturated, 1);
    for (p, (px, b)) in cases.chunks(3).zip(bytes.as_chunks::<8>().0).enumerate() {
        for c in 0..4 {
            let got = u16::from_le_bytes([b[2 * c], b[2 * c + 1]]);
            let want = px.get(c).map_or(0x3C00, |&v| reference(v));
            assert_eq!(got, want, "pixel {p} channel {c}");
        }
    }
}

/// The in-loop encoder gives the F16C conversion's bits (what `pack` writes) for every f32 in
/// [0, 65504]: all 1.2e9 of them, in slices through `half`'s slice conversion.
#[test]
fn the_branch_free_encoder_matches_the_conversion_on_every_value_in_range() {
    use half::slice::HalfFloatSliceExt;
    use lightfold_protocol::format::encode_half;
    const CHUNK: u32 = 1 << 16;
    let last = F16_MAX.to_bits();
    let mut values = vec![0f32; CHUNK as usize];
    let mut want = vec![f16::ZERO; CHUNK as usize];
    let mut first = 0u32;
    while first <= last {
        let n = CHUNK.min(last - first + 1) as usize;
        for (k, v) in values[..n].iter_mut().enumerate() {
            *v = f32::from_bits(first + k as u32);
        }
        want[..n].convert_from_f32_slice(&values[..n]);
        let bad = values[..n]
            .iter()
            .zip(&want[..n])
            .position(|(v, w)| encode_half(*v) != w.to_bits());
        if let Some(k) = bad {
            let v = values[k];
            panic!(
                "{v:e} ({:#010x}): encoder {:#06x}, conversion {:#06x}",
                v.to_bits(),
                encode_half(v),
                want[k].to_bits()
            );
        }
        first += CHUNK;
    }
}
