//! The split path a link uses for bands (write the head, then the payload from where it is; read
//! the head, then the payload into a buffer of the reader's choice) gives the same bytes and the
//! same verdicts as the whole-frame `encode`/`decode`, on valid frames of every kind and on
//! 40 000 damaged ones.

use crate::common;

use bytes::BytesMut;
use common::frame;
use lightfold_protocol::frame::{BAND_PREFIX_LEN, Head, PayloadCheck, check_payload};
use lightfold_protocol::{Codec, Frame, ProtocolError};
use proptest::strategy::{Strategy, ValueTree};
use proptest::test_runner::TestRunner;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Decodes the front of `bytes` as a link reader does: the head first, a band's payload checked
/// on its own. `Ok(None)` = need more bytes.
fn split_decode(codec: &mut Codec, bytes: &[u8]) -> Result<Option<Frame>, ProtocolError> {
    match codec.decode_head(bytes)? {
        Head::Incomplete => Ok(None),
        Head::Other => codec.decode(&mut BytesMut::from(bytes)),
        Head::Band(header) => {
            let end = BAND_PREFIX_LEN + header.payload_len as usize;
            let Some(payload) = bytes.get(BAND_PREFIX_LEN..end) else {
                return Ok(None);
            };
            check_payload(&header, payload)?;
            Ok(Some(Frame::Band(
                header,
                bytes::Bytes::copy_from_slice(payload),
            )))
        }
    }
}

fn frames(n: usize) -> Vec<Frame> {
    let mut runner = TestRunner::deterministic();
    let strategy = frame();
    (0..n)
        .map(|_| strategy.new_tree(&mut runner).unwrap().current())
        .collect()
}

#[test]
fn head_and_payload_are_the_whole_frame() {
    let mut codec = Codec::default();
    let mut bands = 0;
    for f in frames(400) {
        let mut whole = BytesMut::new();
        codec.encode(&f, &mut whole).unwrap();
        let mut split = BytesMut::new();
        codec.encode_head(&f, &mut split).unwrap();
        if let Frame::Band(_, payload) = &f {
            assert_eq!(split.len(), BAND_PREFIX_LEN);
            split.extend_from_slice(payload);
            bands += 1;
        }
        assert_eq!(whole, split, "{f:?}");
        // Every prefix shorter than the head is incomplete; the whole frame decodes the same.
        let head = if matches!(f, Frame::Band(..)) {
            BAND_PREFIX_LEN
        } else {
            5
        };
        for cut in 0..head {
            assert_eq!(codec.decode_head(&whole[..cut]), Ok(Head::Incomplete));
        }
        let expected = matches!(f, Frame::Band(..))
            .then(|| Head::Band(band_header(&f)))
            .unwrap_or(Head::Other);
        assert_eq!(codec.decode_head(&whole), Ok(expected));
        // Debug text, not ==: a control message may hold NaN.
        let back = split_decode(&mut codec, &whole);
        assert_eq!(format!("{back:?}"), format!("{:?}", Ok::<_, ()>(Some(f))));
    }
    assert!(bands > 20, "only {bands} bands among the frames");
}

fn band_header(f: &Frame) -> lightfold_protocol::BandHeader {
    match f {
        Frame::Band(h, _) => *h,
        _ => unreachable!("only called on bands"),
    }
}

#[test]
fn damaged_frames_get_the_same_verdict_both_ways() {
    let corpus: Vec<Vec<u8>> = {
        let mut codec = Codec::default();
        frames(200)
            .iter()
            .map(|f| {
                let mut b = BytesMut::new();
                codec.encode(f, &mut b).unwrap();
                b.to_vec()
            })
            .collect()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(0x5_911);
    let mut codec = Codec::new(1 << 20);
    let (mut early, mut errors) = (0, 0);
    for case in 0..40_000 {
        let mut v = corpus[rng.random_range(0..corpus.len())].clone();
        match case % 4 {
            0 => {
                for _ in 0..rng.random_range(1..=3) {
                    let i = rng.random_range(0..v.len());
                    v[i] ^= 1 << rng.random_range(0..8);
                }
            }
            1 => v.truncate(rng.random_range(0..v.len())),
            2 => {
                // A damaged band header (or kind byte), where the split path judges early.
                let i = rng.random_range(4..v.len().min(BAND_PREFIX_LEN));
                v[i] = rng.random();
            }
            _ => {
                let lie = (v.len() as u32 - 4)
                    .wrapping_add(rng.random_range(0..16))
                    .wrapping_sub(8);
                v[..4].copy_from_slice(&lie.to_be_bytes());
            }
        }
        let whole = codec.decode(&mut BytesMut::from(&v[..]));
        let split = split_decode(&mut codec, &v);
        errors += usize::from(whole.is_err());
        match (&whole, &split) {
            // The split path judges a band's header before its body is in: `decode` must reach
            // the same verdict once the body has arrived.
            (Ok(None), Err(e)) => {
                early += 1;
                let length = u32::from_be_bytes(v[..4].try_into().unwrap()) as usize;
                v.resize(4 + length, 0);
                let later = codec.decode(&mut BytesMut::from(&v[..]));
                assert_eq!(later.as_ref().err(), Some(e), "case {case}");
            }
            // Debug text, not ==: a decoded control message may hold NaN.
            _ => assert_eq!(
                format!("{whole:?}"),
                format!("{split:?}"),
                "case {case}: {v:02x?}"
            ),
        }
    }
    assert!(errors > 10_000, "only {errors} damaged frames were refused");
    assert!(
        early > 100,
        "only {early} bands were judged from their head"
    );
}

#[test]
fn a_payload_checked_in_pieces_gets_the_whole_verdict() {
    let mut rng = ChaCha8Rng::seed_from_u64(0xC4C);
    let bands: Vec<Frame> = frames(300)
        .into_iter()
        .filter(|f| matches!(f, Frame::Band(..)))
        .collect();
    assert!(bands.len() > 20);
    for (i, f) in bands.iter().enumerate() {
        let Frame::Band(header, payload) = f else {
            continue;
        };
        let mut bytes = payload.to_vec();
        // Every third band damaged: a flipped bit, or a byte short.
        match i % 3 {
            1 if !bytes.is_empty() => {
                let at = rng.random_range(0..bytes.len());
                bytes[at] ^= 1 << rng.random_range(0..8);
            }
            2 if !bytes.is_empty() => {
                bytes.pop();
            }
            _ => {}
        }
        let mut check = PayloadCheck::default();
        let mut rest = &bytes[..];
        while !rest.is_empty() {
            let (piece, tail) = rest.split_at(rng.random_range(1..=rest.len()));
            check.update(piece);
            rest = tail;
        }
        assert_eq!(
            check.finish(header),
            check_payload(header, &bytes),
            "band {i}"
        );
    }
}
