//! Accumulate with its sum packed as it is made (`Accumulate::apply_packed_to`) against the
//! two-step path the stage used before: `apply_packed` into an f32 band, then
//! `protocol::format::pack` and the CRC-32 of the payload. Bytes, checksum, saturation count and
//! the all-zero test must agree on every instruction-set path, for every output link format,
//! on arbitrary input bytes (NaN and infinite halves, every `rgb9e5` exponent) and on bands split
//! into several rayon spans.

use crate::common;

use common::{Owned, rng};
use lightfold_compositor::ops::{
    Accumulate, Isa, OpError, PAR_SPAN, PackedIllumination, PackedOut,
};
use lightfold_protocol::format::pack;
use lightfold_protocol::{Layer, PixelFormat};
use rand::Rng;
use serde_json::json;

const OUT_FORMATS: [(PixelFormat, f32); 4] = [
    (PixelFormat::F16x6, 1.0),
    (PixelFormat::F32x6, 1.0),
    (PixelFormat::Rgb9e5x2, 1.0),
    (PixelFormat::Seed64, 40.0),
];

fn p(format: PixelFormat, bytes: &[u8]) -> Option<PackedIllumination<'_>> {
    Some(PackedIllumination {
        format,
        scale: 1.0,
        bytes,
    })
}

/// Arbitrary bytes for `pixels` pixels of `format`; with `tame`, halves and floats are kept
/// finite and small so that sums do not all saturate.
fn bytes(format: PixelFormat, pixels: usize, seed: u64, tame: bool) -> Vec<u8> {
    let mut r = rng(seed);
    let mut b: Vec<u8> = (0..pixels * format.bytes_per_pixel())
        .map(|_| r.random())
        .collect();
    if tame && format == PixelFormat::F16x6 {
        for h in b.chunks_exact_mut(2) {
            h[1] &= 0x3F; // exponent below 16: finite, positive, < 2
        }
    }
    b
}

fn two_step(
    op: &Accumulate,
    isa: Isa,
    inputs: &[Option<PackedIllumination<'_>>],
    pixels: usize,
    (format, scale): (PixelFormat, f32),
) -> (Vec<u8>, u32, u64, bool) {
    let mut sum = Owned::zeros(pixels, &[Layer::Illumination]);
    op.apply_packed_on(isa, inputs, &mut sum.view_mut())
        .unwrap();
    let values = &sum.layers[0].1;
    let mut out = vec![0u8; pixels * format.bytes_per_pixel()];
    let stats = pack(format, values, scale, &mut out).unwrap();
    let crc = crc32fast::hash(&out);
    (out, crc, stats.saturated, values.iter().any(|v| *v != 0.0))
}

#[test]
fn packed_sum_matches_sum_then_pack_on_every_isa() {
    let op = Accumulate::new(&json!({"colors": [[0.5, 1, 2], [3, 2, 1]]})).unwrap();
    let available: Vec<Isa> = Isa::ALL.into_iter().filter(|i| i.available()).collect();
    for pixels in [1, 7, 255, 257, 1023, 2 * PAR_SPAN + 77] {
        for (case, (up_fmt, tame)) in [
            (PixelFormat::F16x6, false),
            (PixelFormat::F16x6, true),
            (PixelFormat::F32x6, true),
        ]
        .into_iter()
        .enumerate()
        {
            let seed = pixels as u64 * 10 + case as u64;
            let up = bytes(up_fmt, pixels, seed, tame);
            let a = bytes(PixelFormat::Rgb9e5x2, pixels, seed + 1, tame);
            let b = bytes(PixelFormat::F16x6, pixels, seed + 2, tame);
            let inputs = [
                p(up_fmt, &up),
                p(PixelFormat::Rgb9e5x2, &a),
                p(PixelFormat::F16x6, &b),
            ];
            for out in OUT_FORMATS {
                for &isa in &available {
                    let want = two_step(&op, isa, &inputs, pixels, out);
                    let mut got = vec![0u8; want.0.len()];
                    let target = PackedOut {
                        layer: Layer::Illumination,
                        format: out.0,
                        scale: out.1,
                        bytes: &mut got,
                    };
                    let s = op.apply_packed_to_on(isa, &inputs, pixels, target).unwrap();
                    let what = format!("{pixels} px, case {case}, out {:?}, {isa}", out.0);
                    assert!(got == want.0, "{what}: bytes differ");
                    assert_eq!(s.checksum(), want.1, "{what}: checksum");
                    assert_eq!(s.saturated, want.2, "{what}: saturated");
                    assert_eq!(s.nonzero, want.3, "{what}: nonzero");
                }
            }
        }
    }
}

#[test]
fn an_all_empty_sum_is_reported_zero_and_bad_targets_are_errors() {
    let op = Accumulate::new(&json!({"colors": [[1, 1, 1]]})).unwrap();
    let pixels = 2 * PAR_SPAN + 5;
    let mut got = vec![0xAAu8; pixels * 12];
    let target = PackedOut {
        layer: Layer::Illumination,
        format: PixelFormat::F16x6,
        scale: 1.0,
        bytes: &mut got,
    };
    let s = op.apply_packed_to(&[None, None], pixels, target).unwrap();
    assert!(!s.nonzero);
    assert_eq!(s.saturated, 0);
    assert!(got.iter().all(|b| *b == 0));
    assert_eq!(s.checksum(), crc32fast::hash(&got));

    // A payload of the wrong size and a layer the operator does not make are errors.
    let mut short = vec![0u8; pixels * 12 - 1];
    let target = PackedOut {
        layer: Layer::Illumination,
        format: PixelFormat::F16x6,
        scale: 1.0,
        bytes: &mut short,
    };
    let e = op.apply_packed_to(&[None, None], pixels, target);
    assert!(matches!(e, Err(OpError::PackedOut { .. })), "{e:?}");
    let mut depth = vec![0u8; pixels * 4];
    let target = PackedOut {
        layer: Layer::Depth,
        format: PixelFormat::DepthF32,
        scale: 1.0,
        bytes: &mut depth,
    };
    let e = op.apply_packed_to(&[None, None], pixels, target);
    assert!(matches!(e, Err(OpError::MissingOutput { .. })), "{e:?}");
    // A seed64 output needs a usable scale.
    let mut seed = vec![0u8; pixels * 8];
    let target = PackedOut {
        layer: Layer::Illumination,
        format: PixelFormat::Seed64,
        scale: f32::NAN,
        bytes: &mut seed,
    };
    let e = op.apply_packed_to(&[None, None], pixels, target);
    assert!(matches!(e, Err(OpError::Pack { .. })), "{e:?}");
}

/// The stage runs a lone `join` of illumination sums as the fused accumulate of white local terms
/// (`daemon/config.rs`): that must give the join's bits, on arbitrary packed inputs (NaN, infinite
/// and negative halves and floats), with an empty band among them.
#[test]
fn a_white_accumulate_gives_the_bits_of_join() {
    use lightfold_compositor::ops::{BandView, Join, Operator};
    use lightfold_protocol::format::unpack;
    let join = Join::new(&json!({"inputs": 3})).unwrap();
    let white =
        Accumulate::new(&json!({"upstream": false, "colors": [[1, 1, 1], [1, 1, 1], [1, 1, 1]]}))
            .unwrap();
    for pixels in [1, 255, 1023, 2 * PAR_SPAN + 77] {
        let seed = pixels as u64;
        let formats = [PixelFormat::F16x6, PixelFormat::F32x6, PixelFormat::F16x6];
        let packed: Vec<Vec<u8>> = formats
            .iter()
            .enumerate()
            .map(|(i, &f)| bytes(f, pixels, seed + i as u64, false))
            .collect();
        let values: Vec<Vec<f32>> = formats
            .iter()
            .zip(&packed)
            .map(|(&f, b)| {
                let mut v = vec![0f32; pixels * 6];
                unpack(f, b, 1.0, &mut v).unwrap();
                v
            })
            .collect();
        // Input 2 arrives empty: join leaves it out, the fused path reads it as `None`.
        let views: Vec<BandView<'_>> = values[..2]
            .iter()
            .map(|v| BandView::new(pixels).with(Layer::Illumination, v))
            .chain([BandView::new(pixels)])
            .collect();
        let mut want = Owned::zeros(pixels, &[Layer::Illumination]);
        join.apply(&views, &mut want.view_mut()).unwrap();
        let inputs = [p(formats[0], &packed[0]), p(formats[1], &packed[1]), None];
        let mut got = Owned::zeros(pixels, &[Layer::Illumination]);
        white.apply_packed(&inputs, &mut got.view_mut()).unwrap();
        let same = got.layers[0]
            .1
            .iter()
            .zip(&want.layers[0].1)
            .all(|(a, b)| a.to_bits() == b.to_bits());
        assert!(same, "{pixels} px: the white accumulate differs from join");
    }
}
