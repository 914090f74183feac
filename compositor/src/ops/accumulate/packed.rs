//! `Accumulate::apply_packed`: unpack and accumulate fused, from the bands as they arrived on
//! their links. Per block of `BLOCK` pixels, `rgb9e5x2` and `seed64` inputs are decoded straight
//! into the sum (`decode.rs`), `f16x6` and `f32x6` are decoded inside the loop, and other formats
//! are unpacked into an L1 buffer just before they are added, so a packed band is read once and
//! never expanded to a full f32 band. `apply_packed_to` also packs each finished block into the
//! outgoing payload (`ops::packed_out`), so the sum never leaves L1 either. The block loop is a
//! dispatched kernel (`ops::dispatch`): the decode is limited by arithmetic, which wider vectors
//! speed up.

use super::decode::{BPP, Decoder, Shape};
use super::fast::{Kind, Term, finish, init, terms};
use super::{Accumulate, AmbientMask, NAME};
use crate::ops::clamp_fast;
use crate::ops::dispatch::{self, Isa, Kernel};
use crate::ops::packed_out::{SpanOut, check_outs, for_packed_spans, pack_block};
use crate::ops::{
    BLOCK, BandMut, OpError, Operator, PackSummary, PackedOut, Signature, check_band, for_spans,
};
use lightfold_protocol::format::{self, FormatError};
use lightfold_protocol::{Layer, PixelFormat};
use std::sync::Mutex;

/// One input's illumination band as it arrived on its link.
#[derive(Debug, Clone, Copy)]
pub struct PackedIllumination<'a> {
    pub format: PixelFormat,
    /// The band header's scale (`seed64`; ignored by the other formats).
    pub scale: f32,
    pub bytes: &'a [u8],
}

/// How the kernel reads one input.
#[derive(Debug, Clone, Copy)]
enum Source<'a> {
    /// Decoded by `decode` straight into the sum.
    Direct(Decoder, &'a [u8]),
    /// `f16x6`, decoded inside the block loop (`format::decode_half`, so compiled for the
    /// kernel's instruction set) into the sum or the block buffer.
    Halves(&'a [u8]),
    /// `f32x6`, read inside the block loop with `unpack`'s clamp, which is also the clamp the
    /// sum applies to every term, so the bits are those of unpacking first.
    Floats(&'a [u8]),
    /// Unpacked by `protocol::format::unpack` into the block buffer, then added.
    Staged(PackedIllumination<'a>),
}

impl<'a> Source<'a> {
    fn of(p: PackedIllumination<'a>) -> Source<'a> {
        match Decoder::of(p.format, p.scale) {
            Some(d) => Source::Direct(d, p.bytes),
            None if p.format == PixelFormat::F16x6 => Source::Halves(p.bytes),
            None if p.format == PixelFormat::F32x6 => Source::Floats(p.bytes),
            None => Source::Staged(p),
        }
    }
}

/// Decodes the `f16x6` pixels `px..px + o.len() / 6` of `bytes` into `o`. The values are
/// finite and in [0, 65504], so the clamp `init` and the terms apply is the identity on them.
#[inline(always)]
fn decode_halves(bytes: &[u8], px: usize, o: &mut [f32]) {
    let bytes = &bytes[px * 12..px * 12 + o.len() * 2];
    for (o, h) in o.iter_mut().zip(bytes.as_chunks::<2>().0) {
        *o = format::decode_half(u16::from_le_bytes(*h));
    }
}

/// Reads the `f32x6` pixels `px..px + o.len() / 6` of `bytes` into `o`, clamped as `unpack` and
/// `init` clamp (NaN and negatives → 0, +Inf → `MAX_VALUE`).
#[inline(always)]
fn decode_floats(bytes: &[u8], px: usize, o: &mut [f32]) {
    let bytes = &bytes[px * 24..px * 24 + o.len() * 4];
    for (o, b) in o.iter_mut().zip(bytes.as_chunks::<4>().0) {
        *o = clamp_fast(f32::from_le_bytes(*b));
    }
}

/// Unpacks the pixels `px..px + x.len() / 6` of a packed band into `x`.
fn unpack_block(p: &PackedIllumination<'_>, px: usize, x: &mut [f32]) -> Result<(), FormatError> {
    let bpp = p.format.bytes_per_pixel();
    let bytes = &p.bytes[px * bpp..(px + x.len() / 6) * bpp];
    format::unpack(p.format, bytes, p.scale, x)
}

/// A band's inputs, as the kernel reads them.
struct Band<'a> {
    up: Option<Source<'a>>,
    /// Per local input: its term, its band (`None`: empty) and its input index.
    locals: Vec<(Term, Option<Source<'a>>, usize)>,
}

/// Where a span's blocks go: f32 values, or packed at once into the outgoing payload.
enum Dest<'s, 'b> {
    Values(&'s mut [f32]),
    Packed(&'s mut SpanOut<'b>),
}

/// The block loop over one span of the output, starting at pixel `first`.
struct Span<'s, 'a, 'b> {
    band: &'s Band<'a>,
    first: usize,
    out: Dest<'s, 'b>,
}

impl Span<'_, '_, '_> {
    /// Block `o` (whole pixels from `px`) of the sum; `x` is a block buffer as long.
    #[inline(always)]
    fn block(&self, isa: Isa, px: usize, o: &mut [f32], x: &mut [f32]) -> Result<(), OpError> {
        let n = o.len() / 6;
        match &self.band.up {
            // Decoded values are finite and non-negative: the clamp is the identity.
            Some(Source::Direct(d, bytes)) => {
                d.load(Shape::best(isa, d), o, &bytes[px * BPP..(px + n) * BPP])
            }
            Some(Source::Halves(bytes)) => decode_halves(bytes, px, o),
            Some(Source::Floats(bytes)) => decode_floats(bytes, px, o),
            Some(Source::Staged(p)) => {
                unpack_block(p, px, x).map_err(|e| packed_error(0, e))?;
                init(o, Some(x));
            }
            None => init(o, None),
        }
        for (t, src, input) in &self.band.locals {
            match (src, t.kind) {
                (None, _) => t.add(o, None, None),
                (Some(Source::Direct(d, bytes)), kind) => {
                    let bytes = &bytes[px * BPP..(px + n) * BPP];
                    match (Shape::best(isa, d), kind) {
                        (Shape::Staged, _) => {
                            d.load(Shape::Staged, x, bytes);
                            t.add(o, Some(x), None);
                        }
                        (shape, Kind::Plain) => d.madd::<false>(shape, o, bytes, &t.cg),
                        (shape, Kind::Uniform) => d.madd::<true>(shape, o, bytes, &t.cg),
                        (_, Kind::Masked) => {
                            unreachable!("apply_packed refuses masked folding")
                        }
                    }
                }
                (Some(Source::Halves(bytes)), _) => {
                    decode_halves(bytes, px, x);
                    t.add(o, Some(x), None);
                }
                (Some(Source::Floats(bytes)), _) => {
                    decode_floats(bytes, px, x);
                    t.add(o, Some(x), None);
                }
                (Some(Source::Staged(p)), _) => {
                    unpack_block(p, px, x).map_err(|e| packed_error(*input, e))?;
                    t.add(o, Some(x), None);
                }
            }
        }
        finish(o);
        Ok(())
    }
}

impl Kernel for Span<'_, '_, '_> {
    type Output = Result<(), OpError>;

    #[inline(always)]
    fn run(mut self, isa: Isa) -> Result<(), OpError> {
        let mut buf = [0f32; BLOCK * 6];
        match std::mem::replace(&mut self.out, Dest::Values(&mut [])) {
            Dest::Values(out) => {
                for (b, o) in out.chunks_mut(BLOCK * 6).enumerate() {
                    let x = &mut buf[..o.len()];
                    self.block(isa, self.first + b * BLOCK, o, x)?;
                }
            }
            Dest::Packed(out) => {
                let mut sum = [0f32; BLOCK * 6];
                let bpp = out.format.bytes_per_pixel();
                for (b, bytes) in out.bytes.chunks_mut(BLOCK * bpp).enumerate() {
                    let n = bytes.len() / bpp;
                    let (o, x) = (&mut sum[..n * 6], &mut buf[..n * 6]);
                    self.block(isa, self.first + b * BLOCK, o, x)?;
                    pack_block(isa, out.format, out.scale, o, bytes, &mut out.summary).map_err(
                        |source| OpError::Pack {
                            op: NAME,
                            layer: Layer::Illumination,
                            source,
                        },
                    )?;
                }
            }
        }
        Ok(())
    }
}

/// Records the first failure of a parallel span (validation makes this unreachable in practice).
fn fail(slot: &Mutex<Option<OpError>>, e: OpError) {
    let mut f = slot.lock().unwrap_or_else(|p| p.into_inner());
    f.get_or_insert(e);
}

fn packed_error(input: usize, source: FormatError) -> OpError {
    OpError::Packed {
        op: NAME,
        input,
        source,
    }
}

impl Accumulate {
    /// Unpack and accumulate fused: `inputs[i]` is input i's illumination band still in its link
    /// format (`None`: an empty band). Gives the bits of unpacking every band and calling `apply`.
    /// The masked ambient folding needs an ambient-mask layer and is not available here. Runs on the
    /// widest instruction set this CPU has (`Isa::best`).
    pub fn apply_packed(
        &self,
        inputs: &[Option<PackedIllumination<'_>>],
        out: &mut BandMut<'_>,
    ) -> Result<(), OpError> {
        self.apply_packed_on(Isa::best(), inputs, out)
    }

    /// `apply_packed` on the instruction set `isa` (the same bits on every one), which this CPU
    /// must have (`Isa::available`); for tests and benchmarks of each path.
    pub fn apply_packed_on(
        &self,
        isa: Isa,
        inputs: &[Option<PackedIllumination<'_>>],
        out: &mut BandMut<'_>,
    ) -> Result<(), OpError> {
        let sig = self.signature();
        let outputs_only = Signature {
            inputs: vec![],
            outputs: sig.outputs,
        };
        check_band(NAME, &outputs_only, &[], out)?;
        let pixels = out.pixels;
        let band = self.packed_band(isa, inputs, pixels)?;
        let failure: Mutex<Option<OpError>> = Mutex::new(None);
        let dst = out.layer_mut(Layer::Illumination).expect("checked");
        for_spans(pixels, vec![(6, dst)], |first, outs| {
            let span = Span {
                band: &band,
                first,
                out: Dest::Values(&mut *outs[0]),
            };
            if let Err(e) = dispatch::run(isa, span) {
                fail(&failure, e);
            }
        });
        match failure.into_inner().unwrap_or_else(|p| p.into_inner()) {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// `apply_packed` with the sum packed as it is made: `out` is the outgoing illumination
    /// band's payload for `pixels` pixels. Gives the bytes, checksum and counts of packing
    /// `apply_packed`'s result with `protocol::format::pack` (`ops::packed_out`).
    pub fn apply_packed_to(
        &self,
        inputs: &[Option<PackedIllumination<'_>>],
        pixels: usize,
        out: PackedOut<'_>,
    ) -> Result<PackSummary, OpError> {
        self.apply_packed_to_on(Isa::best(), inputs, pixels, out)
    }

    /// `apply_packed_to` on the instruction set `isa` (as `apply_packed_on`).
    pub fn apply_packed_to_on(
        &self,
        isa: Isa,
        inputs: &[Option<PackedIllumination<'_>>],
        pixels: usize,
        out: PackedOut<'_>,
    ) -> Result<PackSummary, OpError> {
        if out.layer != Layer::Illumination {
            return Err(OpError::MissingOutput {
                op: NAME,
                layer: Layer::Illumination,
            });
        }
        let mut outs = [out];
        check_outs(NAME, pixels, &outs)?;
        let band = self.packed_band(isa, inputs, pixels)?;
        let mut done = for_packed_spans(pixels, &mut outs, |first, outs| {
            let span = Span {
                band: &band,
                first,
                out: Dest::Packed(&mut outs[0]),
            };
            dispatch::run(isa, span)
        })?;
        Ok(done.pop().unwrap_or_default())
    }

    /// Checks the packed inputs of a band of `pixels` pixels and says how the kernel reads them.
    fn packed_band<'a>(
        &self,
        isa: Isa,
        inputs: &[Option<PackedIllumination<'a>>],
        pixels: usize,
    ) -> Result<Band<'a>, OpError> {
        if !isa.available() {
            return Err(OpError::IsaUnavailable { isa });
        }
        let sig = self.signature();
        if inputs.len() != sig.inputs.len() {
            return Err(OpError::InputCount {
                op: NAME,
                expected: sig.inputs.len(),
                got: inputs.len(),
            });
        }
        if let Some(j) =
            (0..self.coeffs.len()).find(|&j| matches!(self.fold_of(j), Some(AmbientMask::Layer)))
        {
            return Err(OpError::MissingLayer {
                op: NAME,
                input: self.input_of(j),
                layer: Layer::AmbientMask,
            });
        }
        for (i, p) in inputs.iter().enumerate() {
            let Some(p) = p else { continue };
            if p.format.channels() != 6 {
                return Err(OpError::MissingLayer {
                    op: NAME,
                    input: i,
                    layer: Layer::Illumination,
                });
            }
            // An empty unpack checks the scale; the length must match the band.
            format::unpack(p.format, &[], p.scale, &mut []).map_err(|e| packed_error(i, e))?;
            if p.bytes.len() != pixels * p.format.bytes_per_pixel() {
                return Err(packed_error(
                    i,
                    FormatError::PixelCount {
                        format: p.format,
                        expected: pixels,
                        actual: p.bytes.len() / p.format.bytes_per_pixel(),
                    },
                ));
            }
        }
        let first_local = usize::from(self.params.upstream);
        Ok(Band {
            up: inputs[0].filter(|_| self.params.upstream).map(Source::of),
            locals: terms(self)
                .into_iter()
                .zip(&inputs[first_local..])
                .enumerate()
                .map(|(j, (t, p))| (t, p.map(Source::of), first_local + j))
                .collect(),
        })
    }
}
