//! The handshake (`lightfold_protocol::handshake`) against an arbitrary peer: the input's first
//! byte says which side we are, the rest is the peer's byte stream, decoded frame by frame with a
//! hello-sized limit and fed to the state machine. It must never panic; a hello is accepted only
//! if it is well formed; a proof is accepted only when it is the honest peer's (the fuzzer cannot
//! forge one, so a proof of 32 × 0xA5 stands for "send the honest proof", which must then be
//! accepted exactly when the hello before it was). Run with `scripts/fuzz.sh handshake`.

#![no_main]

use bytes::BytesMut;
use libfuzzer_sys::fuzz_target;
use lightfold_protocol::handshake::{Handshake, Hello, check_daemon_id};
use lightfold_protocol::{Codec, Frame, Role};

const TOKEN: &[u8] = b"fuzz cluster token, 32 bytes ok!";
const MARKER: [u8; 32] = [0xA5; 32];

/// The proof an honest peer that sent `peer` would send us.
fn honest_proof(us: &Handshake, peer: &Hello, dialer: bool) -> [u8; 32] {
    let mut mirror = Handshake::new(TOKEN, peer.role, &peer.daemon_id, peer.nonce, !dialer);
    mirror
        .receive_hello(us.hello())
        .expect("our own hello is well formed")
}

fuzz_target!(|data: &[u8]| {
    let Some((&flags, stream)) = data.split_first() else {
        return;
    };
    let dialer = flags & 1 == 1;
    let mut us = Handshake::new(TOKEN, Role::Coordinator, "fuzz-us", [7; 32], dialer);
    let mut codec = Codec::new(512);
    let mut buf = BytesMut::from(stream);
    let mut peer: Option<Hello> = None;
    while let Ok(Some(frame)) = codec.decode(&mut buf) {
        match frame {
            Frame::Hello(h) => {
                let fresh = peer.is_none();
                let ok = us.receive_hello(h.clone());
                let valid = fresh && check_daemon_id(&h.daemon_id).is_ok() && h.nonce != [7; 32];
                assert_eq!(ok.is_ok(), valid, "hello {h:?} after {peer:?}: {ok:?}");
                if ok.is_ok() {
                    peer = Some(h);
                }
            }
            Frame::Proof(p) => {
                let honest = peer.as_ref().map(|h| honest_proof(&us, h, dialer));
                let sent = if p == MARKER { honest.unwrap_or(p) } else { p };
                let verdict = us.verify(sent);
                match (&honest, &verdict) {
                    (Some(h), Ok(info)) => {
                        assert_eq!(*h, sent, "a forged proof was accepted");
                        let peer = peer.as_ref().unwrap();
                        assert_eq!((info.role, &info.daemon_id), (peer.role, &peer.daemon_id));
                    }
                    (Some(h), Err(_)) => assert_ne!(*h, sent, "the honest proof was refused"),
                    (None, Ok(_)) => panic!("a proof before any hello was accepted"),
                    (None, Err(_)) => {}
                }
            }
            _ => {}
        }
    }
});
