//! Feeds arbitrary bytes to `Codec::decode`, frame after frame: it must never panic, never consume
//! bytes without returning a frame, and whatever it decodes must re-encode and decode to the same
//! bytes. The split path links use (`decode_head` on the first bytes, the payload read in place)
//! must agree with `decode`: what `decode_head` condemns `decode` rejects with the same error (once
//! the frame is whole), a
//! band it accepts has the header `decode` returns, and `encode_head` + payload is `encode`.
//! Run with `cargo +nightly fuzz run decode` from the repository root.

#![no_main]

use bytes::BytesMut;
use libfuzzer_sys::fuzz_target;
use lightfold_protocol::frame::Head;
use lightfold_protocol::{Codec, Frame};

fuzz_target!(|data: &[u8]| {
    // A small limit keeps each input's memory bounded; the checks are the same at any limit.
    let mut codec = Codec::new(1 << 20);
    let mut buf = BytesMut::from(data);
    loop {
        let before = buf.len();
        let head = codec.decode_head(&buf);
        match codec.decode(&mut buf) {
            Ok(Some(frame)) => {
                assert!(buf.len() < before, "frame without consuming bytes");
                match (&frame, head) {
                    (Frame::Band(h, _), Ok(Head::Band(hh))) => assert_eq!(*h, hh),
                    (Frame::Band(..), other) => panic!("decode gave a band, decode_head {other:?}"),
                    (_, Ok(Head::Other)) => {}
                    (_, other) => panic!("decode gave a frame, decode_head {other:?}"),
                }
                let mut wire = BytesMut::new();
                codec
                    .encode(&frame, &mut wire)
                    .expect("a decoded frame re-encodes");
                if let Frame::Band(_, payload) = &frame {
                    let mut split = BytesMut::new();
                    codec.encode_head(&frame, &mut split).expect("head encodes");
                    split.extend_from_slice(payload);
                    assert_eq!(split, wire, "encode_head + payload differs from encode");
                }
                let first = wire.clone();
                let back = codec.decode(&mut wire).expect("re-encoded frame decodes");
                let back = back.expect("re-encoded frame is whole");
                let mut second = BytesMut::new();
                codec.encode(&back, &mut second).expect("encodes again");
                assert_eq!(first, second, "decode/encode is not stable");
            }
            Ok(None) => {
                assert_eq!(buf.len(), before, "consumed bytes without a frame");
                // `decode_head` may condemn a band from its prefix while `decode` waits for the
                // whole frame; once the frame is whole, `decode` must reject it the same way.
                if let Err(h) = head {
                    let length = u32::from_be_bytes(buf[..4].try_into().unwrap()) as usize;
                    let mut whole = buf.clone();
                    whole.resize(4 + length, 0);
                    let e = codec
                        .decode(&mut whole)
                        .expect_err("decode_head rejected it");
                    assert_eq!(format!("{h:?}"), format!("{e:?}"), "completed frame");
                }
                break;
            }
            Err(e) => {
                assert_eq!(buf.len(), before, "consumed bytes on an error");
                if let Err(h) = head {
                    // Compared as text: an error may carry a NaN, which is not equal to itself.
                    assert_eq!(
                        format!("{h:?}"),
                        format!("{e:?}"),
                        "decode_head and decode reject differently"
                    );
                }
                break;
            }
        }
    }
});
