//! Handshake: the right token succeeds both ways; a wrong token, version, magic, a replayed
//! transcript and garbage each fail with their own typed error; the token never hits the wire.

use bytes::BytesMut;
use lightfold_protocol::{
    Codec, Frame, Handshake, HandshakeError, Hello, MAGIC, PROTOCOL_VERSION, ProtocolError, Role,
};

const TOKEN: &[u8] = b"correct horse battery staple, 32B";

fn nonce(seed: u8) -> [u8; 32] {
    std::array::from_fn(|i| seed.wrapping_mul(31).wrapping_add(i as u8))
}

/// Runs a whole exchange through the codec, as two daemons would, recording every byte sent.
fn exchange(
    dialer: &mut Handshake,
    acceptor: &mut Handshake,
    wire: &mut BytesMut,
) -> (
    Result<lightfold_protocol::PeerInfo, ProtocolError>,
    Result<lightfold_protocol::PeerInfo, ProtocolError>,
) {
    let mut codec = Codec::default();
    let mut send = |frame: Frame, wire: &mut BytesMut| -> Frame {
        let mut buf = BytesMut::new();
        codec.encode(&frame, &mut buf).expect("encode");
        wire.extend_from_slice(&buf);
        let got = codec
            .decode(&mut buf)
            .expect("decode")
            .expect("whole frame");
        assert!(buf.is_empty());
        got
    };
    let Frame::Hello(dh) = send(Frame::Hello(dialer.hello()), wire) else {
        panic!("not a hello")
    };
    let Frame::Hello(ah) = send(Frame::Hello(acceptor.hello()), wire) else {
        panic!("not a hello")
    };
    let a_proof = acceptor
        .receive_hello(dh)
        .expect("acceptor takes the dialer hello");
    let d_proof = dialer
        .receive_hello(ah)
        .expect("dialer takes the acceptor hello");
    let Frame::Proof(dp) = send(Frame::Proof(d_proof), wire) else {
        panic!("not a proof")
    };
    let Frame::Proof(ap) = send(Frame::Proof(a_proof), wire) else {
        panic!("not a proof")
    };
    (
        dialer.verify(ap).map_err(ProtocolError::from),
        acceptor.verify(dp).map_err(ProtocolError::from),
    )
}

#[test]
fn right_token_succeeds_both_ways() {
    let mut d = Handshake::new(TOKEN, Role::Coordinator, "coord-1", nonce(1), true);
    let mut a = Handshake::new(TOKEN, Role::Node, "node-7", nonce(2), false);
    let mut wire = BytesMut::new();
    let (d_sees, a_sees) = exchange(&mut d, &mut a, &mut wire);
    let d_sees = d_sees.expect("dialer verifies the acceptor");
    let a_sees = a_sees.expect("acceptor verifies the dialer");
    assert_eq!(
        (d_sees.role, d_sees.daemon_id.as_str(), d_sees.version),
        (Role::Node, "node-7", PROTOCOL_VERSION)
    );
    assert_eq!(
        (a_sees.role, a_sees.daemon_id.as_str()),
        (Role::Coordinator, "coord-1")
    );
    assert!(
        !wire.windows(TOKEN.len()).any(|w| w == TOKEN),
        "the token appears in the transcript"
    );
}

#[test]
fn wrong_token_is_bad_proof_on_both_sides() {
    let mut d = Handshake::new(TOKEN, Role::Coordinator, "coord", nonce(3), true);
    let mut a = Handshake::new(b"another token", Role::Node, "node", nonce(4), false);
    let mut wire = BytesMut::new();
    let (d_sees, a_sees) = exchange(&mut d, &mut a, &mut wire);
    assert_eq!(
        d_sees,
        Err(ProtocolError::Handshake(HandshakeError::BadProof))
    );
    assert_eq!(
        a_sees,
        Err(ProtocolError::Handshake(HandshakeError::BadProof))
    );
    for token in [TOKEN, b"another token".as_slice()] {
        assert!(!wire.windows(token.len()).any(|w| w == token));
    }
}

#[test]
fn replayed_dialer_transcript_fails_against_a_fresh_acceptor() {
    // Record an honest exchange.
    let mut d = Handshake::new(TOKEN, Role::Coordinator, "coord", nonce(5), true);
    let mut a = Handshake::new(TOKEN, Role::Node, "node", nonce(6), false);
    let recorded_hello = d.hello();
    let a_hello = a.hello();
    a.receive_hello(recorded_hello.clone()).unwrap();
    let recorded_proof = d.receive_hello(a_hello).unwrap();
    assert!(a.verify(recorded_proof).is_ok());
    // Replay the dialer's hello and proof to the same acceptor restarted with a fresh nonce.
    let mut fresh = Handshake::new(TOKEN, Role::Node, "node", nonce(7), false);
    fresh.receive_hello(recorded_hello).unwrap();
    assert_eq!(fresh.verify(recorded_proof), Err(HandshakeError::BadProof));
}

#[test]
fn reflected_hello_and_proof_are_rejected() {
    let mut a = Handshake::new(TOKEN, Role::Node, "node", nonce(8), false);
    assert_eq!(a.receive_hello(a.hello()), Err(HandshakeError::Reflected));
    // A peer that echoes our own proof back (same token, other nonce) is still refused: the
    // side label differs.
    let mut d = Handshake::new(TOKEN, Role::Coordinator, "coord", nonce(9), true);
    let mut a = Handshake::new(TOKEN, Role::Node, "node", nonce(10), false);
    let a_proof = a.receive_hello(d.hello()).unwrap();
    d.receive_hello(a.hello()).unwrap();
    assert_eq!(a.verify(a_proof), Err(HandshakeError::BadProof));
}

#[test]
fn wrong_version_and_bad_magic_are_typed() {
    let mut a = Handshake::new(TOKEN, Role::Node, "node", nonce(11), false);
    let mut hello = Hello {
        magic: MAGIC,
        version: PROTOCOL_VERSION + 1,
        role: Role::Coordinator,
        daemon_id: "c".into(),
        nonce: nonce(12),
    };
    assert_eq!(
        a.receive_hello(hello.clone()),
        Err(HandshakeError::VersionMismatch {
            ours: PROTOCOL_VERSION,
            theirs: PROTOCOL_VERSION + 1
        })
    );
    hello.version = PROTOCOL_VERSION;
    hello.magic = *b"HTTP";
    assert_eq!(
        a.receive_hello(hello.clone()),
        Err(HandshakeError::BadMagic)
    );

    // The same through the codec: a peer of another version is told apart from garbage.
    let mut codec = Codec::default();
    let mut buf = BytesMut::new();
    hello.magic = MAGIC;
    // The release before this one.
    hello.version = PROTOCOL_VERSION - 1;
    codec
        .encode(&Frame::Hello(hello.clone()), &mut buf)
        .unwrap();
    assert_eq!(
        codec.decode(&mut buf),
        Err(ProtocolError::VersionMismatch {
            ours: PROTOCOL_VERSION,
            theirs: PROTOCOL_VERSION - 1
        })
    );
    let mut buf = BytesMut::new();
    hello.version = PROTOCOL_VERSION;
    hello.magic = *b"GET ";
    codec.encode(&Frame::Hello(hello), &mut buf).unwrap();
    assert_eq!(codec.decode(&mut buf), Err(ProtocolError::BadMagic));
}

#[test]
fn bad_daemon_ids_and_out_of_order_steps() {
    let mut a = Handshake::new(TOKEN, Role::Node, "node", nonce(13), false);
    assert_eq!(a.verify([0; 32]), Err(HandshakeError::OutOfOrder));
    for id in ["", "has space", "ctl\u{7}", &"x".repeat(256)] {
        let hello = Hello {
            magic: MAGIC,
            version: PROTOCOL_VERSION,
            role: Role::Coordinator,
            daemon_id: id.into(),
            nonce: nonce(14),
        };
        assert!(
            matches!(
                a.receive_hello(hello),
                Err(HandshakeError::BadDaemonId { .. })
            ),
            "{id:?}"
        );
    }
    let d = Handshake::new(TOKEN, Role::Coordinator, "coord", nonce(15), true);
    a.receive_hello(d.hello()).unwrap();
    assert_eq!(a.receive_hello(d.hello()), Err(HandshakeError::OutOfOrder));
    assert!(
        !format!("{a:?}").contains("battery"),
        "Debug shows the token"
    );
}

#[test]
fn garbage_gives_a_clear_typed_error() {
    let mut codec = Codec::default();
    let cases: [(&[u8], ProtocolError); 5] = [
        (
            b"GET / HTTP/1.1\r\n\r\n",
            ProtocolError::FrameTooLarge {
                length: 0x4745_5420,
                max: lightfold_protocol::DEFAULT_MAX_FRAME,
            },
        ),
        (&[0, 0, 0, 0, 1], ProtocolError::EmptyFrame),
        (
            &[0, 0, 0, 5, 0x77, 1, 2, 3, 4],
            ProtocolError::UnknownKind(0x77),
        ),
        (
            &[0, 0, 0, 3, 2, 1, 2],
            ProtocolError::BadProof { length: 2 },
        ),
        (
            &[0, 0, 0, 50, 1, b'X', b'X', b'X', b'X'],
            ProtocolError::BadMagic,
        ),
    ];
    for (bytes, want) in cases {
        let mut buf = BytesMut::from(bytes);
        let got = codec.decode(&mut buf);
        assert_eq!(got, Err(want.clone()), "{bytes:?}");
        let msg = want.to_string();
        assert!(msg.chars().next().unwrap().is_lowercase(), "{msg}");
    }
}
