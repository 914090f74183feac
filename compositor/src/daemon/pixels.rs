//! The link formats as the stage and the driver use them: f32 values into a band payload and back,
//! through the protocol's exact pack/unpack, with errors as text for the reports.

use lightfold_protocol::PixelFormat;
use lightfold_protocol::format;

/// Unpacks `bytes` (whole pixels of `format`) into `out`.
pub fn unpack(
    format: PixelFormat,
    bytes: &[u8],
    scale: f32,
    out: &mut [f32],
) -> Result<(), String> {
    format::unpack(format, bytes, scale, out).map_err(|e| e.to_string())
}

/// Packs `values` into `out` (sized for whole pixels of `format`); returns the saturated pixels.
pub fn pack(
    format: PixelFormat,
    values: &[f32],
    scale: f32,
    out: &mut [u8],
) -> Result<u64, String> {
    format::pack(format, values, scale, out)
        .map(|s| s.saturated)
        .map_err(|e| e.to_string())
}
