//! Cutting a rendered frame into bands and packing them into link formats, in the order the
//! cluster protocol fixes: band-major (rows `[b·H, min((b+1)·H, height))`), and within a band the
//! configured layers in configuration order. A band whose source values are all zero is flagged
//! empty and carries no payload, and so is every band wholly outside a sort-first tile's rows,
//! without looking at its pixels. Packing runs on a blocking thread and hands each band to the
//! async sender through a bounded channel, so the first bands are on the wire while later ones are
//! still being packed.

use crate::gpu::pack::PackedFrame;
use bytes::Bytes;
use lightfold_protocol::format::{self, FormatError};
use lightfold_protocol::{BandHeader, Layer, PixelFormat};
use lightfold_scene::Image;
use std::sync::Arc;
use std::time::Instant;
use tokio::sync::mpsc;

/// One packed band, ready for `Frame::Band`.
#[derive(Debug, Clone)]
pub struct PackedBand {
    pub header: BandHeader,
    pub payload: Bytes,
}

/// What packing a whole frame cost and found.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PackTotals {
    pub pack_us: u64,
    pub empty_bands: u32,
    pub saturated: u64,
    pub bands: u32,
    /// Largest finite value of the illumination layer (`FrameStats::peak`).
    pub peak: f32,
}

#[derive(Debug, thiserror::Error)]
pub enum PackError {
    #[error("layer {layer:?} was configured but the renderer produced no image for it")]
    MissingLayer { layer: Layer },
    #[error(
        "layer {layer:?} image is {width}x{height}x{channels}, the frame is {frame_width}x{frame_height}x{expected}"
    )]
    Shape {
        layer: Layer,
        width: u32,
        height: u32,
        channels: usize,
        frame_width: u32,
        frame_height: u32,
        expected: usize,
    },
    #[error("packing layer {layer:?}: {source}")]
    Format { layer: Layer, source: FormatError },
    #[error(
        "the device packed {layers} layers of {width}x{height} in bands of {band_height} rows, the frame configures {expected} of {frame_width}x{frame_height} in bands of {frame_band_height}"
    )]
    DeviceShape {
        layers: usize,
        width: u32,
        height: u32,
        band_height: u32,
        expected: usize,
        frame_width: u32,
        frame_height: u32,
        frame_band_height: u32,
    },
}

/// The layout of a frame's bands (the protocol's, shared with the compositor).
pub use lightfold_protocol::BandLayout;

/// The images of one frame, one per configured layer in configuration order.
pub type LayerImages = Vec<(Layer, PixelFormat, Arc<Image>)>;

/// Checks every configured layer has an image of the frame's size.
pub fn check_images(layout: &BandLayout, images: &LayerImages) -> Result<(), PackError> {
    for (layer, _, img) in images {
        if img.width != layout.width
            || img.height != layout.height
            || img.channels != layer.channels()
            || img.data.len() != img.pixel_count() * img.channels
        {
            return Err(PackError::Shape {
                layer: *layer,
                width: img.width,
                height: img.height,
                channels: img.channels,
                frame_width: layout.width,
                frame_height: layout.height,
                expected: layer.channels(),
            });
        }
    }
    Ok(())
}

/// Whether band `band` of `layout` has no row in `rows` (a sort-first tile's `[y0, y1)`;
/// `None`: every row), so it travels empty unread.
pub fn outside_rows(layout: &BandLayout, band: u32, rows: Option<[u32; 2]>) -> bool {
    let (b0, b1) = layout.rows(band);
    rows.is_some_and(|[y0, y1]| b1 <= y0 || b0 >= y1)
}

/// The empty band `band` of `layer` (no payload).
fn empty_band(layout: &BandLayout, band: u32, layer: Layer, format: PixelFormat) -> PackedBand {
    let mut header = layout.header(band, layer, format);
    header.empty = true;
    header.seal(&[]);
    PackedBand {
        header,
        payload: Bytes::new(),
    }
}

/// Packs one band of one layer.
pub fn pack_band(
    layout: &BandLayout,
    band: u32,
    layer: Layer,
    format: PixelFormat,
    image: &Image,
) -> Result<PackedBand, PackError> {
    let (y0, y1) = layout.rows(band);
    let row = image.width as usize * image.channels;
    let src = &image.data[y0 as usize * row..y1 as usize * row];
    let mut header = layout.header(band, layer, format);
    // Only exact zeros make an empty band: whatever packs to zero but is not zero still travels,
    // so the receiver's unpacked values never depend on this shortcut.
    if src.iter().all(|v| *v == 0.0) {
        return Ok(empty_band(layout, band, layer, format));
    }
    let mut payload = vec![0u8; (src.len() / image.channels) * format.bytes_per_pixel()];
    let stats = format::pack(format, src, layout.scale, &mut payload)
        .map_err(|source| PackError::Format { layer, source })?;
    header.saturated = u32::try_from(stats.saturated).unwrap_or(u32::MAX);
    header.seal(&payload);
    Ok(PackedBand {
        header,
        payload: Bytes::from(payload),
    })
}

/// Packs every band of the frame in protocol order and hands each to `out` (blocking when the
/// sender is behind). Stops early, without error, when the receiver is gone. With `rows` (a
/// sort-first tile, the images zero elsewhere) the bands wholly outside them go out empty
/// without being looked at.
pub fn pack_frame(
    layout: &BandLayout,
    images: &LayerImages,
    rows: Option<[u32; 2]>,
    out: &mpsc::Sender<PackedBand>,
) -> Result<PackTotals, PackError> {
    check_images(layout, images)?;
    let mut totals = PackTotals {
        peak: illumination_peak(images, rows),
        ..PackTotals::default()
    };
    for band in 0..layout.bands() {
        let outside = outside_rows(layout, band, rows);
        for (layer, format, image) in images {
            let start = Instant::now();
            let packed = if outside {
                empty_band(layout, band, *layer, *format)
            } else {
                pack_band(layout, band, *layer, *format, image)?
            };
            totals.pack_us += start.elapsed().as_micros() as u64;
            totals.bands += 1;
            totals.empty_bands += u32::from(packed.header.empty);
            totals.saturated += u64::from(packed.header.saturated);
            if out.blocking_send(packed).is_err() {
                return Ok(totals);
            }
        }
    }
    Ok(totals)
}

/// Cuts a frame packed on the device (`gpu::pack`) into bands in protocol order and hands each
/// to `out`, as [`pack_frame`] does with images: the same headers (a band whose source values
/// are all zero travels empty, saturated pixels counted per band) and the same payloads, each a
/// slice of the layer's packed bytes (no copy). `pack_us` is the time spent sealing bands
/// (checksums). The device packed and read back only the bands a tile's rows meet
/// (`PackedFrame::first_row` to `end_row`); the others are empty.
pub fn assemble_frame(
    layout: &BandLayout,
    layers: &[(Layer, PixelFormat)],
    packed: &PackedFrame,
    out: &mpsc::Sender<PackedBand>,
) -> Result<PackTotals, PackError> {
    let bands = layout.bands();
    let held = |(y0, y1): (u32, u32)| packed.first_row <= y0 && y1 <= packed.end_row;
    let fits = packed.layers.len() == layers.len()
        && (packed.width, packed.height) == (layout.width, layout.height)
        && packed.band_height == layout.band_height.clamp(1, layout.height.max(1))
        && packed.layers.iter().zip(layers).all(|(p, (_, f))| {
            let row = layout.width as usize * f.bytes_per_pixel();
            let rows = packed.end_row.saturating_sub(packed.first_row) as usize;
            p.format == *f && p.bands.len() == bands as usize && p.bytes.len() == row * rows
        });
    if !fits {
        return Err(PackError::DeviceShape {
            layers: packed.layers.len(),
            width: packed.width,
            height: packed.height,
            band_height: packed.band_height,
            expected: layers.len(),
            frame_width: layout.width,
            frame_height: layout.height,
            frame_band_height: layout.band_height,
        });
    }
    let mut totals = PackTotals {
        peak: packed.peak,
        ..PackTotals::default()
    };
    for band in 0..bands {
        let (y0, y1) = layout.rows(band);
        for ((layer, format), p) in layers.iter().zip(&packed.layers) {
            let start = Instant::now();
            let row = layout.width as usize * format.bytes_per_pixel();
            // A band the device did not read back holds nothing (outside the tile).
            let count = if held((y0, y1)) {
                p.bands[band as usize]
            } else {
                Default::default()
            };
            let mut header = BandHeader {
                empty: !count.nonzero,
                saturated: if count.nonzero { count.saturated } else { 0 },
                ..layout.header(band, *layer, *format)
            };
            let payload = if count.nonzero {
                let first = packed.first_row as usize;
                p.bytes
                    .slice((y0 as usize - first) * row..(y1 as usize - first) * row)
            } else {
                Bytes::new()
            };
            header.seal(&payload);
            totals.pack_us += start.elapsed().as_micros() as u64;
            totals.bands += 1;
            totals.empty_bands += u32::from(header.empty);
            totals.saturated += u64::from(header.saturated);
            if out.blocking_send(PackedBand { header, payload }).is_err() {
                return Ok(totals);
            }
        }
    }
    Ok(totals)
}

/// Largest finite value of the frame's illumination layer, 0 without one; with `rows` (a
/// sort-first tile, zero elsewhere) only those rows are looked at.
pub fn illumination_peak(images: &LayerImages, rows: Option<[u32; 2]>) -> f32 {
    images
        .iter()
        .filter(|(layer, _, _)| *layer == Layer::Illumination)
        .flat_map(|(_, _, image)| {
            let row = image.width as usize * image.channels;
            let [y0, y1] = rows.unwrap_or([0, image.height]);
            let (a, b) = (y0 as usize * row, (y1 as usize * row).min(image.data.len()));
            image.data[a.min(b)..b].iter().copied()
        })
        .filter(|v| v.is_finite())
        .fold(0.0, f32::max)
}

/// The same bands stamped with another frame number (checksums cover payloads only, so they
/// stay valid).
pub fn restamp(bands: &[PackedBand], frame: u64) -> impl Iterator<Item = PackedBand> + '_ {
    bands.iter().map(move |b| PackedBand {
        header: BandHeader { frame, ..b.header },
        payload: b.payload.clone(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layout(height: u32, band_height: u32) -> BandLayout {
        BandLayout {
            epoch: 3,
            frame: 9,
            width: 4,
            height,
            band_height,
            scale: 1.0,
        }
    }

    #[test]
    fn bands_cover_every_row_once() {
        for (h, bh) in [(1, 1), (7, 3), (600, 64), (600, 600), (5, 9)] {
            let l = layout(h, bh);
            let mut next = 0;
            for b in 0..l.bands() {
                let (y0, y1) = l.rows(b);
                assert_eq!(y0, next);
                assert!(y1 > y0);
                next = y1;
            }
            assert_eq!(next, h);
        }
    }

    #[test]
    fn frames_pack_band_major_with_empty_bands_flagged() {
        let l = layout(5, 2);
        let mut illum = Image::new(4, 5, 6);
        // Rows 0-1 stay zero; row 3 carries light.
        illum.pixel_mut(1, 3)[0] = 0.5;
        let mut depth = Image::new(4, 5, 1);
        depth.data.iter_mut().for_each(|v| *v = 2.0);
        let images: LayerImages = vec![
            (
                Layer::Illumination,
                PixelFormat::F32x6,
                Arc::new(illum.clone()),
            ),
            (Layer::Depth, PixelFormat::DepthF32, Arc::new(depth)),
        ];
        let (tx, mut rx) = mpsc::channel(64);
        let totals = pack_frame(&l, &images, None, &tx).unwrap();
        drop(tx);
        let mut got = Vec::new();
        while let Ok(b) = rx.try_recv() {
            got.push(b);
        }
        let order: Vec<(u32, Layer, bool)> = got
            .iter()
            .map(|b| (b.header.y0, b.header.layer, b.header.empty))
            .collect();
        assert_eq!(
            order,
            vec![
                (0, Layer::Illumination, true),
                (0, Layer::Depth, false),
                (2, Layer::Illumination, false),
                (2, Layer::Depth, false),
                (4, Layer::Illumination, true),
                (4, Layer::Depth, false),
            ]
        );
        assert_eq!(totals.empty_bands, 2);
        assert_eq!(totals.bands, 6);
        assert!(got[0].payload.is_empty());
        let b = &got[2];
        assert_eq!(b.header.height, 2);
        let mut back = vec![0.0; 4 * 2 * 6];
        format::unpack(b.header.format, &b.payload, b.header.scale, &mut back).unwrap();
        assert_eq!(back, illum.data[2 * 4 * 6..4 * 4 * 6]);
        let again: Vec<PackedBand> = restamp(&got, 10).collect();
        assert!(again.iter().all(|b| b.header.frame == 10));
        assert_eq!(again[2].header.checksum, got[2].header.checksum);
    }

    #[test]
    fn a_wrongly_sized_image_is_refused() {
        let l = layout(5, 2);
        let images: LayerImages = vec![(
            Layer::Illumination,
            PixelFormat::F32x6,
            Arc::new(Image::new(4, 4, 6)),
        )];
        let (tx, _rx) = mpsc::channel(4);
        assert!(matches!(
            pack_frame(&l, &images, None, &tx),
            Err(PackError::Shape { .. })
        ));
    }
}
