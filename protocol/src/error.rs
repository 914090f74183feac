//! The errors a peer's bytes can produce. Every way a frame can be wrong has its own variant with
//! the numbers that were wrong, so a daemon can log (and a test can assert) exactly what happened.

use thiserror::Error;

use crate::band::BandError;
use crate::handshake::HandshakeError;

/// Why a frame could not be decoded or encoded.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ProtocolError {
    /// The length prefix (or an encoded body) exceeds the allowed maximum for its kind.
    #[error("frame of {length} bytes exceeds the maximum of {max}")]
    FrameTooLarge { length: usize, max: usize },
    /// A length prefix of zero: every frame has at least its kind byte.
    #[error("empty frame (length prefix 0)")]
    EmptyFrame,
    #[error("unknown frame kind {0}")]
    UnknownKind(u8),
    #[error("bad magic: the peer does not speak the lightfold protocol")]
    BadMagic,
    #[error("protocol version mismatch: ours {ours}, theirs {theirs}")]
    VersionMismatch { ours: u16, theirs: u16 },
    /// A hello frame whose fields do not parse.
    #[error("malformed hello: {reason}")]
    BadHello { reason: &'static str },
    /// A proof frame whose body is not exactly 32 bytes.
    #[error("proof frame body of {length} bytes, expected 32")]
    BadProof { length: usize },
    /// The bincode decoder rejected a control body (or left bytes over).
    #[error("bad control message: {0}")]
    Control(String),
    /// A control message could not be encoded.
    #[error("control message does not encode: {0}")]
    ControlEncode(String),
    #[error("bad band: {0}")]
    BadBand(#[from] BandError),
    #[error("band checksum mismatch: header says {expected:#010x}, payload has {actual:#010x}")]
    ChecksumMismatch { expected: u32, actual: u32 },
    #[error("handshake failed: {0}")]
    Handshake(#[from] HandshakeError),
}
