//! `depth`: nearest-z select for sort-last compositing. Every input carries a `depth` layer and
//! the same colour layers (illumination, material, …); each output pixel takes all its layers from
//! the input whose surface is nearest, so illumination, material and z travel together.
//!
//! Depth is linear eye distance by default (smaller is nearer; NaN reads as +Inf, no surface), or
//! reversed-Z with `reversed_z` (larger is nearer; NaN, negative and −Inf read as 0, the far
//! plane). Ties, including two empty pixels, go to the lower input index. The winning depth is
//! emitted as read; carried colour layers follow the shared colour policy.

use super::params::{self, de_layers, ser_layers};
use super::{
    BLOCK, BandMut, BandView, InputSpec, OpError, Operator, Signature, check_band, clamp_fast,
    for_spans, sanitize,
};
use lightfold_protocol::Layer;
use serde::{Deserialize, Serialize};
use serde_json::Value;

pub const NAME: &str = "depth";

fn illumination() -> Vec<Layer> {
    vec![Layer::Illumination]
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Params {
    inputs: usize,
    /// Colour layers carried with the depth.
    #[serde(
        default = "illumination",
        deserialize_with = "de_layers",
        serialize_with = "ser_layers"
    )]
    layers: Vec<Layer>,
    #[serde(default)]
    reversed_z: bool,
}

/// The depth operator (see the module documentation).
#[derive(Debug, Clone)]
pub struct Depth {
    params: Params,
}

fn bad(reason: String) -> OpError {
    OpError::BadParam { op: NAME, reason }
}

impl Depth {
    pub fn new(params: &Value) -> Result<Self, OpError> {
        let p: Params = params::parse(NAME, params)?;
        if p.inputs == 0 {
            return Err(bad("inputs must be at least 1".into()));
        }
        for (i, l) in p.layers.iter().enumerate() {
            if *l == Layer::Depth || p.layers[..i].contains(l) {
                return Err(bad(format!("layers lists {l:?} twice or carries depth")));
            }
        }
        Ok(Depth { params: p })
    }

    /// The reference reading of a depth value (see the module documentation).
    fn read_ref(&self, z: f32) -> f32 {
        if self.params.reversed_z {
            if z.is_nan() || z <= 0.0 { 0.0 } else { z }
        } else if z.is_nan() {
            f32::INFINITY
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
            inputs: vec![spec; self.params.inputs],
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
                zout[px] = z;
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
        let reversed = self.params.reversed_z;
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
            let (zout, couts) = outs.split_first_mut().expect("depth output");
            let mut win = [0u32; BLOCK];
            for (b, zo) in zout.chunks_mut(BLOCK).enumerate() {
                let lo = first + b * BLOCK;
                let n = zo.len();
                let read = |z: f32| {
                    if reversed {
                        if z > 0.0 { z } else { 0.0 }
                    } else if !z.is_nan() {
                        z
                    } else {
                        f32::INFINITY
                    }
                };
                for (o, z) in zo.iter_mut().zip(&zs[0][lo..lo + n]) {
                    *o = read(*z);
                }
                win[..n].fill(0);
                for (i, z) in zs.iter().enumerate().skip(1) {
                    for ((o, w), z) in zo.iter_mut().zip(&mut win[..n]).zip(&z[lo..lo + n]) {
                        let z = read(*z);
                        let nearer = if reversed { z > *o } else { z < *o };
                        *o = if nearer { z } else { *o };
                        *w = if nearer { i as u32 } else { *w };
                    }
                }
                for ((ch, srcs), dst) in carried.iter().zip(couts.iter_mut()) {
                    let dst = &mut dst[b * BLOCK * ch..(b * BLOCK + n) * ch];
                    let win = &win[..n];
                    match ch {
                        6 => carry::<6>(dst, srcs, win, lo),
                        3 => carry::<3>(dst, srcs, win, lo),
                        _ => carry::<1>(dst, srcs, win, lo),
                    }
                }
            }
        });
        Ok(())
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

/// Copies the winning input's `CH` channels of each pixel of a block (pixels `lo..`): starts
/// from input 0 and selects each later input where it won, so every loop is a plain vector
/// select rather than a per-pixel gather.
fn carry<const CH: usize>(dst: &mut [f32], srcs: &[&[f32]], win: &[u32], lo: usize) {
    let range = lo * CH..(lo + win.len()) * CH;
    for (d, s) in dst.iter_mut().zip(&srcs[0][range.clone()]) {
        *d = clamp_fast(*s);
    }
    for (i, src) in srcs.iter().enumerate().skip(1) {
        let i = i as u32;
        let (d, s) = (
            dst.as_chunks_mut::<CH>().0,
            src[range.clone()].as_chunks::<CH>().0,
        );
        for ((d, s), w) in d.iter_mut().zip(s).zip(win) {
            let take = *w == i;
            for c in 0..CH {
                d[c] = if take { clamp_fast(s[c]) } else { d[c] };
            }
        }
    }
}
