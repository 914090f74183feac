//! `accumulate`: the illumination-node compositing operator, paper eq. 3–4 and 6–7:
//! `p_n = p_{n−1} + c_n ⊙ I_n` for diffuse and specular, over an optional upstream partial sum
//! (input 0) and one or more local nodes, each with its own colour `c_n`.
//!
//! Options: a uniform specular colour `m^s` pre-multiplied into every node's specular colour
//! (eq. 4, so a single material stage follows), and the ambient folding of eq. 6–7, which adds
//! `c_n^d ⊙ I^a` at one node whose diffuse colour is the ambient colour; `I^a` is 1 everywhere
//! (`mask = "uniform"`: every material has `m^a = m^d`) or read per pixel and channel from that
//! input's `ambient_mask` layer (`mask = "layer"`, eq. 7: `I^a = m^a ⊘ m^d`, which the folding
//! node renders). Terms are added in input-index order, so a chain of
//! stages and one stage with many inputs give the same bits.

use super::params;
mod decode;
mod fast;
mod packed;

pub use packed::PackedIllumination;

use super::{
    BLOCK, BandMut, BandView, InputSpec, MAX_VALUE, OpError, Operator, Signature, check_band,
    for_spans, sanitize,
};
use lightfold_protocol::Layer;
use serde_json::Value;

pub const NAME: &str = AccumulateParams::NAME;

pub use lightfold_protocol::pipeline::{AccumulateParams, AmbientFold, AmbientMask, NodeColor};

/// The key of the JSON parameters (never of the typed ones) that carries per-frame colour
/// changes as `[[input index, colour], …]` (the shape of `FrameParams::colors`), applied over
/// `colors` and then forgotten.
const INPUT_COLORS: &str = "input_colors";

/// The accumulate operator (see the module documentation).
#[derive(Debug, Clone)]
pub struct Accumulate {
    params: AccumulateParams,
    /// Per local input, the six channel factors: `c^d` then `m^s ⊙ c^s`.
    coeffs: Vec<[f32; 6]>,
}

impl Accumulate {
    /// From JSON parameters: `AccumulateParams` and, optionally, `input_colors`.
    pub fn new(params: &Value) -> Result<Self, OpError> {
        let mut params = params.clone();
        let changes = match params.as_object_mut().and_then(|m| m.remove(INPUT_COLORS)) {
            Some(v) => serde_json::from_value::<Vec<(usize, NodeColor)>>(v)
                .map_err(|e| bad(format!("{INPUT_COLORS}: {e}")))?,
            None => Vec::new(),
        };
        let mut p: AccumulateParams = params::parse(NAME, &params)?;
        let first = usize::from(p.upstream);
        for (input, color) in changes {
            let slot = input
                .checked_sub(first)
                .and_then(|j| p.colors.get_mut(j))
                .ok_or_else(|| {
                    bad(format!(
                        "input_colors names input {input}, not a local node"
                    ))
                })?;
            *slot = color;
        }
        Self::from_params(p)
    }

    /// From typed parameters, validated (`AccumulateParams::validate`).
    pub fn from_params(p: AccumulateParams) -> Result<Self, OpError> {
        p.validate()?;
        let ms = p.specular_color.unwrap_or([1.0; 3]);
        let coeffs = p
            .colors
            .iter()
            .map(|color| {
                let (cd, cs) = color.pair();
                [
                    cd[0],
                    cd[1],
                    cd[2],
                    ms[0] * cs[0],
                    ms[1] * cs[1],
                    ms[2] * cs[2],
                ]
            })
            .collect();
        Ok(Accumulate { params: p, coeffs })
    }

    /// Local input `j`'s input index.
    fn input_of(&self, j: usize) -> usize {
        self.params.input_of(j)
    }

    /// The folding mask of local input `j`, if it folds the ambient term.
    fn fold_of(&self, j: usize) -> Option<AmbientMask> {
        let a = self.params.ambient?;
        (a.input as usize == self.input_of(j)).then_some(a.mask)
    }

    /// The layers of every input and the local-input lookups both versions start from.
    #[allow(clippy::type_complexity)]
    fn views<'a>(
        &self,
        inputs: &[BandView<'a>],
    ) -> (
        Option<&'a [f32]>,
        Vec<(Option<&'a [f32]>, Option<&'a [f32]>)>,
    ) {
        let up = if self.params.upstream {
            inputs[0].layer(Layer::Illumination)
        } else {
            None
        };
        let locals = (0..self.coeffs.len())
            .map(|j| {
                let v = &inputs[self.input_of(j)];
                (v.layer(Layer::Illumination), v.layer(Layer::AmbientMask))
            })
            .collect();
        (up, locals)
    }
}

fn bad(reason: String) -> OpError {
    OpError::BadParam { op: NAME, reason }
}

impl Operator for Accumulate {
    fn name(&self) -> &'static str {
        NAME
    }

    fn signature(&self) -> Signature {
        let optional_ill = InputSpec {
            required: vec![],
            optional: vec![Layer::Illumination],
        };
        let mut inputs = Vec::new();
        if self.params.upstream {
            inputs.push(optional_ill.clone());
        }
        for j in 0..self.coeffs.len() {
            inputs.push(match self.fold_of(j) {
                Some(AmbientMask::Layer) => InputSpec {
                    required: vec![Layer::AmbientMask],
                    optional: vec![Layer::Illumination],
                },
                _ => optional_ill.clone(),
            });
        }
        Signature {
            inputs,
            outputs: vec![Layer::Illumination],
        }
    }

    fn apply_scalar(&self, inputs: &[BandView<'_>], out: &mut BandMut<'_>) -> Result<(), OpError> {
        check_band(NAME, &self.signature(), inputs, out)?;
        let (up, locals) = self.views(inputs);
        let folds: Vec<Option<AmbientMask>> = (0..locals.len()).map(|j| self.fold_of(j)).collect();
        let pixels = out.pixels;
        let dst = out.layer_mut(Layer::Illumination).expect("checked");
        for px in 0..pixels {
            for ch in 0..6 {
                let mut p = match up {
                    Some(u) => sanitize(u[px * 6 + ch]),
                    None => 0.0,
                };
                for (j, &(ill, amb)) in locals.iter().enumerate() {
                    let i = match ill {
                        Some(x) => sanitize(x[px * 6 + ch]),
                        None => 0.0,
                    };
                    // Eq. 6–7: the folded ambient joins the diffuse illumination before c_n^d.
                    let term = match (folds[j], ch < 3) {
                        (Some(AmbientMask::Uniform), true) => i + 1.0,
                        (Some(AmbientMask::Layer), true) => {
                            i + sanitize(amb.expect("checked")[px * 3 + ch])
                        }
                        _ => i,
                    };
                    p += self.coeffs[j][ch] * term;
                }
                dst[px * 6 + ch] = p.min(MAX_VALUE);
            }
        }
        Ok(())
    }

    fn apply(&self, inputs: &[BandView<'_>], out: &mut BandMut<'_>) -> Result<(), OpError> {
        check_band(NAME, &self.signature(), inputs, out)?;
        let (up, locals) = self.views(inputs);
        let terms = fast::terms(self);
        let pixels = out.pixels;
        let dst = out.layer_mut(Layer::Illumination).expect("checked");
        for_spans(pixels, vec![(6, dst)], |first, outs| {
            let span = &mut *outs[0];
            for (b, o) in span.chunks_mut(BLOCK * 6).enumerate() {
                let lo = (first + b * BLOCK) * 6;
                let hi = lo + o.len();
                fast::init(o, up.map(|u| &u[lo..hi]));
                for (t, (x, a)) in terms.iter().zip(&locals) {
                    t.add(o, x.map(|x| &x[lo..hi]), a.map(|a| &a[lo / 2..hi / 2]));
                }
                fast::finish(o);
            }
        });
        Ok(())
    }

    fn set_params(&mut self, params: &Value) -> Result<(), OpError> {
        let current = serde_json::to_value(&self.params).map_err(|e| bad(e.to_string()))?;
        let merged = params::merge(NAME, &current, params)?;
        let next = Accumulate::new(&merged)?;
        if next.signature() != self.signature() {
            return Err(OpError::SignatureChange { op: NAME });
        }
        *self = next;
        Ok(())
    }
}
