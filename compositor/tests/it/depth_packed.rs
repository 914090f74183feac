//! `Depth::apply_packed` against the general path a stage runs without it: unpack every input
//! layer with `protocol::format::unpack` (zeros for an empty band), `Depth::apply`, pack every
//! output with `protocol::format::pack`, CRC-32 of the payload, saturated pixels, and whether
//! any value is not zero. Inputs are random bit patterns heavy in the words the formats treat
//! specially (NaN with either sign and any payload, ±Inf, −0, subnormals, the largest finite
//! values) and in equal depths (ties), with empty bands, pixel counts that are not a multiple of
//! the block, and a band of three rayon spans; on every instruction set this CPU has.

use lightfold_compositor::ops::{
    BandMut, BandView, Depth, Isa, OpError, Operator, PAR_SPAN, PackedLayer, PackedOut,
};
use lightfold_protocol::format::{pack, unpack};
use lightfold_protocol::{Layer, PixelFormat};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::{Value, json};

use Layer::{Depth as Z, Diffuse, Illumination as Ill};
use PixelFormat::{DepthF32, F16x4, F16x6, F32x3, F32x6};

/// One input layer as it arrived: `None` is an empty band.
#[derive(Debug, Clone)]
struct Band {
    layer: Layer,
    format: PixelFormat,
    bytes: Option<Vec<u8>>,
}

/// What one output came to: payload, CRC-32, saturated pixels, any value not zero.
type Packed = (Vec<u8>, u32, u64, bool);

/// A half's bits: mostly the special ones.
fn half(r: &mut ChaCha8Rng) -> u16 {
    let sign = if r.random_bool(0.5) { 0x8000 } else { 0 };
    match r.random_range(0..12) {
        0 => 0x7C00 | sign,
        1 => (0x7C00 | r.random_range(1..0x400)) | sign,
        2 => sign,
        3 => r.random_range(1..0x400) | sign,
        4 => 0x7BFF | sign,
        5 => r.random(),
        6 => 0x3C00,
        _ => r.random_range(0..0x7C00),
    }
}

/// An f32's bits: mostly the special ones.
fn float(r: &mut ChaCha8Rng) -> u32 {
    let sign = if r.random_bool(0.5) { 0x8000_0000 } else { 0 };
    match r.random_range(0..12) {
        0 => 0x7F80_0000 | sign,
        1 => (0x7F80_0000 | r.random_range(1..0x80_0000)) | sign,
        2 => sign,
        3 => r.random_range(1..0x80_0000) | sign,
        4 => r.random_range(0x7F7F_0000..0x7F80_0000) | sign,
        5 => r.random(),
        _ => r.random_range(0.0..4.0f32).to_bits(),
    }
}

/// A depth's bits: the specials, and a few plain values shared by all inputs so ties are common.
fn depth(r: &mut ChaCha8Rng) -> u32 {
    match r.random_range(0..10) {
        0..4 => [0.0f32, -0.0, 1.0, 2.0, -1.0][r.random_range(0..5)].to_bits(),
        4..7 => float(r),
        _ => r.random_range(-4.0..4.0f32).to_bits(),
    }
}

/// A band of `pixels` random words of `format`, empty one time in six.
fn band(layer: Layer, format: PixelFormat, pixels: usize, r: &mut ChaCha8Rng) -> Band {
    let empty = r.random_range(0..6) == 0;
    let mut bytes = Vec::with_capacity(pixels * format.bytes_per_pixel());
    for _ in 0..pixels * format.bytes_per_pixel() / word(format) {
        match format {
            DepthF32 => bytes.extend(depth(r).to_le_bytes()),
            F16x6 | F16x4 => bytes.extend(half(r).to_le_bytes()),
            _ => bytes.extend(float(r).to_le_bytes()),
        }
    }
    Band {
        layer,
        format,
        bytes: (!empty).then_some(bytes),
    }
}

fn word(format: PixelFormat) -> usize {
    if matches!(format, F16x6 | F16x4) {
        2
    } else {
        4
    }
}

/// The general path: unpack, `apply`, pack each output.
fn general(
    op: &Depth,
    inputs: &[Vec<Band>],
    outs: &[(Layer, PixelFormat)],
    px: usize,
) -> Vec<Packed> {
    let unpacked: Vec<Vec<(Layer, Vec<f32>)>> = inputs
        .iter()
        .map(|layers| {
            layers
                .iter()
                .map(|b| {
                    let mut v = vec![0f32; px * b.layer.channels()];
                    if let Some(bytes) = &b.bytes {
                        unpack(b.format, bytes, 1.0, &mut v).expect("whole pixels");
                    }
                    (b.layer, v)
                })
                .collect()
        })
        .collect();
    let views: Vec<BandView<'_>> = unpacked
        .iter()
        .map(|ls| ls.iter().fold(BandView::new(px), |v, (l, d)| v.with(*l, d)))
        .collect();
    let produced = op.signature().outputs;
    let mut bufs: Vec<Vec<f32>> = produced
        .iter()
        .map(|l| vec![0f32; px * l.channels()])
        .collect();
    let mut out = produced
        .iter()
        .zip(bufs.iter_mut())
        .fold(BandMut::new(px), |m, (l, d)| m.with(*l, d));
    op.apply(&views, &mut out).expect("well-formed band");
    outs.iter()
        .map(|&(layer, format)| {
            let values = &bufs[produced.iter().position(|l| *l == layer).expect("produced")];
            let mut bytes = vec![0u8; px * format.bytes_per_pixel()];
            let saturated = pack(format, values, 1.0, &mut bytes)
                .expect("fits")
                .saturated;
            let nonzero = values.iter().any(|v| *v != 0.0);
            let crc = crc32fast::hash(&bytes);
            (bytes, crc, saturated, nonzero)
        })
        .collect()
}

/// The inputs as the stage hands them to `apply_packed`.
fn packed_layers(inputs: &[Vec<Band>]) -> Vec<Vec<PackedLayer<'_>>> {
    inputs
        .iter()
        .map(|ls| {
            ls.iter()
                .map(|b| PackedLayer {
                    layer: b.layer,
                    format: b.format,
                    scale: 1.0,
                    bytes: b.bytes.as_deref(),
                })
                .collect()
        })
        .collect()
}

/// `apply_packed_on(isa, …)` into payloads filled with garbage first (every byte must be written).
fn fused(
    op: &Depth,
    isa: Isa,
    inputs: &[Vec<Band>],
    outs: &[(Layer, PixelFormat)],
    px: usize,
) -> Result<Vec<Packed>, OpError> {
    let layers = packed_layers(inputs);
    let mut bufs: Vec<Vec<u8>> = outs
        .iter()
        .map(|(_, f)| vec![0xA5; px * f.bytes_per_pixel()])
        .collect();
    let mut packed: Vec<PackedOut<'_>> = outs
        .iter()
        .zip(bufs.iter_mut())
        .map(|(&(layer, format), bytes)| PackedOut {
            layer,
            format,
            scale: 1.0,
            bytes,
        })
        .collect();
    let sums = op.apply_packed_on(isa, &layers, &mut packed)?;
    drop(packed);
    Ok(bufs
        .into_iter()
        .zip(sums)
        .map(|(b, s)| (b, s.checksum(), s.saturated, s.nonzero))
        .collect())
}

fn depth_op(params: Value) -> Depth {
    Depth::new(&params).expect("valid parameters")
}

/// Compares both paths on every instruction set, on one thread and on three (so a band of
/// three spans runs them in parallel).
fn compare(op: &Depth, inputs: &[Vec<Band>], outs: &[(Layer, PixelFormat)], px: usize, what: &str) {
    let want = general(op, inputs, outs, px);
    for threads in [1, 3] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        for isa in Isa::ALL.into_iter().filter(|i| i.available()) {
            let got = pool
                .install(|| fused(op, isa, inputs, outs, px))
                .expect("supported band");
            for (k, (g, w)) in got.iter().zip(&want).enumerate() {
                let ctx = format!("{what} px={px} {isa} {threads}t output {:?}", outs[k]);
                if g.0 != w.0 {
                    let at = g.0.iter().zip(&w.0).position(|(a, b)| a != b).unwrap_or(0);
                    panic!("{ctx}: payload differs first at byte {at}");
                }
                assert_eq!(
                    (g.1, g.2, g.3),
                    (w.1, w.2, w.3),
                    "{ctx}: crc, saturated, nonzero"
                );
            }
        }
    }
}

/// Pixel counts: one pixel, block remainders, and three rayon spans with a ragged last one.
fn sizes() -> [usize; 6] {
    [1, 3, 255, 257, 1001, 2 * PAR_SPAN + 77]
}

#[test]
fn illumination_matches_general_path() {
    let mut seed = 0;
    for (reversed, zero) in [(false, false), (true, false), (false, true)] {
        for n in [2usize, 3] {
            let op = depth_op(json!({"inputs": n, "reversed_z": reversed, "zero_is_empty": zero}));
            for colour in [F16x6, F32x6] {
                for px in sizes() {
                    seed += 1;
                    let mut r = ChaCha8Rng::seed_from_u64(seed);
                    let inputs: Vec<Vec<Band>> = (0..n)
                        .map(|_| vec![band(Ill, colour, px, &mut r), band(Z, DepthF32, px, &mut r)])
                        .collect();
                    let outs = [(Z, DepthF32), (Ill, colour)];
                    let what = format!("{n} inputs {colour:?} reversed={reversed} zero={zero}");
                    compare(&op, &inputs, &outs, px, &what);
                }
            }
        }
    }
}

#[test]
fn several_layers_in_any_order_match_general_path() {
    let mut seed = 1000;
    for (reversed, zero) in [(false, false), (true, false), (false, true)] {
        let op = depth_op(json!({"inputs": 3, "layers": ["illumination", "diffuse"],
            "reversed_z": reversed, "zero_is_empty": zero}));
        for (ill, dif) in [(F16x6, F16x4), (F32x6, F32x3), (F16x6, F32x3)] {
            for px in [7, 513, 2 * PAR_SPAN + 77] {
                seed += 1;
                let mut r = ChaCha8Rng::seed_from_u64(seed);
                let inputs: Vec<Vec<Band>> = (0..3)
                    .map(|i| {
                        let mut ls = vec![
                            band(Ill, ill, px, &mut r),
                            band(Z, DepthF32, px, &mut r),
                            band(Diffuse, dif, px, &mut r),
                        ];
                        ls.rotate_left(i);
                        ls
                    })
                    .collect();
                let what = format!("{ill:?}+{dif:?} reversed={reversed}");
                compare(
                    &op,
                    &inputs,
                    &[(Diffuse, dif), (Z, DepthF32), (Ill, ill)],
                    px,
                    &what,
                );
                compare(&op, &inputs, &[(Ill, ill)], px, &what);
            }
        }
    }
}

/// All-empty inputs and −0 depths give all-zero outputs (sent as empty bands): the zero test
/// must agree, and depth's −0 must keep its bits (`depth32` keeps the sign) yet count as zero.
#[test]
fn zero_outputs_match_general_path() {
    let px = 300;
    let op = depth_op(json!({"inputs": 2}));
    let empty = |layer, format| Band {
        layer,
        format,
        bytes: None,
    };
    let inputs = vec![vec![empty(Ill, F16x6), empty(Z, DepthF32)]; 2];
    let outs = [(Z, DepthF32), (Ill, F16x6)];
    compare(&op, &inputs, &outs, px, "all empty");
    let got = fused(&op, Isa::best(), &inputs, &outs, px).expect("supported");
    assert!(
        got.iter().all(|o| !o.3),
        "all-empty inputs gave a nonzero output"
    );

    let minus_zero: Vec<u8> = (0..px).flat_map(|_| (-0.0f32).to_le_bytes()).collect();
    let nan_colour: Vec<u8> = (0..px * 6).flat_map(|_| 0xFE00u16.to_le_bytes()).collect();
    let input = |z: &[u8]| {
        vec![
            Band {
                layer: Ill,
                format: F16x6,
                bytes: Some(nan_colour.clone()),
            },
            Band {
                layer: Z,
                format: DepthF32,
                bytes: Some(z.to_vec()),
            },
        ]
    };
    let inputs = vec![
        input(&minus_zero),
        vec![empty(Ill, F16x6), empty(Z, DepthF32)],
    ];
    compare(&op, &inputs, &outs, px, "minus zero");
    let got = fused(&op, Isa::best(), &inputs, &outs, px).expect("supported");
    assert!(
        got.iter().all(|o| !o.3),
        "-0 depths and NaN colour gave a nonzero output"
    );
    assert_eq!(
        got[0].0, minus_zero,
        "the tie goes to input 0, whose -0 travels as read"
    );

    // `f16x4` material whose channels are all −0 still carries a pad of 1.0: not a value.
    let op = depth_op(json!({"inputs": 2, "layers": ["diffuse"]}));
    let pads: Vec<u8> = (0..px)
        .flat_map(|_| [0x8000u16, 0x8000, 0x8000, 0x3C00])
        .flat_map(u16::to_le_bytes)
        .collect();
    let input = || {
        vec![
            Band {
                layer: Diffuse,
                format: F16x4,
                bytes: Some(pads.clone()),
            },
            empty(Z, DepthF32),
        ]
    };
    let outs = [(Diffuse, F16x4)];
    compare(&op, &[input(), input()], &outs, px, "pads only");
    let got = fused(&op, Isa::best(), &[input(), input()], &outs, px).expect("supported");
    assert!(!got[0].3, "a pad counted as a value");
}

#[test]
fn packed_supported_refuses_formats_a_byte_select_cannot_reproduce() {
    let op = depth_op(json!({"inputs": 2}));
    let both = |ill: PixelFormat| vec![vec![(Ill, ill), (Z, DepthF32)]; 2];
    let std_out = [(Z, DepthF32), (Ill, F16x6)];
    assert!(op.packed_supported(&both(F16x6), &std_out));
    assert!(op.packed_supported(&both(F16x6), &[(Ill, F16x6)]));
    assert!(op.packed_supported(&both(F16x6), &[]));
    assert!(op.packed_supported(&both(F32x6), &[(Ill, F32x6), (Z, DepthF32)]));

    // A different output format is a conversion, not a select.
    assert!(!op.packed_supported(&both(F16x6), &[(Ill, F32x6)]));
    assert!(!op.packed_supported(&both(F32x6), &[(Ill, F16x6)]));
    // Quantised or scaled formats do not round-trip bit for bit.
    for f in [PixelFormat::Seed64, PixelFormat::Rgb9e5x2] {
        assert!(!op.packed_supported(&both(f), &[(Ill, f)]), "{f:?}");
    }
    // Inputs in different formats.
    let mixed = vec![
        vec![(Ill, F16x6), (Z, DepthF32)],
        vec![(Ill, F32x6), (Z, DepthF32)],
    ];
    assert!(!op.packed_supported(&mixed, &[(Ill, F16x6)]));
    // Wrong input count, missing layers, an extra or doubled layer.
    assert!(!op.packed_supported(&both(F16x6)[..1], &std_out));
    let no_depth = vec![vec![(Ill, F16x6), (Z, DepthF32)], vec![(Ill, F16x6)]];
    assert!(!op.packed_supported(&no_depth, &std_out));
    let no_ill = vec![vec![(Ill, F16x6), (Z, DepthF32)], vec![(Z, DepthF32)]];
    assert!(!op.packed_supported(&no_ill, &std_out));
    let extra = vec![vec![(Ill, F16x6), (Z, DepthF32), (Diffuse, F16x4)]; 2];
    assert!(!op.packed_supported(&extra, &std_out));
    let twice = vec![vec![(Ill, F16x6), (Z, DepthF32), (Ill, F16x6)]; 2];
    assert!(!op.packed_supported(&twice, &std_out));
    // Outputs the operator does not make, or listed twice.
    assert!(!op.packed_supported(&both(F16x6), &[(Diffuse, F16x4)]));
    assert!(!op.packed_supported(&both(F16x6), &[(Ill, F16x6), (Ill, F16x6)]));

    let op = depth_op(json!({"inputs": 2, "layers": ["illumination", "diffuse"]}));
    let with = |dif: PixelFormat| vec![vec![(Ill, F16x6), (Z, DepthF32), (Diffuse, dif)]; 2];
    for dif in [F16x4, F32x3] {
        assert!(op.packed_supported(&with(dif), &[(Diffuse, dif), (Ill, F16x6)]));
    }
    for dif in [PixelFormat::Rgba8Linear, PixelFormat::Rgba8Srgb] {
        assert!(
            !op.packed_supported(&with(dif), &[(Diffuse, dif)]),
            "{dif:?}"
        );
    }
}

#[test]
fn apply_packed_refuses_what_it_cannot_do() {
    let px = 10;
    let op = depth_op(json!({"inputs": 2}));
    let mut r = ChaCha8Rng::seed_from_u64(9);
    let input = |f, r: &mut ChaCha8Rng| vec![band(Ill, f, px, r), band(Z, DepthF32, px, r)];
    let inputs = vec![input(F16x6, &mut r), input(F16x6, &mut r)];
    let outs = [(Z, DepthF32), (Ill, F16x6)];

    let err = fused(&op, Isa::Baseline, &inputs, &[(Ill, F32x6)], px).unwrap_err();
    assert!(
        matches!(
            err,
            OpError::PackedFormat {
                layer: Ill,
                format: F32x6,
                ..
            }
        ),
        "{err}"
    );
    let seed = vec![
        input(PixelFormat::Seed64, &mut r),
        input(PixelFormat::Seed64, &mut r),
    ];
    let err = fused(&op, Isa::Baseline, &seed, &[(Z, DepthF32)], px).unwrap_err();
    assert!(matches!(err, OpError::PackedFormat { .. }), "{err}");

    // An input band of the wrong length.
    let mut short = inputs.clone();
    short[1][0].bytes = Some(vec![0u8; (px - 1) * 12]);
    let err = fused(&op, Isa::Baseline, &short, &outs, px).unwrap_err();
    assert!(matches!(err, OpError::Packed { input: 1, .. }), "{err}");

    // Outputs of different pixel counts.
    let layers = packed_layers(&inputs);
    let (mut z, mut ill) = (vec![0u8; px * 4], vec![0u8; (px + 1) * 12]);
    let mut bad = [
        PackedOut {
            layer: Z,
            format: DepthF32,
            scale: 1.0,
            bytes: &mut z,
        },
        PackedOut {
            layer: Ill,
            format: F16x6,
            scale: 1.0,
            bytes: &mut ill,
        },
    ];
    let err = op.apply_packed(&layers, &mut bad).unwrap_err();
    assert!(
        matches!(err, OpError::PackedOut { layer: Ill, .. }),
        "{err}"
    );
    assert!(
        op.apply_packed(&layers, &mut [])
            .expect("nothing to do")
            .is_empty()
    );

    if let Some(isa) = Isa::ALL.into_iter().find(|i| !i.available()) {
        let err = fused(&op, isa, &inputs, &outs, px).unwrap_err();
        assert_eq!(err, OpError::IsaUnavailable { isa });
    }
}
