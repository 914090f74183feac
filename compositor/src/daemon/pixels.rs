//! The link formats as the stage and the driver use them: f32 values into a band payload and back,
//! through the protocol's exact pack/unpack, split across the rayon pool for large bands (a 1080p
//! band is a few hundred thousand pixels; the pack/unpack loops are per pixel and independent).

use crate::ops::PAR_SPAN;
use lightfold_protocol::PixelFormat;
use lightfold_protocol::format;
use rayon::prelude::*;

/// Whether a band of `pixels` is worth splitting across threads.
fn parallel(pixels: usize) -> bool {
    pixels >= 2 * PAR_SPAN && rayon::current_num_threads() > 1
}

/// Unpacks `bytes` (whole pixels of `format`) into `out`.
pub fn unpack(
    format: PixelFormat,
    bytes: &[u8],
    scale: f32,
    out: &mut [f32],
) -> Result<(), String> {
    let (bpp, ch) = (format.bytes_per_pixel(), format.channels());
    let pixels = out.len() / ch;
    if !parallel(pixels) || bytes.len() != pixels * bpp || !out.len().is_multiple_of(ch) {
        return format::unpack(format, bytes, scale, out).map_err(|e| e.to_string());
    }
    bytes
        .par_chunks(PAR_SPAN * bpp)
        .zip(out.par_chunks_mut(PAR_SPAN * ch))
        .try_for_each(|(b, o)| format::unpack(format, b, scale, o))
        .map_err(|e| e.to_string())
}

/// Packs `values` into `out` (sized for whole pixels of `format`); returns the saturated pixels.
pub fn pack(
    format: PixelFormat,
    values: &[f32],
    scale: f32,
    out: &mut [u8],
) -> Result<u64, String> {
    let (bpp, ch) = (format.bytes_per_pixel(), format.channels());
    let pixels = values.len() / ch;
    if !parallel(pixels) || out.len() != pixels * bpp || !values.len().is_multiple_of(ch) {
        return format::pack(format, values, scale, out)
            .map(|s| s.saturated)
            .map_err(|e| e.to_string());
    }
    values
        .par_chunks(PAR_SPAN * ch)
        .zip(out.par_chunks_mut(PAR_SPAN * bpp))
        .map(|(v, o)| format::pack(format, v, scale, o).map(|s| s.saturated))
        .try_reduce(|| 0, |a, b| Ok(a + b))
        .map_err(|e| e.to_string())
}
