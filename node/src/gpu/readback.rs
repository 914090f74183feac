//! Reading render targets back to the CPU: one copy per texture (or the deferred lit buffer) into
//! a mappable buffer kept from frame to frame, rows padded to wgpu's 256-byte alignment, all in
//! one submission and one wait, then unpadded and converted to f32 channels. A sort-first tile
//! reads back only its rows; the images it gives are whole, zero in every other row.

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
    /// Bytes the last frame copied to the host.
    read: u64,
}

impl Staging {
    /// Bytes the last frame copied to the host.
    pub(super) fn bytes(&self) -> u64 {
        self.read
    }

    /// Buffer `i`, of at least `size` bytes (made again, of exactly `size`, when smaller: a tile
    /// whose rows move from frame to frame reuses the buffer of its largest frame).
    fn buffer(&mut self, device: &wgpu::Device, i: usize, size: u64) -> wgpu::Buffer {
        if self.buffers.len() <= i {
            self.buffers.resize(i + 1, None);
        }
        let slot = &mut self.buffers[i];
        if let Some(b) = slot.as_ref().filter(|b| b.size() >= size) {
            return b.clone();
        }
        let usage = wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ;
        kept(device, slot, "readback", size, usage)
    }
}

/// The rows `[y0, y1)` of an image `height` rows tall that a frame reads back.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct ReadRows {
    pub y0: u32,
    pub y1: u32,
    pub height: u32,
}

impl ReadRows {
    /// The rows `rows` of a `height`-row image (`None`: every row).
    pub(super) fn of(rows: Option<[u32; 2]>, height: u32) -> ReadRows {
        let [y0, y1] = rows.unwrap_or([0, height]);
        ReadRows { y0, y1, height }
    }

    fn count(&self) -> u32 {
        self.y1 - self.y0
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
    let rows = ReadRows::of(None, texture.height());
    copy_rows(encoder, texture, buffer, offset, row, rows);
}

/// Copies rows `rows` of `texture` into `buffer` from `offset`, rows `row` bytes apart.
fn copy_rows(
    encoder: &mut wgpu::CommandEncoder,
    texture: &wgpu::Texture,
    buffer: &wgpu::Buffer,
    offset: u64,
    row: u32,
    rows: ReadRows,
) {
    encoder.copy_texture_to_buffer(
        wgpu::TexelCopyTextureInfo {
            texture,
            mip_level: 0,
            origin: wgpu::Origin3d {
                x: 0,
                y: rows.y0,
                z: 0,
            },
            aspect: wgpu::TextureAspect::All,
        },
        wgpu::TexelCopyBufferInfo {
            buffer,
            layout: wgpu::TexelCopyBufferLayout {
                offset,
                bytes_per_row: Some(row),
                rows_per_image: Some(rows.count()),
            },
        },
        wgpu::Extent3d {
            width: texture.width(),
            height: rows.count(),
            depth_or_array_layers: 1,
        },
    );
}

/// Copies rows `rows` of every source into `staging` in one submission, waits once, and returns
/// per source its f32 values over the whole image, zero outside `rows` (the lit buffer: 6 a
/// pixel; a texture: `keep_channels` a pixel, row 0 at the top).
pub(super) fn read(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    staging: &mut Staging,
    sources: &[ReadSource<'_>],
    rows: ReadRows,
) -> Result<Vec<Vec<f32>>, RenderError> {
    let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
        label: Some("readback"),
    });
    // (buffer, padded row bytes, bytes copied)
    let mut buffers = Vec::with_capacity(sources.len());
    for (i, source) in sources.iter().enumerate() {
        match source {
            ReadSource::Lit(lit) => {
                // Rows of 32 bytes a pixel, the image's height of them.
                let row = lit.size() / u64::from(rows.height.max(1));
                let size = row * u64::from(rows.count());
                let buffer = staging.buffer(device, i, size);
                encoder.copy_buffer_to_buffer(lit, row * u64::from(rows.y0), &buffer, 0, size);
                buffers.push((buffer, 0, size));
            }
            ReadSource::Texture(r) => {
                let (bpp, _, _) = format_info(r.texture.format())?;
                let row = padded_row(r.texture.width(), bpp);
                let size = u64::from(row) * u64::from(rows.count());
                let buffer = staging.buffer(device, i, size);
                copy_rows(&mut encoder, r.texture, &buffer, 0, row, rows);
                buffers.push((buffer, row, size));
            }
        }
    }
    queue.submit([encoder.finish()]);
    staging.read = buffers.iter().map(|(_, _, size)| size).sum();
    let (tx, rx) = std::sync::mpsc::channel();
    for (i, (buffer, _, size)) in buffers.iter().enumerate() {
        let tx = tx.clone();
        buffer.map_async(wgpu::MapMode::Read, ..*size, move |r| {
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
            .map(|(source, (buffer, row, size))| convert(source, buffer, *row, *size, rows))
            .collect(),
    };
    for ((buffer, _, _), mapped) in buffers.iter().zip(mapped) {
        if mapped {
            buffer.unmap();
        }
    }
    result
}

/// The first `size` mapped bytes of `buffer`, rows `rows` of `source`, as the f32 values of the
/// whole image (zero outside those rows).
fn convert(
    source: &ReadSource<'_>,
    buffer: &wgpu::Buffer,
    row: u32,
    size: u64,
    rows: ReadRows,
) -> Result<Vec<f32>, RenderError> {
    let mapped = buffer
        .get_mapped_range(..size)
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
            let pixels = bytes.len() / 32;
            let per_row = pixels / rows.count().max(1) as usize;
            let len = per_row * rows.height as usize * 6;
            let mut out = zeros_above(len, per_row * 6, rows);
            for px in bytes.chunks_exact(32) {
                f32s(&px[0..12], &mut out);
                f32s(&px[16..28], &mut out);
            }
            out.resize(len, 0.0);
            Ok(out)
        }
        ReadSource::Texture(r) => {
            let (bpp, channels, half) = format_info(r.texture.format())?;
            let keep = r.keep_channels.min(channels);
            let w = r.texture.width() as usize;
            let len = w * rows.height as usize * keep;
            let mut out = zeros_above(len, w * keep, rows);
            for y in 0..rows.count() as usize {
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
            out.resize(len, 0.0);
            Ok(out)
        }
    }
}

/// A vector of capacity `len` (the whole image's values) holding the zeros of the rows above
/// `rows`, `row` values each; the caller appends the read rows, then zeros to `len`.
fn zeros_above(len: usize, row: usize, rows: ReadRows) -> Vec<f32> {
    let mut out = Vec::with_capacity(len);
    out.resize(row * rows.y0 as usize, 0.0);
    out
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
