//! Pixel formats of the links (ARCHITECTURE §7) and their pack/unpack. Every format clamps its
//! input into its representable range first (NaN → 0, negatives → 0 except depth, +Inf and values
//! above the range → the largest value, counted as saturated), so unpack never yields NaN; the
//! per-format modules hold tight loops chosen once per call, never per pixel. Ranges and error
//! bounds are documented in `docs/formats.md` and asserted tight by the property tests.

use serde::{Deserialize, Serialize};
use thiserror::Error;

mod floats;
mod halfs;
mod rgb9e5;
mod rgba8;
mod seed64;

/// One little-endian half of `f16x6`/`f16x4` as `unpack` reads it (finite values exactly, +Inf →
/// 65504, NaN and negatives → 0): for kernels that decode halves inside their own loops.
pub use halfs::decode as decode_half;
/// A value in [0, 65504] as the half `pack` writes (ties to even), for kernels that pack halves
/// inside their own loops.
pub use halfs::encode as encode_half;
pub use rgb9e5::MAX as RGB9E5_MAX;
pub use rgba8::srgb_encode_tables;

/// A packed pixel format. Illumination formats carry six channels (diffuse RGB, specular RGB);
/// material formats three (RGB); depth one.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[repr(u8)]
pub enum PixelFormat {
    /// The paper's 64-bit network pixel: diffuse 3×11-bit + specular 3×10-bit fixed point, with a
    /// per-frame scale.
    Seed64 = 0,
    /// Two shared-exponent RGB triples (9-bit mantissas, 5-bit exponent), 8 bytes.
    Rgb9e5x2 = 1,
    /// Six half floats, 12 bytes.
    F16x6 = 2,
    /// Six f32, 24 bytes.
    F32x6 = 3,
    /// RGB as linear 8-bit (plus a pad byte), 4 bytes.
    Rgba8Linear = 4,
    /// RGB as sRGB-encoded 8-bit (plus a pad byte), 4 bytes.
    Rgba8Srgb = 5,
    /// RGB as half floats (plus a pad half), 8 bytes.
    F16x4 = 6,
    /// One f32 (depth), 4 bytes.
    DepthF32 = 7,
    /// RGB as three f32, 12 bytes (final radiance to the coordinator).
    F32x3 = 8,
}

impl PixelFormat {
    pub const ALL: [PixelFormat; 9] = [
        PixelFormat::Seed64,
        PixelFormat::Rgb9e5x2,
        PixelFormat::F16x6,
        PixelFormat::F32x6,
        PixelFormat::Rgba8Linear,
        PixelFormat::Rgba8Srgb,
        PixelFormat::F16x4,
        PixelFormat::DepthF32,
        PixelFormat::F32x3,
    ];

    pub fn bytes_per_pixel(self) -> usize {
        match self {
            PixelFormat::Seed64 | PixelFormat::Rgb9e5x2 | PixelFormat::F16x4 => 8,
            PixelFormat::F16x6 | PixelFormat::F32x3 => 12,
            PixelFormat::F32x6 => 24,
            PixelFormat::Rgba8Linear | PixelFormat::Rgba8Srgb | PixelFormat::DepthF32 => 4,
        }
    }

    /// f32 channels per pixel this format packs.
    pub fn channels(self) -> usize {
        match self {
            PixelFormat::Seed64
            | PixelFormat::Rgb9e5x2
            | PixelFormat::F16x6
            | PixelFormat::F32x6 => 6,
            PixelFormat::DepthF32 => 1,
            _ => 3,
        }
    }

    pub fn from_u8(v: u8) -> Option<PixelFormat> {
        PixelFormat::ALL.get(v as usize).copied()
    }

    pub fn name(self) -> &'static str {
        match self {
            PixelFormat::Seed64 => "seed64",
            PixelFormat::Rgb9e5x2 => "rgb9e5x2",
            PixelFormat::F16x6 => "f16x6",
            PixelFormat::F32x6 => "f32x6",
            PixelFormat::Rgba8Linear => "rgba8",
            PixelFormat::Rgba8Srgb => "rgba8srgb",
            PixelFormat::F16x4 => "f16x4",
            PixelFormat::DepthF32 => "depth32",
            PixelFormat::F32x3 => "f32x3",
        }
    }

    pub fn from_name(s: &str) -> Option<PixelFormat> {
        PixelFormat::ALL.into_iter().find(|f| f.name() == s)
    }
}

/// Largest finite half float, the saturation value of `f16x6` and `f16x4`.
pub const F16_MAX: f32 = 65504.0;

/// What packing had to give up.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PackStats {
    /// Pixels with at least one channel above the format's range (including +Inf).
    pub saturated: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Error)]
pub enum FormatError {
    #[error("{len} f32 values are not a whole number of {format:?} pixels ({channels} channels)")]
    SrcLength {
        format: PixelFormat,
        len: usize,
        channels: usize,
    },
    #[error(
        "{len} packed bytes are not a whole number of {format:?} pixels ({bytes_per_pixel} bytes)"
    )]
    PackedLength {
        format: PixelFormat,
        len: usize,
        bytes_per_pixel: usize,
    },
    #[error("{format:?} buffer holds {actual} pixels, the other side {expected}")]
    PixelCount {
        format: PixelFormat,
        expected: usize,
        actual: usize,
    },
    /// `seed64` packs against a finite positive scale (unpack also accepts 0).
    #[error("scale {scale} is not finite and positive")]
    BadScale { scale: f32 },
}

/// Packs `src` (`format.channels()` f32 per pixel) into `dst` (`bytes_per_pixel` per pixel).
/// `scale` is only used by `seed64` (value = code/(2^bits−1)·scale); other formats ignore it.
pub fn pack(
    format: PixelFormat,
    src: &[f32],
    scale: f32,
    dst: &mut [u8],
) -> Result<PackStats, FormatError> {
    let channels = format.channels();
    if !src.len().is_multiple_of(channels) {
        return Err(FormatError::SrcLength {
            format,
            len: src.len(),
            channels,
        });
    }
    check_packed(format, dst.len(), src.len() / channels)?;
    let saturated = match format {
        PixelFormat::Seed64 => {
            if !(scale.is_finite() && scale > 0.0) {
                return Err(FormatError::BadScale { scale });
            }
            seed64::pack(src, scale, dst)
        }
        PixelFormat::Rgb9e5x2 => rgb9e5::pack(src, dst),
        PixelFormat::F16x6 => halfs::pack::<6, 6>(src, dst),
        PixelFormat::F16x4 => halfs::pack::<3, 4>(src, dst),
        PixelFormat::F32x6 => floats::pack_nonneg::<6>(src, dst),
        PixelFormat::F32x3 => floats::pack_nonneg::<3>(src, dst),
        PixelFormat::DepthF32 => floats::pack_depth(src, dst),
        PixelFormat::Rgba8Linear => rgba8::pack_linear(src, dst),
        PixelFormat::Rgba8Srgb => rgba8::pack_srgb(src, dst),
    };
    Ok(PackStats { saturated })
}

/// Unpacks `src` into `dst` (`format.channels()` f32 per pixel). Any byte pattern decodes to
/// finite values inside the format's range: a corrupt or hostile payload cannot yield NaN.
pub fn unpack(
    format: PixelFormat,
    src: &[u8],
    scale: f32,
    dst: &mut [f32],
) -> Result<(), FormatError> {
    let channels = format.channels();
    if !dst.len().is_multiple_of(channels) {
        return Err(FormatError::SrcLength {
            format,
            len: dst.len(),
            channels,
        });
    }
    check_packed(format, src.len(), dst.len() / channels)?;
    match format {
        PixelFormat::Seed64 => {
            if !(scale.is_finite() && scale >= 0.0) {
                return Err(FormatError::BadScale { scale });
            }
            seed64::unpack(src, scale, dst);
        }
        PixelFormat::Rgb9e5x2 => rgb9e5::unpack(src, dst),
        PixelFormat::F16x6 => halfs::unpack::<6, 6>(src, dst),
        PixelFormat::F16x4 => halfs::unpack::<3, 4>(src, dst),
        PixelFormat::F32x6 | PixelFormat::F32x3 => floats::unpack_nonneg(src, dst),
        PixelFormat::DepthF32 => floats::unpack_depth(src, dst),
        PixelFormat::Rgba8Linear => rgba8::unpack_linear(src, dst),
        PixelFormat::Rgba8Srgb => rgba8::unpack_srgb(src, dst),
    }
    Ok(())
}

fn check_packed(format: PixelFormat, len: usize, pixels: usize) -> Result<(), FormatError> {
    let bytes_per_pixel = format.bytes_per_pixel();
    if !len.is_multiple_of(bytes_per_pixel) {
        return Err(FormatError::PackedLength {
            format,
            len,
            bytes_per_pixel,
        });
    }
    if len / bytes_per_pixel != pixels {
        return Err(FormatError::PixelCount {
            format,
            expected: pixels,
            actual: len / bytes_per_pixel,
        });
    }
    Ok(())
}

/// The documented round-trip error bound: for an input `value`,
/// `|unpack(pack(value)) − value| ≤ bound(format, value, scale)`.
///
/// It is the distance from `value` to the format's range (what clamping loses: NaN counts as 0,
/// negatives clamp to 0 except for depth, values above the range to its top) plus the quantisation
/// error at the clamped value. Two formats need more context than one value:
/// - `seed64` quantises diffuse (11 bits) and specular (10 bits) differently; this returns the
///   looser specular bound, [`channel_bound`] gives each channel's own.
/// - `rgb9e5x2` shares one exponent per triple: pass the triple's **largest** channel as `value`;
///   every channel `c` of the triple then has error ≤ (distance of `c` to the range) +
///   `bound(format, max, scale) − (distance of max to the range)`, see [`quantisation_bound`].
pub fn bound(format: PixelFormat, value: f32, scale: f32) -> f32 {
    channel_bound(format, format.channels() - 1, value, scale)
}

/// [`bound`] for one channel (0-based) of the pixel; differs from `bound` only for `seed64`.
pub fn channel_bound(format: PixelFormat, channel: usize, value: f32, scale: f32) -> f32 {
    let q = f64::from(quantisation_bound(format, channel, value, scale));
    round_up(clamp_distance(format, value, scale) + q)
}

/// The nearest f32 at or above `x`, so a bound never shrinks in conversion.
fn round_up(x: f64) -> f32 {
    let y = x as f32;
    if f64::from(y) < x { y.next_up() } else { y }
}

/// The value pack actually encodes: `value` clamped into the format's range.
pub fn clamp_to_range(format: PixelFormat, value: f32, scale: f32) -> f32 {
    match format {
        PixelFormat::Seed64 => clamp_nonneg(value, scale),
        PixelFormat::Rgb9e5x2 => clamp_nonneg(value, RGB9E5_MAX),
        PixelFormat::F16x6 | PixelFormat::F16x4 => clamp_nonneg(value, F16_MAX),
        PixelFormat::F32x6 | PixelFormat::F32x3 => clamp_nonneg(value, f32::MAX),
        PixelFormat::DepthF32 => floats::clamp_depth(value),
        PixelFormat::Rgba8Linear | PixelFormat::Rgba8Srgb => clamp_nonneg(value, 1.0),
    }
}

/// How far `value` lies outside the range (exact, in f64).
fn clamp_distance(format: PixelFormat, value: f32, scale: f32) -> f64 {
    if value.is_nan() {
        return 0.0;
    }
    let clamped = clamp_to_range(format, value, scale);
    // Subtracting infinities would give NaN; an infinite input is infinitely far from any value.
    if value.is_infinite() {
        f64::INFINITY
    } else {
        (f64::from(value) - f64::from(clamped)).abs()
    }
}

/// The quantisation part of the bound, at the clamped `value` (for `rgb9e5x2` the triple's
/// largest channel), for one channel of the pixel.
pub fn quantisation_bound(format: PixelFormat, channel: usize, value: f32, scale: f32) -> f32 {
    let clamped = clamp_to_range(format, value, scale);
    match format {
        PixelFormat::Seed64 => seed64::bound(channel, scale),
        PixelFormat::Rgb9e5x2 => rgb9e5::bound(clamped),
        PixelFormat::F16x6 | PixelFormat::F16x4 => halfs::bound(clamped),
        PixelFormat::F32x6 | PixelFormat::F32x3 | PixelFormat::DepthF32 => 0.0,
        PixelFormat::Rgba8Linear => rgba8::bound_linear(),
        PixelFormat::Rgba8Srgb => rgba8::bound_srgb(clamped),
    }
}

/// `v` clamped to `[0, max]`, NaN → 0. Written as selects so they compile to plain `maxps`/`minps`
/// (`f32::max` must also handle NaN in its second operand, which costs extra instructions).
#[inline(always)]
pub(crate) fn clamp_nonneg(v: f32, max: f32) -> f32 {
    let x = if v > 0.0 { v } else { 0.0 };
    if x < max { x } else { max }
}

/// Pixels of C channels with a channel above `max` (NaN never counts). A flat count, which
/// vectorises, screens the slice first; the per-pixel count runs only when something saturated.
#[inline]
pub(crate) fn count_saturated<const C: usize>(src: &[f32], max: f32) -> u64 {
    let over = src.iter().fold(0usize, |n, &v| n + usize::from(v > max));
    if over == 0 {
        return 0;
    }
    // Branch-free per pixel: saturation comes in clusters a branch predictor cannot learn.
    let pixels = src.as_chunks::<C>().0;
    let over = |p: &[f32; C]| p.iter().fold(false, |acc, &v| acc | (v > max));
    pixels.iter().map(|p| u64::from(over(p))).sum()
}

/// Rounds `x` in `[0, 2^22]` to the nearest integer (ties to even): adding 2^23 leaves the integer
/// in the low mantissa bits, exactly, without a float→int conversion.
#[inline(always)]
pub(crate) fn round_u32(x: f32) -> u32 {
    (x + 8_388_608.0).to_bits() & 0x7F_FFFF
}
