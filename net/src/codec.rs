//! `tokio_util::codec` glue over the pure `protocol::Codec`.

use bytes::BytesMut;
use lightfold_protocol::frame::{Codec, Frame, ProtocolError};

/// Frames on a TCP stream, with an explicit maximum frame length.
#[derive(Debug)]
pub struct LinkCodec(Codec);

impl LinkCodec {
    pub fn new(max_frame: usize) -> Self {
        LinkCodec(Codec::new(max_frame))
    }
}

/// I/O errors surface through the protocol error so a `Framed` stream has one error type.
#[derive(Debug, thiserror::Error)]
pub enum CodecError {
    #[error(transparent)]
    Protocol(#[from] ProtocolError),
    #[error("i/o: {0}")]
    Io(#[from] std::io::Error),
}

impl tokio_util::codec::Decoder for LinkCodec {
    type Item = Frame;
    type Error = CodecError;

    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<Frame>, CodecError> {
        Ok(self.0.decode(src)?)
    }
}

impl tokio_util::codec::Encoder<Frame> for LinkCodec {
    type Error = CodecError;

    fn encode(&mut self, item: Frame, dst: &mut BytesMut) -> Result<(), CodecError> {
        Ok(self.0.encode(&item, dst)?)
    }
}
