//! `depth`: nearest-z select for sort-last compositing. Every input carries a `depth` layer and
//! the same colour layers (illumination, material, …); each output pixel takes all its layers from
//! the input whose surface is nearest, so illumination, material and z travel together.
//!
//! Depth is linear eye distance by default (smaller is nearer; NaN reads as +Inf, no surface), or
//! reversed-Z with `reversed_z` (larger is nearer; NaN, negative and −Inf read as 0, the far
//! plane), or linear with `zero_is_empty`, as render nodes write eye depth (0 where no surface
//! covers the pixel: 0, negative, NaN and +Inf read as +Inf, and an empty winner is emitted as 0,
//! so a sort-last partition's background never wins). Ties, including two empty pixels, go to
//! the lower input index. The winning depth is emitted as read (but for `zero_is_empty`'s empty
//! pixels); carried colour layers follow the shared colour policy.
//!
//! The fast path works per block of pixels: one pass over the depths finds each pixel's nearest
//! input, the winner is repeated per value of a 3- or 6-channel layer, and every carried layer is
//! then a flat select between the inputs' values, so no loop has a per-pixel branch, broadcast or
//! gather. The block loop is a dispatched kernel (`ops::dispatch`, the same bits on every path).
//! `apply_packed` (`packed.rs`) selects straight from the link bytes into the outgoing payloads.

mod packed;

pub use packed::PackedLayer;

use super::dispatch::{self, Isa, Kernel};
use super::params;
use super::{
    BLOCK, BandMut, BandView, InputSpec, OpError, Operator, Signature, check_band, clamp_fast,
    for_spans, sanitize,
};
use lightfold_protocol::Layer;
use serde_json::Value;

pub const NAME: &str = DepthParams::NAME;

pub use lightfold_protocol::pipeline::DepthParams;

fn bad(reason: String) -> OpError {
    OpError::BadParam { op: NAME, reason }
}

/// The depth operator (see the module documentation).
#[derive(Debug, Clone)]
pub struct Depth {
    params: DepthParams,
}

impl Depth {
    /// From JSON parameters (`DepthParams`).
    pub fn new(params: &Value) -> Result<Self, OpError> {
        Self::from_params(params::parse(NAME, params)?)
    }

    /// From typed parameters, validated (`DepthParams::validate`).
    pub fn from_params(p: DepthParams) -> Result<Self, OpError> {
        p.validate()?;
        Ok(Depth { params: p })
    }

    /// The depth reading as the kernels' mode: [`LINEAR`], [`REVERSED`] or [`ZERO_EMPTY`].
    fn mode(&self) -> u8 {
        match (self.params.reversed_z, self.params.zero_is_empty) {
            (true, _) => REVERSED,
            (false, true) => ZERO_EMPTY,
            (false, false) => LINEAR,
        }
    }

    /// The reference reading of a depth value (see the module documentation).
    fn read_ref(&self, z: f32) -> f32 {
        if self.params.reversed_z {
            if z.is_nan() || z <= 0.0 { 0.0 } else { z }
        } else if z.is_nan() || (self.params.zero_is_empty && !(z > 0.0 && z < f32::INFINITY)) {
            f32::INFINITY
        } else {
            z
        }
    }

    /// The depth emitted for a winner read as `z`: as read, but an empty `zero_is_empty` pixel
    /// is 0 again.
    fn emit_ref(&self, z: f32) -> f32 {
        if self.params.zero_is_empty && z == f32::INFINITY {
            0.0
        } else {
            z
        }
    }
}

impl Operator for Depth {
    fn name(&self) -> &'static str {
        NAME
    }

    fn signature(&self) -> Signature {
        let mut layers = vec![Layer::Depth];
        layers.extend(&self.params.layers);
        let spec = InputSpec {
            required: layers.clone(),
            optional: vec![],
        };
        Signature {
            inputs: vec![spec; self.params.inputs as usize],
            outputs: layers,
        }
    }

    fn apply_scalar(&self, inputs: &[BandView<'_>], out: &mut BandMut<'_>) -> Result<(), OpError> {
        check_band(NAME, &self.signature(), inputs, out)?;
        let pixels = out.pixels;
        let mut winners = vec![0usize; pixels];
        {
            let zout = out.layer_mut(Layer::Depth).expect("checked");
            for px in 0..pixels {
                let mut best: Option<(usize, f32)> = None;
                for (i, view) in inputs.iter().enumerate() {
                    let z = self.read_ref(view.layer(Layer::Depth).expect("checked")[px]);
                    let nearer = match best {
                        None => true,
                        Some((_, b)) if self.params.reversed_z => z > b,
                        Some((_, b)) => z < b,
                    };
                    if nearer {
                        best = Some((i, z));
                    }
                }
                let (w, z) = best.expect("at least one input");
                winners[px] = w;
                zout[px] = self.emit_ref(z);
            }
        }
        for &layer in &self.params.layers {
            let ch = layer.channels();
            let dst = out.layer_mut(layer).expect("checked");
            for px in 0..pixels {
                let src = inputs[winners[px]].layer(layer).expect("checked");
                for c in 0..ch {
                    dst[px * ch + c] = sanitize(src[px * ch + c]);
                }
            }
        }
        Ok(())
    }

    fn apply(&self, inputs: &[BandView<'_>], out: &mut BandMut<'_>) -> Result<(), OpError> {
        self.apply_on(Isa::best(), inputs, out)
    }

    fn set_params(&mut self, params: &Value) -> Result<(), OpError> {
        let current = serde_json::to_value(&self.params).map_err(|e| bad(e.to_string()))?;
        let next = Depth::new(&params::merge(NAME, &current, params)?)?;
        if next.signature() != self.signature() {
            return Err(OpError::SignatureChange { op: NAME });
        }
        *self = next;
        Ok(())
    }
}

impl Depth {
    /// `apply` on the instruction set `isa` (the same bits on every one), which this CPU must have
    /// (`Isa::available`); for tests and benchmarks of each path.
    pub fn apply_on(
        &self,
        isa: Isa,
        inputs: &[BandView<'_>],
        out: &mut BandMut<'_>,
    ) -> Result<(), OpError> {
        if !isa.available() {
            return Err(OpError::IsaUnavailable { isa });
        }
        check_band(NAME, &self.signature(), inputs, out)?;
        let zs: Vec<&[f32]> = inputs
            .iter()
            .map(|v| v.layer(Layer::Depth).expect("checked"))
            .collect();
        let carried: Vec<(usize, Vec<&[f32]>)> = self
            .params
            .layers
            .iter()
            .map(|&l| {
                let srcs = inputs
                    .iter()
                    .map(|v| v.layer(l).expect("checked"))
                    .collect();
                (l.channels(), srcs)
            })
            .collect();
        let mode = self.mode();
        let pixels = out.pixels;
        let mut slots: Vec<Option<(Layer, &mut [f32])>> = out
            .layers
            .iter_mut()
            .map(|(l, d)| Some((*l, &mut **d)))
            .collect();
        // Depth first, then the carried layers in parameter order.
        let mut outs: Vec<(usize, &mut [f32])> = Vec::new();
        for want in std::iter::once(Layer::Depth).chain(self.params.layers.iter().copied()) {
            let pos = slots
                .iter()
                .position(|s| matches!(s, Some((l, _)) if *l == want))
                .expect("checked");
            let (_, data) = slots[pos].take().expect("checked");
            outs.push((want.channels(), data));
        }
        for_spans(pixels, outs, |first, outs| {
            let span = Span {
                zs: &zs,
                carried: &carried,
                first,
                outs,
            };
            match mode {
                REVERSED => dispatch::run(isa, Select::<REVERSED>(span)),
                ZERO_EMPTY => dispatch::run(isa, Select::<ZERO_EMPTY>(span)),
                _ => dispatch::run(isa, Select::<LINEAR>(span)),
            }
        });
        Ok(())
    }
}

/// One span of the output: depth first, then the carried layers (`carried` order), from pixel
/// `first` of the band.
struct Span<'s, 'a, 'o> {
    zs: &'s [&'a [f32]],
    carried: &'s [(usize, Vec<&'a [f32]>)],
    first: usize,
    outs: &'s mut [&'o mut [f32]],
}

/// Depth readings, as the kernels' `MODE`: linear, reversed-Z, linear with 0 empty.
pub(super) const LINEAR: u8 = 0;
pub(super) const REVERSED: u8 = 1;
pub(super) const ZERO_EMPTY: u8 = 2;

/// The block loop of `apply`, with the depth reading fixed (`MODE`) so no loop tests it.
struct Select<'s, 'a, 'o, const MODE: u8>(Span<'s, 'a, 'o>);

/// The fast reading of a depth value: `Depth::read_ref` as selects (NaN fails every comparison).
#[inline(always)]
fn read<const MODE: u8>(z: f32) -> f32 {
    match MODE {
        REVERSED => {
            if z > 0.0 {
                z
            } else {
                0.0
            }
        }
        ZERO_EMPTY => {
            if z > 0.0 && z < f32::INFINITY {
                z
            } else {
                f32::INFINITY
            }
        }
        _ => {
            if !z.is_nan() {
                z
            } else {
                f32::INFINITY
            }
        }
    }
}

/// `Depth::emit_ref` over a block of read depths.
#[inline(always)]
pub(super) fn emit<const MODE: u8>(zo: &mut [f32]) {
    if MODE == ZERO_EMPTY {
        for z in zo {
            *z = if *z == f32::INFINITY { 0.0 } else { *z };
        }
    }
}

impl<const MODE: u8> Kernel for Select<'_, '_, '_, MODE> {
    type Output = ();

    #[inline(always)]
    fn run(self, _isa: Isa) {
        let Span {
            zs,
            carried,
            first,
            outs,
        } = self.0;
        let (zout, couts) = outs.split_first_mut().expect("depth output");
        let (need3, need6) = (
            carried.iter().any(|(ch, _)| *ch == 3),
            carried.iter().any(|(ch, _)| *ch == 6),
        );
        // The winning input per pixel, and the same repeated per value of 3- and 6-channel
        // layers, so the carry is one flat select per value with no per-pixel broadcast in it.
        let mut win = [0u32; BLOCK];
        let mut win3 = [0u32; BLOCK * 3];
        let mut win6 = [0u32; BLOCK * 6];
        for (b, zo) in zout.chunks_mut(BLOCK).enumerate() {
            let lo = first + b * BLOCK;
            let n = zo.len();
            let win = &mut win[..n];
            nearest::<MODE>(zo, win, zs, lo);
            emit::<MODE>(zo);
            if need3 {
                widen::<3>(win, &mut win3[..n * 3]);
            }
            if need6 {
                widen::<6>(win, &mut win6[..n * 6]);
            }
            for ((ch, srcs), dst) in carried.iter().zip(couts.iter_mut()) {
                let (ch, dst) = (*ch, &mut dst[b * BLOCK * ch..(b * BLOCK + n) * ch]);
                let wins: &[u32] = match ch {
                    6 => &win6[..n * 6],
                    3 => &win3[..n * 3],
                    _ => win,
                };
                carry(dst, srcs, wins, lo * ch);
            }
        }
    }
}

/// The nearest input of each pixel of a block (pixels `lo..`) into `win`, its depth as read into
/// `zo`. Ties keep the lower input (strict comparison in input order).
#[inline(always)]
fn nearest<const MODE: u8>(zo: &mut [f32], win: &mut [u32], zs: &[&[f32]], lo: usize) {
    let n = zo.len();
    for (o, z) in zo.iter_mut().zip(&zs[0][lo..lo + n]) {
        *o = read::<MODE>(*z);
    }
    win.fill(0);
    for (i, z) in zs.iter().enumerate().skip(1) {
        let i = i as u32;
        for ((o, w), z) in zo.iter_mut().zip(win.iter_mut()).zip(&z[lo..lo + n]) {
            let z = read::<MODE>(*z);
            let nearer = if MODE == REVERSED { z > *o } else { z < *o };
            *o = if nearer { z } else { *o };
            *w = if nearer { i } else { *w };
        }
    }
}

/// Repeats each pixel's winner for its `CH` values.
#[inline(always)]
fn widen<const CH: usize>(win: &[u32], wide: &mut [u32]) {
    for (w, o) in win.iter().zip(wide.as_chunks_mut::<CH>().0) {
        *o = [*w; CH];
    }
}

/// Copies the winning input's value of each value of a block (values `lo..` of every source,
/// `wins` the winner per value): input 0, then each later input where it won. Every loop is a
/// flat vector select. The colour policy is applied to each value before the select: a select
/// between two plain loads is turned by LLVM into a load through a selected pointer, which the
/// vectoriser can only emit as a gather (4× slower than the whole operator should take).
#[inline(always)]
fn carry(dst: &mut [f32], srcs: &[&[f32]], wins: &[u32], lo: usize) {
    let range = lo..lo + dst.len();
    match srcs {
        [s0] => {
            for (d, s) in dst.iter_mut().zip(&s0[range]) {
                *d = clamp_fast(*s);
            }
        }
        [s0, s1, rest @ ..] => {
            let (s0, s1) = (&s0[range.clone()], &s1[range.clone()]);
            for (((d, a), b), w) in dst.iter_mut().zip(s0).zip(s1).zip(wins) {
                let (a, b) = (clamp_fast(*a), clamp_fast(*b));
                *d = if *w == 1 { b } else { a };
            }
            for (i, src) in rest.iter().enumerate() {
                let i = i as u32 + 2;
                for ((d, s), w) in dst.iter_mut().zip(&src[range.clone()]).zip(wins) {
                    let s = clamp_fast(*s);
                    *d = if *w == i { s } else { *d };
                }
            }
        }
        [] => {}
    }
}
