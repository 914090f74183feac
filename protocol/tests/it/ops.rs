//! The typed operator vocabulary (`pipeline::OpSpec`): every operator round-trips through the
//! wire inside a compositor configuration, hostile bytes in its place are refused without a
//! panic, and out-of-range parameters are refused by `validate` with the reason.

use crate::common::op_spec;

use bytes::{BufMut, BytesMut};
use lightfold_protocol::pipeline::*;
use lightfold_protocol::*;
use proptest::prelude::*;
use rand::{Rng, SeedableRng};

fn config(ops: Vec<OpSpec>) -> CompositorConfig {
    CompositorConfig {
        epoch: 7,
        width: 64,
        height: 32,
        band_height: 8,
        inputs: vec![StageInput {
            peer: "n0".into(),
            layers: vec![(Layer::Illumination, format::PixelFormat::F16x6)],
        }],
        ops,
        wiring: Vec::new(),
        outputs: vec![(Layer::Radiance, format::PixelFormat::F32x3)],
        downstream: "127.0.0.1:9".into(),
        input_index: 0,
        frames_in_flight: 2,
    }
}

fn encode(m: Message) -> BytesMut {
    let mut buf = BytesMut::new();
    Codec::default()
        .encode(&Frame::Control(m), &mut buf)
        .expect("valid frame encodes");
    buf
}

fn round_trip(ops: Vec<OpSpec>) {
    let m = Message::ConfigureCompositor(config(ops));
    let mut buf = encode(m.clone());
    assert_eq!(
        Codec::default().decode(&mut buf),
        Ok(Some(Frame::Control(m)))
    );
    assert!(buf.is_empty());
}

/// One of every operator, with every optional part set.
fn every_operator() -> Vec<OpSpec> {
    vec![
        OpSpec::Accumulate(AccumulateParams {
            colors: vec![
                NodeColor::Rgb([1.0, 0.5, 0.25]),
                NodeColor::Split {
                    diffuse: [0.1, 0.2, 0.3],
                    specular: [0.4, 0.5, 0.6],
                },
            ],
            upstream: false,
            specular_color: Some([0.5; 3]),
            ambient: Some(AmbientFold {
                input: 1,
                mask: AmbientMask::Layer,
            }),
        }),
        OpSpec::Material(MaterialParams {
            stage: MaterialStage::Single,
            ambient_color: Some([0.1, 0.1, 0.2]),
            specular: true,
            emissive: true,
        }),
        OpSpec::Depth(DepthParams {
            inputs: 3,
            layers: vec![Layer::Illumination, Layer::Diffuse],
            reversed_z: false,
            zero_is_empty: true,
        }),
        OpSpec::Join(JoinParams {
            inputs: 2,
            layer: Layer::Diffuse,
        }),
        OpSpec::Merge(MergeParams {
            inputs: vec![
                vec![Layer::Illumination],
                vec![Layer::Depth, Layer::Emissive],
            ],
        }),
        OpSpec::Output(OutputParams { exposure: 2.5 }),
        OpSpec::Penumbra(PenumbraParams {
            kernel: Kernel::Box,
            specular: true,
            ..PenumbraParams::planned(640, 480, 5, 45.0)
        }),
        OpSpec::Blend(BlendParams { inputs: 4 }),
    ]
}

#[test]
fn every_operator_round_trips_through_the_wire() {
    let all = every_operator();
    let names: Vec<&str> = all.iter().map(OpSpec::name).collect();
    assert_eq!(names, OP_NAMES, "one of each operator, in OpSpec order");
    for op in &all {
        op.validate().unwrap_or_else(|e| panic!("{e}"));
        round_trip(vec![op.clone()]);
    }
    round_trip(all);
}

proptest! {
    #[test]
    fn any_operators_round_trip(ops in prop::collection::vec(op_spec(), 0..6)) {
        let m = Message::ConfigureCompositor(config(ops));
        let mut buf = encode(m.clone());
        prop_assert_eq!(Codec::default().decode(&mut buf), Ok(Some(Frame::Control(m))));
    }
}

/// Hostile bytes where the operators travel: every truncation, random bytes over the operator
/// list, and a lying list length decode to an error (or to some message), never a panic, and
/// never allocate past the control limit.
#[test]
fn hostile_operator_bytes_are_refused_without_panic() {
    let m = Message::ConfigureCompositor(config(every_operator()));
    let whole = encode(m);
    let body = whole[5..].to_vec();
    let reframe = |body: &[u8]| {
        let mut buf = BytesMut::new();
        buf.put_u32(body.len() as u32 + 1);
        buf.put_u8(whole[4]);
        buf.put_slice(body);
        buf
    };
    // Every truncation of the body is an error, not a partial message.
    for cut in 0..body.len() {
        let mut buf = reframe(&body[..cut]);
        assert!(Codec::default().decode(&mut buf).is_err(), "cut at {cut}");
    }
    // Random bytes from the operator list on: decode must not panic.
    let ops_at = body.len() - 200.min(body.len());
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(44);
    for _ in 0..2000 {
        let mut b = body.clone();
        for x in &mut b[ops_at..] {
            if rng.random_bool(0.1) {
                *x = rng.random();
            }
        }
        let _ = Codec::default().decode(&mut reframe(&b));
    }
    // An operator list claiming 2^62 (or 2^31) entries, and an unknown operator tag. The empty
    // list is one varint 0 byte; find it by encoding with one operator and comparing.
    let empty = encode(Message::ConfigureCompositor(config(Vec::new())));
    let empty_body = empty[5..].to_vec();
    let one = encode(Message::ConfigureCompositor(config(vec![OpSpec::Output(
        OutputParams::default(),
    )])));
    let one_body = one[5..].to_vec();
    let at = empty_body
        .iter()
        .zip(&one_body)
        .position(|(a, b)| a != b)
        .expect("the bodies differ at the operator count");
    for lie in [
        // bincode varints: 253 then a u64, 252 then a u32 (little-endian).
        vec![253u8, 0, 0, 0, 0, 0, 0, 0, 0x40],
        vec![252u8, 0xFF, 0xFF, 0xFF, 0x7F],
    ] {
        let mut b = empty_body[..at].to_vec();
        b.extend_from_slice(&lie);
        b.extend_from_slice(&empty_body[at + 1..]);
        assert!(Codec::default().decode(&mut reframe(&b)).is_err());
    }
    // Operator count 1, tag 200 (no such operator).
    let mut b = empty_body[..at].to_vec();
    b.extend_from_slice(&[1, 200]);
    b.extend_from_slice(&empty_body[at + 1..]);
    assert!(Codec::default().decode(&mut reframe(&b)).is_err());
}

#[test]
fn out_of_range_parameters_are_refused_with_the_reason() {
    let reason = |op: OpSpec| op.validate().unwrap_err().to_string();
    let planned = PenumbraParams::planned(64, 32, 3, 45.0);
    assert!(
        reason(OpSpec::Penumbra(PenumbraParams {
            radius: 9,
            ..planned.clone()
        }))
        .contains("radius must be in 1..=8, got 9")
    );
    assert!(
        reason(OpSpec::Penumbra(PenumbraParams {
            depth_tolerance: f32::NAN,
            ..planned.clone()
        }))
        .contains("depth_tolerance must be finite and positive")
    );
    assert!(
        reason(OpSpec::Penumbra(PenumbraParams {
            width: 0,
            ..planned
        }))
        .contains("width must be at least 1")
    );
    assert!(
        reason(OpSpec::Output(OutputParams {
            exposure: f32::INFINITY
        }))
        .contains("exposure must be finite and non-negative")
    );
    let e = reason(OpSpec::Accumulate(AccumulateParams {
        colors: vec![NodeColor::Rgb([1.0, -1.0, 0.0])],
        upstream: true,
        specular_color: None,
        ambient: None,
    }));
    assert!(
        e.contains("operator accumulate") && e.contains("diffuse colour of input 1 must be finite"),
        "{e}"
    );
    assert!(
        reason(OpSpec::Join(JoinParams {
            inputs: 0,
            layer: Layer::Illumination
        }))
        .contains("inputs must be at least 1")
    );
    assert!(
        reason(OpSpec::Blend(BlendParams { inputs: 1 }))
            .contains("inputs must be at least 2 (a back and a layer over it), got 1")
    );
    assert!(reason(OpSpec::Blend(BlendParams { inputs: 5000 })).contains("at most 4096"));
    assert!(
        reason(OpSpec::Depth(DepthParams {
            inputs: u32::MAX,
            layers: vec![Layer::Illumination],
            reversed_z: false,
            zero_is_empty: false,
        }))
        .contains("at most 4096")
    );
    assert!(
        reason(OpSpec::Merge(MergeParams {
            inputs: vec![vec![Layer::Diffuse], vec![Layer::Diffuse]],
        }))
        .contains("layer diffuse comes from two inputs")
    );
    assert!(
        reason(OpSpec::Material(MaterialParams {
            stage: MaterialStage::Ambient,
            ambient_color: None,
            specular: false,
            emissive: false,
        }))
        .contains("the ambient stage needs ambient_color")
    );
}
