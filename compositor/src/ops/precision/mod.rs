//! What the link formats do to the accumulated illumination, as code the planner and the cluster
//! tests use: the recommended format per kind of link, and the error bound of a chain of stages
//! that accumulate in f32 and re-pack at every hop. `study` measures both on synthetic HDR and
//! dark content; docs/precision.md has the figures and the reasoning.

pub mod study;

use lightfold_protocol::PixelFormat;
use lightfold_protocol::format::{self, F16_MAX, RGB9E5_MAX};

pub use lightfold_protocol::pipeline::{LinkKind, recommended_link_format};

/// A link format with the scale fixed-point formats need (`seed64`; ignored by the others).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinkFormat {
    pub format: PixelFormat,
    pub scale: f32,
}

impl LinkFormat {
    pub fn new(format: PixelFormat, scale: f32) -> Self {
        LinkFormat { format, scale }
    }
}

impl From<PixelFormat> for LinkFormat {
    /// Scale 1 (the only scale-free formats are the float and shared-exponent ones).
    fn from(format: PixelFormat) -> Self {
        LinkFormat { format, scale: 1.0 }
    }
}

/// The largest value a channel of `link` holds without saturating.
pub fn link_range(link: LinkFormat) -> f32 {
    match link.format {
        PixelFormat::Seed64 => link.scale,
        PixelFormat::Rgb9e5x2 => RGB9E5_MAX,
        PixelFormat::F16x6 | PixelFormat::F16x4 => F16_MAX,
        PixelFormat::Rgba8Linear | PixelFormat::Rgba8Srgb => 1.0,
        PixelFormat::F32x6 | PixelFormat::F32x3 | PixelFormat::DepthF32 => f32::MAX,
    }
}

/// The documented error bound of a chain: after `hops` stages that each add one term in f32 and
/// re-pack the partial sum into `link`, a channel whose partial sums never exceed `value` is
/// within the returned distance of the exact sum of the terms (the f32 products `c_n ⊙ I_n`).
/// For `rgb9e5x2`, `value` must bound the largest channel of the channel's RGB triple (the
/// exponent is shared); for `seed64` it is the coarser specular (10-bit) step. Infinite when
/// `value` does not fit the link's range (the chain saturates) or is not finite.
///
/// Each hop adds the f32 rounding of the sum (half an ulp, ≤ 2^-24 of the partial) and the
/// format's quantisation at the partial (`protocol::format::quantisation_bound`); the partial a
/// hop packs may already exceed the exact one by the error so far, which the bound accounts for.
pub fn chain_bound(link: impl Into<LinkFormat>, hops: u32, value: f32) -> f32 {
    let link = link.into();
    if !value.is_finite() || value > link_range(link) {
        return f32::INFINITY;
    }
    let value = if value > 0.0 { value } else { 0.0 };
    let channel = link.format.channels().saturating_sub(1);
    let mut err = 0f64;
    for _ in 0..hops {
        let v = (f64::from(value) + err) as f32;
        let v = v.min(link_range(link));
        let q = format::quantisation_bound(link.format, channel, v, link.scale);
        err += f64::from(q) + f64::from(v) * f64::from(f32::EPSILON) / 2.0;
    }
    let e = err as f32;
    if f64::from(e) < err { e.next_up() } else { e }
}
