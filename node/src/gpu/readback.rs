//! Reading render targets back to the CPU: one copy per texture into a mappable buffer whose rows
//! are padded to wgpu's 256-byte alignment, then unpadded and converted to f32 channels.

use super::frame::RenderError;

/// A render target to read and how many of its channels to keep.
#[derive(Debug, Clone, Copy)]
pub struct ReadRequest<'a> {
    pub texture: &'a wgpu::Texture,
    pub keep_channels: usize,
}

/// Bytes per row of a `width`-pixel copy, padded to `COPY_BYTES_PER_ROW_ALIGNMENT`.
pub fn padded_row(width: u32, bytes_per_pixel: u32) -> u32 {
    let align = wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
    (width * bytes_per_pixel).div_ceil(align) * align
}

fn format_info(f: wgpu::TextureFormat) -> Result<(u32, usize, bool), RenderError> {
    // (bytes per pixel, channels, half floats); 32-bit formats hold f32 bits either way.
    match f {
        wgpu::TextureFormat::Rgba32Float | wgpu::TextureFormat::Rgba32Uint => Ok((16, 4, false)),
        wgpu::TextureFormat::Rgba16Float => Ok((8, 4, true)),
        wgpu::TextureFormat::R32Float | wgpu::TextureFormat::R32Uint => Ok((4, 1, false)),
        other => Err(RenderError::Gpu(format!(
            "cannot read back format {other:?}"
        ))),
    }
}

/// Copies every requested target and returns, per request, `keep_channels` f32 values per pixel
/// (row 0 at the top).
pub fn read_targets(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    requests: &[ReadRequest<'_>],
) -> Result<Vec<Vec<f32>>, RenderError> {
    let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
        label: Some("readback"),
    });
    let mut staging = Vec::with_capacity(requests.len());
    for r in requests {
        let size = r.texture.size();
        let (bpp, _, _) = format_info(r.texture.format())?;
        let row = padded_row(size.width, bpp);
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: row as u64 * size.height as u64,
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        encoder.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: r.texture,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &buffer,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(row),
                    rows_per_image: Some(size.height),
                },
            },
            wgpu::Extent3d {
                width: size.width,
                height: size.height,
                depth_or_array_layers: 1,
            },
        );
        staging.push((buffer, row));
    }
    queue.submit([encoder.finish()]);
    let (tx, rx) = std::sync::mpsc::channel();
    for (i, (buffer, _)) in staging.iter().enumerate() {
        let tx = tx.clone();
        buffer.map_async(wgpu::MapMode::Read, .., move |r| {
            let _ = tx.send((i, r));
        });
    }
    drop(tx);
    device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(|e| RenderError::Gpu(format!("readback wait: {e}")))?;
    for (i, r) in rx.iter() {
        r.map_err(|e| RenderError::Gpu(format!("map of target {i}: {e}")))?;
    }
    let mut out = Vec::with_capacity(requests.len());
    for (r, (buffer, row)) in requests.iter().zip(&staging) {
        let size = r.texture.size();
        let (bpp, channels, half) = format_info(r.texture.format())?;
        let keep = r.keep_channels.min(channels);
        let mapped = buffer
            .get_mapped_range(..)
            .map_err(|e| RenderError::Gpu(format!("mapped range: {e}")))?;
        let mut data = Vec::with_capacity(size.width as usize * size.height as usize * keep);
        for y in 0..size.height as usize {
            let line = &mapped[y * *row as usize..][..(size.width * bpp) as usize];
            for px in line.chunks_exact(bpp as usize) {
                for c in 0..keep {
                    let v = if half {
                        half::f16::from_le_bytes([px[c * 2], px[c * 2 + 1]]).to_f32()
                    } else {
                        f32::from_le_bytes([px[c * 4], px[c * 4 + 1], px[c * 4 + 2], px[c * 4 + 3]])
                    };
                    data.push(v);
                }
            }
        }
        drop(mapped);
        buffer.unmap();
        out.push(data);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::padded_row;

    #[test]
    fn rows_pad_to_256_bytes() {
        assert_eq!(padded_row(800, 16), 12800);
        assert_eq!(padded_row(161, 16), 2816);
        assert_eq!(padded_row(1, 4), 256);
    }
}
