//! Reading render targets back to the CPU: one copy per texture (or the deferred lit buffer) into
//! a mappable buffer kept from frame to frame, rows padded to wgpu's 256-byte alignment, all in
//! one submission and one wait, then unpadded and converted to f32 channels.

use super::frame::RenderError;

/// A render target to read and how many of its channels to keep.
#[derive(Debug, Clone, Copy)]
pub(super) struct ReadRequest<'a> {
    pub texture: &'a wgpu::Texture,
    pub keep_channels: usize,
}

/// What one frame reads back: the deferred pass's lit buffer (two vec4<f32> a pixel, read as
/// six channels: diffuse RGB then specular RGB), and textures.
#[derive(Debug, Clone, Copy)]
pub(super) enum ReadSource<'a> {
    Lit(&'a wgpu::Buffer),
    Texture(ReadRequest<'a>),
}

/// Mappable buffers kept from frame to frame, one per read of a frame, so a steady stream of
/// frames allocates none (a fresh host-visible buffer per target and frame was most of the
/// readback on a discrete GPU, `docs/gpu.md`).
#[derive(Debug, Default)]
pub(super) struct Staging {
    buffers: Vec<Option<wgpu::Buffer>>,
}

impl Staging {
    /// Bytes the kept buffers hold: what the last frame copied to the host.
    pub(super) fn bytes(&self) -> u64 {
        self.buffers.iter().flatten().map(|b| b.size()).sum()
    }

    /// Buffer `i`, of exactly `size` bytes (made again when the size changes).
    fn buffer(&mut self, device: &wgpu::Device, i: usize, size: u64) -> wgpu::Buffer {
        if self.buffers.len() <= i {
            self.buffers.resize(i + 1, None);
        }
        let usage = wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ;
        kept(device, &mut self.buffers[i], "readback", size, usage)
    }
}

/// The buffer kept in `slot`, of exactly `size` bytes, made again when the size differs.
pub(super) fn kept(
    device: &wgpu::Device,
    slot: &mut Option<wgpu::Buffer>,
    label: &'static str,
    size: u64,
    usage: wgpu::BufferUsages,
) -> wgpu::Buffer {
    if slot.as_ref().is_none_or(|b| b.size() != size) {
        *slot = Some(device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size,
            usage,
            mapped_at_creation: false,
        }));
    }
    slot.clone().expect("made above")
}

/// Bytes per row of a `width`-pixel copy, padded to `COPY_BYTES_PER_ROW_ALIGNMENT`.
pub(super) fn padded_row(width: u32, bytes_per_pixel: u32) -> u32 {
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

/// Copies the whole of `texture` into `buffer` from `offset`, rows `row` bytes apart (a multiple
/// of `COPY_BYTES_PER_ROW_ALIGNMENT`).
pub(super) fn copy_texture(
    encoder: &mut wgpu::CommandEncoder,
    texture: &wgpu::Texture,
    buffer: &wgpu::Buffer,
    offset: u64,
    row: u32,
) {
    let size = texture.size();
    encoder.copy_texture_to_buffer(
        wgpu::TexelCopyTextureInfo {
            texture,
            mip_level: 0,
            origin: wgpu::Origin3d::ZERO,
            aspect: wgpu::TextureAspect::All,
        },
        wgpu::TexelCopyBufferInfo {
            buffer,
            layout: wgpu::TexelCopyBufferLayout {
                offset,
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
}

/// Copies every source into `staging` in one submission, waits once, and returns per source its
/// f32 values (the lit buffer: 6 a pixel; a texture: `keep_channels` a pixel, row 0 at the top).
pub(super) fn read(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    staging: &mut Staging,
    sources: &[ReadSource<'_>],
) -> Result<Vec<Vec<f32>>, RenderError> {
    let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
        label: Some("readback"),
    });
    let mut buffers = Vec::with_capacity(sources.len());
    for (i, source) in sources.iter().enumerate() {
        match source {
            ReadSource::Lit(lit) => {
                let buffer = staging.buffer(device, i, lit.size());
                encoder.copy_buffer_to_buffer(lit, 0, &buffer, 0, lit.size());
                buffers.push((buffer, 0));
            }
            ReadSource::Texture(r) => {
                let size = r.texture.size();
                let (bpp, _, _) = format_info(r.texture.format())?;
                let row = padded_row(size.width, bpp);
                let buffer = staging.buffer(device, i, row as u64 * size.height as u64);
                copy_texture(&mut encoder, r.texture, &buffer, 0, row);
                buffers.push((buffer, row));
            }
        }
    }
    queue.submit([encoder.finish()]);
    let (tx, rx) = std::sync::mpsc::channel();
    for (i, (buffer, _)) in buffers.iter().enumerate() {
        let tx = tx.clone();
        buffer.map_async(wgpu::MapMode::Read, .., move |r| {
            let _ = tx.send((i, r));
        });
    }
    drop(tx);
    device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(|e| RenderError::Gpu(format!("readback wait: {e}")))?;
    let mut failed = None;
    let mut mapped = vec![false; buffers.len()];
    for (i, r) in rx.iter() {
        match r {
            Ok(()) => mapped[i] = true,
            Err(e) => {
                failed.get_or_insert(RenderError::Gpu(format!("map of target {i}: {e}")));
            }
        }
    }
    let result = match failed {
        Some(e) => Err(e),
        None => sources
            .iter()
            .zip(&buffers)
            .map(|(source, (buffer, row))| convert(source, buffer, *row))
            .collect(),
    };
    for ((buffer, _), mapped) in buffers.iter().zip(mapped) {
        if mapped {
            buffer.unmap();
        }
    }
    result
}

/// The mapped `buffer` of `source` as f32 values.
fn convert(
    source: &ReadSource<'_>,
    buffer: &wgpu::Buffer,
    row: u32,
) -> Result<Vec<f32>, RenderError> {
    let mapped = buffer
        .get_mapped_range(..)
        .map_err(|e| RenderError::Gpu(format!("mapped range: {e}")))?;
    let bytes: &[u8] = &mapped;
    let f32s = |b: &[u8], out: &mut Vec<f32>| match bytemuck::try_cast_slice::<u8, f32>(b) {
        Ok(v) => out.extend_from_slice(v),
        // Mapped memory is aligned in practice; read it bytewise if it ever is not.
        Err(_) => out.extend(
            b.chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])),
        ),
    };
    match source {
        ReadSource::Lit(_) => {
            // vec4 diffuse, vec4 specular: keep xyz of each.
            let mut out = Vec::with_capacity(bytes.len() / 32 * 6);
            for px in bytes.chunks_exact(32) {
                f32s(&px[0..12], &mut out);
                f32s(&px[16..28], &mut out);
            }
            Ok(out)
        }
        ReadSource::Texture(r) => {
            let size = r.texture.size();
            let (bpp, channels, half) = format_info(r.texture.format())?;
            let keep = r.keep_channels.min(channels);
            let (w, h) = (size.width as usize, size.height as usize);
            let mut out = Vec::with_capacity(w * h * keep);
            for y in 0..h {
                let line = &bytes[y * row as usize..][..w * bpp as usize];
                if half {
                    for px in line.chunks_exact(bpp as usize) {
                        for c in px.chunks_exact(2).take(keep) {
                            out.push(half::f16::from_le_bytes([c[0], c[1]]).to_f32());
                        }
                    }
                } else if keep == channels {
                    f32s(line, &mut out);
                } else {
                    for px in line.chunks_exact(bpp as usize) {
                        f32s(&px[..keep * 4], &mut out);
                    }
                }
            }
            Ok(out)
        }
    }
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
