//! Fast versions against the scalar references on random bands with odd widths and hostile
//! values (NaN, ±Inf, negatives, subnormals, values that overflow when summed). Every operator is
//! held to the same bits, on one thread and with the band split across the rayon pool.

use crate::common;

use common::{Owned, assert_same_bits, hostile, rng, run};
use lightfold_compositor::ops::{self, Operator, Output, PAR_SPAN};
use lightfold_protocol::Layer;
use serde_json::{Value, json};

/// Widths that exercise the vector remainders, one pixel, and a band large enough to be split
/// into parallel spans with a ragged last span.
fn widths() -> Vec<usize> {
    vec![1, 2, 3, 5, 7, 13, 31, 255, 257, 1023, 2 * PAR_SPAN + 77]
}

/// Random inputs for `op`: required layers always, optional ones present two times in three.
fn inputs_for(op: &dyn Operator, pixels: usize, seed: u64) -> Vec<Owned> {
    let mut r = rng(seed);
    op.signature()
        .inputs
        .iter()
        .enumerate()
        .map(|(i, spec)| {
            let mut layers = spec.required.clone();
            for &l in &spec.optional {
                if !(seed + i as u64).is_multiple_of(3) {
                    layers.push(l);
                }
            }
            Owned::random(pixels, &layers, &mut r, hostile)
        })
        .collect()
}

fn differential(name: &str, params: Value) {
    let op = ops::create(name, &params).unwrap();
    for (n, pixels) in widths().into_iter().enumerate() {
        for seed in 0..3u64 {
            let inputs = inputs_for(&*op, pixels, seed * 100 + n as u64);
            let fast = run(&*op, &inputs, pixels, false);
            let reference = run(&*op, &inputs, pixels, true);
            assert_same_bits(&fast, &reference, &format!("{name} {params} w={pixels}"));
            // Colour is never NaN; `merge` copies depth as given (the `depth` operator reads it).
            for (_, d) in fast.layers.iter().filter(|(l, _)| *l != Layer::Depth) {
                assert!(d.iter().all(|v| !v.is_nan()), "{name}: NaN out");
            }
        }
    }
}

#[test]
fn accumulate_matches_reference() {
    differential("accumulate", json!({"colors": [[0.5, 1, 2]]}));
    differential(
        "accumulate",
        json!({"upstream": false, "colors": [[0.3, 0.7, 1.1], [2, 2, 2], [0, 1, 3e37]]}),
    );
    differential(
        "accumulate",
        json!({"colors": [[0.3, 0.7, 1.1], {"diffuse": [1, 2, 3], "specular": [0.1, 0.2, 0.3]}],
               "specular_color": [0.9, 0.5, 0.1], "ambient": {"input": 2}}),
    );
    differential(
        "accumulate",
        json!({"colors": [[0.3, 0.7, 1.1], [1, 1, 1]], "ambient": {"input": 1, "mask": "layer"}}),
    );
}

#[test]
fn material_matches_reference() {
    differential("material", json!({"stage": "specular"}));
    differential("material", json!({"stage": "diffuse"}));
    differential(
        "material",
        json!({"stage": "ambient", "ambient_color": [0.1, 0.2, 0.3]}),
    );
    differential("material", json!({"stage": "emissive"}));
    differential("material", json!({"stage": "single"}));
    differential(
        "material",
        json!({"stage": "single", "specular": true, "emissive": true, "ambient_color": [0.1, 0.2, 0.3]}),
    );
    differential("material", json!({"stage": "single", "emissive": true}));
}

#[test]
fn depth_matches_reference() {
    differential("depth", json!({"inputs": 1}));
    differential(
        "depth",
        json!({"inputs": 4, "layers": ["illumination", "diffuse", "specular"]}),
    );
    differential(
        "depth",
        json!({"inputs": 3, "layers": ["radiance"], "reversed_z": true}),
    );
}

/// Every instruction-set path of the depth select (`ops::dispatch`) gives the reference bits:
/// one to five inputs, forward and reversed Z, carried layers of 3 and 6 channels, hostile depths
/// and colours, ties (depths drawn from a handful of values, empty pixels included).
#[test]
fn depth_every_isa_matches_reference() {
    use lightfold_compositor::ops::{Depth, Isa, OpError};
    use lightfold_protocol::Layer;
    use rand::Rng;

    let available: Vec<Isa> = Isa::ALL.into_iter().filter(|i| i.available()).collect();
    for isa in Isa::ALL.into_iter().filter(|i| !i.available()) {
        eprintln!("this cpu lacks {isa}: that path is not tested here");
        let op = Depth::new(&json!({"inputs": 1})).unwrap();
        let src = Owned::zeros(1, &[Layer::Depth, Layer::Illumination]);
        let mut out = Owned::zeros(1, &[Layer::Depth, Layer::Illumination]);
        let e = op.apply_on(isa, &[src.view()], &mut out.view_mut());
        assert!(matches!(e, Err(OpError::IsaUnavailable { .. })), "{e:?}");
    }
    assert!(available.contains(&Isa::Baseline) && available.contains(&Isa::best()));
    let few = [
        f32::NAN,
        f32::INFINITY,
        0.0,
        -0.0,
        1.0,
        2.0,
        -1.0,
        f32::NEG_INFINITY,
    ];
    for inputs in 1..=5usize {
        for (reversed, zero_is_empty) in [(false, false), (true, false), (false, true)] {
            let layers = if inputs % 2 == 0 {
                vec!["illumination", "diffuse"]
            } else {
                vec!["radiance", "illumination", "specular"]
            };
            let params = json!({"inputs": inputs, "layers": layers, "reversed_z": reversed,
                "zero_is_empty": zero_is_empty});
            let op = Depth::new(&params).unwrap();
            for (n, pixels) in widths().into_iter().enumerate() {
                let mut all = inputs_for(&op, pixels, 500 + n as u64);
                // Half the cases draw depths from a few values, so ties are common.
                if n % 2 == 1 {
                    let mut r = rng(n as u64);
                    for o in &mut all {
                        for (l, d) in &mut o.layers {
                            if *l == Layer::Depth {
                                d.iter_mut()
                                    .for_each(|z| *z = few[r.random_range(0..few.len())]);
                            }
                        }
                    }
                }
                let want = run(&op, &all, pixels, true);
                for &isa in &available {
                    let views: Vec<_> = all.iter().map(|o| o.view()).collect();
                    let mut got = Owned::zeros(
                        pixels,
                        &want.layers.iter().map(|(l, _)| *l).collect::<Vec<_>>(),
                    );
                    op.apply_on(isa, &views, &mut got.view_mut()).unwrap();
                    assert_same_bits(&got, &want, &format!("{params} w={pixels} on {isa}"));
                }
            }
        }
    }
}

#[test]
fn merge_matches_reference() {
    differential("merge", json!({"inputs": [["illumination"]]}));
    differential(
        "merge",
        json!({"inputs": [["illumination"], ["depth", "diffuse", "specular"], ["emissive"]]}),
    );
}

#[test]
fn blend_matches_reference() {
    differential("blend", json!({"inputs": 2}));
    differential("blend", json!({"inputs": 5}));
}

#[test]
fn join_matches_reference() {
    differential("join", json!({"inputs": 1}));
    differential("join", json!({"inputs": 5}));
    differential("join", json!({"inputs": 2, "layer": "radiance"}));
}

#[test]
fn output_matches_reference() {
    differential("output", json!({"exposure": 0.7}));
}

/// The fast sRGB encoder gives the reference bytes: on a sweep through every 251st float of
/// [0, 1], around every code threshold, and on hostile values, at two exposures.
#[test]
fn srgb8_matches_reference() {
    let mut lin: Vec<f32> = (0..=1.0f32.to_bits())
        .step_by(251)
        .map(f32::from_bits)
        .collect();
    // Around each code boundary, found by a coarse scan of the reference.
    let mut prev = ops::output::srgb8(0.0);
    for i in 0..=200_000u32 {
        let x = i as f32 / 200_000.0;
        let c = ops::output::srgb8(x);
        if c != prev {
            let b = x.to_bits();
            lin.extend((b.saturating_sub(2000)..b + 2000).map(f32::from_bits));
            prev = c;
        }
    }
    let mut r = rng(7);
    lin.extend((0..100_000).map(|_| hostile(&mut r)));
    lin.extend([1.0, 1.0 + f32::EPSILON, 2.0, f32::MAX]);
    lin.truncate(lin.len() / 3 * 3);
    for exposure in [1.0, 3.3] {
        let op = Output::new(&json!({ "exposure": exposure })).unwrap();
        let mut fast = vec![0u8; lin.len()];
        let mut reference = vec![0u8; lin.len()];
        op.encode_srgb8(&lin, &mut fast).unwrap();
        op.encode_srgb8_scalar(&lin, &mut reference).unwrap();
        if let Some(k) = (0..lin.len()).find(|&k| fast[k] != reference[k]) {
            panic!(
                "exposure {exposure}: {:e} → fast {} reference {}",
                lin[k], fast[k], reference[k]
            );
        }
    }
}

/// The split across rayon spans changes nothing: one thread and the pool give the same bits.
#[test]
fn one_thread_and_pool_agree() {
    let op = ops::create("accumulate", &json!({"colors": [[0.5, 1, 2], [1, 1, 1]]})).unwrap();
    let pixels = 3 * PAR_SPAN + 5;
    let inputs = inputs_for(&*op, pixels, 11);
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let many = rayon::ThreadPoolBuilder::new()
        .num_threads(3)
        .build()
        .unwrap();
    let a = one.install(|| run(&*op, &inputs, pixels, false));
    let b = many.install(|| run(&*op, &inputs, pixels, false));
    assert_same_bits(&a, &b, "threads");
}

/// Fused unpack + accumulate gives the bits of unpacking every band and then accumulating.
#[test]
fn packed_accumulate_matches_unpack_then_apply() {
    use lightfold_compositor::ops::{Accumulate, OpError, PackedIllumination};
    use lightfold_protocol::format::{pack, unpack};
    use lightfold_protocol::{Layer, PixelFormat};

    let op = Accumulate::new(&json!({"colors": [[0.5, 1, 2], [1, 1, 1], [3, 2, 1]],
                                     "ambient": {"input": 2}}))
    .unwrap();
    for format in [
        PixelFormat::Rgb9e5x2,
        PixelFormat::Seed64,
        PixelFormat::F16x6,
        PixelFormat::F32x6,
    ] {
        for (n, pixels) in widths().into_iter().enumerate() {
            let scale = 3.0;
            let mut r = rng(n as u64);
            let raw: Vec<Owned> = (0..4)
                .map(|_| Owned::random(pixels, &[Layer::Illumination], &mut r, hostile))
                .collect();
            let packed: Vec<Vec<u8>> = raw
                .iter()
                .map(|o| {
                    let mut b = vec![0u8; pixels * format.bytes_per_pixel()];
                    pack(format, o.layer(Layer::Illumination), scale, &mut b).unwrap();
                    b
                })
                .collect();
            // Input 3 is an empty band.
            let unpacked: Vec<Owned> = packed
                .iter()
                .enumerate()
                .map(|(i, b)| {
                    if i == 3 {
                        return Owned::zeros(pixels, &[]);
                    }
                    let mut v = vec![0f32; pixels * 6];
                    unpack(format, b, scale, &mut v).unwrap();
                    Owned {
                        pixels,
                        layers: vec![(Layer::Illumination, v)],
                    }
                })
                .collect();
            let want = run(&op, &unpacked, pixels, false);
            let views: Vec<Option<PackedIllumination<'_>>> = packed
                .iter()
                .enumerate()
                .map(|(i, b)| {
                    (i != 3).then_some(PackedIllumination {
                        format,
                        scale,
                        bytes: b,
                    })
                })
                .collect();
            let mut got = Owned::zeros(pixels, &[Layer::Illumination]);
            op.apply_packed(&views, &mut got.view_mut()).unwrap();
            assert_same_bits(&got, &want, &format!("{format:?} w={pixels}"));
        }
    }
    // Malformed packed input is an error, not a panic.
    let mut out = Owned::zeros(2, &[Layer::Illumination]);
    let short = PackedIllumination {
        format: PixelFormat::F16x6,
        scale: 1.0,
        bytes: &[0u8; 13],
    };
    let e = op.apply_packed(&[None, Some(short), None, None], &mut out.view_mut());
    assert!(matches!(e, Err(OpError::Packed { input: 1, .. })), "{e:?}");
    let bad_scale = PackedIllumination {
        format: PixelFormat::Seed64,
        scale: f32::NAN,
        bytes: &[0u8; 16],
    };
    let e = op.apply_packed(&[Some(bad_scale), None, None, None], &mut out.view_mut());
    assert!(matches!(e, Err(OpError::Packed { input: 0, .. })), "{e:?}");
    let material = PackedIllumination {
        format: PixelFormat::F32x3,
        scale: 1.0,
        bytes: &[0u8; 24],
    };
    let e = op.apply_packed(&[None, Some(material), None, None], &mut out.view_mut());
    assert!(matches!(e, Err(OpError::MissingLayer { .. })), "{e:?}");
    assert!(op.apply_packed(&[None], &mut out.view_mut()).is_err());
}

/// Every instruction-set path of the fused decode (`ops::dispatch`) gives the bits of unpacking
/// and then accumulating: on arbitrary bytes (every exponent, every code, the spare bit), with
/// and without the eq. 6 folding, and for `seed64` scales whose lane factors are exact (decoded
/// directly), with subnormal lane factors (1e-31: staged through `unpack` instead), subnormal
/// factors or zero.
#[test]
fn packed_accumulate_every_isa_matches_unpack_then_apply() {
    use lightfold_compositor::ops::{Accumulate, Isa, OpError, PackedIllumination};
    use lightfold_protocol::format::unpack;
    use lightfold_protocol::{Layer, PixelFormat};
    use rand::Rng;

    let ops = [
        Accumulate::new(&json!({"colors": [[0.5, 1, 2], [3, 2, 1]]})).unwrap(),
        Accumulate::new(
            &json!({"upstream": false, "colors": [[0.3, 0.7, 1.1], [2, 2, 2], [1, 0, 3e37]],
                                "ambient": {"input": 1}}),
        )
        .unwrap(),
    ];
    let available: Vec<Isa> = Isa::ALL.into_iter().filter(|i| i.available()).collect();
    for isa in Isa::ALL.into_iter().filter(|i| !i.available()) {
        eprintln!("this cpu lacks {isa}: that path is not tested here");
        let mut out = Owned::zeros(1, &[Layer::Illumination]);
        let e = ops[0].apply_packed_on(isa, &[None, None, None], &mut out.view_mut());
        assert!(matches!(e, Err(OpError::IsaUnavailable { .. })), "{e:?}");
    }
    assert!(available.contains(&Isa::Baseline) && available.contains(&Isa::best()));
    let cases = [
        (PixelFormat::Rgb9e5x2, 1.0),
        (PixelFormat::Seed64, 3.0),
        (PixelFormat::Seed64, 1e-31),
        (PixelFormat::Seed64, 7.5e-37),
        (PixelFormat::Seed64, 0.0),
    ];
    for (format, scale) in cases {
        for (n, pixels) in widths().into_iter().enumerate() {
            let mut r = rng(1000 + n as u64);
            let bytes: Vec<Vec<u8>> = (0..3)
                .map(|_| (0..pixels * 8).map(|_| r.random::<u8>()).collect())
                .collect();
            let unpacked: Vec<Owned> = bytes
                .iter()
                .map(|b| {
                    let mut v = vec![0f32; pixels * 6];
                    unpack(format, b, scale, &mut v).unwrap();
                    Owned {
                        pixels,
                        layers: vec![(Layer::Illumination, v)],
                    }
                })
                .collect();
            let views: Vec<Option<PackedIllumination<'_>>> = bytes
                .iter()
                .map(|b| {
                    Some(PackedIllumination {
                        format,
                        scale,
                        bytes: b,
                    })
                })
                .collect();
            for (k, op) in ops.iter().enumerate() {
                let want = run(op, &unpacked, pixels, false);
                for &isa in &available {
                    let mut got = Owned::zeros(pixels, &[Layer::Illumination]);
                    op.apply_packed_on(isa, &views, &mut got.view_mut())
                        .unwrap();
                    let what = format!("op {k} {format:?} scale {scale} w={pixels} on {isa}");
                    assert_same_bits(&got, &want, &what);
                }
            }
        }
    }
}
