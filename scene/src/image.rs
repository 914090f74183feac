//! In-memory images of `channels` interleaved f32 values per pixel, row 0 at the top, and their
//! EXR (linear) and PNG (sRGB at an exposure) files.

use std::path::Path;

/// Layout of the six-channel illumination layer: diffuse RGB then specular RGB.
pub const ILLUMINATION_CHANNELS: usize = 6;

#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub channels: usize,
    pub data: Vec<f32>,
}

#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    #[error("cannot write {path}: {message}")]
    Write { path: String, message: String },
    #[error("cannot read {path}: {message}")]
    Read { path: String, message: String },
    #[error("image has {channels} channels; {what} needs {needed}")]
    Channels {
        channels: usize,
        needed: usize,
        what: &'static str,
    },
}

impl Image {
    pub fn new(width: u32, height: u32, channels: usize) -> Self {
        Image {
            width,
            height,
            channels,
            data: vec![0.0; width as usize * height as usize * channels],
        }
    }

    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    pub fn pixel(&self, x: u32, y: u32) -> &[f32] {
        let i = (y as usize * self.width as usize + x as usize) * self.channels;
        &self.data[i..i + self.channels]
    }

    pub fn pixel_mut(&mut self, x: u32, y: u32) -> &mut [f32] {
        let i = (y as usize * self.width as usize + x as usize) * self.channels;
        &mut self.data[i..i + self.channels]
    }

    /// The first three channels as RGB pixels.
    pub fn rgb(&self, x: u32, y: u32) -> [f32; 3] {
        let p = self.pixel(x, y);
        [p[0], p[1], p[2]]
    }

    /// Writes the first three channels as linear RGB (float) EXR.
    pub fn write_exr(&self, path: &Path) -> Result<(), ImageError> {
        self.need(3, "EXR output")?;
        let c = self.channels;
        let w = self.width as usize;
        exr::prelude::write_rgb_file(path, w, self.height as usize, |x, y| {
            let i = (y * w + x) * c;
            (self.data[i], self.data[i + 1], self.data[i + 2])
        })
        .map_err(|e| ImageError::Write {
            path: path.display().to_string(),
            message: e.to_string(),
        })
    }

    /// The first three channels as linear RGB (float) EXR file bytes.
    pub fn exr_bytes(&self) -> Result<Vec<u8>, ImageError> {
        use exr::prelude::{SpecificChannels, Vec2, WritableImage};
        self.need(3, "EXR output")?;
        let c = self.channels;
        let w = self.width as usize;
        let channels = SpecificChannels::rgb(|p: Vec2<usize>| {
            let i = (p.y() * w + p.x()) * c;
            (self.data[i], self.data[i + 1], self.data[i + 2])
        });
        let image = exr::image::Image::from_channels((w, self.height as usize), channels);
        let mut out = std::io::Cursor::new(Vec::new());
        image
            .write()
            .to_buffered(&mut out)
            .map_err(|e| ImageError::Write {
                path: "(memory)".to_string(),
                message: e.to_string(),
            })?;
        Ok(out.into_inner())
    }

    /// Reads the first RGB(A) layer of an EXR file as a 3-channel image.
    pub fn read_exr(path: &Path) -> Result<Image, ImageError> {
        let img = exr::prelude::read_first_rgba_layer_from_file(
            path,
            |res, _| {
                let (w, h) = (res.width(), res.height());
                Image::new(w as u32, h as u32, 3)
            },
            |img: &mut Image, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                let p = img.pixel_mut(pos.x() as u32, pos.y() as u32);
                p.copy_from_slice(&[r, g, b]);
            },
        )
        .map_err(|e| ImageError::Read {
            path: path.display().to_string(),
            message: e.to_string(),
        })?;
        Ok(img.layer_data.channel_data.pixels)
    }

    /// 8-bit sRGB of the first three channels: `sRGB(clamp(exposure·L))`.
    pub fn to_srgb8(&self, exposure: f32) -> Result<Vec<u8>, ImageError> {
        self.need(3, "sRGB output")?;
        let mut out = Vec::with_capacity(self.pixel_count() * 3);
        lightfold_protocol::srgb::encode_rgb8(&self.data, self.channels, exposure, &mut out);
        Ok(out)
    }

    /// Writes the first three channels as an sRGB PNG at `exposure`.
    pub fn write_png(&self, path: &Path, exposure: f32) -> Result<(), ImageError> {
        let bytes = self.to_srgb8(exposure)?;
        image::save_buffer(
            path,
            &bytes,
            self.width,
            self.height,
            image::ColorType::Rgb8,
        )
        .map_err(|e| ImageError::Write {
            path: path.display().to_string(),
            message: e.to_string(),
        })
    }

    /// The first three channels as sRGB PNG file bytes at `exposure`.
    pub fn png_bytes(&self, exposure: f32) -> Result<Vec<u8>, ImageError> {
        use image::ImageEncoder;
        let rgb = self.to_srgb8(exposure)?;
        let mut out = Vec::new();
        image::codecs::png::PngEncoder::new(&mut out)
            .write_image(
                &rgb,
                self.width,
                self.height,
                image::ExtendedColorType::Rgb8,
            )
            .map_err(|e| ImageError::Write {
                path: "(memory)".to_string(),
                message: e.to_string(),
            })?;
        Ok(out)
    }

    fn need(&self, needed: usize, what: &'static str) -> Result<(), ImageError> {
        if self.channels < needed {
            return Err(ImageError::Channels {
                channels: self.channels,
                needed,
                what,
            });
        }
        Ok(())
    }
}
