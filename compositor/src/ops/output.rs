//! `output`: the sink compositor's last step. `apply` emits linear HDR radiance for EXR (the
//! colour policy applied, nothing else); `encode_srgb8` tone-maps a radiance band to 8-bit sRGB
//! for PNG as `sRGB(clamp(exposure·L))` (ARCHITECTURE §2).
//!
//! The sRGB transfer and its table encoder are `lightfold_protocol::srgb` (one copy for every
//! crate); the table encoder gives the reference's bytes, not an approximation of them.
//! Unlike a bare transfer, +Inf reads as the largest value and encodes as white.

use super::params;
use super::{
    BandMut, BandView, InputSpec, OpError, Operator, PAR_SPAN, Signature, check_band, clamp_fast,
    for_spans, sanitize,
};
use lightfold_protocol::Layer;
use rayon::prelude::*;
use serde_json::Value;

pub const NAME: &str = OutputParams::NAME;

pub use lightfold_protocol::pipeline::OutputParams;

/// The output operator (see the module documentation).
#[derive(Debug, Clone)]
pub struct Output {
    params: OutputParams,
}

fn bad(reason: String) -> OpError {
    OpError::BadParam { op: NAME, reason }
}

pub use lightfold_protocol::srgb::{linear_to_srgb, srgb8};

impl Output {
    /// From JSON parameters (`OutputParams`).
    pub fn new(params: &Value) -> Result<Self, OpError> {
        Self::from_params(params::parse(NAME, params)?)
    }

    /// From typed parameters, validated (`OutputParams::validate`).
    pub fn from_params(p: OutputParams) -> Result<Self, OpError> {
        p.validate()?;
        Ok(Output { params: p })
    }

    pub fn exposure(&self) -> f32 {
        self.params.exposure
    }

    fn check_rgb8(radiance: &[f32], rgb8: &[u8]) -> Result<(), OpError> {
        if !radiance.len().is_multiple_of(3) || rgb8.len() != radiance.len() {
            return Err(OpError::BufferLength {
                op: NAME,
                what: "the sRGB8 buffer (3 bytes a pixel, as radiance has 3 values)",
                expected: radiance.len() - radiance.len() % 3,
                got: rgb8.len(),
            });
        }
        Ok(())
    }

    /// The reference tone map: `rgb8[k] = srgb8(exposure · L[k])`, three bytes a pixel.
    pub fn encode_srgb8_scalar(&self, radiance: &[f32], rgb8: &mut [u8]) -> Result<(), OpError> {
        Self::check_rgb8(radiance, rgb8)?;
        for (b, l) in rgb8.iter_mut().zip(radiance) {
            *b = srgb8(self.params.exposure * sanitize(*l));
        }
        Ok(())
    }

    /// The fast tone map; the same bytes as `encode_srgb8_scalar`.
    pub fn encode_srgb8(&self, radiance: &[f32], rgb8: &mut [u8]) -> Result<(), OpError> {
        Self::check_rgb8(radiance, rgb8)?;
        let e = self.params.exposure;
        let run = |bytes: &mut [u8], lin: &[f32]| {
            for (b, l) in bytes.iter_mut().zip(lin) {
                *b = lightfold_protocol::srgb::encode8(e * clamp_fast(*l));
            }
        };
        if rgb8.len() >= 2 * PAR_SPAN * 3 && rayon::current_num_threads() > 1 {
            rgb8.par_chunks_mut(PAR_SPAN * 3)
                .zip(radiance.par_chunks(PAR_SPAN * 3))
                .for_each(|(b, l)| run(b, l));
        } else {
            run(rgb8, radiance);
        }
        Ok(())
    }
}

impl Operator for Output {
    fn name(&self) -> &'static str {
        NAME
    }

    fn signature(&self) -> Signature {
        Signature {
            inputs: vec![InputSpec {
                required: vec![Layer::Radiance],
                optional: vec![],
            }],
            outputs: vec![Layer::Radiance],
        }
    }

    fn apply_scalar(&self, inputs: &[BandView<'_>], out: &mut BandMut<'_>) -> Result<(), OpError> {
        check_band(NAME, &self.signature(), inputs, out)?;
        let src = inputs[0].layer(Layer::Radiance).expect("checked");
        let dst = out.layer_mut(Layer::Radiance).expect("checked");
        for (d, s) in dst.iter_mut().zip(src) {
            *d = sanitize(*s);
        }
        Ok(())
    }

    fn apply(&self, inputs: &[BandView<'_>], out: &mut BandMut<'_>) -> Result<(), OpError> {
        check_band(NAME, &self.signature(), inputs, out)?;
        let src = inputs[0].layer(Layer::Radiance).expect("checked");
        let pixels = out.pixels;
        let dst = out.layer_mut(Layer::Radiance).expect("checked");
        for_spans(pixels, vec![(3, dst)], |first, outs| {
            let o = &mut *outs[0];
            let s = &src[first * 3..first * 3 + o.len()];
            for (d, s) in o.iter_mut().zip(s) {
                *d = clamp_fast(*s);
            }
        });
        Ok(())
    }

    fn set_params(&mut self, params: &Value) -> Result<(), OpError> {
        let current = serde_json::to_value(&self.params).map_err(|e| bad(e.to_string()))?;
        *self = Output::new(&params::merge(NAME, &current, params)?)?;
        Ok(())
    }
}
