//! One band through the stage: unpack every input layer to f32, run the operator fold, pack the
//! outputs and seal their headers; or, for a lone `accumulate` (a `join` runs as one) or `depth`
//! over formats they read packed, one fused pass from the input payloads straight into the output
//! payloads (`ops::packed_out`). Synchronous and allocation-free in steady state (scratch and
//! payload buffers are reused), so the engine runs it on the stage's compute pool while the next
//! band arrives.

use super::inputs::InBand;
use super::pixels::{pack, unpack};
use super::stage_plan::{Operators, StagePlan};
use crate::ops::{
    Accumulate, BandMut, BandView, Depth, OpError, PackSummary, PackedIllumination, PackedLayer,
    PackedOut,
};
use crate::pipeline::{PipelineError, Scratch as PipelineScratch};
use bytes::Bytes;
use lightfold_protocol::{BandHeader, Layer, PixelFormat};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Why a band could not be combined. Headers were checked before, so these are internal faults
/// or packed values a format rejects.
#[derive(Debug, thiserror::Error)]
pub(super) enum ComputeError {
    #[error(transparent)]
    Pipeline(PipelineError),
    #[error(transparent)]
    Fused(OpError),
    #[error("cannot unpack input {input} layer {layer:?} ({format:?}): {reason}")]
    Unpack {
        input: usize,
        layer: Layer,
        format: PixelFormat,
        reason: String,
    },
    #[error("cannot pack output layer {layer:?} as {format:?}: {reason}")]
    Pack {
        layer: Layer,
        format: PixelFormat,
        reason: String,
    },
}

/// Reused f32 buffers: per stage input per layer, the stage's output layers, and the
/// pipeline's intermediate results; and the pool outgoing payloads come from.
#[derive(Debug)]
pub(crate) struct Scratch {
    inputs: Vec<Vec<Vec<f32>>>,
    outs: Vec<Vec<f32>>,
    pipeline: PipelineScratch,
    pool: Arc<BufferPool>,
}

impl Scratch {
    pub(super) fn new(pool: Arc<BufferPool>) -> Scratch {
        Scratch {
            inputs: Vec::new(),
            outs: Vec::new(),
            pipeline: PipelineScratch::default(),
            pool,
        }
    }
}

/// Most payload buffers kept for reuse (a few bands in the writer's queue and on the wire).
const POOLED: usize = 16;

/// Payload buffers handed back when the last reference to a sent band is dropped, so a
/// steady stream of bands neither zeroes nor faults in fresh pages for every band.
#[derive(Debug, Default)]
pub(crate) struct BufferPool {
    free: Mutex<Vec<Vec<u8>>>,
}

impl BufferPool {
    /// A buffer of `len` bytes with unspecified content (the packer overwrites all of it).
    fn take(&self, len: usize) -> Vec<u8> {
        let mut buf = self
            .free
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .pop()
            .unwrap_or_default();
        buf.resize(len, 0);
        buf
    }

    fn put(&self, buf: Vec<u8>) {
        let mut free = self.free.lock().unwrap_or_else(|e| e.into_inner());
        if free.len() < POOLED {
            free.push(buf);
        }
    }
}

/// A pooled payload: goes back to its pool when the band's last `Bytes` is dropped.
struct Pooled {
    buf: Vec<u8>,
    pool: Arc<BufferPool>,
}

impl AsRef<[u8]> for Pooled {
    fn as_ref(&self) -> &[u8] {
        &self.buf
    }
}

impl Drop for Pooled {
    fn drop(&mut self) {
        self.pool.put(std::mem::take(&mut self.buf));
    }
}

/// The packed result of one band and what it cost.
#[derive(Debug, Default)]
pub(crate) struct BandOut {
    pub bands: Vec<(BandHeader, Bytes)>,
    pub composite: Duration,
    pub pack: Duration,
    pub saturated: u64,
    pub empty: u32,
}

/// What one band is combined from: `centre[i][j]` is stage input i's layer j (configuration
/// order) for the band itself; `above` and `below` are the neighbouring bands, given where the
/// stage has a halo (`StagePlan::halo`) and the band has that neighbour.
pub(crate) struct Window {
    pub above: Option<Arc<Received>>,
    pub centre: Arc<Received>,
    pub below: Option<Arc<Received>>,
}

/// One band of every input layer, in configuration order.
pub(crate) type Received = Vec<Vec<InBand>>;

/// Combines band `b` of `frame` from `window`. `scale` is the fixed-point scale of this frame's
/// outgoing bands.
pub(crate) fn combine(
    plan: &StagePlan,
    ops: &Operators,
    frame: u64,
    b: u32,
    window: &Window,
    scale: f32,
    scratch: &mut Scratch,
) -> Result<BandOut, ComputeError> {
    let received: &[Vec<InBand>] = &window.centre;
    let cfg = &plan.config;
    let (y0, rows) = plan.band_rows(b);
    let pixels = cfg.width as usize * rows as usize;
    let start = Instant::now();
    let out = BandOut::default();
    let Some(pipeline) = ops.pipeline.as_ref() else {
        return relay(plan, frame, y0, rows, &received[0], scale, scratch, out);
    };
    if let Some(depth) = &ops.depth {
        return depth_packed(
            plan,
            depth,
            frame,
            (y0, rows),
            received,
            scale,
            scratch,
            out,
        );
    }
    if let Some(acc) = &ops.fused {
        return fused(
            plan,
            acc,
            frame,
            (y0, rows),
            received,
            scale,
            scratch,
            start,
        );
    }

    // The band and, for a neighbourhood filter, `halo` rows of each neighbouring band.
    let top = if window.above.is_some() {
        plan.halo.min(y0) as usize
    } else {
        0
    };
    let bottom = if window.below.is_some() {
        plan.halo.min(cfg.height - (y0 + rows)) as usize
    } else {
        0
    };
    let w = cfg.width as usize;
    let extended = pixels + (top + bottom) * w;
    let present = unpack_window(plan, window, rows, (top, bottom), scratch)?;
    let views: Vec<BandView<'_>> = received
        .iter()
        .zip(&scratch.inputs)
        .zip(&present)
        .map(|((layers, bufs), here)| {
            layers
                .iter()
                .zip(bufs)
                .zip(here)
                .filter(|(_, keep)| **keep)
                .fold(BandView::new(extended), |v, ((band, data), _)| {
                    v.with(band.header.layer, data)
                })
        })
        .collect();
    scratch.outs.resize_with(plan.produced.len(), Vec::new);
    for (buf, layer) in scratch.outs.iter_mut().zip(&plan.produced) {
        buf.resize(extended * layer.channels(), 0.0);
    }
    let mut band_mut = plan
        .produced
        .iter()
        .zip(scratch.outs.iter_mut())
        .fold(BandMut::new(extended), |m, (l, d)| m.with(*l, d));
    pipeline
        .run(&views, &mut band_mut, &mut scratch.pipeline)
        .map_err(ComputeError::Pipeline)?;
    finish(plan, frame, y0, rows, top * w, scale, scratch, out, start)
}

/// One accumulate over illumination-only inputs (`Operators::fused`), added straight from the
/// packed bytes: a lone illumination output is packed block by block as the sum is made,
/// otherwise the sum is packed by [`finish`].
#[allow(clippy::too_many_arguments)]
fn fused(
    plan: &StagePlan,
    acc: &Accumulate,
    frame: u64,
    (y0, rows): (u32, u32),
    received: &[Vec<InBand>],
    scale: f32,
    scratch: &mut Scratch,
    start: Instant,
) -> Result<BandOut, ComputeError> {
    let cfg = &plan.config;
    let pixels = cfg.width as usize * rows as usize;
    let packed: Vec<Option<PackedIllumination<'_>>> = received
        .iter()
        .map(|layers| {
            let b = &layers[0];
            (!b.header.empty).then_some(PackedIllumination {
                format: b.header.format,
                scale: b.header.scale,
                bytes: &b.payload,
            })
        })
        .collect();
    if let [(Layer::Illumination, format)] = cfg.outputs[..] {
        // The sum is packed block by block as it is made (`ops::packed_out`): composite and
        // pack are one pass, timed as composite.
        let header = header(plan, frame, Layer::Illumination, format, y0, rows, scale);
        let mut bytes = scratch.pool.take(pixels * format.bytes_per_pixel());
        let target = PackedOut {
            layer: Layer::Illumination,
            format,
            scale,
            bytes: &mut bytes,
        };
        let summary = acc
            .apply_packed_to(&packed, pixels, target)
            .map_err(ComputeError::Fused)?;
        let mut out = BandOut {
            composite: start.elapsed(),
            ..BandOut::default()
        };
        let band = packed_band(header, bytes, &summary, &mut out, &scratch.pool);
        out.bands.push(band);
        return Ok(out);
    }
    scratch.outs.resize_with(1, Vec::new);
    scratch.outs[0].resize(pixels * Layer::Illumination.channels(), 0.0);
    let mut band_mut = BandMut::new(pixels).with(Layer::Illumination, &mut scratch.outs[0]);
    acc.apply_packed(&packed, &mut band_mut)
        .map_err(ComputeError::Fused)?;
    let out = BandOut::default();
    finish(plan, frame, y0, rows, 0, scale, scratch, out, start)
}

/// Unpacks every input layer of the window's band of `rows` rows, with `top` rows of the band
/// above and `bottom` rows of the band below, into `scratch.inputs` (empty parts as zeros).
/// Returns, per input and layer, whether it is in the view: a layer empty throughout is left
/// out unless its reader requires it.
fn unpack_window(
    plan: &StagePlan,
    window: &Window,
    rows: u32,
    (top, bottom): (usize, usize),
    scratch: &mut Scratch,
) -> Result<Vec<Vec<bool>>, ComputeError> {
    let received: &[Vec<InBand>] = &window.centre;
    let w = plan.config.width as usize;
    let extended = w * rows as usize + (top + bottom) * w;
    scratch.inputs.resize_with(received.len(), Vec::new);
    let mut present: Vec<Vec<bool>> = Vec::with_capacity(received.len());
    for (i, layers) in received.iter().enumerate() {
        scratch.inputs[i].resize_with(layers.len(), Vec::new);
        let mut here = Vec::with_capacity(layers.len());
        for (j, band) in layers.iter().enumerate() {
            let buf = &mut scratch.inputs[i][j];
            let layer = band.header.layer;
            let ch = layer.channels();
            let above = window.above.as_ref().map(|a| &a[i][j]).filter(|_| top > 0);
            let below = window
                .below
                .as_ref()
                .map(|a| &a[i][j])
                .filter(|_| bottom > 0);
            let parts = [(above, top), (Some(band), rows as usize), (below, bottom)];
            let any = parts
                .iter()
                .any(|(b, _)| b.is_some_and(|b| !b.header.empty));
            // Only required layers need zeros; optional ones are left out of the view.
            let keep = any || plan.required[i].contains(&layer);
            here.push(keep);
            if !keep {
                continue;
            }
            buf.resize(extended * ch, 0.0);
            let mut at = 0;
            for (k, (part, part_rows)) in parts.into_iter().enumerate() {
                let len = part_rows * w * ch;
                let dst = &mut buf[at..at + len];
                at += len;
                let Some(part) = part.filter(|p| !p.header.empty) else {
                    dst.fill(0.0);
                    continue;
                };
                let format = part.header.format;
                let row_bytes = w * format.bytes_per_pixel();
                let have = part.header.height as usize;
                // The rows next to the band: the last ones above it, the first ones below.
                let first = if k == 0 { have - part_rows } else { 0 };
                let bytes = &part.payload[first * row_bytes..(first + part_rows) * row_bytes];
                unpack(format, bytes, part.header.scale, dst).map_err(|reason| {
                    ComputeError::Unpack {
                        input: i,
                        layer,
                        format,
                        reason,
                    }
                })?;
            }
        }
        present.push(here);
    }
    Ok(present)
}

/// A lone `depth` over layers it selects as bits (`Operators::depth`): every output is selected
/// and packed in one pass from the packed inputs (`Depth::apply_packed`), timed as composite.
#[allow(clippy::too_many_arguments)]
fn depth_packed(
    plan: &StagePlan,
    depth: &Depth,
    frame: u64,
    (y0, rows): (u32, u32),
    received: &[Vec<InBand>],
    scale: f32,
    scratch: &mut Scratch,
    mut out: BandOut,
) -> Result<BandOut, ComputeError> {
    let start = Instant::now();
    let pixels = plan.config.width as usize * rows as usize;
    let inputs: Vec<Vec<PackedLayer<'_>>> = received
        .iter()
        .map(|layers| {
            layers
                .iter()
                .map(|b| PackedLayer {
                    layer: b.header.layer,
                    format: b.header.format,
                    scale: b.header.scale,
                    bytes: (!b.header.empty).then_some(&b.payload[..]),
                })
                .collect()
        })
        .collect();
    let outputs = &plan.config.outputs;
    let mut buffers: Vec<Vec<u8>> = outputs
        .iter()
        .map(|(_, f)| scratch.pool.take(pixels * f.bytes_per_pixel()))
        .collect();
    let mut targets: Vec<PackedOut<'_>> = outputs
        .iter()
        .zip(buffers.iter_mut())
        .map(|(&(layer, format), bytes)| PackedOut {
            layer,
            format,
            scale,
            bytes,
        })
        .collect();
    let summaries = depth
        .apply_packed(&inputs, &mut targets)
        .map_err(ComputeError::Fused)?;
    drop(targets);
    out.composite = start.elapsed();
    for ((&(layer, format), bytes), summary) in outputs.iter().zip(buffers).zip(&summaries) {
        let header = header(plan, frame, layer, format, y0, rows, scale);
        let band = packed_band(header, bytes, summary, &mut out, &scratch.pool);
        out.bands.push(band);
    }
    Ok(out)
}

/// A payload a fused kernel packed (`ops::packed_out`), sealed with its summary: an empty band
/// if every value was zero.
fn packed_band(
    mut header: BandHeader,
    bytes: Vec<u8>,
    summary: &PackSummary,
    out: &mut BandOut,
    pool: &Arc<BufferPool>,
) -> (BandHeader, Bytes) {
    if !summary.nonzero {
        pool.put(bytes);
        return empty_band(header, out);
    }
    header.payload_len = u32::try_from(bytes.len()).unwrap_or(u32::MAX);
    header.checksum = summary.checksum();
    pooled_band(header, bytes, summary.saturated, out, pool)
}

/// Packs the combined layers (`scratch.outs`, in `plan.produced` order) as the stage's outputs.
#[allow(clippy::too_many_arguments)]
fn finish(
    plan: &StagePlan,
    frame: u64,
    y0: u32,
    rows: u32,
    skip: usize,
    scale: f32,
    scratch: &mut Scratch,
    mut out: BandOut,
    start: Instant,
) -> Result<BandOut, ComputeError> {
    let cfg = &plan.config;
    let packing = Instant::now();
    out.composite = packing - start;

    for &(layer, format) in &cfg.outputs {
        let idx = plan
            .produced
            .iter()
            .position(|l| *l == layer)
            .unwrap_or_default();
        let header = header(plan, frame, layer, format, y0, rows, scale);
        // The band's own rows (`skip` pixels of halo above them).
        let ch = layer.channels();
        let own = cfg.width as usize * rows as usize * ch;
        let values = &scratch.outs[idx][skip * ch..skip * ch + own];
        let packed = pack_band(header, values, &mut out, &scratch.pool)?;
        out.bands.push(packed);
    }
    out.pack = packing.elapsed();
    Ok(out)
}

/// The no-operator stage: forwards each configured output layer of its one input, repacking
/// only when the format changes.
#[allow(clippy::too_many_arguments)]
fn relay(
    plan: &StagePlan,
    frame: u64,
    y0: u32,
    rows: u32,
    layers: &[InBand],
    scale: f32,
    scratch: &mut Scratch,
    mut out: BandOut,
) -> Result<BandOut, ComputeError> {
    let packing = Instant::now();
    let pixels = plan.config.width as usize * rows as usize;
    scratch.inputs.resize_with(1, Vec::new);
    scratch.inputs[0].resize_with(1, Vec::new);
    for &(layer, format) in &plan.config.outputs {
        let Some(band) = layers.iter().find(|b| b.header.layer == layer) else {
            continue;
        };
        let mut h = header(plan, frame, layer, format, y0, rows, scale);
        if band.header.empty {
            let empty = empty_band(h, &mut out);
            out.bands.push(empty);
        } else if band.header.format == format {
            h.scale = band.header.scale;
            h.saturated = band.header.saturated;
            h.payload_len = band.header.payload_len;
            h.checksum = band.header.checksum;
            out.bands.push((h, band.payload.clone()));
        } else {
            let buf = &mut scratch.inputs[0][0];
            buf.resize(pixels * layer.channels(), 0.0);
            unpack(band.header.format, &band.payload, band.header.scale, buf).map_err(
                |reason| ComputeError::Unpack {
                    input: 0,
                    layer,
                    format: band.header.format,
                    reason,
                },
            )?;
            let values = std::mem::take(buf);
            let packed = pack_band(h, &values, &mut out, &scratch.pool);
            scratch.inputs[0][0] = values;
            out.bands.push(packed?);
        }
    }
    out.pack = packing.elapsed();
    Ok(out)
}

fn header(
    plan: &StagePlan,
    frame: u64,
    layer: Layer,
    format: PixelFormat,
    y0: u32,
    rows: u32,
    scale: f32,
) -> BandHeader {
    BandHeader {
        frame,
        epoch: plan.epoch(),
        layer,
        format,
        x0: 0,
        y0,
        width: plan.config.width,
        height: rows,
        scale,
        empty: false,
        payload_len: 0,
        checksum: 0,
        saturated: 0,
    }
}

/// Packs `values` under `header` (all zeros become an empty band with no payload).
fn pack_band(
    mut header: BandHeader,
    values: &[f32],
    out: &mut BandOut,
    pool: &Arc<BufferPool>,
) -> Result<(BandHeader, Bytes), ComputeError> {
    if values.iter().all(|v| *v == 0.0) {
        return Ok(empty_band(header, out));
    }
    let len = values.len() / header.format.channels() * header.format.bytes_per_pixel();
    let mut bytes = pool.take(len);
    let saturated = pack(header.format, values, header.scale, &mut bytes).map_err(|reason| {
        ComputeError::Pack {
            layer: header.layer,
            format: header.format,
            reason,
        }
    })?;
    header.seal(&bytes);
    Ok(pooled_band(header, bytes, saturated, out, pool))
}

/// An all-zero band: sent as an empty band with no payload.
fn empty_band(mut header: BandHeader, out: &mut BandOut) -> (BandHeader, Bytes) {
    header.empty = true;
    header.seal(&[]);
    out.empty += 1;
    (header, Bytes::new())
}

/// A packed and sealed payload from `pool`, which gets the buffer back when the band is sent.
fn pooled_band(
    mut header: BandHeader,
    bytes: Vec<u8>,
    saturated: u64,
    out: &mut BandOut,
    pool: &Arc<BufferPool>,
) -> (BandHeader, Bytes) {
    header.saturated = u32::try_from(saturated).unwrap_or(u32::MAX);
    out.saturated += saturated;
    let pooled = Pooled {
        buf: bytes,
        pool: Arc::clone(pool),
    };
    (header, Bytes::from_owner(pooled))
}
