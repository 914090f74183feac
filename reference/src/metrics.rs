//! Image metrics over linear radiance, used by every accuracy claim: RMSE, relative MSE, PSNR,
//! max abs error, energy bias, non-finite count and FLIP, over the whole image and over a mask
//! (the penumbra). Values are compared after scaling by the exposure, so PSNR's peak of 1.0 is
//! the white point of the PNG a person looks at.

use lightfold_scene::Image;
use std::fmt;

/// The `ε` of relative MSE, `(t − r)² / (r² + ε)`, in exposure-scaled units.
pub const REL_MSE_EPSILON: f64 = 1e-2;
/// A comparison is "within the floor" when its RMSE is at most this multiple of the floor's.
pub const FLOOR_FACTOR: f64 = 10.0;

#[derive(Debug, thiserror::Error)]
pub enum MetricsError {
    #[error(
        "image sizes differ: test is {test_width}x{test_height}, reference {ref_width}x{ref_height}"
    )]
    Size {
        test_width: u32,
        test_height: u32,
        ref_width: u32,
        ref_height: u32,
    },
    #[error("{what} has {channels} channels; metrics need at least 3")]
    Channels { what: &'static str, channels: usize },
    #[error("mask has {mask} entries for {pixels} pixels")]
    Mask { mask: usize, pixels: usize },
}

/// Pixel-error statistics over a set of pixels (RGB channels, exposure-scaled).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ErrorStats {
    /// Pixels counted (finite in both images).
    pub pixels: usize,
    pub rmse: f64,
    /// Mean of `(t − r)² / (r² + ε)` over channels.
    pub rel_mse: f64,
    /// `10·log10(1 / MSE)`; infinite for identical images.
    pub psnr: f64,
    pub max_abs: f64,
    /// `mean(test) / mean(reference) − 1`; 0 when both are black.
    pub energy_bias: f64,
    /// Pixels with a NaN or infinite channel in either image (left out of the other figures).
    pub non_finite: usize,
}

/// The full comparison of a test image against a reference.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Metrics {
    pub exposure: f32,
    pub whole: ErrorStats,
    /// Mean FLIP error (LDR, sRGB of `clamp(exposure·L)`) over the whole image.
    pub flip: f64,
    /// The same over the penumbra mask, when one was given.
    pub penumbra: Option<ErrorStats>,
    pub penumbra_flip: Option<f64>,
}

impl Metrics {
    /// Whether this error is within [`FLOOR_FACTOR`]× the noise floor: RMSE over the whole image
    /// and (when both have one) over the penumbra, and no non-finite pixels.
    pub fn within_floor(&self, floor: &Metrics) -> bool {
        let ok = |e: &ErrorStats, f: &ErrorStats| e.rmse <= FLOOR_FACTOR * f.rmse;
        let penumbra = match (&self.penumbra, &floor.penumbra) {
            (Some(e), Some(f)) => ok(e, f),
            _ => true,
        };
        self.whole.non_finite == 0 && ok(&self.whole, &floor.whole) && penumbra
    }
}

impl fmt::Display for ErrorStats {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "pixels {:>8}  rmse {:.3e}  relmse {:.3e}  psnr {:>6.2} dB  max {:.3e}  bias {:+.3e}  non-finite {}",
            self.pixels,
            self.rmse,
            self.rel_mse,
            self.psnr,
            self.max_abs,
            self.energy_bias,
            self.non_finite
        )
    }
}

impl fmt::Display for Metrics {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // (Errors of the linear values × exposure; FLIP of the tone-mapped images at it.)
        writeln!(
            f,
            "whole     {}  flip {:.4}  (at exposure {})",
            self.whole, self.flip, self.exposure
        )?;
        match (&self.penumbra, self.penumbra_flip) {
            (Some(p), Some(fl)) => write!(f, "penumbra  {p}  flip {fl:.4}"),
            (Some(p), None) => write!(f, "penumbra  {p}"),
            _ => write!(
                f,
                "penumbra  (no mask: it needs the reference's unoccluded image, \
                 `compare --unoccluded FILE`, which `lightfold render --unoccluded-out FILE` writes)"
            ),
        }
    }
}

/// Compares `test` against `reference`: whole image, and over `penumbra` when given.
pub fn compare(
    test: &Image,
    reference: &Image,
    exposure: f32,
    penumbra: Option<&[bool]>,
) -> Result<Metrics, MetricsError> {
    compare_over(test, reference, exposure, None, penumbra)
}

/// [`compare`] with the "whole image" limited to the pixels `compared` holds (all without it):
/// the area-light truth leaves out pixel centres that lie on a boundary between two surfaces
/// ([`crate::masks::ties`]).
pub fn compare_over(
    test: &Image,
    reference: &Image,
    exposure: f32,
    compared: Option<&[bool]>,
    penumbra: Option<&[bool]>,
) -> Result<Metrics, MetricsError> {
    let whole = error_stats(test, reference, exposure, compared)?;
    let flip = flip_map(test, reference, exposure)?;
    let mean = |mask: Option<&[bool]>| {
        let (mut sum, mut n) = (0.0f64, 0usize);
        for (i, &e) in flip.iter().enumerate() {
            if mask.is_none_or(|m| m.get(i).copied().unwrap_or(false)) {
                sum += f64::from(e);
                n += 1;
            }
        }
        if n == 0 { 0.0 } else { sum / n as f64 }
    };
    let masked = penumbra
        .map(|m| error_stats(test, reference, exposure, Some(m)))
        .transpose()?;
    Ok(Metrics {
        exposure,
        whole,
        flip: mean(compared),
        penumbra: masked,
        penumbra_flip: penumbra.map(|m| mean(Some(m))),
    })
}

/// Pixel-error statistics over the pixels where `mask` is true (all pixels without a mask).
pub fn error_stats(
    test: &Image,
    reference: &Image,
    exposure: f32,
    mask: Option<&[bool]>,
) -> Result<ErrorStats, MetricsError> {
    check(test, reference)?;
    let n = test.pixel_count();
    if let Some(m) = mask
        && m.len() != n
    {
        return Err(MetricsError::Mask {
            mask: m.len(),
            pixels: n,
        });
    }
    let x = f64::from(exposure);
    let (mut se, mut rel, mut max, mut st, mut sr) = (0.0, 0.0, 0.0f64, 0.0, 0.0);
    let (mut pixels, mut non_finite) = (0usize, 0usize);
    for i in 0..n {
        if mask.is_some_and(|m| !m[i]) {
            continue;
        }
        let t = &test.data[i * test.channels..i * test.channels + 3];
        let r = &reference.data[i * reference.channels..i * reference.channels + 3];
        if !t.iter().chain(r).all(|v| v.is_finite()) {
            non_finite += 1;
            continue;
        }
        pixels += 1;
        for k in 0..3 {
            let (tv, rv) = (x * f64::from(t[k]), x * f64::from(r[k]));
            let d = tv - rv;
            se += d * d;
            rel += d * d / (rv * rv + REL_MSE_EPSILON);
            max = max.max(d.abs());
            st += tv;
            sr += rv;
        }
    }
    let count = (3 * pixels).max(1) as f64;
    let mse = se / count;
    let energy_bias = if sr != 0.0 {
        st / sr - 1.0
    } else if st == 0.0 {
        0.0
    } else {
        f64::INFINITY
    };
    Ok(ErrorStats {
        pixels,
        rmse: mse.sqrt(),
        rel_mse: rel / count,
        psnr: if mse > 0.0 {
            -10.0 * mse.log10()
        } else {
            f64::INFINITY
        },
        max_abs: max,
        energy_bias,
        non_finite,
    })
}

/// Per-pixel LDR FLIP error in [0, 1] between the sRGB renderings of `clamp(exposure·L)`.
pub fn flip_map(test: &Image, reference: &Image, exposure: f32) -> Result<Vec<f32>, MetricsError> {
    check(test, reference)?;
    let srgb = |img: &Image, what| {
        img.to_srgb8(exposure).map_err(|_| MetricsError::Channels {
            what,
            channels: img.channels,
        })
    };
    let (w, h) = (test.width, test.height);
    if w == 0 || h == 0 {
        return Ok(Vec::new());
    }
    let r = nv_flip::FlipImageRgb8::with_data(w, h, &srgb(reference, "reference")?);
    let t = nv_flip::FlipImageRgb8::with_data(w, h, &srgb(test, "test")?);
    Ok(nv_flip::flip(r, t, nv_flip::DEFAULT_PIXELS_PER_DEGREE).to_vec())
}

/// The FLIP error map rendered with the magma colour map (8-bit RGB, row 0 at the top).
pub fn flip_error_map_rgb8(
    test: &Image,
    reference: &Image,
    exposure: f32,
) -> Result<Vec<u8>, MetricsError> {
    let map = flip_map(test, reference, exposure)?;
    if map.is_empty() {
        return Ok(Vec::new());
    }
    let img = nv_flip::FlipImageFloat::with_data(test.width, test.height, &map);
    Ok(img.apply_color_lut(&nv_flip::magma_lut()).to_vec())
}

fn check(test: &Image, reference: &Image) -> Result<(), MetricsError> {
    if test.width != reference.width || test.height != reference.height {
        return Err(MetricsError::Size {
            test_width: test.width,
            test_height: test.height,
            ref_width: reference.width,
            ref_height: reference.height,
        });
    }
    for (what, img) in [("test", test), ("reference", reference)] {
        if img.channels < 3 || img.data.len() < img.pixel_count() * img.channels {
            return Err(MetricsError::Channels {
                what,
                channels: img.channels,
            });
        }
    }
    Ok(())
}
