//! Framing: every message variant and every frame kind round-trips through the codec, in one
//! piece and byte by byte; limits and band validation give their own typed errors.

use crate::common;

use std::collections::BTreeSet;

use bytes::{BufMut, Bytes, BytesMut};
use common::{VARIANTS, band, frame, message, variant};
use lightfold_protocol::format::PixelFormat;
use lightfold_protocol::*;
use proptest::prelude::*;
use proptest::strategy::ValueTree;
use proptest::test_runner::TestRunner;

fn encode(frame: &Frame) -> BytesMut {
    let mut buf = BytesMut::new();
    Codec::default()
        .encode(frame, &mut buf)
        .expect("valid frame encodes");
    buf
}

proptest! {
    #[test]
    fn every_message_round_trips(m in message()) {
        let f = Frame::Control(m);
        let mut buf = encode(&f);
        let got = Codec::default().decode(&mut buf);
        prop_assert_eq!(got, Ok(Some(f)));
        prop_assert!(buf.is_empty());
    }

    #[test]
    fn every_frame_round_trips_whole_and_in_pieces(frames in prop::collection::vec(frame(), 1..4)) {
        let mut wire = BytesMut::new();
        let mut codec = Codec::default();
        for f in &frames {
            codec.encode(f, &mut wire).unwrap();
        }
        // Fed one byte at a time the decoder waits (Ok(None)) until each frame is whole.
        let mut buf = BytesMut::new();
        let mut got = Vec::new();
        for &b in wire.iter() {
            buf.put_u8(b);
            let before = buf.len();
            match codec.decode(&mut buf) {
                Ok(Some(f)) => got.push(f),
                Ok(None) => prop_assert_eq!(buf.len(), before, "consumed bytes without a frame"),
                Err(e) => prop_assert!(false, "valid stream failed: {}", e),
            }
        }
        prop_assert!(buf.is_empty());
        prop_assert_eq!(got, frames);
    }
}

#[test]
fn message_strategy_covers_every_variant() {
    let mut runner = TestRunner::deterministic();
    let strategy = message();
    let seen: BTreeSet<&str> = (0..3000)
        .map(|_| variant(&strategy.new_tree(&mut runner).unwrap().current()))
        .collect();
    assert_eq!(seen, VARIANTS.into_iter().collect::<BTreeSet<_>>());
}

#[test]
fn lying_lengths_never_allocate_past_the_limit() {
    let mut codec = Codec::new(1 << 20);
    for length in [(1u32 << 20) + 1, u32::MAX] {
        let mut buf = BytesMut::with_capacity(16);
        buf.put_u32(length);
        buf.put_u8(3);
        let cap = buf.capacity();
        let got = codec.decode(&mut buf);
        assert_eq!(
            got,
            Err(ProtocolError::FrameTooLarge {
                length: length as usize,
                max: 1 << 20
            })
        );
        assert_eq!(
            buf.capacity(),
            cap,
            "reserved memory for a frame it refused"
        );
    }
    // A control frame longer than MAX_CONTROL is refused from its first five bytes.
    let mut buf = BytesMut::new();
    buf.put_u32((MAX_CONTROL + 2) as u32);
    buf.put_u8(3);
    assert_eq!(
        Codec::default().decode(&mut buf),
        Err(ProtocolError::FrameTooLarge {
            length: MAX_CONTROL + 2,
            max: MAX_CONTROL + 1
        })
    );
}

#[test]
fn encode_refuses_what_decode_would_refuse_and_leaves_dst_alone() {
    let mut codec = Codec::new(64);
    let mut dst = BytesMut::from(&b"prefix"[..]);
    let chunk = Message::SceneChunk {
        hash: [0; 32],
        offset: 0,
        data: vec![7; 100],
        last: true,
    };
    assert!(matches!(
        codec.encode(&Frame::Control(chunk), &mut dst),
        Err(ProtocolError::FrameTooLarge { .. })
    ));
    assert_eq!(&dst[..], b"prefix");
    let hello = Hello {
        magic: MAGIC,
        version: PROTOCOL_VERSION,
        role: Role::Node,
        daemon_id: "x".repeat(256),
        nonce: [0; 32],
    };
    assert!(matches!(
        Codec::default().encode(&Frame::Hello(hello), &mut dst),
        Err(ProtocolError::BadHello { .. })
    ));
    assert_eq!(&dst[..], b"prefix");
    let huge = Message::SceneChunk {
        hash: [0; 32],
        offset: 0,
        data: vec![0; MAX_CONTROL],
        last: true,
    };
    assert!(matches!(
        Codec::default().encode(&Frame::Control(huge), &mut dst),
        Err(ProtocolError::FrameTooLarge { .. })
    ));
    assert_eq!(&dst[..], b"prefix");
}

fn sample_band() -> (BandHeader, Bytes) {
    let mut runner = TestRunner::deterministic();
    loop {
        let (h, p) = band().new_tree(&mut runner).unwrap().current();
        if !h.empty && !p.is_empty() {
            return (h, p);
        }
    }
}

/// Encodes a band with a header edited after sealing, bypassing encode's own validation.
fn raw_band(header: &BandHeader, payload: &[u8]) -> BytesMut {
    let mut body = BytesMut::new();
    header.encode(&mut body);
    body.put_slice(payload);
    let mut buf = BytesMut::new();
    buf.put_u32(1 + body.len() as u32);
    buf.put_u8(4);
    buf.put_slice(&body);
    buf
}

#[test]
fn band_validation_errors_are_typed() {
    let (h, p) = sample_band();
    let decode = |header: &BandHeader, payload: &[u8]| {
        Codec::default().decode(&mut raw_band(header, payload))
    };
    assert!(matches!(decode(&h, &p), Ok(Some(Frame::Band(..)))));

    let mut bad = h;
    bad.format = if h.layer.channels() == 6 {
        PixelFormat::F32x3
    } else {
        PixelFormat::F32x6
    };
    bad.seal(&p);
    assert!(matches!(
        decode(&bad, &p),
        Err(ProtocolError::BadBand(
            BandError::FormatLayerMismatch { .. }
        ))
    ));

    for scale in [f32::NAN, -1.0, f32::INFINITY] {
        let mut bad = h;
        bad.scale = scale;
        assert!(
            matches!(
                decode(&bad, &p),
                Err(ProtocolError::BadBand(BandError::BadScale(_)))
            ),
            "{scale}"
        );
    }

    let mut bad = h;
    bad.width += 1;
    assert!(matches!(
        decode(&bad, &p),
        Err(ProtocolError::BadBand(BandError::PayloadLenMismatch { .. }))
    ));

    let mut bad = h;
    bad.x0 = u32::MAX;
    assert!(matches!(
        decode(&bad, &p),
        Err(ProtocolError::BadBand(BandError::RectOverflow { .. }))
    ));

    // Header consistent with itself, but the frame carries one byte less.
    let mut short = raw_band(&h, &p);
    short.truncate(short.len() - 1);
    let len = short.len() as u32 - 4;
    short[..4].copy_from_slice(&len.to_be_bytes());
    assert!(matches!(
        Codec::default().decode(&mut short),
        Err(ProtocolError::BadBand(
            BandError::PayloadSizeMismatch { .. }
        ))
    ));

    let mut flipped = p.to_vec();
    flipped[0] ^= 1;
    assert!(matches!(
        decode(&h, &flipped),
        Err(ProtocolError::ChecksumMismatch { .. })
    ));

    let mut empty = h;
    empty.empty = true;
    empty.seal(&[]);
    assert!(
        matches!(decode(&empty, &[]), Ok(Some(Frame::Band(e, payload))) if e.empty && payload.is_empty())
    );
    assert!(matches!(
        Codec::default().encode(&Frame::Band(empty, p.clone()), &mut BytesMut::new()),
        Err(ProtocolError::BadBand(
            BandError::PayloadSizeMismatch { .. }
        ))
    ));

    let mut raw = raw_band(&h, &p);
    raw[5 + 18] = 0x80;
    assert!(matches!(
        Codec::default().decode(&mut raw),
        Err(ProtocolError::BadBand(BandError::UnknownFlags(0x80)))
    ));
    let mut raw = raw_band(&h, &p);
    raw[5 + 16] = 200;
    assert!(matches!(
        Codec::default().decode(&mut raw),
        Err(ProtocolError::BadBand(BandError::UnknownLayer(200)))
    ));
}

#[test]
fn control_with_trailing_bytes_is_refused() {
    let mut buf = encode(&Frame::Control(Message::Ping { seq: 5 }));
    buf.put_u8(0);
    let len = buf.len() as u32 - 4;
    buf[..4].copy_from_slice(&len.to_be_bytes());
    assert!(
        matches!(Codec::default().decode(&mut buf), Err(ProtocolError::Control(msg)) if msg.contains("trailing"))
    );
}
