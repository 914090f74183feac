//! The fast `accumulate`: per block of `BLOCK` pixels, the output is initialised from the
//! upstream partial, each local term is added in input order with loops over four pixels at a
//! time (24 lanes the compiler vectorises), and the block saturates once at the end. The same
//! kernels serve `apply_packed`, which unpacks each input's block into an L1 buffer just before
//! adding it, so a packed band is read once and never expanded to a full f32 band.

use super::{Accumulate, AmbientMask, NAME};
use crate::ops::{
    BLOCK, BandMut, OpError, Operator, Signature, check_band, clamp_fast, for_spans, saturate,
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

/// How one local input contributes.
#[derive(Debug, Clone, Copy)]
enum Kind {
    Plain,
    /// Eq. 6 with `I^a = 1`.
    Uniform,
    /// Eq. 6 with `I^a` from the ambient layer.
    Masked,
}

/// One local input's contribution: its kind and channel factors.
#[derive(Debug, Clone)]
pub(super) struct Term {
    kind: Kind,
    c24: [f32; 24],
    c6: [f32; 6],
}

pub(super) fn terms(op: &Accumulate) -> Vec<Term> {
    (0..op.coeffs.len())
        .map(|j| Term {
            kind: match op.fold_of(j) {
                None => Kind::Plain,
                Some(AmbientMask::Uniform) => Kind::Uniform,
                Some(AmbientMask::Layer) => Kind::Masked,
            },
            c24: std::array::from_fn(|k| op.coeffs[j][k % 6]),
            c6: op.coeffs[j],
        })
        .collect()
}

/// Eq. 6 with `I^a = 1`: 1 on the diffuse channels, 0 (an exact no-op) on the specular ones.
const UNIFORM_AMBIENT: [f32; 24] = {
    let mut a = [0.0; 24];
    let mut k = 0;
    while k < 24 {
        if k % 6 < 3 {
            a[k] = 1.0;
        }
        k += 1;
    }
    a
};

/// Starts a block from the upstream partial (sanitised) or from zero.
#[inline]
pub(super) fn init(o: &mut [f32], up: Option<&[f32]>) {
    match up {
        Some(u) => {
            for (o, u) in o.iter_mut().zip(u) {
                *o = clamp_fast(*u);
            }
        }
        None => o.fill(0.0),
    }
}

/// Saturates a finished block (sums of non-negative terms may have reached +Inf).
#[inline]
pub(super) fn finish(o: &mut [f32]) {
    for o in o.iter_mut() {
        *o = saturate(*o);
    }
}

impl Term {
    /// Adds this term to the block `o`; `x` is the block of the input's illumination (absent:
    /// an empty band) and `a` the block of its ambient layer (masked folding only).
    #[inline]
    pub(super) fn add(&self, o: &mut [f32], x: Option<&[f32]>, a: Option<&[f32]>) {
        match (self.kind, x) {
            (Kind::Plain, None) => {}
            (Kind::Plain, Some(x)) => madd::<false>(o, x, &self.c24),
            (Kind::Uniform, Some(x)) => madd::<true>(o, x, &self.c24),
            (Kind::Uniform, None) => {
                // An empty band on the folding node still adds c^d ⊙ I^a.
                for o4 in o.chunks_mut(24) {
                    for ((o, a), c) in o4.iter_mut().zip(&UNIFORM_AMBIENT).zip(&self.c24) {
                        *o += *c * *a;
                    }
                }
            }
            (Kind::Masked, x) => {
                let (c, a) = (
                    &self.c6,
                    a.expect("checked: the masked input has an ambient layer"),
                );
                for (px, (o, a)) in o.chunks_exact_mut(6).zip(a.chunks_exact(3)).enumerate() {
                    let x: [f32; 6] = match x {
                        Some(x) => std::array::from_fn(|k| clamp_fast(x[px * 6 + k])),
                        None => [0.0; 6],
                    };
                    for k in 0..3 {
                        o[k] += c[k] * (x[k] + clamp_fast(a[k]));
                    }
                    for k in 3..6 {
                        o[k] += c[k] * x[k];
                    }
                }
            }
        }
    }
}

/// `o += c ⊙ clamp(x)`, or with `FOLD` `o += c ⊙ (clamp(x) + I^a)` for `I^a = 1`, over whole
/// groups of four pixels, then the rest.
#[inline(always)]
fn madd<const FOLD: bool>(o: &mut [f32], x: &[f32], c: &[f32; 24]) {
    let term = |x: f32, k: usize| {
        if FOLD {
            clamp_fast(x) + UNIFORM_AMBIENT[k]
        } else {
            clamp_fast(x)
        }
    };
    let mut oc = o.chunks_exact_mut(24);
    let mut xc = x.chunks_exact(24);
    for (o, x) in (&mut oc).zip(&mut xc) {
        for k in 0..24 {
            o[k] += c[k] * term(x[k], k);
        }
    }
    for (k, (o, x)) in oc
        .into_remainder()
        .iter_mut()
        .zip(xc.remainder())
        .enumerate()
    {
        *o += c[k] * term(*x, k);
    }
}

/// Unpacks the pixels `px..px + x.len() / 6` of a packed band into `x`.
fn unpack_block(p: &PackedIllumination<'_>, px: usize, x: &mut [f32]) -> Result<(), FormatError> {
    let bpp = p.format.bytes_per_pixel();
    let bytes = &p.bytes[px * bpp..(px + x.len() / 6) * bpp];
    if p.format == PixelFormat::Rgb9e5x2 {
        rgb9e5_words(bytes, x);
        return Ok(());
    }
    format::unpack(p.format, bytes, p.scale, x)
}

/// `rgb9e5x2` decoded one 32-bit triple at a time with signed conversions, which the compiler
/// keeps branch-free (measured 1.9× `protocol::format::unpack` on one core). The same bits as
/// `unpack` (tests/differential.rs): the exponent word scales exact small integers.
fn rgb9e5_words(bytes: &[u8], x: &mut [f32]) {
    for (b, o) in bytes
        .as_chunks::<4>()
        .0
        .iter()
        .zip(x.as_chunks_mut::<3>().0)
    {
        let w = u32::from_le_bytes(*b);
        let f = f32::from_bits(((w >> 27) + 103) << 23);
        *o = [
            (w & 511) as i32 as f32 * f,
            (w >> 9 & 511) as i32 as f32 * f,
            (w >> 18 & 511) as i32 as f32 * f,
        ];
    }
}

/// The bytes of pixels `px..px + n` of a packed band.
fn block_bytes<'a>(p: &PackedIllumination<'a>, px: usize, n: usize) -> &'a [u8] {
    let bpp = p.format.bytes_per_pixel();
    &p.bytes[px * bpp..(px + n) * bpp]
}

/// Formats the fused path decodes itself, straight into the accumulation with no staging buffer
/// (measured: `seed64` this way is as fast as a staged decode; `rgb9e5x2` per pixel was 2×
/// slower than its staged word decoder, so only `seed64` goes direct). The bits are those of
/// `protocol::format::unpack` (tests/differential.rs): small exact integers times the same f32
/// factor.
#[derive(Debug, Clone, Copy)]
enum Direct {
    /// `seed64` with its diffuse and specular step, computed as `unpack` computes them.
    Seed64 { fd: f32, fs: f32 },
}

impl Direct {
    fn of(p: &PackedIllumination<'_>) -> Option<Direct> {
        match p.format {
            PixelFormat::Seed64 => Some(Direct::Seed64 {
                fd: p.scale / 2047.0,
                fs: p.scale / 1023.0,
            }),
            _ => None,
        }
    }

    /// `o = decode(bytes)`.
    #[inline]
    fn load(self, o: &mut [f32], bytes: &[u8]) {
        match self {
            Direct::Seed64 { fd, fs } => load_with(o, bytes, |b| seed64(b, fd, fs)),
        }
    }

    /// `o += c ⊙ decode(bytes)` (with `FOLD`, `c ⊙ (decode(bytes) + I^a)`).
    #[inline]
    fn madd<const FOLD: bool>(self, o: &mut [f32], bytes: &[u8], c: &[f32; 6]) {
        match self {
            Direct::Seed64 { fd, fs } => madd_with::<FOLD, _>(o, bytes, c, |b| seed64(b, fd, fs)),
        }
    }
}

#[inline(always)]
fn load_with<F: Fn(&[u8; 8]) -> [f32; 6]>(o: &mut [f32], bytes: &[u8], dec: F) {
    for (o, b) in o
        .as_chunks_mut::<6>()
        .0
        .iter_mut()
        .zip(bytes.as_chunks::<8>().0)
    {
        *o = dec(b);
    }
}

#[inline(always)]
fn madd_with<const FOLD: bool, F: Fn(&[u8; 8]) -> [f32; 6]>(
    o: &mut [f32],
    bytes: &[u8],
    c: &[f32; 6],
    dec: F,
) {
    for (o, b) in o
        .as_chunks_mut::<6>()
        .0
        .iter_mut()
        .zip(bytes.as_chunks::<8>().0)
    {
        let x = dec(b);
        for k in 0..6 {
            let term = if FOLD {
                x[k] + UNIFORM_AMBIENT[k]
            } else {
                x[k]
            };
            o[k] += c[k] * term;
        }
    }
}

/// One `seed64` pixel: 3×11-bit diffuse then 3×10-bit specular codes.
#[inline(always)]
fn seed64(b: &[u8; 8], fd: f32, fs: f32) -> [f32; 6] {
    let w = u64::from_le_bytes(*b);
    [
        (w & 0x7FF) as i32 as f32 * fd,
        (w >> 11 & 0x7FF) as i32 as f32 * fd,
        (w >> 22 & 0x7FF) as i32 as f32 * fd,
        (w >> 33 & 0x3FF) as i32 as f32 * fs,
        (w >> 43 & 0x3FF) as i32 as f32 * fs,
        (w >> 53 & 0x3FF) as i32 as f32 * fs,
    ]
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
    /// The masked ambient folding needs an ambient layer and is not available here.
    pub fn apply_packed(
        &self,
        inputs: &[Option<PackedIllumination<'_>>],
        out: &mut BandMut<'_>,
    ) -> Result<(), OpError> {
        let sig = self.signature();
        if inputs.len() != sig.inputs.len() {
            return Err(OpError::InputCount {
                op: NAME,
                expected: sig.inputs.len(),
                got: inputs.len(),
            });
        }
        let outputs_only = Signature {
            inputs: vec![],
            outputs: sig.outputs,
        };
        check_band(NAME, &outputs_only, &[], out)?;
        if let Some(j) =
            (0..self.coeffs.len()).find(|&j| matches!(self.fold_of(j), Some(AmbientMask::Layer)))
        {
            return Err(OpError::MissingLayer {
                op: NAME,
                input: self.input_of(j),
                layer: Layer::Ambient,
            });
        }
        let pixels = out.pixels;
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
        let up = if self.params.upstream {
            inputs[0]
        } else {
            None
        };
        let locals = &inputs[first_local..];
        let terms = terms(self);
        let failure: Mutex<Option<OpError>> = Mutex::new(None);
        let dst = out.layer_mut(Layer::Illumination).expect("checked");
        for_spans(pixels, vec![(6, dst)], |first, outs| {
            let span = &mut *outs[0];
            let mut buf = [0f32; BLOCK * 6];
            for (b, o) in span.chunks_mut(BLOCK * 6).enumerate() {
                let (px, n) = (first + b * BLOCK, o.len() / 6);
                let x = &mut buf[..n * 6];
                match &up {
                    Some(p) => match Direct::of(p) {
                        // Decoded values are finite and non-negative: the clamp is the identity.
                        Some(d) => d.load(o, block_bytes(p, px, n)),
                        None if p.format == PixelFormat::Rgb9e5x2 => {
                            rgb9e5_words(block_bytes(p, px, n), o)
                        }
                        None => match unpack_block(p, px, x) {
                            Ok(()) => init(o, Some(x)),
                            Err(e) => return fail(&failure, packed_error(0, e)),
                        },
                    },
                    None => init(o, None),
                }
                for (j, (t, p)) in terms.iter().zip(locals).enumerate() {
                    let Some(p) = p else {
                        t.add(o, None, None);
                        continue;
                    };
                    match (Direct::of(p), t.kind) {
                        (Some(d), Kind::Plain) => d.madd::<false>(o, block_bytes(p, px, n), &t.c6),
                        (Some(d), Kind::Uniform) => d.madd::<true>(o, block_bytes(p, px, n), &t.c6),
                        _ => match unpack_block(p, px, x) {
                            Ok(()) => t.add(o, Some(x), None),
                            Err(e) => return fail(&failure, packed_error(first_local + j, e)),
                        },
                    }
                }
                finish(o);
            }
        });
        match failure.into_inner().unwrap_or_else(|p| p.into_inner()) {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}
