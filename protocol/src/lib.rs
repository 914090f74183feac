//! lightfold's wire protocol: the handshake, control messages, band headers, framing and the
//! packed pixel formats, as pure code over byte buffers.
//!
//! Must not depend on tokio, wgpu or do any I/O: encoders write into `BufMut`, decoders read from
//! `Buf` and tell "need more bytes" from "invalid", so the daemons, the tests and the fuzzer drive
//! the same code.

pub mod format;
pub mod message;

pub use format::PixelFormat;
pub use message::*;
