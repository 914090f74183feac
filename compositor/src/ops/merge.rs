//! `merge`: layers of several inputs put together into one stream, unchanged. Input i gives the
//! layers `inputs[i]` names; the output carries all of them, in that order, and no layer may come
//! from two inputs. A sort-last partition's stage uses it to put the illumination its
//! `accumulate` summed beside the depth and material layers of the part's first node, so the
//! `depth` operator downstream can select all of them together (`docs/planner.md`
//! § Partitions).
//!
//! Colour layers follow the shared value policy; depth is copied bit for bit (its reading is the
//! `depth` operator's business).

use super::params::{self, layer_from_name, layer_name};
use super::{
    BandMut, BandView, InputSpec, OpError, Operator, Signature, check_band, clamp_fast, sanitize,
};
use lightfold_protocol::Layer;
use serde::{Deserialize, Serialize};
use serde_json::Value;

pub const NAME: &str = "merge";

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Params {
    /// Per input, the names of the layers it gives.
    inputs: Vec<Vec<String>>,
}

/// The merge operator (see the module documentation).
#[derive(Debug, Clone)]
pub struct Merge {
    params: Params,
    layers: Vec<Vec<Layer>>,
}

fn bad(reason: String) -> OpError {
    OpError::BadParam { op: NAME, reason }
}

impl Merge {
    pub fn new(params: &Value) -> Result<Self, OpError> {
        let p: Params = params::parse(NAME, params)?;
        if p.inputs.is_empty() {
            return Err(bad("inputs must name at least one input".into()));
        }
        let mut layers = Vec::with_capacity(p.inputs.len());
        let mut seen: Vec<Layer> = Vec::new();
        for (i, names) in p.inputs.iter().enumerate() {
            if names.is_empty() {
                return Err(bad(format!("input {i} gives no layer")));
            }
            let mut own = Vec::with_capacity(names.len());
            for name in names {
                let l =
                    layer_from_name(name).ok_or_else(|| bad(format!("unknown layer {name:?}")))?;
                if seen.contains(&l) {
                    return Err(bad(format!("layer {name} comes from two inputs")));
                }
                seen.push(l);
                own.push(l);
            }
            layers.push(own);
        }
        Ok(Merge { params: p, layers })
    }

    /// The parameters that merge `layers[i]` from input i.
    pub fn params(layers: &[Vec<Layer>]) -> Value {
        let names: Vec<Vec<&str>> = layers
            .iter()
            .map(|ls| ls.iter().map(|&l| layer_name(l)).collect())
            .collect();
        serde_json::json!({ "inputs": names })
    }

    fn run(
        &self,
        inputs: &[BandView<'_>],
        out: &mut BandMut<'_>,
        copy: impl Fn(&[f32], &mut [f32]),
    ) -> Result<(), OpError> {
        check_band(NAME, &self.signature(), inputs, out)?;
        for (view, layers) in inputs.iter().zip(&self.layers) {
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
                .layers
                .iter()
                .map(|ls| InputSpec {
                    required: ls.clone(),
                    optional: vec![],
                })
                .collect(),
            outputs: self.layers.concat(),
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
