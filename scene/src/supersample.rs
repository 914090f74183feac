//! Antialiasing by supersampling (`--aa N`): the image is rendered at N·W × N·H — every pixel
//! covered by an N × N grid of sub-pixel centres — and each N × N block of the **final
//! radiance** is averaged into one output pixel (a box filter over the pixel's area). The resolve
//! comes after the material stage (`e + m⊙I`), never before it: the material multiply does not
//! commute with averaging (ARCHITECTURE §3). Depth resolves to the nearest covered sample.
//!
//! N = 1 renders and returns the image as it is, bit for bit.

use crate::image::Image;
use crate::limits::{LimitError, check_image_size};
use crate::model::Camera;

/// Why a supersampling factor cannot be used.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SupersampleError {
    #[error("--aa must be at least 1 (1 = one sample per pixel), not 0")]
    Zero,
    #[error(
        "--aa {factor} renders {width}x{height} as {}x{} internally: {limit}",
        u64::from(*width) * u64::from(*factor),
        u64::from(*height) * u64::from(*factor)
    )]
    TooLarge {
        factor: u32,
        width: u32,
        height: u32,
        limit: LimitError,
    },
    #[error("cannot resolve a {width}x{height} image by {factor}: not a multiple of it")]
    NotMultiple {
        factor: u32,
        width: u32,
        height: u32,
    },
}

/// The internal size of a `width × height` image supersampled `factor × factor`, checked against
/// the image limits (`crate::limits`).
pub fn supersampled_size(
    width: u32,
    height: u32,
    factor: u32,
) -> Result<(u32, u32), SupersampleError> {
    if factor == 0 {
        return Err(SupersampleError::Zero);
    }
    let too_large = |limit| SupersampleError::TooLarge {
        factor,
        width,
        height,
        limit,
    };
    let (w, h) = match (width.checked_mul(factor), height.checked_mul(factor)) {
        (Some(w), Some(h)) => (w, h),
        _ => {
            return Err(too_large(LimitError::ImageSize {
                width: width.saturating_mul(factor),
                height: height.saturating_mul(factor),
            }));
        }
    };
    check_image_size(w, h).map_err(too_large)?;
    Ok((w, h))
}

impl Camera {
    /// The same view at `factor` times the width and height (pixel `(i, j)` of the result has its
    /// centre at `((i + 0.5) / factor, (j + 0.5) / factor)` of this camera's image).
    pub fn supersampled(&self, factor: u32) -> Result<Camera, SupersampleError> {
        let (width, height) = supersampled_size(self.width, self.height, factor)?;
        Ok(Camera {
            width,
            height,
            ..*self
        })
    }
}

fn check_multiple(img: &Image, factor: u32) -> Result<(u32, u32), SupersampleError> {
    if factor == 0 {
        return Err(SupersampleError::Zero);
    }
    if !img.width.is_multiple_of(factor) || !img.height.is_multiple_of(factor) {
        return Err(SupersampleError::NotMultiple {
            factor,
            width: img.width,
            height: img.height,
        });
    }
    Ok((img.width / factor, img.height / factor))
}

/// Folds every `factor × factor` block of `img` into one pixel with `fold(block values of one
/// channel)`.
fn resolve_with(
    img: &Image,
    factor: u32,
    fold: impl Fn(&mut dyn Iterator<Item = f32>) -> f32,
) -> Result<Image, SupersampleError> {
    let (w, h) = check_multiple(img, factor)?;
    if factor == 1 {
        return Ok(img.clone());
    }
    let mut out = Image::new(w, h, img.channels);
    let n = factor as usize;
    for y in 0..h as usize {
        for x in 0..w as usize {
            for c in 0..img.channels {
                let mut values = (0..n).flat_map(|dy| {
                    let row = (y * n + dy) * img.width as usize;
                    (0..n).map(move |dx| img.data[(row + x * n + dx) * img.channels + c])
                });
                out.data[(y * w as usize + x) * img.channels + c] = fold(&mut values);
            }
        }
    }
    Ok(out)
}

impl Image {
    /// The box-filter resolve: each output pixel is the mean of its `factor × factor` block
    /// (summed in f64), in every channel. `factor = 1` returns the image unchanged.
    pub fn box_resolve(&self, factor: u32) -> Result<Image, SupersampleError> {
        let count = f64::from(factor) * f64::from(factor);
        resolve_with(self, factor, |v| {
            (v.map(f64::from).sum::<f64>() / count) as f32
        })
    }

    /// The depth resolve (0 = background): each output pixel takes the nearest covered sample of
    /// its block (the smallest positive depth), 0 when the whole block is background. So a
    /// silhouette pixel has the depth of the surface that covers part of it, never a blend of
    /// foreground and background distances that no surface has.
    pub fn nearest_depth_resolve(&self, factor: u32) -> Result<Image, SupersampleError> {
        resolve_with(self, factor, |v| {
            v.filter(|z| *z > 0.0)
                .fold(0.0, |m: f32, z| if m == 0.0 || z < m { z } else { m })
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(w: u32, h: u32, c: usize) -> Image {
        let mut img = Image::new(w, h, c);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = i as f32 * 0.25 - 3.0;
        }
        img
    }

    /// A 4x2 single-channel image: blocks of 2x2 are `[0, 1, 4, 5]` and `[2, 3, 6, 7]`.
    fn four_by_two(data: [f32; 8]) -> Image {
        Image {
            width: 4,
            height: 2,
            channels: 1,
            data: data.to_vec(),
        }
    }

    #[test]
    fn factor_one_is_the_same_bits() {
        let img = ramp(5, 3, 3);
        assert_eq!(img.box_resolve(1).unwrap(), img);
        assert_eq!(img.nearest_depth_resolve(1).unwrap(), img);
    }

    #[test]
    fn box_resolve_averages_each_block() {
        let img = four_by_two([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]);
        let r = img.box_resolve(2).unwrap();
        assert_eq!((r.width, r.height), (2, 1));
        assert_eq!(r.data, vec![2.5, 4.5]);
        // Channels stay apart, and the mean is preserved.
        let img = ramp(6, 9, 3);
        let r = img.box_resolve(3).unwrap();
        let mean =
            |i: &Image| i.data.iter().map(|&v| f64::from(v)).sum::<f64>() / i.data.len() as f64;
        assert!((mean(&r) - mean(&img)).abs() < 1e-5);
        assert_eq!(r.pixel(1, 2)[1], {
            let mut s = 0.0f64;
            for y in 6..9 {
                for x in 3..6 {
                    s += f64::from(img.pixel(x, y)[1]);
                }
            }
            (s / 9.0) as f32
        });
    }

    #[test]
    fn depth_takes_the_nearest_covered_sample() {
        let img = four_by_two([0.0, 3.0, 0.0, 0.0, 2.0, 5.0, 0.0, 0.0]);
        let r = img.nearest_depth_resolve(2).unwrap();
        assert_eq!(r.data, vec![2.0, 0.0]);
    }

    #[test]
    fn bad_factors_are_errors() {
        let img = ramp(5, 4, 1);
        assert_eq!(
            img.box_resolve(2),
            Err(SupersampleError::NotMultiple {
                factor: 2,
                width: 5,
                height: 4
            })
        );
        assert_eq!(img.box_resolve(0), Err(SupersampleError::Zero));
        assert_eq!(supersampled_size(8, 8, 0), Err(SupersampleError::Zero));
        assert_eq!(supersampled_size(800, 600, 4), Ok((3200, 2400)));
        // 4096x4096 pixels in all: 800x600 at 8 is 6400x4800, over it.
        let e = supersampled_size(800, 600, 8).unwrap_err();
        assert!(matches!(e, SupersampleError::TooLarge { factor: 8, .. }));
        assert!(e.to_string().contains("6400x4800"), "{e}");
        // Overflow of u32 is the same error, not a wrap.
        assert!(matches!(
            supersampled_size(u32::MAX, 1, 2),
            Err(SupersampleError::TooLarge { .. })
        ));
    }
}
