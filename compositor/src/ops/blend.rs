//! `blend`: premultiplied "over" with a per-channel transmittance, back to front (the paper's
//! alpha blending; `docs/translucency.md` § Peeled layers). Input 0 is the back (`radiance`);
//! each later input is a layer in front of everything before it, its `radiance` premultiplied by
//! its coverage and its `transmittance` `T` (what of the light behind passes through it):
//! `out = R_0`, then `out = R_i + T_i ⊙ out` for i = 1, 2, … in order, the last input the
//! nearest. A scalar alpha's "over" is `T = 1 − α` in every channel.
//!
//! Values: radiance follows the value policy (NaN and non-positive read as 0, +Inf as
//! `MAX_VALUE`, sums saturate); a transmittance is clamped to [0, 1] (NaN reads as 0: a broken
//! value hides what is behind rather than brightening it). An absent layer reads as zeros for
//! radiance and as 1 for transmittance (an empty band: nothing in front there).

use super::params;
use super::{
    BLOCK, BandMut, BandView, InputSpec, OpError, Operator, Signature, check_band, clamp_fast,
    for_spans, sanitize, saturate,
};
use lightfold_protocol::Layer;
use serde_json::Value;

pub const NAME: &str = BlendParams::NAME;

pub use lightfold_protocol::pipeline::BlendParams;

/// The blend operator (see the module documentation).
#[derive(Debug, Clone)]
pub struct Blend {
    params: BlendParams,
}

impl Blend {
    /// From JSON parameters (`BlendParams`).
    pub fn new(params: &Value) -> Result<Self, OpError> {
        Self::from_params(params::parse(NAME, params)?)
    }

    /// From typed parameters, validated (`BlendParams::validate`).
    pub fn from_params(p: BlendParams) -> Result<Self, OpError> {
        p.validate()?;
        Ok(Blend { params: p })
    }
}

fn bad(reason: String) -> OpError {
    OpError::BadParam { op: NAME, reason }
}

/// The reference reading of a transmittance: clamped to [0, 1], NaN as 0.
#[inline]
pub fn transmittance(t: f32) -> f32 {
    if t.is_nan() || t <= 0.0 {
        0.0
    } else if t >= 1.0 {
        1.0
    } else {
        t
    }
}

/// `transmittance` as selects (NaN fails `t > 0`).
#[inline(always)]
fn transmittance_fast(t: f32) -> f32 {
    let t = if t > 0.0 { t } else { 0.0 };
    if t < 1.0 { t } else { 1.0 }
}

impl Operator for Blend {
    fn name(&self) -> &'static str {
        NAME
    }

    fn signature(&self) -> Signature {
        let back = InputSpec {
            required: vec![],
            optional: vec![Layer::Radiance],
        };
        let front = InputSpec {
            required: vec![],
            optional: vec![Layer::Radiance, Layer::Transmittance],
        };
        let mut inputs = vec![back];
        inputs.extend(std::iter::repeat_n(front, self.params.inputs as usize - 1));
        Signature {
            inputs,
            outputs: vec![Layer::Radiance],
        }
    }

    fn apply_scalar(&self, inputs: &[BandView<'_>], out: &mut BandMut<'_>) -> Result<(), OpError> {
        check_band(NAME, &self.signature(), inputs, out)?;
        let dst = out.layer_mut(Layer::Radiance).expect("checked");
        for (k, d) in dst.iter_mut().enumerate() {
            let mut p = inputs[0]
                .layer(Layer::Radiance)
                .map_or(0.0, |r| sanitize(r[k]));
            for v in &inputs[1..] {
                let t = v
                    .layer(Layer::Transmittance)
                    .map_or(1.0, |t| transmittance(t[k]));
                let r = v.layer(Layer::Radiance).map_or(0.0, |r| sanitize(r[k]));
                p = (r + t * p).min(super::MAX_VALUE);
            }
            *d = p;
        }
        Ok(())
    }

    fn apply(&self, inputs: &[BandView<'_>], out: &mut BandMut<'_>) -> Result<(), OpError> {
        check_band(NAME, &self.signature(), inputs, out)?;
        let back = inputs[0].layer(Layer::Radiance);
        // Per front input, its radiance and transmittance (each absent in an empty band).
        type Front<'a> = (Option<&'a [f32]>, Option<&'a [f32]>);
        let fronts: Vec<Front<'_>> = inputs[1..]
            .iter()
            .map(|v| (v.layer(Layer::Radiance), v.layer(Layer::Transmittance)))
            .collect();
        let pixels = out.pixels;
        let dst = out.layer_mut(Layer::Radiance).expect("checked");
        for_spans(pixels, vec![(3, dst)], |first, outs| {
            let span = &mut *outs[0];
            for (b, o) in span.chunks_mut(BLOCK * 3).enumerate() {
                let lo = (first + b * BLOCK) * 3;
                let hi = lo + o.len();
                match back {
                    Some(r) => {
                        for (o, x) in o.iter_mut().zip(&r[lo..hi]) {
                            *o = clamp_fast(*x);
                        }
                    }
                    None => o.fill(0.0),
                }
                for (r, t) in &fronts {
                    if let Some(t) = t {
                        for (o, t) in o.iter_mut().zip(&t[lo..hi]) {
                            *o *= transmittance_fast(*t);
                        }
                    }
                    if let Some(r) = r {
                        for (o, x) in o.iter_mut().zip(&r[lo..hi]) {
                            // The reference's `r + t·p` (addition commutes bit for bit).
                            *o += clamp_fast(*x);
                        }
                    }
                    for o in o.iter_mut() {
                        *o = saturate(*o);
                    }
                }
            }
        });
        Ok(())
    }

    fn set_params(&mut self, params: &Value) -> Result<(), OpError> {
        let current = serde_json::to_value(&self.params).map_err(|e| bad(e.to_string()))?;
        let next = Blend::new(&params::merge(NAME, &current, params)?)?;
        if next.signature() != self.signature() {
            return Err(OpError::SignatureChange { op: NAME });
        }
        *self = next;
        Ok(())
    }
}
