//! `merge`: layers of several inputs put together into one stream, unchanged. Input i gives the
//! layers `inputs[i]` names; the output carries all of them, in that order, and no layer may come
//! from two inputs. A sort-last partition's stage uses it to put the illumination its
//! `accumulate` summed beside the depth and material layers of the part's first node, so the
//! `depth` operator downstream can select all of them together (`docs/planner.md`
//! § Partitions).
//!
//! Colour layers follow the shared value policy; depth is copied bit for bit (its reading is the
//! `depth` operator's business).

use super::params;
use super::{
    BandMut, BandView, InputSpec, OpError, Operator, Signature, check_band, clamp_fast, sanitize,
};
use lightfold_protocol::Layer;
use serde_json::Value;

pub const NAME: &str = MergeParams::NAME;

pub use lightfold_protocol::pipeline::MergeParams;

fn bad(reason: String) -> OpError {
    OpError::BadParam { op: NAME, reason }
}

/// The merge operator (see the module documentation).
#[derive(Debug, Clone)]
pub struct Merge {
    params: MergeParams,
}

impl Merge {
    /// From JSON parameters (`MergeParams`: per input, the names of the layers it gives).
    pub fn new(params: &Value) -> Result<Self, OpError> {
        Self::from_params(params::parse(NAME, params)?)
    }

    /// From typed parameters, validated (`MergeParams::validate`).
    pub fn from_params(p: MergeParams) -> Result<Self, OpError> {
        p.validate()?;
        Ok(Merge { params: p })
    }

    fn run(
        &self,
        inputs: &[BandView<'_>],
        out: &mut BandMut<'_>,
        copy: impl Fn(&[f32], &mut [f32]),
    ) -> Result<(), OpError> {
        check_band(NAME, &self.signature(), inputs, out)?;
        for (view, layers) in inputs.iter().zip(&self.params.inputs) {
            for &l in layers {
                let src = view.layer(l).expect("checked");
                let dst = out.layer_mut(l).expect("checked");
                if l == Layer::Depth {
                    dst.copy_from_slice(src);
                } else {
                    copy(src, dst);
                }
            }
        }
        Ok(())
    }
}

impl Operator for Merge {
    fn name(&self) -> &'static str {
        NAME
    }

    fn signature(&self) -> Signature {
        Signature {
            inputs: self
                .params
                .inputs
                .iter()
                .map(|ls| InputSpec {
                    required: ls.clone(),
                    optional: vec![],
                })
                .collect(),
            outputs: self.params.inputs.concat(),
        }
    }

    fn apply_scalar(&self, inputs: &[BandView<'_>], out: &mut BandMut<'_>) -> Result<(), OpError> {
        self.run(inputs, out, |src, dst| {
            for (d, &s) in dst.iter_mut().zip(src) {
                *d = sanitize(s);
            }
        })
    }

    fn apply(&self, inputs: &[BandView<'_>], out: &mut BandMut<'_>) -> Result<(), OpError> {
        self.run(inputs, out, |src, dst| {
            for (d, &s) in dst.iter_mut().zip(src) {
                *d = clamp_fast(s);
            }
        })
    }

    fn set_params(&mut self, params: &Value) -> Result<(), OpError> {
        let current = serde_json::to_value(&self.params).map_err(|e| bad(e.to_string()))?;
        let next = Merge::new(&params::merge(NAME, &current, params)?)?;
        if next.signature() != self.signature() {
            return Err(OpError::SignatureChange { op: NAME });
        }
        *self = next;
        Ok(())
    }
}
