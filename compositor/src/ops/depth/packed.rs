//! `Depth::apply_packed`: the nearest-z select from the bands as they arrived on their links
//! straight into the outgoing payloads, for the link formats where selecting a value's bits is
//! exactly what unpacking, `apply` and packing would do to it. Unpack maps every depth to a finite
//! value and every colour value into its format's range, the colour policy leaves such values
//! alone, and packing a value already in range gives back its bits; so the round trip of a
//! selected colour word is a fixed map of its bits (`Word::clean`: finite non-negative values
//! travel unchanged, +Inf becomes the largest finite value, NaN and everything with the sign bit,
//! −0 included, becomes +0), and nothing ever counts as saturated (pack sees no value beyond the
//! range). Per block of `BLOCK` pixels one pass over the depth words finds each pixel's winner,
//! the winner is repeated per word of each colour layer, every word is a flat select of cleaned
//! words, and the checksum and zero test are folded in while the block is in L1
//! (`ops::packed_out`). The block loop is a dispatched kernel (`ops::dispatch`).

use super::{Depth, LINEAR, NAME, REVERSED, ZERO_EMPTY, bad, emit};
use crate::ops::dispatch::{self, Isa, Kernel};
use crate::ops::packed_out::{SpanOut, add_packed, check_outs, for_packed_spans};
use crate::ops::{BLOCK, OpError, PackSummary, PackedOut};
use lightfold_protocol::format::FormatError;
use lightfold_protocol::{Layer, PixelFormat};

/// One layer of one input's band as it arrived on its link.
#[derive(Debug, Clone, Copy)]
pub struct PackedLayer<'a> {
    pub layer: Layer,
    pub format: PixelFormat,
    /// The band header's scale (no format the packed path takes uses it).
    pub scale: f32,
    /// The payload; `None`: the band arrived empty, which reads as all zeros.
    pub bytes: Option<&'a [u8]>,
}

/// Whether a carried colour layer in `format` can be selected as bits: formats whose unpack maps
/// every word into a range that their pack reproduces exactly (no quantisation, no shared
/// exponent, no scale, no sRGB curve).
fn selectable(format: PixelFormat) -> bool {
    matches!(
        format,
        PixelFormat::F16x6 | PixelFormat::F16x4 | PixelFormat::F32x6 | PixelFormat::F32x3
    )
}

/// Most inputs `apply_packed` takes (winners are 16-bit input indices).
const MAX_INPUTS: usize = 1 << 16;

fn refuse(layer: Layer, format: PixelFormat) -> OpError {
    OpError::PackedFormat {
        op: NAME,
        layer,
        format,
    }
}

impl Depth {
    /// Whether `apply_packed` gives the general path's bytes (unpack, `apply`, pack) for a band
    /// with these layers per input (`inputs[i]`, link order) and these outputs: depth is
    /// `depth32` everywhere, every input carries exactly the depth and the carried layers, each
    /// carried layer travels in one of `f16x6`, `f16x4`, `f32x6`, `f32x3` and in the same format
    /// on every input and on the output, and no output is listed twice.
    pub fn packed_supported(
        &self,
        inputs: &[Vec<(Layer, PixelFormat)>],
        outputs: &[(Layer, PixelFormat)],
    ) -> bool {
        self.check_packed(inputs, outputs).is_ok()
    }

    /// `packed_supported` with the reason for a refusal.
    fn check_packed(
        &self,
        inputs: &[Vec<(Layer, PixelFormat)>],
        outputs: &[(Layer, PixelFormat)],
    ) -> Result<(), OpError> {
        let p = &self.params;
        let n = p.inputs as usize;
        if inputs.len() != n {
            return Err(OpError::InputCount {
                op: NAME,
                expected: n,
                got: inputs.len(),
            });
        }
        // Winners share vector lanes with halves, as 16-bit input indices.
        if n > MAX_INPUTS {
            return Err(bad(format!(
                "the packed path takes at most {MAX_INPUTS} inputs"
            )));
        }
        // The format of each carried layer, fixed by the first input that has it.
        let mut carried: Vec<Option<PixelFormat>> = vec![None; p.layers.len()];
        for (i, layers) in inputs.iter().enumerate() {
            for (k, &(layer, format)) in layers.iter().enumerate() {
                let twice = layers[..k].iter().any(|(l, _)| *l == layer);
                let fits = if layer == Layer::Depth {
                    format == PixelFormat::DepthF32
                } else if let Some(j) = p.layers.iter().position(|l| *l == layer) {
                    selectable(format)
                        && format.channels() == layer.channels()
                        && *carried[j].get_or_insert(format) == format
                } else {
                    // A layer the operator does not read: the general path would still unpack
                    // it (and could fail on it), so the two paths could differ.
                    false
                };
                if twice || !fits {
                    return Err(refuse(layer, format));
                }
            }
            for &layer in std::iter::once(&Layer::Depth).chain(&p.layers) {
                if !layers.iter().any(|(l, _)| *l == layer) {
                    return Err(OpError::MissingLayer {
                        op: NAME,
                        input: i,
                        layer,
                    });
                }
            }
        }
        for (k, &(layer, format)) in outputs.iter().enumerate() {
            let want = if layer == Layer::Depth {
                Some(PixelFormat::DepthF32)
            } else {
                let j = p.layers.iter().position(|l| *l == layer);
                j.and_then(|j| carried[j])
            };
            if want != Some(format) || outputs[..k].iter().any(|(l, _)| *l == layer) {
                return Err(refuse(layer, format));
            }
        }
        Ok(())
    }

    /// Nearest-z select from packed inputs into packed outputs. `inputs[i]` holds input i's
    /// layers as they arrived (any order), `outs` the outgoing payloads, all of the same pixel
    /// count: any of the operator's output layers, in any order. Gives each output the bytes,
    /// checksum, saturation count and zero test of unpacking every input layer (zeros for an
    /// empty band), `apply`, and packing the output with `protocol::format::pack`, for the
    /// formats `packed_supported` accepts; refuses the others (`OpError::PackedFormat`). Runs on
    /// the widest instruction set this CPU has (`Isa::best`).
    pub fn apply_packed(
        &self,
        inputs: &[Vec<PackedLayer<'_>>],
        outs: &mut [PackedOut<'_>],
    ) -> Result<Vec<PackSummary>, OpError> {
        self.apply_packed_on(Isa::best(), inputs, outs)
    }

    /// `apply_packed` on the instruction set `isa` (the same bits on every one), which this CPU
    /// must have (`Isa::available`); for tests and benchmarks of each path.
    pub fn apply_packed_on(
        &self,
        isa: Isa,
        inputs: &[Vec<PackedLayer<'_>>],
        outs: &mut [PackedOut<'_>],
    ) -> Result<Vec<PackSummary>, OpError> {
        if !isa.available() {
            return Err(OpError::IsaUnavailable { isa });
        }
        let formats: Vec<Vec<(Layer, PixelFormat)>> = inputs
            .iter()
            .map(|ls| ls.iter().map(|l| (l.layer, l.format)).collect())
            .collect();
        let out_formats: Vec<(Layer, PixelFormat)> =
            outs.iter().map(|o| (o.layer, o.format)).collect();
        self.check_packed(&formats, &out_formats)?;
        let Some(first) = outs.first() else {
            return Ok(Vec::new());
        };
        let pixels = first.bytes.len() / first.format.bytes_per_pixel();
        check_outs(NAME, pixels, outs)?;
        for (i, layers) in inputs.iter().enumerate() {
            for l in layers {
                let bpp = l.format.bytes_per_pixel();
                match l.bytes {
                    Some(b) if b.len() != pixels * bpp => {
                        return Err(OpError::Packed {
                            op: NAME,
                            input: i,
                            source: FormatError::PixelCount {
                                format: l.format,
                                expected: pixels,
                                actual: b.len() / bpp,
                            },
                        });
                    }
                    _ => {}
                }
            }
        }
        // Checked above: every input has each layer once, so `find` is its band.
        let of = |layer: Layer| -> Vec<Option<&[u8]>> {
            inputs
                .iter()
                .map(|ls| ls.iter().find(|l| l.layer == layer).and_then(|l| l.bytes))
                .collect()
        };
        let band = Band {
            depth: of(Layer::Depth),
            outs: outs
                .iter()
                .map(|o| match o.layer {
                    Layer::Depth => Role::Depth,
                    layer => Role::Colour(o.format, of(layer)),
                })
                .collect(),
        };
        let mode = self.mode();
        for_packed_spans(pixels, outs, |first, outs| {
            let span = Span {
                band: &band,
                first,
                outs,
            };
            match mode {
                REVERSED => dispatch::run(isa, Select::<REVERSED>(span)),
                ZERO_EMPTY => dispatch::run(isa, Select::<ZERO_EMPTY>(span)),
                _ => dispatch::run(isa, Select::<LINEAR>(span)),
            }
            Ok(())
        })
    }
}

/// A band's payloads as the kernel reads them (`None`: an empty band).
struct Band<'a> {
    /// Each input's depth.
    depth: Vec<Option<&'a [u8]>>,
    /// What each output is, in `outs` order.
    outs: Vec<Role<'a>>,
}

enum Role<'a> {
    Depth,
    /// A carried layer in its format (the same on every input and the output), per input.
    Colour(PixelFormat, Vec<Option<&'a [u8]>>),
}

/// One span of every output, from pixel `first` of the band.
struct Span<'s, 'a, 'o> {
    band: &'s Band<'a>,
    first: usize,
    outs: &'s mut [SpanOut<'o>],
}

/// The block loop of `apply_packed`, with the depth reading fixed (`MODE`).
struct Select<'s, 'a, 'o, const MODE: u8>(Span<'s, 'a, 'o>);

/// Zero bytes standing in for an empty band: the largest block of words a source can give.
static ZEROS: [u8; BLOCK * 24] = [0; BLOCK * 24];

/// A packed little-endian word of a link format: a half or an f32, as its bits.
trait Word: Copy + PartialEq + PartialOrd {
    type Le: Copy;
    const ZERO: Self;
    /// +Inf, and the largest finite value, which unpack reads +Inf as.
    const INF: Self;
    const MAX: Self;
    /// The pad of a padded format (1.0).
    const ONE: Self;
    fn from_le(b: Self::Le) -> Self;
    fn to_le(self) -> Self::Le;
    /// Input index `i` as a winner of this width (`check_packed` bounds the input count).
    fn input(i: u32) -> Self;
    fn words(b: &[u8]) -> &[Self::Le];
    fn words_mut(b: &mut [u8]) -> &mut [Self::Le];

    /// The word after unpack and pack. Unpack keeps finite non-negative values exactly (f16
    /// subnormals and f32 subnormals too), reads +Inf as the largest finite value and NaN and
    /// everything with the sign bit (−0 too) as +0; pack gives an in-range value its bits back.
    /// As unsigned integers, the kept words are exactly those below +Inf.
    #[inline(always)]
    fn clean(self) -> Self {
        let kept = if self < Self::INF { self } else { Self::ZERO };
        if self == Self::INF { Self::MAX } else { kept }
    }
}

macro_rules! word {
    ($t:ty, $n:literal, inf: $inf:literal, max: $max:literal, one: $one:literal) => {
        impl Word for $t {
            type Le = [u8; $n];
            const ZERO: $t = 0;
            const INF: $t = $inf;
            const MAX: $t = $max;
            const ONE: $t = $one;
            #[inline(always)]
            fn from_le(b: [u8; $n]) -> $t {
                <$t>::from_le_bytes(b)
            }
            #[inline(always)]
            fn to_le(self) -> [u8; $n] {
                self.to_le_bytes()
            }
            #[inline(always)]
            fn input(i: u32) -> $t {
                i as $t
            }
            #[inline(always)]
            fn words(b: &[u8]) -> &[[u8; $n]] {
                b.as_chunks::<$n>().0
            }
            #[inline(always)]
            fn words_mut(b: &mut [u8]) -> &mut [[u8; $n]] {
                b.as_chunks_mut::<$n>().0
            }
        }
    };
}

word!(u16, 2, inf: 0x7C00, max: 0x7BFF, one: 0x3C00);
word!(u32, 4, inf: 0x7F80_0000, max: 0x7F7F_FFFF, one: 0x3F80_0000);

/// Words `at..at + len` of a source, zeros for an empty band.
#[inline(always)]
fn part<W: Word>(src: Option<&[u8]>, at: usize, len: usize) -> &[W::Le] {
    match src {
        Some(b) => &W::words(b)[at..at + len],
        None => &W::words(&ZEROS)[..len],
    }
}

/// Words per pixel of a selectable format.
fn words_of(format: PixelFormat) -> usize {
    match format {
        PixelFormat::F16x6 | PixelFormat::F16x4 => format.bytes_per_pixel() / 2,
        _ => format.bytes_per_pixel() / 4,
    }
}

impl<const MODE: u8> Kernel for Select<'_, '_, '_, MODE> {
    type Output = ();

    #[inline(always)]
    fn run(self, _isa: Isa) {
        let Span { band, first, outs } = self.0;
        let Some(o) = outs.first() else { return };
        let pixels = o.bytes.len() / o.format.bytes_per_pixel();
        let mut zo = [0f32; BLOCK];
        let mut win = [0u32; BLOCK];
        // The winners repeated per word, as words of the layer's width so the select compares
        // lanes of one width.
        let mut wide16 = [0u16; BLOCK * 6];
        let mut wide32 = [0u32; BLOCK * 6];
        for start in (0..pixels).step_by(BLOCK) {
            let (n, lo) = (BLOCK.min(pixels - start), first + start);
            let win = &mut win[..n];
            nearest::<MODE>(&mut zo[..n], win, &band.depth, lo);
            emit::<MODE>(&mut zo[..n]);
            // Words per pixel the wide winners hold for this block (0: not yet).
            let (mut held16, mut held32) = (0, 0);
            for (role, out) in band.outs.iter().zip(outs.iter_mut()) {
                let bpp = out.format.bytes_per_pixel();
                let bytes = &mut out.bytes[start * bpp..(start + n) * bpp];
                let nonzero = match role {
                    Role::Depth => store_depth(&zo[..n], bytes),
                    Role::Colour(format, srcs) => {
                        let words = words_of(*format);
                        let at = lo * words;
                        if matches!(format, PixelFormat::F16x6 | PixelFormat::F16x4) {
                            let wins = &mut wide16[..n * words];
                            if held16 != words {
                                widen_as(words, win, wins);
                                held16 = words;
                            }
                            let nonzero = select::<u16>(u16::words_mut(bytes), srcs, at, wins);
                            if *format == PixelFormat::F16x4 {
                                pad::<u16, 4>(u16::words_mut(bytes))
                            } else {
                                nonzero
                            }
                        } else {
                            let wins = &mut wide32[..n * words];
                            if held32 != words {
                                widen_as(words, win, wins);
                                held32 = words;
                            }
                            select::<u32>(u32::words_mut(bytes), srcs, at, wins)
                        }
                    }
                };
                // Unpacked values are all inside the format's range: pack saturates none.
                add_packed(&mut out.summary, bytes, 0, nonzero);
            }
        }
    }
}

/// Repeats each pixel's winner for its `words` words (3, 4 or 6).
#[inline(always)]
fn widen_as<W: Word>(words: usize, win: &[u32], wide: &mut [W]) {
    #[inline(always)]
    fn each<W: Word, const CH: usize>(win: &[u32], wide: &mut [W]) {
        for (w, o) in win.iter().zip(wide.as_chunks_mut::<CH>().0) {
            *o = [W::input(*w); CH];
        }
    }
    match words {
        3 => each::<W, 3>(win, wide),
        4 => each::<W, 4>(win, wide),
        _ => each::<W, 6>(win, wide),
    }
}

/// The reading of a `depth32` word as unpack (NaN → 0, ±Inf → ±`f32::MAX`) and then
/// `Depth::read_ref` (reversed-Z: not positive → 0; zero-empty: not positive → +Inf) leave it,
/// as selects.
#[inline(always)]
fn key<const MODE: u8>(b: [u8; 4]) -> f32 {
    let v = f32::from_le_bytes(b);
    let x = match MODE {
        REVERSED => {
            if v > 0.0 {
                v
            } else {
                0.0
            }
        }
        _ => {
            let x = if v.is_nan() { 0.0 } else { v };
            if x > -f32::MAX { x } else { -f32::MAX }
        }
    };
    let x = if x < f32::MAX { x } else { f32::MAX };
    if MODE == ZERO_EMPTY && x <= 0.0 {
        f32::INFINITY
    } else {
        x
    }
}

/// The nearest input of each pixel of a block (pixels `lo..`) into `win`, its depth as read into
/// `zo`. Ties keep the lower input (strict comparison in input order), as `apply`.
#[inline(always)]
fn nearest<const MODE: u8>(zo: &mut [f32], win: &mut [u32], depth: &[Option<&[u8]>], lo: usize) {
    let n = zo.len();
    for (o, z) in zo.iter_mut().zip(part::<u32>(depth[0], lo, n)) {
        *o = key::<MODE>(*z);
    }
    win.fill(0);
    for (i, d) in depth.iter().enumerate().skip(1) {
        let i = i as u32;
        let zs = part::<u32>(*d, lo, n);
        for ((o, w), z) in zo.iter_mut().zip(win.iter_mut()).zip(zs) {
            let z = key::<MODE>(*z);
            let nearer = if MODE == REVERSED { z > *o } else { z < *o };
            *o = if nearer { z } else { *o };
            *w = if nearer { i } else { *w };
        }
    }
}

/// The cleaned word of the winning input for each word of a block (words `at..` of every
/// source, `wins` the winner per word) into `dst`; returns whether any is not zero. Each word is
/// cleaned before the select, so the select is between two computed values: a select between two
/// plain loads becomes a load through a selected pointer, which vectorises only as a gather (see
/// `carry` in `depth/mod.rs`).
#[inline(always)]
fn select<W: Word>(dst: &mut [W::Le], srcs: &[Option<&[u8]>], at: usize, wins: &[W]) -> bool {
    let len = dst.len();
    match srcs {
        [s0] => {
            let mut nonzero = false;
            for (d, a) in dst.iter_mut().zip(part::<W>(*s0, at, len)) {
                let a = W::from_le(*a).clean();
                *d = a.to_le();
                nonzero |= a != W::ZERO;
            }
            nonzero
        }
        [s0, s1, rest @ ..] => {
            let (s0, s1) = (part::<W>(*s0, at, len), part::<W>(*s1, at, len));
            // A flat OR (no early exit), so it vectorises.
            let mut nonzero = false;
            for (((d, a), b), w) in dst.iter_mut().zip(s0).zip(s1).zip(wins) {
                let (a, b) = (W::from_le(*a).clean(), W::from_le(*b).clean());
                let v = if *w == W::input(1) { b } else { a };
                *d = v.to_le();
                nonzero |= v != W::ZERO;
            }
            if rest.is_empty() {
                return nonzero;
            }
            for (i, src) in rest.iter().enumerate() {
                let i = W::input(i as u32 + 2);
                for ((d, s), w) in dst.iter_mut().zip(part::<W>(*src, at, len)).zip(wins) {
                    let s = W::from_le(*s).clean();
                    *d = if *w == i { s.to_le() } else { *d };
                }
            }
            dst.iter()
                .fold(false, |a, d| a | (W::from_le(*d) != W::ZERO))
        }
        [] => false,
    }
}

/// Writes the pad of a padded format of `E` words per pixel (as pack writes it, whatever the
/// input's pad was) over the last word of each pixel; returns whether any value (not pad) is not
/// zero.
#[inline(always)]
fn pad<W: Word, const E: usize>(dst: &mut [W::Le]) -> bool {
    let mut nonzero = false;
    for p in dst.as_chunks_mut::<E>().0 {
        for v in &p[..E - 1] {
            nonzero |= W::from_le(*v) != W::ZERO;
        }
        p[E - 1] = W::ONE.to_le();
    }
    nonzero
}

/// Writes a block of depths as read; returns whether any is not zero (−0 is zero).
#[inline(always)]
fn store_depth(zo: &[f32], bytes: &mut [u8]) -> bool {
    let mut nonzero = false;
    for (o, z) in bytes.as_chunks_mut::<4>().0.iter_mut().zip(zo) {
        *o = z.to_le_bytes();
        nonzero |= *z != 0.0;
    }
    nonzero
}
