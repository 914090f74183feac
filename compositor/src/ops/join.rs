//! `join`: N inputs of one layer summed into one, in input-index order. Float addition is not
//! associative, so the order is part of the contract: the same topology gives the same bits run to
//! run; a chain and a tree of the same inputs differ only by rounding (tests/chain_tree.rs).

use super::params;
use super::{
    BLOCK, BandMut, BandView, InputSpec, OpError, Operator, Signature, check_band, clamp_fast,
    for_spans, sanitize, saturate,
};
use serde_json::Value;

pub const NAME: &str = JoinParams::NAME;

pub use lightfold_protocol::pipeline::JoinParams;

/// The join operator (see the module documentation).
#[derive(Debug, Clone)]
pub struct Join {
    params: JoinParams,
}

impl Join {
    /// From JSON parameters (`JoinParams`).
    pub fn new(params: &Value) -> Result<Self, OpError> {
        Self::from_params(params::parse(NAME, params)?)
    }

    /// From typed parameters, validated (`JoinParams::validate`).
    pub fn from_params(p: JoinParams) -> Result<Self, OpError> {
        p.validate()?;
        Ok(Join { params: p })
    }

    fn layers<'a>(&self, inputs: &[BandView<'a>]) -> Vec<Option<&'a [f32]>> {
        inputs.iter().map(|v| v.layer(self.params.layer)).collect()
    }
}

fn bad(reason: String) -> OpError {
    OpError::BadParam { op: NAME, reason }
}

impl Operator for Join {
    fn name(&self) -> &'static str {
        NAME
    }

    fn signature(&self) -> Signature {
        let spec = InputSpec {
            required: vec![],
            optional: vec![self.params.layer],
        };
        Signature {
            inputs: vec![spec; self.params.inputs as usize],
            outputs: vec![self.params.layer],
        }
    }

    fn apply_scalar(&self, inputs: &[BandView<'_>], out: &mut BandMut<'_>) -> Result<(), OpError> {
        check_band(NAME, &self.signature(), inputs, out)?;
        let srcs = self.layers(inputs);
        let dst = out.layer_mut(self.params.layer).expect("checked");
        for (k, d) in dst.iter_mut().enumerate() {
            let mut p = 0.0f32;
            for x in srcs.iter().flatten() {
                p += sanitize(x[k]);
            }
            *d = p.min(super::MAX_VALUE);
        }
        Ok(())
    }

    fn apply(&self, inputs: &[BandView<'_>], out: &mut BandMut<'_>) -> Result<(), OpError> {
        check_band(NAME, &self.signature(), inputs, out)?;
        let srcs: Vec<&[f32]> = self.layers(inputs).into_iter().flatten().collect();
        let ch = self.params.layer.channels();
        let pixels = out.pixels;
        let dst = out.layer_mut(self.params.layer).expect("checked");
        for_spans(pixels, vec![(ch, dst)], |first, outs| {
            let span = &mut *outs[0];
            for (b, o) in span.chunks_mut(BLOCK * ch).enumerate() {
                let lo = (first + b * BLOCK) * ch;
                let hi = lo + o.len();
                let Some((head, rest)) = srcs.split_first() else {
                    o.fill(0.0);
                    continue;
                };
                // 0 + x is x for the sanitised (non-negative) values, so starting from the first
                // present input gives the reference's bits.
                for (o, x) in o.iter_mut().zip(&head[lo..hi]) {
                    *o = clamp_fast(*x);
                }
                for x in rest {
                    for (o, x) in o.iter_mut().zip(&x[lo..hi]) {
                        *o += clamp_fast(*x);
                    }
                }
                for o in o.iter_mut() {
                    *o = saturate(*o);
                }
            }
        });
        Ok(())
    }

    fn set_params(&mut self, params: &Value) -> Result<(), OpError> {
        let current = serde_json::to_value(&self.params).map_err(|e| bad(e.to_string()))?;
        let next = Join::new(&params::merge(NAME, &current, params)?)?;
        if next.signature() != self.signature() {
            return Err(OpError::SignatureChange { op: NAME });
        }
        *self = next;
        Ok(())
    }
}
