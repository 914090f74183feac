//! Mutation test: valid encodings of every frame kind and every message variant, damaged in
//! 120 000 deterministic ways (bit flips, truncation, length lies, inserted, deleted and
//! overwritten bytes, spliced frames). The decoder must never panic, never consume bytes without
//! returning a frame, answer `Ok(None)` for a truncated frame, and otherwise return either a
//! frame that re-encodes consistently or a typed error with a message.

use crate::common;

use std::collections::BTreeMap;

use bytes::BytesMut;
use common::{VARIANTS, band, frame, hello, message, variant};
use lightfold_protocol::{Codec, Frame, ProtocolError};
use proptest::prelude::any;
use proptest::strategy::{Strategy, ValueTree};
use proptest::test_runner::TestRunner;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const CASES: usize = 120_000;

/// Valid encoded frames: at least two of every message variant, hellos, proofs and bands.
fn corpus() -> Vec<Vec<u8>> {
    let mut runner = TestRunner::deterministic();
    let mut frames: Vec<Frame> = Vec::new();
    let mut per_variant: BTreeMap<&str, usize> = BTreeMap::new();
    let messages = message();
    while per_variant.len() < VARIANTS.len() || per_variant.values().any(|&n| n < 2) {
        let m = messages.new_tree(&mut runner).unwrap().current();
        let n = per_variant.entry(variant(&m)).or_default();
        if *n < 4 {
            *n += 1;
            frames.push(Frame::Control(m));
        }
    }
    for _ in 0..6 {
        frames.push(Frame::Hello(
            hello().new_tree(&mut runner).unwrap().current(),
        ));
        frames.push(Frame::Proof(
            any::<[u8; 32]>().new_tree(&mut runner).unwrap().current(),
        ));
    }
    for _ in 0..16 {
        let (h, p) = band().new_tree(&mut runner).unwrap().current();
        frames.push(Frame::Band(h, p));
    }
    for _ in 0..8 {
        frames.push(frame().new_tree(&mut runner).unwrap().current());
    }
    let mut codec = Codec::default();
    frames
        .iter()
        .map(|f| {
            let mut buf = BytesMut::new();
            codec.encode(f, &mut buf).expect("corpus frame encodes");
            buf.to_vec()
        })
        .collect()
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Mutation {
    BitFlips,
    Truncate,
    LengthLie,
    Insert,
    Delete,
    Overwrite,
    Splice,
}

const MUTATIONS: [Mutation; 7] = [
    Mutation::BitFlips,
    Mutation::Truncate,
    Mutation::LengthLie,
    Mutation::Insert,
    Mutation::Delete,
    Mutation::Overwrite,
    Mutation::Splice,
];

fn mutate(rng: &mut ChaCha8Rng, kind: Mutation, frame: &[u8], other: &[u8]) -> Vec<u8> {
    let mut v = frame.to_vec();
    let at = |rng: &mut ChaCha8Rng, len: usize| rng.random_range(0..len.max(1));
    match kind {
        Mutation::BitFlips => {
            for _ in 0..rng.random_range(1..=4) {
                let i = at(rng, v.len());
                v[i] ^= 1 << rng.random_range(0..8);
            }
        }
        Mutation::Truncate => v.truncate(at(rng, v.len())),
        Mutation::LengthLie => {
            let real = (v.len() - 4) as u32;
            let lie = match rng.random_range(0..5) {
                0 => 0,
                1 => real.saturating_sub(rng.random_range(1..=real.max(1))),
                2 => real + rng.random_range(1..64),
                3 => rng.random(),
                _ => u32::MAX,
            };
            v[..4].copy_from_slice(&lie.to_be_bytes());
        }
        Mutation::Insert => {
            let i = at(rng, v.len() + 1);
            let bytes: Vec<u8> = (0..rng.random_range(1..8)).map(|_| rng.random()).collect();
            v.splice(i..i, bytes);
        }
        Mutation::Delete => {
            let i = at(rng, v.len());
            let n = rng.random_range(1..8).min(v.len() - i);
            v.drain(i..i + n);
        }
        Mutation::Overwrite => {
            for _ in 0..rng.random_range(1..4) {
                let i = at(rng, v.len());
                v[i] = rng.random();
            }
        }
        Mutation::Splice => {
            // The head of one frame glued to the tail of another.
            let cut = at(rng, v.len());
            v.truncate(cut);
            v.extend_from_slice(&other[at(rng, other.len())..]);
        }
    }
    v
}

/// Short name of an outcome, for the tally.
fn outcome(result: &Result<Option<Frame>, ProtocolError>) -> String {
    match result {
        Ok(Some(_)) => "frame".into(),
        Ok(None) => "need more".into(),
        Err(e) => format!("{e:?}")
            .split(['(', ' ', '{'])
            .next()
            .unwrap_or("")
            .to_owned(),
    }
}

#[test]
fn mutated_frames_never_panic_and_fail_with_typed_errors() {
    let corpus = corpus();
    let mut rng = ChaCha8Rng::seed_from_u64(0xF00D);
    let mut codec = Codec::default();
    let mut tally: BTreeMap<String, usize> = BTreeMap::new();
    for case in 0..CASES {
        let kind = MUTATIONS[case % MUTATIONS.len()];
        let original = &corpus[rng.random_range(0..corpus.len())];
        let other = &corpus[rng.random_range(0..corpus.len())];
        let bytes = mutate(&mut rng, kind, original, other);
        let mut buf = BytesMut::from(&bytes[..]);
        // A mutated buffer may hold several frames (or pieces): decode until it stops.
        for _ in 0..8 {
            let before = buf.clone();
            let result = codec.decode(&mut buf);
            *tally.entry(outcome(&result)).or_default() += 1;
            match result {
                Ok(Some(f)) => {
                    assert!(
                        buf.len() < before.len(),
                        "case {case}: frame without consuming bytes"
                    );
                    // Whatever decoded must encode, and decode back to the same bytes.
                    let mut again = BytesMut::new();
                    codec.encode(&f, &mut again).unwrap_or_else(|e| {
                        panic!("case {case}: decoded {f:?} does not re-encode: {e}")
                    });
                    let wire = again.clone();
                    let back = codec
                        .decode(&mut again)
                        .expect("re-encoded frame decodes")
                        .expect("whole");
                    let mut twice = BytesMut::new();
                    codec.encode(&back, &mut twice).expect("encodes again");
                    assert_eq!(wire, twice, "case {case}: decode/encode is not stable");
                }
                Ok(None) => {
                    assert_eq!(
                        buf, before,
                        "case {case}: consumed bytes while waiting for more"
                    );
                    break;
                }
                Err(e) => {
                    assert_eq!(buf, before, "case {case}: consumed bytes on error");
                    let text = e.to_string();
                    assert!(
                        text.chars().next().is_some_and(char::is_lowercase),
                        "case {case}: unclear error {text:?}"
                    );
                    break;
                }
            }
        }
        if kind == Mutation::Truncate {
            let mut buf = BytesMut::from(&bytes[..]);
            assert_eq!(
                codec.decode(&mut buf),
                Ok(None),
                "case {case}: truncated valid frame"
            );
        }
    }
    println!("{tally:#?}");
    // The mutations must reach every layer of the decoder, not just the length check.
    for expected in [
        "frame",
        "need more",
        "FrameTooLarge",
        "EmptyFrame",
        "UnknownKind",
        "BadMagic",
        "VersionMismatch",
        "BadHello",
        "BadProof",
        "Control",
        "BadBand",
        "ChecksumMismatch",
    ] {
        assert!(
            tally.get(expected).is_some_and(|&n| n > 0),
            "no case reached {expected}: {tally:#?}"
        );
    }
}

#[test]
fn random_garbage_streams_never_panic() {
    let mut rng = ChaCha8Rng::seed_from_u64(0xBAD);
    let mut codec = Codec::new(1 << 16);
    for _ in 0..20_000 {
        let len = rng.random_range(0..64);
        let mut bytes: Vec<u8> = (0..len).map(|_| rng.random()).collect();
        // Mostly plausible prefixes, so the garbage gets past the length check.
        if bytes.len() >= 5 && rng.random_bool(0.8) {
            let body = rng.random_range(1..=bytes.len() as u32 - 4);
            bytes[..4].copy_from_slice(&body.to_be_bytes());
            bytes[4] = rng.random_range(0..6);
        }
        let mut buf = BytesMut::from(&bytes[..]);
        for _ in 0..4 {
            match codec.decode(&mut buf) {
                Ok(Some(_)) => continue,
                Ok(None) => break,
                Err(e) => {
                    assert!(!e.to_string().is_empty());
                    break;
                }
            }
        }
    }
}
