//! Pixel formats of the links (ARCHITECTURE §7).

use serde::{Deserialize, Serialize};

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
