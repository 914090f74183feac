//! Packing on the device: a compute pass (`shaders/wgsl/pack.wgsl`) writes each configured layer
//! of a frame straight from the lit buffer and the render targets into its link format, into one
//! tightly packed buffer, with what the band headers need (per band: a non-zero source value, the
//! saturated pixels) and the frame's illumination peak. Only those bytes are read back: a pixel
//! costs its link formats' bytes (plus a few words a band), where the f32 readback cost 32 bytes
//! for the lit buffer and 8–16 a target before the CPU packed it.
//!
//! The packed bytes equal `lightfold_protocol::format::pack` of the f32 values the readback would
//! give, bit for bit, for every format and any input (NaN, infinities, subnormals, negatives:
//! the node's differential tests). The shader decides everything on the f32 bits with integer
//! operations so that no driver's float shortcuts can change a bit; the one case it cannot make
//! exact — `seed64` at a scale below 2⁻¹⁰⁰, where a flushed subnormal could round differently —
//! is refused by [`DevicePacker::supports`], and the node packs that frame on the CPU.
//!
//! Textures are first copied raw into device-local buffers (a copy on the device), so f16 texels
//! reach the shader as their bits, not through a texture unit that might flush subnormals.

use super::device::{Gpu, captured};
use super::frame::RenderError;
use super::readback::{copy_texture, kept, padded_row};
use bytes::Bytes;
use lightfold_protocol::PixelFormat;
use lightfold_protocol::format::srgb_encode_tables;

/// Pixels of one row a workgroup packs (`@workgroup_size` in the shader).
const WORKGROUP: u32 = 64;
/// Bytes between two layers' parameters (the uniform-offset alignment WebGPU guarantees).
const PARAM_STRIDE: u64 = 256;
/// Layers one frame may pack (a node has at most six: illumination, four materials, depth).
pub const MAX_LAYERS: usize = 8;
/// The smallest `seed64` scale the device packs exactly (see the module notes).
const MIN_SEED64_SCALE: f32 = 7.888_609e-31; // 2^-100

/// Where a layer's f32 channels are on the device.
#[derive(Debug, Clone, Copy)]
pub enum PackSource<'a> {
    /// The deferred pass's lit buffer: two `vec4<f32>` a pixel (diffuse, specular); six channels.
    Lit(&'a wgpu::Buffer),
    /// The forward pass's diffuse and specular targets (f32 bits, four channels a texel); six
    /// channels, three from each.
    Split(&'a wgpu::Texture, &'a wgpu::Texture),
    /// One target (`Rgba16Float`, `Rgba32Float`/`Rgba32Uint`, `R32Float`/`R32Uint`): its first
    /// channels, as many as the format packs.
    Texture(&'a wgpu::Texture),
}

/// One layer to pack.
#[derive(Debug, Clone, Copy)]
pub struct PackLayer<'a> {
    pub source: PackSource<'a>,
    pub format: PixelFormat,
}

/// What a band of one layer needs for its header.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BandCount {
    /// Some source value of the band is not ±0 (otherwise the band travels empty).
    pub nonzero: bool,
    /// Pixels with a channel above the format's range.
    pub saturated: u32,
}

/// One layer packed: its rows from [`PackedFrame::first_row`] down (every row without a tile),
/// in its link format.
#[derive(Debug, Clone)]
pub struct PackedLayer {
    pub format: PixelFormat,
    pub bytes: Bytes,
    /// Per band of `band_height` rows.
    pub bands: Vec<BandCount>,
}

/// A frame packed on the device.
#[derive(Debug, Clone)]
pub struct PackedFrame {
    pub width: u32,
    pub height: u32,
    pub band_height: u32,
    pub layers: Vec<PackedLayer>,
    /// Largest finite value of the illumination layer's source (0 without one).
    pub peak: f32,
    /// Bytes copied from the device to the host for this frame.
    pub read_bytes: u64,
    /// The first row the layers' bytes hold: a sort-first tile reads back only the bands its
    /// rows meet, `first_row` to [`PackedFrame::end_row`] (every other band is empty).
    pub first_row: u32,
    pub end_row: u32,
}

/// The layer parameters of `pack.wgsl` (field for field).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    width: u32,
    height: u32,
    band_height: u32,
    format: u32,
    halves: u32,
    channels: u32,
    texel_words: u32,
    row_words: u32,
    group_offset: u32,
    peak: u32,
    kd: u32,
    ks: u32,
    scale: u32,
    limit: u32,
    band_base: u32,
    _pad: u32,
}

/// How a texture's texels lie in its raw copy.
#[derive(Debug, Clone, Copy)]
struct Texels {
    bytes: u32,
    channels: u32,
    halves: bool,
}

fn texels(format: wgpu::TextureFormat) -> Result<Texels, RenderError> {
    use wgpu::TextureFormat as F;
    let (bytes, channels, halves) = match format {
        F::Rgba16Float => (8, 4, true),
        F::Rgba32Float | F::Rgba32Uint => (16, 4, false),
        F::R32Float | F::R32Uint => (4, 1, false),
        other => {
            return Err(RenderError::Gpu(format!(
                "cannot pack from a {other:?} target"
            )));
        }
    };
    Ok(Texels {
        bytes,
        channels,
        halves,
    })
}

/// The pipeline and the buffers it keeps from frame to frame (so a steady stream of frames
/// allocates none).
#[derive(Debug)]
pub struct DevicePacker {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    params: wgpu::Buffer,
    srgb: wgpu::Buffer,
    raw: Vec<wgpu::Buffer>,
    out: Option<wgpu::Buffer>,
    counts: Option<wgpu::Buffer>,
    staging: Option<wgpu::Buffer>,
}

fn storage(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

impl DevicePacker {
    /// Compiles the pack pass. A device that cannot (no compute, too few storage buffers) is an
    /// error; the node then packs on the CPU.
    pub fn new(gpu: &Gpu) -> Result<DevicePacker, RenderError> {
        let device = &gpu.device;
        let (made, error) = captured(device, || {
            let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some("pack"),
                source: wgpu::ShaderSource::Wgsl(lightfold_shaders::PACK_WGSL.into()),
            });
            let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some("pack"),
                entries: &[
                    wgpu::BindGroupLayoutEntry {
                        binding: 0,
                        visibility: wgpu::ShaderStages::COMPUTE,
                        ty: wgpu::BindingType::Buffer {
                            ty: wgpu::BufferBindingType::Uniform,
                            has_dynamic_offset: false,
                            min_binding_size: None,
                        },
                        count: None,
                    },
                    storage(1, true),
                    storage(2, false),
                    storage(3, false),
                    storage(4, true),
                ],
            });
            let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some("pack"),
                bind_group_layouts: &[Some(&layout)],
                immediate_size: 0,
            });
            let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some("cs_pack"),
                layout: Some(&pl),
                module: &module,
                entry_point: Some("cs_pack"),
                compilation_options: Default::default(),
                cache: None,
            });
            let params = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("pack parameters"),
                size: PARAM_STRIDE * MAX_LAYERS as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let (thresholds, starts) = srgb_encode_tables();
            let mut table: Vec<u32> = thresholds.iter().map(|t| t.to_bits()).collect();
            table.extend(starts.iter().map(|&s| u32::from(s)));
            let srgb = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("pack sRGB tables"),
                size: table.len() as u64 * 4,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            gpu.queue
                .write_buffer(&srgb, 0, bytemuck::cast_slice(&table));
            (pipeline, layout, params, srgb)
        });
        if let Some(e) = error {
            return Err(RenderError::Gpu(format!(
                "the device cannot build the pack pass: {e}"
            )));
        }
        let (pipeline, layout, params, srgb) = made;
        Ok(DevicePacker {
            pipeline,
            layout,
            params,
            srgb,
            raw: Vec::new(),
            out: None,
            counts: None,
            staging: None,
        })
    }

    /// Whether the device packs `format` at `scale` exactly (everything but `seed64` at a scale
    /// below 2⁻¹⁰⁰ or one the CPU pack refuses).
    pub fn supports(format: PixelFormat, scale: f32) -> bool {
        format != PixelFormat::Seed64 || (scale.is_finite() && scale >= MIN_SEED64_SCALE)
    }

    /// Whether a `width`×`height` frame of `formats` stays within this device's storage-binding
    /// limit, counting each source at its largest (the forward pass's two 16-byte targets for
    /// illumination): a frame that does not is packed on the CPU instead of failing.
    pub fn fits(limits: &wgpu::Limits, formats: &[PixelFormat], width: u32, height: u32) -> bool {
        let max = limits.max_storage_buffer_binding_size;
        let pixels = u64::from(width) * u64::from(height);
        let rows = |bytes: u32| u64::from(padded_row(width, bytes)) * u64::from(height);
        formats.iter().all(|f| {
            let source = match f.channels() {
                6 => (2 * rows(16)).max(pixels * 32),
                3 => rows(16),
                _ => rows(4),
            };
            pixels * f.bytes_per_pixel() as u64 <= max && source <= max
        })
    }

    /// Packs `layers` of a `width`×`height` frame cut into bands of `band_height` rows: copies,
    /// one compute pass, one copy to the host, one wait. The sources must hold this frame (their
    /// passes submitted before).
    pub fn pack(
        &mut self,
        gpu: &Gpu,
        layers: &[PackLayer<'_>],
        width: u32,
        height: u32,
        band_height: u32,
        scale: f32,
    ) -> Result<PackedFrame, RenderError> {
        self.pack_rows(gpu, layers, [width, height], band_height, scale, None)
    }

    /// [`DevicePacker::pack`] of a sort-first tile, image rows `rows` (`None`: every row; the
    /// sources zero elsewhere): only the bands those rows meet are packed (and the rows above
    /// them, which the shader cannot skip) and only they are read back.
    pub fn pack_rows(
        &mut self,
        gpu: &Gpu,
        layers: &[PackLayer<'_>],
        [width, height]: [u32; 2],
        band_height: u32,
        scale: f32,
        rows: Option<[u32; 2]>,
    ) -> Result<PackedFrame, RenderError> {
        let device = &gpu.device;
        let limits = &gpu.limits;
        if layers.len() > MAX_LAYERS {
            return Err(RenderError::Gpu(format!(
                "{} layers to pack, at most {MAX_LAYERS}",
                layers.len()
            )));
        }
        if let Some(l) = layers.iter().find(|l| !Self::supports(l.format, scale)) {
            return Err(RenderError::Gpu(format!(
                "{:?} at scale {scale} cannot be packed on the device",
                l.format
            )));
        }
        let band_height = band_height.clamp(1, height.max(1));
        let bands = height.div_ceil(band_height);
        // The rows of the bands the tile meets.
        let [y0, y1] = rows.unwrap_or([0, height]);
        let first_row = (y0.min(height) / band_height) * band_height;
        let end_row = y1
            .div_ceil(band_height)
            .saturating_mul(band_height)
            .min(height);
        let end_row = end_row.max(first_row);
        let shape = PackShape {
            width,
            height,
            band_height,
            bands,
            scale,
            pixels: u64::from(width) * u64::from(height),
            max_binding: limits.max_storage_buffer_binding_size,
        };
        let align = u64::from(limits.min_storage_buffer_offset_alignment).max(256);

        // Where each layer's packed bytes go, and its parameters (sources resolved below).
        let (offsets, out_size) = layer_offsets(layers, &shape, align)?;
        let count_words = 1 + 2 * u64::from(bands) * layers.len() as u64;
        let counts_size = count_words * 4;
        let out = kept(
            device,
            &mut self.out,
            "packed frame",
            out_size.max(4),
            wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        );
        let counts = kept(
            device,
            &mut self.counts,
            "pack counts",
            counts_size,
            wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
        );
        // The host gets the tile's rows of the layers back to back (no alignment padding), then
        // the counts.
        let reads: Vec<(u64, u64)> = layers
            .iter()
            .zip(&offsets)
            .map(|(l, &(offset, _))| {
                let row = u64::from(width) * l.format.bytes_per_pixel() as u64;
                (
                    offset + row * u64::from(first_row),
                    row * u64::from(end_row - first_row),
                )
            })
            .collect();
        let packed_size: u64 = reads.iter().map(|(_, size)| size).sum();
        let read_bytes = packed_size + counts_size;
        // At least the frame's size: a tile whose rows move reuses its largest frame's buffer.
        if self.staging.as_ref().is_none_or(|b| b.size() < read_bytes) {
            self.staging = None;
        }
        let staging = kept(
            device,
            &mut self.staging,
            "pack readback",
            read_bytes,
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        );

        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("pack"),
        });
        encoder.clear_buffer(&counts, 0, None);
        let mut params = Vec::with_capacity(layers.len());
        let mut sources: Vec<wgpu::Buffer> = Vec::with_capacity(layers.len());
        for (i, l) in layers.iter().enumerate() {
            let (p, source) = self.layer_source(device, &mut encoder, i, l, &shape)?;
            params.push(p);
            sources.push(source);
        }
        for (i, p) in params.iter().enumerate() {
            gpu.queue
                .write_buffer(&self.params, i as u64 * PARAM_STRIDE, bytemuck::bytes_of(p));
        }
        let groups = self.bind_groups(device, &sources, &offsets, &out, &counts);
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("pack"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.pipeline);
            for g in &groups {
                pass.set_bind_group(0, g, &[]);
                // No row below the tile's last band (their counts stay cleared: empty).
                pass.dispatch_workgroups(width.div_ceil(WORKGROUP), end_row, 1);
            }
        }
        let mut at = 0;
        for &(offset, size) in &reads {
            if size > 0 {
                encoder.copy_buffer_to_buffer(&out, offset, &staging, at, size);
            }
            at += size;
        }
        encoder.copy_buffer_to_buffer(&counts, 0, &staging, packed_size, counts_size);
        gpu.queue.submit([encoder.finish()]);

        map_for_reading(device, &staging, read_bytes, "the packed frame")?;
        let frame = {
            let mapped = staging
                .get_mapped_range(..read_bytes)
                .map_err(|e| RenderError::Gpu(format!("mapped range: {e}")))?;
            unpack(&mapped, layers, &reads, &shape, packed_size, read_bytes)
        };
        staging.unmap();
        Ok(PackedFrame {
            first_row,
            end_row,
            ..frame
        })
    }

    /// Layer `i`'s parameters and the buffer its shader reads: the lit buffer itself, or the
    /// raw copy of its targets, whose copies are recorded into `encoder`.
    fn layer_source(
        &mut self,
        device: &wgpu::Device,
        encoder: &mut wgpu::CommandEncoder,
        i: usize,
        l: &PackLayer<'_>,
        shape: &PackShape,
    ) -> Result<(Params, wgpu::Buffer), RenderError> {
        let PackShape {
            width,
            height,
            band_height,
            bands,
            scale,
            pixels,
            max_binding,
        } = *shape;
        let channels = l.format.channels() as u32;
        let mut p = Params {
            width,
            height,
            band_height,
            format: l.format as u32,
            channels,
            peak: u32::from(channels == 6),
            band_base: 1 + 2 * bands * i as u32,
            ..Params::default()
        };
        if l.format == PixelFormat::Seed64 {
            p.kd = (2047.0 / scale).to_bits();
            p.ks = (1023.0 / scale).to_bits();
            p.scale = scale.to_bits();
            let limit = scale * 2.0;
            p.limit = if limit.is_finite() { limit } else { f32::MAX }.to_bits();
        }
        let six = |what: &str| {
            if channels == 6 {
                Ok(())
            } else {
                Err(RenderError::Gpu(format!(
                    "{what} holds six channels, {:?} packs {channels}",
                    l.format
                )))
            }
        };
        let source = match l.source {
            PackSource::Lit(lit) => {
                six("the lit buffer")?;
                if lit.size() < pixels * 32 || lit.size() > max_binding {
                    return Err(RenderError::Gpu(format!(
                        "the lit buffer of {} bytes does not fit a {width}x{height} pack",
                        lit.size()
                    )));
                }
                p.texel_words = 8;
                p.row_words = width * 8;
                p.group_offset = 4;
                lit.clone()
            }
            PackSource::Split(diffuse, specular) => {
                six("the forward pass's targets")?;
                same_size(diffuse, width, height)?;
                same_size(specular, width, height)?;
                let t = texels(diffuse.format())?;
                if t.halves || t.channels < 3 || diffuse.format() != specular.format() {
                    return Err(RenderError::Gpu(format!(
                        "cannot pack illumination from {:?} targets",
                        diffuse.format()
                    )));
                }
                let row = padded_row(width, t.bytes);
                let region = u64::from(row) * u64::from(height);
                let raw = self.raw(device, i, 2 * region, max_binding)?;
                copy_texture(encoder, diffuse, &raw, 0, row);
                copy_texture(encoder, specular, &raw, region, row);
                p.texel_words = t.bytes / 4;
                p.row_words = row / 4;
                p.group_offset = (region / 4) as u32;
                raw
            }
            PackSource::Texture(texture) => {
                same_size(texture, width, height)?;
                let t = texels(texture.format())?;
                if channels > t.channels.min(3) && channels != t.channels {
                    return Err(RenderError::Gpu(format!(
                        "a {:?} target cannot give the {channels} channels of {:?}",
                        texture.format(),
                        l.format
                    )));
                }
                let row = padded_row(width, t.bytes);
                let raw = self.raw(device, i, u64::from(row) * u64::from(height), max_binding)?;
                copy_texture(encoder, texture, &raw, 0, row);
                p.halves = u32::from(t.halves);
                p.texel_words = if t.halves { 2 } else { t.bytes / 4 };
                p.row_words = row / 4;
                raw
            }
        };
        Ok((p, source))
    }

    /// One bind group per layer: its parameters, its source, its part of `out`, the counts
    /// and the sRGB tables.
    fn bind_groups(
        &self,
        device: &wgpu::Device,
        sources: &[wgpu::Buffer],
        offsets: &[(u64, u64)],
        out: &wgpu::Buffer,
        counts: &wgpu::Buffer,
    ) -> Vec<wgpu::BindGroup> {
        sources
            .iter()
            .zip(offsets)
            .enumerate()
            .map(|(i, (source, &(offset, size)))| {
                device.create_bind_group(&wgpu::BindGroupDescriptor {
                    label: Some("pack"),
                    layout: &self.layout,
                    entries: &[
                        wgpu::BindGroupEntry {
                            binding: 0,
                            resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                                buffer: &self.params,
                                offset: i as u64 * PARAM_STRIDE,
                                size: wgpu::BufferSize::new(std::mem::size_of::<Params>() as u64),
                            }),
                        },
                        wgpu::BindGroupEntry {
                            binding: 1,
                            resource: source.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 2,
                            resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                                buffer: out,
                                offset,
                                size: wgpu::BufferSize::new(size),
                            }),
                        },
                        wgpu::BindGroupEntry {
                            binding: 3,
                            resource: counts.as_entire_binding(),
                        },
                        wgpu::BindGroupEntry {
                            binding: 4,
                            resource: self.srgb.as_entire_binding(),
                        },
                    ],
                })
            })
            .collect()
    }

    /// The raw-copy buffer of source `i`, of at least `size` bytes.
    fn raw(
        &mut self,
        device: &wgpu::Device,
        i: usize,
        size: u64,
        max_binding: u64,
    ) -> Result<wgpu::Buffer, RenderError> {
        if size > max_binding {
            return Err(RenderError::BindingTooLarge {
                what: "a target copied for packing",
                bytes: size,
                maximum: max_binding,
            });
        }
        while self.raw.len() <= i {
            self.raw.push(device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("pack source"),
                size: 4,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }));
        }
        if self.raw[i].size() < size {
            self.raw[i] = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("pack source"),
                size,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
        }
        Ok(self.raw[i].clone())
    }
}

fn same_size(texture: &wgpu::Texture, width: u32, height: u32) -> Result<(), RenderError> {
    let s = texture.size();
    if (s.width, s.height) == (width, height) {
        Ok(())
    } else {
        Err(RenderError::Gpu(format!(
            "a {}x{} target cannot be packed as a {width}x{height} frame",
            s.width, s.height
        )))
    }
}
/// The frame one pack covers: its size and bands, the `seed64` scale, its pixels and the
/// device's storage-binding limit.
#[derive(Debug, Clone, Copy)]
struct PackShape {
    width: u32,
    height: u32,
    /// Rows a band (clamped to the frame) and bands.
    band_height: u32,
    bands: u32,
    scale: f32,
    pixels: u64,
    max_binding: u64,
}

/// Where each layer's packed bytes go in the output buffer (offset, size), each at `align`,
/// and the buffer's size. A layer beyond the storage-binding limit is an error.
fn layer_offsets(
    layers: &[PackLayer<'_>],
    shape: &PackShape,
    align: u64,
) -> Result<(Vec<(u64, u64)>, u64), RenderError> {
    let mut offsets = Vec::with_capacity(layers.len());
    let mut out_size = 0u64;
    for l in layers {
        let size = shape.pixels * l.format.bytes_per_pixel() as u64;
        if size > shape.max_binding {
            return Err(RenderError::BindingTooLarge {
                what: "a packed layer",
                bytes: size,
                maximum: shape.max_binding,
            });
        }
        offsets.push((out_size, size));
        out_size = (out_size + size).div_ceil(align) * align;
    }
    Ok((offsets, out_size))
}

/// Maps the first `size` bytes of `staging` for reading and waits for it; `what` names the
/// contents in errors.
pub(super) fn map_for_reading(
    device: &wgpu::Device,
    staging: &wgpu::Buffer,
    size: u64,
    what: &str,
) -> Result<(), RenderError> {
    let (tx, rx) = std::sync::mpsc::channel();
    staging.map_async(wgpu::MapMode::Read, ..size, move |r| {
        let _ = tx.send(r);
    });
    device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(|e| RenderError::Gpu(format!("waiting for {what}: {e}")))?;
    match rx.try_recv() {
        Ok(Ok(())) => Ok(()),
        Ok(Err(e)) => Err(RenderError::Gpu(format!("map of {what}: {e}"))),
        Err(_) => Err(RenderError::Gpu(format!("{what} was never mapped"))),
    }
}

/// The packed frame in `bytes` as read back: the layers back to back (`offsets`' sizes), then
/// the counts from `packed_size` (the peak, then per layer and band its two words).
fn unpack(
    bytes: &[u8],
    layers: &[PackLayer<'_>],
    offsets: &[(u64, u64)],
    shape: &PackShape,
    packed_size: u64,
    read_bytes: u64,
) -> PackedFrame {
    let bands = shape.bands;
    let word = |i: u64| {
        let at = (packed_size + 4 * i) as usize;
        u32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]])
    };
    let mut at = 0usize;
    let packed = layers
        .iter()
        .zip(offsets)
        .enumerate()
        .map(|(i, (l, &(_, size)))| PackedLayer {
            format: l.format,
            bytes: {
                let b = Bytes::copy_from_slice(&bytes[at..at + size as usize]);
                at += size as usize;
                b
            },
            bands: (0..u64::from(bands))
                .map(|b| {
                    let base = 1 + 2 * (u64::from(bands) * i as u64 + b);
                    BandCount {
                        nonzero: word(base) != 0,
                        saturated: word(base + 1),
                    }
                })
                .collect(),
        })
        .collect();
    PackedFrame {
        width: shape.width,
        height: shape.height,
        band_height: shape.band_height,
        layers: packed,
        peak: f32::from_bits(word(0)),
        read_bytes,
        first_row: 0,
        end_row: shape.height,
    }
}

/// Values a pack must get right: zeros of both signs, NaN, infinities, the largest finite, the
/// smallest normal and subnormals, each format's top (f16, rgb9e5) and the values just around
/// it and around 1, half-precision subnormals, and the sRGB knee.
pub const HOSTILE_SPECIALS: &[f32] = &[
    0.0,
    -0.0,
    f32::NAN,
    f32::INFINITY,
    f32::NEG_INFINITY,
    f32::MAX,
    -f32::MAX,
    f32::MIN_POSITIVE,
    1e-45,
    1e-40,
    65504.0,
    65519.996,
    65520.0,
    65408.0,
    65415.0,
    1.0,
    1.000_000_1,
    0.999_999_94,
    1.5259e-5,
    6.1035e-5,
    5.96e-8,
    0.5 / 255.0,
    0.003_130_8,
    -1.0,
];

/// f32 values packing finds hard, deterministic: every special value, subnormals, values at and
/// around each format's range and rounding ties, and random bit patterns.
fn hostile(n: usize) -> Vec<f32> {
    const SPECIAL: &[f32] = HOSTILE_SPECIALS;
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    (0..n)
        .map(|i| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let r = (state >> 32) as u32;
            match i % 4 {
                0 => SPECIAL[(r as usize) % SPECIAL.len()],
                1 => f32::from_bits(r),
                2 => (r % 4096) as f32 * 0.5 / 2047.0,
                _ => (r >> 8) as f32 / (1u32 << 24) as f32 * 4.0,
            }
        })
        .collect()
}

/// A `width`×`height` texture of `format` holding `bytes` (rows packed), that can be packed
/// from: what the self-check and the tests stand in for render targets with.
pub fn source_texture(
    gpu: &Gpu,
    format: wgpu::TextureFormat,
    width: u32,
    height: u32,
    bytes: &[u8],
) -> wgpu::Texture {
    use wgpu::util::DeviceExt;
    gpu.device.create_texture_with_data(
        &gpu.queue,
        &wgpu::TextureDescriptor {
            label: Some("pack source"),
            size: wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage: wgpu::TextureUsages::COPY_SRC | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        },
        wgpu::util::TextureDataOrder::LayerMajor,
        bytes,
    )
}

impl DevicePacker {
    /// Packs hostile values in every format from a lit buffer, an f16 target and a depth target
    /// on this device and compares them with the CPU pack, byte for byte. A driver that differs
    /// anywhere (a node must never send other bits than the CPU would) is an error naming the
    /// first format that differs; the node then packs on the CPU.
    pub fn self_check(gpu: &Gpu) -> Result<(), RenderError> {
        use lightfold_protocol::format::pack;
        use wgpu::util::DeviceExt;
        const W: u32 = 61;
        const H: u32 = 5;
        let pixels = (W * H) as usize;
        let mut packer = DevicePacker::new(gpu)?;
        let values = hostile(pixels * 8);
        let lit = gpu
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("pack self-check"),
                contents: bytemuck::cast_slice(&values),
                usage: wgpu::BufferUsages::STORAGE,
            });
        let six: Vec<f32> = values
            .chunks_exact(8)
            .flat_map(|p| [p[0], p[1], p[2], p[4], p[5], p[6]])
            .collect();
        let texture = |format, bytes: &[u8]| source_texture(gpu, format, W, H, bytes);
        let halves: Vec<u16> = values
            .iter()
            .take(pixels * 4)
            .map(|v| v.to_bits() as u16)
            .collect();
        let f16_target = texture(
            wgpu::TextureFormat::Rgba16Float,
            bytemuck::cast_slice(&halves),
        );
        let three: Vec<f32> = halves
            .chunks_exact(4)
            .flat_map(|t| t[..3].iter().map(|&h| half::f16::from_bits(h).to_f32()))
            .collect();
        let depth = &values[..pixels];
        let depth_target = texture(wgpu::TextureFormat::R32Float, bytemuck::cast_slice(depth));
        let cases: [(PackSource<'_>, &[f32], &[PixelFormat]); 3] = [
            (
                PackSource::Lit(&lit),
                &six,
                &[
                    PixelFormat::Seed64,
                    PixelFormat::Rgb9e5x2,
                    PixelFormat::F16x6,
                    PixelFormat::F32x6,
                ],
            ),
            (
                PackSource::Texture(&f16_target),
                &three,
                &[
                    PixelFormat::F16x4,
                    PixelFormat::Rgba8Linear,
                    PixelFormat::Rgba8Srgb,
                    PixelFormat::F32x3,
                ],
            ),
            (
                PackSource::Texture(&depth_target),
                depth,
                &[PixelFormat::DepthF32],
            ),
        ];
        for (source, values, formats) in cases {
            for &format in formats {
                let scale = 0.75;
                let mut want = vec![0u8; pixels * format.bytes_per_pixel()];
                let stats = pack(format, values, scale, &mut want)
                    .map_err(|e| RenderError::Gpu(format!("self-check CPU pack: {e}")))?;
                let got = packer.pack(gpu, &[PackLayer { source, format }], W, H, 2, scale)?;
                let layer = &got.layers[0];
                let saturated: u64 = layer.bands.iter().map(|b| u64::from(b.saturated)).sum();
                if layer.bytes[..] != want[..] || saturated != stats.saturated {
                    let at = layer.bytes.iter().zip(&want).position(|(a, b)| a != b);
                    return Err(RenderError::Gpu(format!(
                        "this device packs {format:?} differently from the CPU (first byte \
                         differing: {at:?}; saturated {saturated} against {})",
                        stats.saturated
                    )));
                }
            }
        }
        Ok(())
    }
}
