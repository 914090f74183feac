//! The versioned handshake (ARCHITECTURE §6), as a pure state machine: the caller supplies fresh
//! nonces and moves the frames. Each side sends a [`Hello`] (magic, version, role, daemon id, a
//! fresh 32-byte nonce), then a proof `HMAC-SHA256(token, domain ‖ side ‖ dialer hello ‖ acceptor
//! hello)`. The token never travels; a recorded transcript replayed later fails because the
//! verifier's own fresh nonce is inside the MAC; the side label stops a peer reflecting our proof
//! back at us; the comparison is constant-time.

use std::fmt;

use hmac::{Hmac, Mac};
use sha2::Sha256;
use thiserror::Error;

use crate::message::Role;

pub const MAGIC: [u8; 4] = *b"LFLD";
/// 2: `CompositorConfig::wiring`. 4: `FrameParams::time` (scene time). 8: scenes travel as scene
/// bytes version 6 (glTF metallic-roughness materials, mesh tangents), which nodes of 7 cannot read.
/// 9: `Message::Error` names the epoch and frame it is about; `Message::Release`. 10:
/// `FrameStats::setup_us`, `read_bytes` and `prefetched` (nodes pack on the device and render
/// the next frame while sending one), `Capabilities::device`. 11: `Capabilities::cpu_host`. 12:
/// `WireLight::area` (closed-form glossy specular of area lights), scene bytes version 7. 13:
/// `NodeConfig::moves` (objects moved in a live session). 14: `CompositorConfig::ops` carries
/// typed operator parameters (`pipeline::OpSpec`) instead of names and JSON text,
/// `FrameParams::lights` (virtual point lights of animated scenes traced per frame), scene bytes
/// version 8 (soft suns and cylinder lights). 15: `WireLight::cell` and the cell filter
/// (`NodeConfig::filter` ≥ `CELL_FILTER`). 16: sort-first tiles (`NodeConfig::rows`,
/// `FrameParams::rows`). 17: `Layer::AmbientMask` (eq. 7's per-pixel ambient mask, wire code 7).
/// 18: peeled translucency: `Layer::Transmittance` (wire code 8), `NodeConfig::peel` and the
/// `blend` operator.
pub const PROTOCOL_VERSION: u16 = 18;
/// Longest daemon id a hello may carry (its wire length is one byte).
pub const MAX_DAEMON_ID: usize = 255;

/// Domain separation: these MACs can never be confused with any other use of the token.
const DOMAIN: &[u8] = b"lightfold/handshake/v1\0";

type HmacSha256 = Hmac<Sha256>;

/// The first frame each side sends.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Hello {
    pub magic: [u8; 4],
    pub version: u16,
    pub role: Role,
    pub daemon_id: String,
    pub nonce: [u8; 32],
}

/// Who the peer proved to be.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PeerInfo {
    pub role: Role,
    pub daemon_id: String,
    pub version: u16,
}

#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum HandshakeError {
    #[error("bad magic: the peer does not speak the lightfold protocol")]
    BadMagic,
    #[error("protocol version mismatch: ours {ours}, theirs {theirs}")]
    VersionMismatch { ours: u16, theirs: u16 },
    #[error("bad daemon id: {reason}")]
    BadDaemonId { reason: &'static str },
    /// The peer's nonce equals ours: our own hello was sent back to us.
    #[error("peer echoed our nonce (reflected handshake)")]
    Reflected,
    /// The proof does not match: wrong token, or a replayed transcript.
    #[error("bad proof: wrong cluster token or replayed handshake")]
    BadProof,
    /// A second hello, or a proof before the peer's hello.
    #[error("handshake step out of order")]
    OutOfOrder,
}

/// One side's handshake state.
pub struct Handshake {
    token: Vec<u8>,
    ours: Hello,
    dialer: bool,
    peer: Option<Hello>,
}

// The token must never reach a log, so Debug is written by hand.
impl fmt::Debug for Handshake {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Handshake")
            .field("token", &"<redacted>")
            .field("ours", &self.ours)
            .field("dialer", &self.dialer)
            .field("peer", &self.peer)
            .finish()
    }
}

/// Checks a daemon id is something a log and a config can hold.
pub fn check_daemon_id(id: &str) -> Result<(), HandshakeError> {
    if id.is_empty() {
        return Err(HandshakeError::BadDaemonId { reason: "empty" });
    }
    if id.len() > MAX_DAEMON_ID {
        return Err(HandshakeError::BadDaemonId {
            reason: "longer than 255 bytes",
        });
    }
    if id.chars().any(|c| c.is_control() || c.is_whitespace()) {
        return Err(HandshakeError::BadDaemonId {
            reason: "contains whitespace or control characters",
        });
    }
    Ok(())
}

impl Hello {
    /// Unambiguous encoding of the hello for the MAC (independent of the wire form, and total:
    /// it cannot fail whatever the id).
    fn transcript(&self, mac: &mut HmacSha256) {
        mac.update(&self.magic);
        mac.update(&self.version.to_be_bytes());
        mac.update(&[crate::frame::role_code(self.role)]);
        mac.update(&(self.daemon_id.len() as u64).to_be_bytes());
        mac.update(self.daemon_id.as_bytes());
        mac.update(&self.nonce);
    }
}

impl Handshake {
    /// `dialer` is true on the side that opened the connection. An empty token is accepted here
    /// (it still authenticates nothing); refusing one is the caller's policy.
    pub fn new(token: &[u8], role: Role, daemon_id: &str, nonce: [u8; 32], dialer: bool) -> Self {
        Handshake {
            token: token.to_vec(),
            ours: Hello {
                magic: MAGIC,
                version: PROTOCOL_VERSION,
                role,
                daemon_id: daemon_id.to_owned(),
                nonce,
            },
            dialer,
            peer: None,
        }
    }

    pub fn hello(&self) -> Hello {
        self.ours.clone()
    }

    /// Checks magic/version/id sanity, records the peer's hello; returns our proof to send.
    pub fn receive_hello(&mut self, peer: Hello) -> Result<[u8; 32], HandshakeError> {
        if self.peer.is_some() {
            return Err(HandshakeError::OutOfOrder);
        }
        if peer.magic != MAGIC {
            return Err(HandshakeError::BadMagic);
        }
        if peer.version != PROTOCOL_VERSION {
            return Err(HandshakeError::VersionMismatch {
                ours: PROTOCOL_VERSION,
                theirs: peer.version,
            });
        }
        check_daemon_id(&peer.daemon_id)?;
        if peer.nonce == self.ours.nonce {
            return Err(HandshakeError::Reflected);
        }
        self.peer = Some(peer);
        self.proof(self.dialer)
    }

    /// Verifies the peer's proof; on success returns who the peer is.
    pub fn verify(&self, proof: [u8; 32]) -> Result<PeerInfo, HandshakeError> {
        let peer = self.peer.as_ref().ok_or(HandshakeError::OutOfOrder)?;
        // verify_slice compares in constant time.
        self.mac(!self.dialer)?
            .verify_slice(&proof)
            .map_err(|_| HandshakeError::BadProof)?;
        Ok(PeerInfo {
            role: peer.role,
            daemon_id: peer.daemon_id.clone(),
            version: peer.version,
        })
    }

    /// The MAC state for the proof that the side `by_dialer` sends.
    fn mac(&self, by_dialer: bool) -> Result<HmacSha256, HandshakeError> {
        let peer = self.peer.as_ref().ok_or(HandshakeError::OutOfOrder)?;
        let (dialer, acceptor) = if self.dialer {
            (&self.ours, peer)
        } else {
            (peer, &self.ours)
        };
        // HMAC accepts keys of any length, so this cannot fail.
        let mut mac = <HmacSha256 as Mac>::new_from_slice(&self.token)
            .map_err(|_| HandshakeError::BadProof)?;
        mac.update(DOMAIN);
        mac.update(if by_dialer {
            b"dialer\0"
        } else {
            b"acceptor\0"
        });
        dialer.transcript(&mut mac);
        acceptor.transcript(&mut mac);
        Ok(mac)
    }

    fn proof(&self, by_dialer: bool) -> Result<[u8; 32], HandshakeError> {
        Ok(self.mac(by_dialer)?.finalize().into_bytes().into())
    }
}
