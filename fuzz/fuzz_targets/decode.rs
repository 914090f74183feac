//! Feeds arbitrary bytes to `Codec::decode`, frame after frame: it must never panic, never consume
//! bytes without returning a frame, and whatever it decodes must re-encode and decode to the same
//! bytes. Run with `cargo fuzz run decode` from the repository root.

#![no_main]

use bytes::BytesMut;
use libfuzzer_sys::fuzz_target;
use lightfold_protocol::Codec;

fuzz_target!(|data: &[u8]| {
    // A small limit keeps each input's memory bounded; the checks are the same at any limit.
    let mut codec = Codec::new(1 << 20);
    let mut buf = BytesMut::from(data);
    loop {
        let before = buf.len();
        match codec.decode(&mut buf) {
            Ok(Some(frame)) => {
                assert!(buf.len() < before, "frame without consuming bytes");
                let mut wire = BytesMut::new();
                codec
                    .encode(&frame, &mut wire)
                    .expect("a decoded frame re-encodes");
                let first = wire.clone();
                let back = codec.decode(&mut wire).expect("re-encoded frame decodes");
                let back = back.expect("re-encoded frame is whole");
                let mut second = BytesMut::new();
                codec.encode(&back, &mut second).expect("encodes again");
                assert_eq!(first, second, "decode/encode is not stable");
            }
            Ok(None) | Err(_) => {
                assert_eq!(buf.len(), before, "consumed bytes without a frame");
                break;
            }
        }
    }
});
