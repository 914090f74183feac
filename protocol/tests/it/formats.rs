//! Pixel formats: every round trip stays within the documented bound, the bound is tight (the
//! worst observed quantisation error is at least half of it), special values land where the docs
//! say, saturation is counted per pixel, and no byte pattern unpacks to NaN.

use lightfold_protocol::PixelFormat;
use lightfold_protocol::format::{
    FormatError, channel_bound, clamp_to_range, pack, quantisation_bound, unpack,
};
use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const SCALES: [f32; 5] = [1e-3, 0.75, 1.0, 37.5, 1.0e4];

/// Top of the format's range (what +Inf becomes).
fn range_max(format: PixelFormat, scale: f32) -> f32 {
    clamp_to_range(format, f32::INFINITY, scale)
}

/// One input value: wide log-uniform magnitudes (1e-8..1e8), dense in-range values, values near
/// the top of the range, negatives, and the special values.
fn sample(rng: &mut ChaCha8Rng, format: PixelFormat, scale: f32) -> f32 {
    let top = range_max(format, scale).min(1e30);
    let log_uniform =
        |rng: &mut ChaCha8Rng, lo: f32, hi: f32| (rng.random_range(lo.ln()..hi.ln())).exp();
    match rng.random_range(0..100) {
        0..40 => log_uniform(rng, 1e-8, 1e8),
        40..65 => rng.random_range(0.0..=top),
        65..75 => log_uniform(rng, 1e-12_f32.max(top * 1e-9), top),
        75..82 => top * rng.random_range(0.99..1.01),
        82..90 => -log_uniform(rng, 1e-8, 1e8),
        _ => {
            const SPECIAL: [f32; 14] = [
                0.0,
                -0.0,
                f32::NAN,
                f32::INFINITY,
                f32::NEG_INFINITY,
                1e-45,
                1e-40,
                f32::MIN_POSITIVE,
                f32::MAX,
                -f32::MAX,
                6.0e-8,
                5.9604645e-8,
                65504.0,
                65408.0,
            ];
            SPECIAL[rng.random_range(0..SPECIAL.len())]
        }
    }
}

/// Worst quantisation error / quantisation bound seen, per channel.
#[derive(Default)]
struct Tightness {
    worst: [f64; 6],
}

/// Packs and unpacks `pixels`, checks every channel against the bound and the special-value
/// rules, and the saturation count; records the tightness of in-range channels.
fn check(
    format: PixelFormat,
    scale: f32,
    src: &[f32],
    tight: &mut Tightness,
) -> Result<(), String> {
    let ch = format.channels();
    let n = src.len() / ch;
    let mut packed = vec![0u8; n * format.bytes_per_pixel()];
    let stats = pack(format, src, scale, &mut packed).map_err(|e| e.to_string())?;
    let mut out = vec![f32::NAN; src.len()];
    unpack(format, &packed, scale, &mut out).map_err(|e| e.to_string())?;
    let top = range_max(format, scale);
    let mut saturated = 0;
    for (p, (inp, got)) in src.chunks(ch).zip(out.chunks(ch)).enumerate() {
        // Depth also saturates −Inf to −f32::MAX; elsewhere negatives are clamped, not saturated.
        let depth = format == PixelFormat::DepthF32;
        saturated += u64::from(
            inp.iter()
                .any(|&v| v > top || (depth && v == f32::NEG_INFINITY)),
        );
        for c in 0..ch {
            let (v, o) = (inp[c], got[c]);
            let ctx = || format!("{format:?} scale {scale} pixel {p} channel {c}: {v:e} -> {o:e}");
            if !o.is_finite() {
                return Err(format!("non-finite output: {}", ctx()));
            }
            if format != PixelFormat::DepthF32 && o < 0.0 {
                return Err(format!("negative output: {}", ctx()));
            }
            if v.is_nan() {
                if o != 0.0 {
                    return Err(format!("NaN must become 0: {}", ctx()));
                }
                continue;
            }
            if v.is_infinite() {
                if o != clamp_to_range(format, v, scale) {
                    return Err(format!("infinity must saturate: {}", ctx()));
                }
                continue;
            }
            // Shared-exponent formats quantise against the triple's largest clamped channel.
            let q = if format == PixelFormat::Rgb9e5x2 {
                let triple = &inp[c / 3 * 3..c / 3 * 3 + 3];
                let m = triple
                    .iter()
                    .map(|&x| clamp_to_range(format, x, scale))
                    .fold(0.0f32, f32::max);
                quantisation_bound(format, c, m, scale)
            } else {
                quantisation_bound(format, c, v, scale)
            };
            let clamped = clamp_to_range(format, v, scale);
            let err = (f64::from(o) - f64::from(v)).abs();
            let allowed = (f64::from(v) - f64::from(clamped)).abs() + f64::from(q);
            if err > allowed {
                return Err(format!("error {err:e} above bound {allowed:e}: {}", ctx()));
            }
            // The public bound agrees (for rgb9e5x2 it needs the triple's maximum instead).
            let public = f64::from(channel_bound(format, c, v, scale));
            if format != PixelFormat::Rgb9e5x2 && err > public {
                return Err(format!(
                    "error {err:e} above channel_bound {public:e}: {}",
                    ctx()
                ));
            }
            if clamped == v {
                if q == 0.0 {
                    if err != 0.0 {
                        return Err(format!("exact format lost precision: {}", ctx()));
                    }
                } else {
                    tight.worst[c] = tight.worst[c].max(err / f64::from(q));
                }
            }
        }
    }
    if stats.saturated != saturated {
        return Err(format!(
            "{format:?}: {} saturated pixels counted, {saturated} expected",
            stats.saturated
        ));
    }
    Ok(())
}

fn scales_for(format: PixelFormat) -> &'static [f32] {
    if format == PixelFormat::Seed64 {
        &SCALES
    } else {
        &SCALES[2..3]
    }
}

#[test]
fn round_trips_within_tight_bounds() {
    let mut rng = ChaCha8Rng::seed_from_u64(0x5eed);
    for format in PixelFormat::ALL {
        let mut tight = Tightness::default();
        for &scale in scales_for(format) {
            for _ in 0..8 {
                let src: Vec<f32> = (0..4096 * format.channels())
                    .map(|_| sample(&mut rng, format, scale))
                    .collect();
                check(format, scale, &src, &mut tight).unwrap();
            }
        }
        let exact = matches!(
            format,
            PixelFormat::F32x6 | PixelFormat::F32x3 | PixelFormat::DepthF32
        );
        for c in 0..format.channels() {
            let worst = tight.worst[c];
            if exact {
                // `check` already failed on any in-range error above zero.
                println!("{:>10} channel {c}: exact", format.name());
                continue;
            }
            println!(
                "{:>10} channel {c}: worst in-range error = {worst:.4} of the bound",
                format.name()
            );
            assert!(worst <= 1.0, "{format:?} channel {c}: {worst}");
            assert!(
                worst >= 0.5,
                "{format:?} channel {c}: bound is loose, worst case only {worst} of it"
            );
        }
    }
}

#[test]
fn unpack_of_any_bytes_is_finite_and_in_range() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for format in PixelFormat::ALL {
        let mut bytes = vec![0u8; 20_000 * format.bytes_per_pixel()];
        rng.fill(&mut bytes[..]);
        // Every special f32/f16 bit pattern too.
        for (i, b) in bytes.iter_mut().take(64).enumerate() {
            *b = if i % 2 == 0 { 0xFF } else { 0x7F };
        }
        let mut out = vec![0f32; 20_000 * format.channels()];
        unpack(format, &bytes, 3.0, &mut out).unwrap();
        let top = range_max(format, 3.0);
        let bottom = clamp_to_range(format, f32::NEG_INFINITY, 3.0);
        for &o in &out {
            assert!(o.is_finite() && o >= bottom && o <= top, "{format:?}: {o}");
        }
    }
}

#[test]
fn lengths_and_scales_are_checked() {
    let f = PixelFormat::Seed64;
    let mut dst = [0u8; 16];
    assert!(matches!(
        pack(f, &[0.0; 7], 1.0, &mut dst),
        Err(FormatError::SrcLength { .. })
    ));
    assert!(matches!(
        pack(f, &[0.0; 6], 1.0, &mut dst),
        Err(FormatError::PixelCount {
            expected: 1,
            actual: 2,
            ..
        })
    ));
    assert!(matches!(
        pack(f, &[0.0; 12], 1.0, &mut dst[..15]),
        Err(FormatError::PackedLength { .. })
    ));
    for scale in [0.0, -1.0, f32::NAN, f32::INFINITY] {
        assert!(
            matches!(
                pack(f, &[0.0; 12], scale, &mut dst),
                Err(FormatError::BadScale { .. })
            ),
            "{scale}"
        );
    }
    let mut out = [1f32; 12];
    unpack(f, &dst, 0.0, &mut out).unwrap();
    assert!(matches!(
        unpack(f, &dst, -1.0, &mut out),
        Err(FormatError::BadScale { .. })
    ));
}

/// Any value, biased towards the interesting ones.
fn any_value() -> impl Strategy<Value = f32> {
    prop_oneof![
        4 => (-8.0f64..8.0).prop_map(|e| 10f64.powf(e) as f32),
        2 => any::<f32>(),
        1 => (0u32..0x0080_0000).prop_map(f32::from_bits),
        1 => prop::sample::select(vec![0.0, -0.0, f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 1.0, 65504.0, 65408.0]),
        1 => (-8.0f64..8.0).prop_map(|e| -(10f64.powf(e) as f32)),
    ]
}

proptest! {
    #[test]
    fn every_format_round_trips_within_bound(
        format in prop::sample::select(PixelFormat::ALL.to_vec()),
        scale in prop::sample::select(SCALES.to_vec()),
        pixels in prop::collection::vec(prop::array::uniform6(any_value()), 1..40),
    ) {
        let src: Vec<f32> = pixels.iter().flat_map(|p| p[..format.channels()].to_vec()).collect();
        let mut tight = Tightness::default();
        if let Err(e) = check(format, scale, &src, &mut tight) {
            prop_assert!(false, "{}", e);
        }
    }
}
