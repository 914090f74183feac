//! Framing: `[u32 BE length of the rest][u8 kind][body]`, one codec for every frame a link carries.
//! The length is checked against an explicit maximum before anything is reserved, so a lying
//! length never allocates; the decoder consumes bytes only when it returns a whole frame and
//! answers `Ok(None)` for "need more bytes", so the daemons, the tests and the fuzzer all drive
//! this one function over plain buffers. Bands also split at their payload, so a link can write a
//! payload it already holds without copying it (`encode_head`) and read one into a buffer of its
//! choice (`decode_head`, then `check_payload`) under the same rules as `decode`.

use bytes::{Buf, BufMut, Bytes, BytesMut};

use crate::band::{BAND_HEADER_LEN, BandError, BandHeader};
use crate::handshake::{Hello, MAGIC, MAX_DAEMON_ID, PROTOCOL_VERSION};
use crate::message::{Message, Role};

pub use crate::error::ProtocolError;

/// Default largest frame: a whole 1080p `f32x6` frame (about 50 MB) fits with room to spare.
pub const DEFAULT_MAX_FRAME: usize = 256 << 20;
/// Largest control body. bincode may reserve up to this much for a lying container length
/// inside a control frame, so it is kept far below the frame limit; scene chunks must be smaller.
pub const MAX_CONTROL: usize = 16 << 20;

/// Bytes in front of a band payload: length prefix, kind byte and band header.
pub const BAND_PREFIX_LEN: usize = 5 + BAND_HEADER_LEN;

const KIND_HELLO: u8 = 1;
const KIND_PROOF: u8 = 2;
const KIND_CONTROL: u8 = 3;
const KIND_BAND: u8 = 4;

/// Hello body: magic, version, role, id length, id, nonce.
const HELLO_FIXED: usize = 4 + 2 + 1 + 1 + 32;

/// Everything a link carries.
// A control message (a node's whole configuration inline) is larger than a band's header; bands
// move by the thousand, but 300 bytes moved with each is nothing beside what they carry
// (`Bytes`, shared), and boxing would allocate for every control message instead.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum Frame {
    Hello(Hello),
    Proof([u8; 32]),
    Control(Message),
    Band(BandHeader, Bytes),
}

/// What the first bytes of a buffer say about the frame they start ([`Codec::decode_head`]).
#[derive(Debug, Clone, PartialEq)]
pub enum Head {
    /// Too few bytes to tell yet: a band needs its [`BAND_PREFIX_LEN`]-byte prefix, any other
    /// frame its first 5 bytes.
    Incomplete,
    /// A band with a valid header whose payload (`header.payload_len` bytes, agreeing with the
    /// length prefix) follows the [`BAND_PREFIX_LEN`]-byte prefix.
    Band(BandHeader),
    /// Any other kind of frame: decode it whole with [`Codec::decode`].
    Other,
}

type ControlConfig = bincode::config::Configuration<
    bincode::config::LittleEndian,
    bincode::config::Varint,
    bincode::config::Limit<MAX_CONTROL>,
>;

/// bincode's standard configuration with the control size limit.
fn control_config() -> ControlConfig {
    bincode::config::standard().with_limit::<MAX_CONTROL>()
}

pub(crate) fn role_code(role: Role) -> u8 {
    match role {
        Role::Coordinator => 0,
        Role::Node => 1,
        Role::Compositor => 2,
        Role::Viewer => 3,
    }
}

fn role_from_code(code: u8) -> Option<Role> {
    Some(match code {
        0 => Role::Coordinator,
        1 => Role::Node,
        2 => Role::Compositor,
        3 => Role::Viewer,
        _ => return None,
    })
}

/// Length-prefixed frame codec with an explicit maximum frame length.
#[derive(Debug, Clone)]
pub struct Codec {
    /// Largest accepted value of the length prefix (kind byte + body).
    pub max_frame: usize,
}

impl Default for Codec {
    fn default() -> Self {
        Codec::new(DEFAULT_MAX_FRAME)
    }
}

impl Codec {
    pub fn new(max_frame: usize) -> Self {
        Codec { max_frame }
    }

    /// Consumes bytes only when a whole frame is decoded. Ok(None) = need more bytes.
    pub fn decode(&mut self, src: &mut BytesMut) -> Result<Option<Frame>, ProtocolError> {
        let Some(length) = self.check_prefix(src)? else {
            return Ok(None);
        };
        let total = 4 + length;
        if src.len() < total {
            src.reserve(total - src.len());
            return Ok(None);
        }
        let kind = src[4];
        let body = &src[5..total];
        let frame = match kind {
            KIND_HELLO => Frame::Hello(decode_hello(body)?),
            KIND_PROOF => {
                let proof: [u8; 32] = body
                    .try_into()
                    .map_err(|_| ProtocolError::BadProof { length: body.len() })?;
                Frame::Proof(proof)
            }
            KIND_CONTROL => Frame::Control(decode_control(body)?),
            KIND_BAND => {
                let header = BandHeader::decode(body)?;
                check_payload(&header, &body[BAND_HEADER_LEN..])?;
                let mut whole = src.split_to(total);
                whole.advance(5 + BAND_HEADER_LEN);
                return Ok(Some(Frame::Band(header, whole.freeze())));
            }
            other => return Err(ProtocolError::UnknownKind(other)),
        };
        src.advance(total);
        Ok(Some(frame))
    }

    /// Checks the prefix (length, and kind and hello magic/version once present) and returns
    /// the length of the rest of the frame, or `None` before the length has arrived. Rejects what
    /// the first bytes already condemn, without waiting for a body that may never come.
    fn check_prefix(&self, src: &[u8]) -> Result<Option<usize>, ProtocolError> {
        let Some(prefix) = src.first_chunk::<4>() else {
            return Ok(None);
        };
        let length = u32::from_be_bytes(*prefix) as usize;
        if length == 0 {
            return Err(ProtocolError::EmptyFrame);
        }
        if length > self.max_frame {
            return Err(ProtocolError::FrameTooLarge {
                length,
                max: self.max_frame,
            });
        }
        if let Some(&kind) = src.get(4) {
            check_kind_length(kind, length - 1)?;
            if kind == KIND_HELLO {
                check_hello_prefix(&src[5..src.len().min(4 + length)])?;
            }
        }
        Ok(Some(length))
    }

    /// Judges the frame at the front of `src` from its first bytes, consuming nothing. For a band
    /// it checks everything [`Codec::decode`] checks except the payload's checksum, which
    /// [`check_payload`] does once the payload is in: a reader can then put the payload where it
    /// likes. Whatever `decode` rejects from these bytes, this rejects with the same error.
    pub fn decode_head(&mut self, src: &[u8]) -> Result<Head, ProtocolError> {
        let Some(length) = self.check_prefix(src)? else {
            return Ok(Head::Incomplete);
        };
        match src.get(4) {
            None => Ok(Head::Incomplete),
            Some(&KIND_BAND) => {
                let Some(prefix) = src.get(..BAND_PREFIX_LEN) else {
                    return Ok(Head::Incomplete);
                };
                let header = BandHeader::decode(&prefix[5..])?;
                let payload = length - 1 - BAND_HEADER_LEN;
                if payload != header.payload_len as usize {
                    return Err(BandError::PayloadSizeMismatch {
                        header: header.payload_len,
                        actual: payload,
                    }
                    .into());
                }
                Ok(Head::Band(header))
            }
            Some(_) => Ok(Head::Other),
        }
    }

    /// Appends one frame to `dst`; on error `dst` is left as it was.
    pub fn encode(&mut self, frame: &Frame, dst: &mut BytesMut) -> Result<(), ProtocolError> {
        self.encode_parts(frame, dst, true)
    }

    /// Appends one frame to `dst` except a band's payload, which belongs on the wire right after
    /// (a link writes it from where it already is, without a copy); `encode` then
    /// `encode_head` + payload give the same bytes. On error `dst` is left as it was.
    pub fn encode_head(&mut self, frame: &Frame, dst: &mut BytesMut) -> Result<(), ProtocolError> {
        self.encode_parts(frame, dst, false)
    }

    fn encode_parts(
        &self,
        frame: &Frame,
        dst: &mut BytesMut,
        payload: bool,
    ) -> Result<(), ProtocolError> {
        let start = dst.len();
        let result = self.encode_inner(frame, dst, start, payload);
        if result.is_err() {
            dst.truncate(start);
        }
        result
    }

    fn encode_inner(
        &self,
        frame: &Frame,
        dst: &mut BytesMut,
        start: usize,
        with_payload: bool,
    ) -> Result<(), ProtocolError> {
        let body_len = match frame {
            Frame::Hello(hello) => HELLO_FIXED + hello.daemon_id.len(),
            Frame::Proof(_) => 32,
            // Patched below once bincode has written the body.
            Frame::Control(_) => 0,
            Frame::Band(_, payload) => BAND_HEADER_LEN + payload.len(),
        };
        let length = 1 + body_len;
        if length > self.max_frame {
            return Err(ProtocolError::FrameTooLarge {
                length,
                max: self.max_frame,
            });
        }
        dst.reserve(match frame {
            Frame::Band(..) if !with_payload => BAND_PREFIX_LEN,
            _ => 4 + length,
        });
        dst.put_u32(length as u32);
        match frame {
            Frame::Hello(hello) => {
                if hello.daemon_id.len() > MAX_DAEMON_ID {
                    return Err(ProtocolError::BadHello {
                        reason: "daemon id longer than 255 bytes",
                    });
                }
                dst.put_u8(KIND_HELLO);
                dst.put_slice(&hello.magic);
                dst.put_u16(hello.version);
                dst.put_u8(role_code(hello.role));
                dst.put_u8(hello.daemon_id.len() as u8);
                dst.put_slice(hello.daemon_id.as_bytes());
                dst.put_slice(&hello.nonce);
            }
            Frame::Proof(proof) => {
                dst.put_u8(KIND_PROOF);
                dst.put_slice(proof);
            }
            Frame::Control(message) => {
                dst.put_u8(KIND_CONTROL);
                let mut writer = dst.writer();
                bincode::serde::encode_into_std_write(message, &mut writer, control_config())
                    .map_err(|e| ProtocolError::ControlEncode(e.to_string()))?;
                let body = writer.get_ref().len() - start - 5;
                if body > MAX_CONTROL || 1 + body > self.max_frame {
                    let max = MAX_CONTROL.min(self.max_frame.saturating_sub(1)) + 1;
                    return Err(ProtocolError::FrameTooLarge {
                        length: 1 + body,
                        max,
                    });
                }
                dst[start..start + 4].copy_from_slice(&(1 + body as u32).to_be_bytes());
            }
            Frame::Band(header, payload) => {
                header.validate()?;
                if payload.len() != header.payload_len as usize {
                    return Err(BandError::PayloadSizeMismatch {
                        header: header.payload_len,
                        actual: payload.len(),
                    }
                    .into());
                }
                dst.put_u8(KIND_BAND);
                header.encode(dst);
                if with_payload {
                    dst.put_slice(payload);
                }
            }
        }
        Ok(())
    }
}

/// Checks a band payload against its header: its length and its checksum.
pub fn check_payload(header: &BandHeader, payload: &[u8]) -> Result<(), ProtocolError> {
    let mut check = PayloadCheck::default();
    check.update(payload);
    check.finish(header)
}

/// [`check_payload`] over a payload that arrives in pieces: each piece is hashed as it comes,
/// while it is still in cache, instead of in one more pass over the whole payload.
#[derive(Debug, Clone, Default)]
pub struct PayloadCheck {
    hasher: crc32fast::Hasher,
    len: usize,
}

impl PayloadCheck {
    /// The next bytes of the payload.
    pub fn update(&mut self, bytes: &[u8]) {
        self.hasher.update(bytes);
        self.len += bytes.len();
    }

    /// The verdict on everything passed to `update`, as [`check_payload`] gives it.
    pub fn finish(self, header: &BandHeader) -> Result<(), ProtocolError> {
        if self.len != header.payload_len as usize {
            return Err(BandError::PayloadSizeMismatch {
                header: header.payload_len,
                actual: self.len,
            }
            .into());
        }
        let actual = self.hasher.finalize();
        if actual != header.checksum {
            return Err(ProtocolError::ChecksumMismatch {
                expected: header.checksum,
                actual,
            });
        }
        Ok(())
    }
}

/// Per-kind size rules, checked as soon as the kind byte arrives.
fn check_kind_length(kind: u8, body: usize) -> Result<(), ProtocolError> {
    match kind {
        KIND_HELLO if !(HELLO_FIXED..=HELLO_FIXED + MAX_DAEMON_ID).contains(&body) => {
            Err(ProtocolError::BadHello {
                reason: "body length out of range",
            })
        }
        KIND_PROOF if body != 32 => Err(ProtocolError::BadProof { length: body }),
        KIND_CONTROL if body > MAX_CONTROL => Err(ProtocolError::FrameTooLarge {
            length: body + 1,
            max: MAX_CONTROL + 1,
        }),
        KIND_BAND if body < BAND_HEADER_LEN => Err(BandError::Truncated { length: body }.into()),
        KIND_HELLO | KIND_PROOF | KIND_CONTROL | KIND_BAND => Ok(()),
        other => Err(ProtocolError::UnknownKind(other)),
    }
}

/// Magic and version sit first in every version's hello, so they are judged from a prefix.
fn check_hello_prefix(body: &[u8]) -> Result<(), ProtocolError> {
    if let Some(magic) = body.first_chunk::<4>()
        && *magic != MAGIC
    {
        return Err(ProtocolError::BadMagic);
    }
    if let Some(&[hi, lo]) = body.get(4..6).and_then(|v| v.first_chunk::<2>()) {
        let theirs = u16::from_be_bytes([hi, lo]);
        if theirs != PROTOCOL_VERSION {
            return Err(ProtocolError::VersionMismatch {
                ours: PROTOCOL_VERSION,
                theirs,
            });
        }
    }
    Ok(())
}

fn decode_hello(body: &[u8]) -> Result<Hello, ProtocolError> {
    check_hello_prefix(body)?;
    let bad = |reason| ProtocolError::BadHello { reason };
    let (fixed, rest) = body.split_first_chunk::<8>().ok_or(bad("truncated"))?;
    let role = role_from_code(fixed[6]).ok_or(bad("unknown role"))?;
    let id_len = fixed[7] as usize;
    if rest.len() != id_len + 32 {
        return Err(bad("daemon id length disagrees with the body length"));
    }
    let (id, nonce) = rest.split_at(id_len);
    let daemon_id = std::str::from_utf8(id).map_err(|_| bad("daemon id is not utf-8"))?;
    Ok(Hello {
        magic: MAGIC,
        version: PROTOCOL_VERSION,
        role,
        daemon_id: daemon_id.to_owned(),
        nonce: nonce.try_into().map_err(|_| bad("truncated nonce"))?,
    })
}

fn decode_control(body: &[u8]) -> Result<Message, ProtocolError> {
    let (message, read): (Message, usize) =
        bincode::serde::decode_from_slice(body, control_config())
            .map_err(|e| ProtocolError::Control(e.to_string()))?;
    if read != body.len() {
        return Err(ProtocolError::Control(format!(
            "{} trailing bytes after the message",
            body.len() - read
        )));
    }
    Ok(message)
}
