//! Band headers (ARCHITECTURE §6): a fixed 52-byte binary header naming one rectangle of one layer
//! of one frame, followed on the wire by the raw packed payload. Pixels never go through serde; the
//! header is validated field by field so a corrupt or hostile band is rejected before any pixel is
//! touched.

use bytes::BufMut;
use thiserror::Error;

use crate::format::PixelFormat;
use crate::message::Layer;

/// Encoded size of a [`BandHeader`].
pub const BAND_HEADER_LEN: usize = 52;

/// Flag bit: the band is all zeros and carries no payload.
const FLAG_EMPTY: u8 = 1;

/// One band: a rectangle of one layer of one frame in one format.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BandHeader {
    pub frame: u64,
    /// Plan epoch; bands of an old epoch are dropped by the receiver.
    pub epoch: u64,
    pub layer: Layer,
    pub format: PixelFormat,
    pub x0: u32,
    pub y0: u32,
    pub width: u32,
    pub height: u32,
    /// Fixed-point scale (used by `seed64`, carried for every format; finite, ≥ 0).
    pub scale: f32,
    /// All-zero band: no payload on the wire.
    pub empty: bool,
    pub payload_len: u32,
    /// CRC-32 (IEEE) of the payload.
    pub checksum: u32,
    /// Pixels the producer had to saturate when packing this band.
    pub saturated: u32,
}

/// The band grid of one frame on a link: its ids, size, band height and fixed-point scale. The
/// one place band rows and unsealed headers are derived from (render nodes and the compositor's
/// test drivers alike).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BandLayout {
    pub epoch: u64,
    pub frame: u64,
    pub width: u32,
    pub height: u32,
    pub band_height: u32,
    /// Fixed-point scale carried by every band (used by `seed64`).
    pub scale: f32,
}

impl BandLayout {
    pub fn bands(&self) -> u32 {
        self.height.div_ceil(self.band_height.max(1))
    }

    /// Rows `[y0, y1)` of band `b`.
    pub fn rows(&self, b: u32) -> (u32, u32) {
        let h = self.band_height.max(1);
        let y0 = b.saturating_mul(h).min(self.height);
        (y0, y0.saturating_add(h).min(self.height))
    }

    /// The header of band `b` of `layer` before its payload is known (not empty, nothing
    /// saturated, unsealed).
    pub fn header(&self, b: u32, layer: Layer, format: PixelFormat) -> BandHeader {
        let (y0, y1) = self.rows(b);
        BandHeader {
            frame: self.frame,
            epoch: self.epoch,
            layer,
            format,
            x0: 0,
            y0,
            width: self.width,
            height: y1 - y0,
            scale: self.scale,
            empty: false,
            payload_len: 0,
            checksum: 0,
            saturated: 0,
        }
    }
}

/// What is wrong with a band header or its payload length.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum BandError {
    #[error("band body of {length} bytes is shorter than the {BAND_HEADER_LEN}-byte header")]
    Truncated { length: usize },
    #[error("unknown layer code {0}")]
    UnknownLayer(u8),
    #[error("unknown pixel format code {0}")]
    UnknownFormat(u8),
    #[error(
        "format {format:?} has {format_channels} channels but layer {layer:?} has {layer_channels}"
    )]
    FormatLayerMismatch {
        layer: Layer,
        format: PixelFormat,
        layer_channels: usize,
        format_channels: usize,
    },
    #[error("unknown band flags {0:#04x}")]
    UnknownFlags(u8),
    #[error("reserved header byte is {0}, expected 0")]
    Reserved(u8),
    #[error("scale {0} is not finite and non-negative")]
    BadScale(f32),
    #[error("rectangle at ({x0}, {y0}) of {width}x{height} overflows 32-bit coordinates")]
    RectOverflow {
        x0: u32,
        y0: u32,
        width: u32,
        height: u32,
    },
    #[error("header payload length {header} but the rectangle needs {expected}")]
    PayloadLenMismatch { header: u32, expected: usize },
    #[error("header payload length {header} but {actual} payload bytes follow")]
    PayloadSizeMismatch { header: u32, actual: usize },
}

/// Wire code of a layer; explicit so reordering `Layer::ALL` can never change the protocol.
fn layer_code(layer: Layer) -> u8 {
    match layer {
        Layer::Illumination => 0,
        Layer::Diffuse => 1,
        Layer::Specular => 2,
        Layer::Ambient => 3,
        Layer::Emissive => 4,
        Layer::Depth => 5,
        Layer::Radiance => 6,
        Layer::AmbientMask => 7,
        Layer::Transmittance => 8,
    }
}

fn layer_from_code(code: u8) -> Option<Layer> {
    Some(match code {
        0 => Layer::Illumination,
        1 => Layer::Diffuse,
        2 => Layer::Specular,
        3 => Layer::Ambient,
        4 => Layer::Emissive,
        5 => Layer::Depth,
        6 => Layer::Radiance,
        7 => Layer::AmbientMask,
        8 => Layer::Transmittance,
        _ => return None,
    })
}

/// CRC-32 of a band payload, as carried in [`BandHeader::checksum`].
pub fn checksum(payload: &[u8]) -> u32 {
    crc32fast::hash(payload)
}

impl BandHeader {
    /// Payload bytes the rectangle needs in this format; 0 when the band is empty. Saturates
    /// instead of overflowing so a hostile header cannot wrap around to a small number.
    pub fn expected_payload_len(&self) -> usize {
        if self.empty {
            return 0;
        }
        (self.width as usize)
            .saturating_mul(self.height as usize)
            .saturating_mul(self.format.bytes_per_pixel())
    }

    /// Sets `payload_len` and `checksum` from the payload about to be sent.
    pub fn seal(&mut self, payload: &[u8]) {
        self.payload_len = u32::try_from(payload.len()).unwrap_or(u32::MAX);
        self.checksum = checksum(payload);
    }

    /// Checks everything the header can say about itself (not the checksum, which needs the
    /// payload).
    pub fn validate(&self) -> Result<(), BandError> {
        if self.format.channels() != self.layer.channels() {
            return Err(BandError::FormatLayerMismatch {
                layer: self.layer,
                format: self.format,
                layer_channels: self.layer.channels(),
                format_channels: self.format.channels(),
            });
        }
        if !(self.scale.is_finite() && self.scale >= 0.0) {
            return Err(BandError::BadScale(self.scale));
        }
        if self.x0.checked_add(self.width).is_none() || self.y0.checked_add(self.height).is_none() {
            return Err(BandError::RectOverflow {
                x0: self.x0,
                y0: self.y0,
                width: self.width,
                height: self.height,
            });
        }
        let expected = self.expected_payload_len();
        if self.payload_len as usize != expected {
            return Err(BandError::PayloadLenMismatch {
                header: self.payload_len,
                expected,
            });
        }
        Ok(())
    }

    /// Writes the fixed header (big-endian fields).
    pub fn encode(&self, dst: &mut impl BufMut) {
        dst.put_u64(self.frame);
        dst.put_u64(self.epoch);
        dst.put_u8(layer_code(self.layer));
        dst.put_u8(self.format as u8);
        dst.put_u8(if self.empty { FLAG_EMPTY } else { 0 });
        dst.put_u8(0);
        dst.put_u32(self.x0);
        dst.put_u32(self.y0);
        dst.put_u32(self.width);
        dst.put_u32(self.height);
        dst.put_u32(self.scale.to_bits());
        dst.put_u32(self.payload_len);
        dst.put_u32(self.checksum);
        dst.put_u32(self.saturated);
    }

    /// Parses and validates a header from the first [`BAND_HEADER_LEN`] bytes of `src`.
    pub fn decode(src: &[u8]) -> Result<BandHeader, BandError> {
        let Some(h) = src.first_chunk::<BAND_HEADER_LEN>() else {
            return Err(BandError::Truncated { length: src.len() });
        };
        let u32_at = |i: usize| u32::from_be_bytes([h[i], h[i + 1], h[i + 2], h[i + 3]]);
        let u64_at = |i: usize| (u64::from(u32_at(i)) << 32) | u64::from(u32_at(i + 4));
        let layer = layer_from_code(h[16]).ok_or(BandError::UnknownLayer(h[16]))?;
        let format = PixelFormat::from_u8(h[17]).ok_or(BandError::UnknownFormat(h[17]))?;
        let flags = h[18];
        if flags & !FLAG_EMPTY != 0 {
            return Err(BandError::UnknownFlags(flags));
        }
        if h[19] != 0 {
            return Err(BandError::Reserved(h[19]));
        }
        let header = BandHeader {
            frame: u64_at(0),
            epoch: u64_at(8),
            layer,
            format,
            x0: u32_at(20),
            y0: u32_at(24),
            width: u32_at(28),
            height: u32_at(32),
            scale: f32::from_bits(u32_at(36)),
            empty: flags & FLAG_EMPTY != 0,
            payload_len: u32_at(40),
            checksum: u32_at(44),
            saturated: u32_at(48),
        };
        header.validate()?;
        Ok(header)
    }
}
