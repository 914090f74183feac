//! lightfold's wire protocol: the handshake, control messages, band headers, framing and the
//! packed pixel formats, as pure code over byte buffers.
//!
//! Must not depend on tokio, wgpu or do any I/O: encoders write into `BufMut`, decoders read from
//! `Buf` and tell "need more bytes" from "invalid", so the daemons, the tests and the fuzzer drive
//! the same code. Beside the wire, it holds the few pure definitions every crate must share and
//! none may copy: the sRGB transfer (`srgb`), the summary statistics (`stats`) and the
//! compositing vocabulary (`pipeline`: operators and their typed parameters, layer names, link
//! formats, the penumbra filter's shape).

pub mod band;
pub mod error;
pub mod format;
pub mod frame;
pub mod handshake;
pub mod message;
pub mod pipeline;
pub mod srgb;
pub mod stats;

pub use band::{BAND_HEADER_LEN, BandError, BandHeader, BandLayout};
pub use error::ProtocolError;
pub use format::{FormatError, PackStats, PixelFormat};
pub use frame::{Codec, DEFAULT_MAX_FRAME, Frame, MAX_CONTROL};
pub use handshake::{Handshake, HandshakeError, Hello, MAGIC, PROTOCOL_VERSION, PeerInfo};
pub use message::*;
pub use pipeline::{OpSpec, ParamError};
