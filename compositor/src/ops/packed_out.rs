//! Packing fused into an operator's block loop. A fused kernel finishes each block of `BLOCK`
//! pixels in an L1 buffer and packs it at once into the outgoing band's payload, folding the
//! payload checksum, the saturation count and the all-zero test into the same pass, so the
//! band's f32 result is never written to memory and read back (by the pack, the checksum and the
//! empty-band test, three passes over a 1080p band's 3 MB of f32 per layer). The bytes, checksum
//! and counts are those of packing the whole f32 band with `protocol::format::pack` and sealing
//! it: every link format packs each pixel on its own, and CRC-32 spans combine exactly.

use super::{Isa, OpError, PAR_SPAN};
use crc32fast::Hasher;
use lightfold_protocol::format::{self, F16_MAX, FormatError};
use lightfold_protocol::{Layer, PixelFormat};
use rayon::prelude::*;

/// One output layer packed in place: its link format, the fixed-point scale (`seed64`), and the
/// payload, sized for the band's pixels.
#[derive(Debug)]
pub struct PackedOut<'a> {
    pub layer: Layer,
    pub format: PixelFormat,
    pub scale: f32,
    pub bytes: &'a mut [u8],
}

/// What packing one output layer gave.
#[derive(Debug, Clone, Default)]
pub struct PackSummary {
    /// Pixels with a channel beyond the format's range (`PackStats::saturated`).
    pub saturated: u64,
    /// Whether any value was not zero (an all-zero band is sent as an empty band instead).
    pub nonzero: bool,
    hasher: Hasher,
}

impl PackSummary {
    /// The CRC-32 of the packed payload (`protocol::band::checksum`).
    pub fn checksum(&self) -> u32 {
        self.hasher.clone().finalize()
    }

    /// Appends the summary of the span that follows this one.
    fn append(&mut self, next: &PackSummary) {
        self.saturated += next.saturated;
        self.nonzero |= next.nonzero;
        self.hasher.combine(&next.hasher);
    }
}

/// Packs the finished block `values` (whole pixels of `format`) into `bytes`, its place in the
/// payload, and adds it to `summary`. Compiled inside the calling kernel (`ops::dispatch`): on
/// AVX-512 an `f16x6` block is rounded in this loop (`format::encode_half`, 2.3× the slice
/// conversion there); elsewhere, and for the other formats, `format::pack` packs it.
#[inline(always)]
pub(crate) fn pack_block(
    isa: Isa,
    format: PixelFormat,
    scale: f32,
    values: &[f32],
    bytes: &mut [u8],
    summary: &mut PackSummary,
) -> Result<(), FormatError> {
    // A flat OR (no early exit), so it vectorises; the values are in L1.
    summary.nonzero |= values.iter().fold(false, |a, v| a | (*v != 0.0));
    if isa == Isa::Avx512 && format == PixelFormat::F16x6 {
        summary.saturated += pack_halves(values, bytes);
    } else {
        summary.saturated += format::pack(format, values, scale, bytes)?.saturated;
    }
    summary.hasher.update(bytes);
    Ok(())
}

/// `format::pack` of `f16x6`: clamp to [0, 65504] (NaN → 0), round to nearest even, count the
/// pixels with a channel above 65504.
#[inline(always)]
fn pack_halves(values: &[f32], bytes: &mut [u8]) -> u64 {
    let mut over = false;
    for (o, &v) in bytes.as_chunks_mut::<2>().0.iter_mut().zip(values) {
        over |= v > F16_MAX;
        let x = if v > 0.0 { v } else { 0.0 };
        let x = if x < F16_MAX { x } else { F16_MAX };
        *o = format::encode_half(x).to_le_bytes();
    }
    if !over {
        return 0;
    }
    let pixels = values.as_chunks::<6>().0;
    let saturated = |p: &[f32; 6]| p.iter().fold(false, |a, &v| a | (v > F16_MAX));
    pixels.iter().map(|p| u64::from(saturated(p))).sum()
}

/// Adds `bytes`, already packed in place by a kernel that selects packed values instead of packing
/// f32 (`depth`), to `summary`: their `saturated` pixels and whether any value was not zero.
#[inline]
pub(crate) fn add_packed(summary: &mut PackSummary, bytes: &[u8], saturated: u64, nonzero: bool) {
    summary.nonzero |= nonzero;
    summary.saturated += saturated;
    summary.hasher.update(bytes);
}

/// Checks that every output's payload holds exactly `pixels` pixels of its format.
pub(crate) fn check_outs(
    op: &'static str,
    pixels: usize,
    outs: &[PackedOut<'_>],
) -> Result<(), OpError> {
    for o in outs {
        let expected = pixels * o.format.bytes_per_pixel();
        if o.bytes.len() != expected || o.format.channels() != o.layer.channels() {
            return Err(OpError::PackedOut {
                op,
                layer: o.layer,
                format: o.format,
                expected,
                actual: o.bytes.len(),
            });
        }
    }
    Ok(())
}

/// One span's part of every output: the layer's format and scale, its bytes, and its summary.
pub(crate) struct SpanOut<'s> {
    pub format: PixelFormat,
    pub scale: f32,
    pub bytes: &'s mut [u8],
    pub summary: PackSummary,
}

/// Runs `f(first_pixel, outs)` over spans of `PAR_SPAN` pixels of every output, on the rayon
/// pool when the band has at least two spans and the pool more than one thread (as
/// `ops::for_spans`), and returns each output's summary, spans combined in order.
pub(crate) fn for_packed_spans<F>(
    pixels: usize,
    outs: &mut [PackedOut<'_>],
    f: F,
) -> Result<Vec<PackSummary>, OpError>
where
    F: Fn(usize, &mut [SpanOut<'_>]) -> Result<(), OpError> + Sync,
{
    let spans = pixels.div_ceil(PAR_SPAN).max(1);
    let mut tasks: Vec<Vec<SpanOut<'_>>> = (0..spans).map(|_| Vec::new()).collect();
    for o in outs.iter_mut() {
        let span_bytes = PAR_SPAN * o.format.bytes_per_pixel();
        let mut chunks = o.bytes.chunks_mut(span_bytes.max(1));
        for task in tasks.iter_mut() {
            task.push(SpanOut {
                format: o.format,
                scale: o.scale,
                bytes: chunks.next().unwrap_or_default(),
                summary: PackSummary::default(),
            });
        }
    }
    let run = |(i, mut task): (usize, Vec<SpanOut<'_>>)| {
        f(i * PAR_SPAN, &mut task)?;
        Ok(task.into_iter().map(|s| s.summary).collect::<Vec<_>>())
    };
    let done: Vec<Vec<PackSummary>> = if pixels < 2 * PAR_SPAN || rayon::current_num_threads() < 2 {
        tasks
            .into_iter()
            .enumerate()
            .map(run)
            .collect::<Result<_, OpError>>()?
    } else {
        tasks
            .into_par_iter()
            .enumerate()
            .map(run)
            .collect::<Result<_, OpError>>()?
    };
    let mut total = vec![PackSummary::default(); outs.len()];
    for span in &done {
        for (t, s) in total.iter_mut().zip(span) {
            t.append(s);
        }
    }
    Ok(total)
}
