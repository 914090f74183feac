//! Compositing operators (per pixel, and one neighbourhood filter, `penumbra`) (paper §3, ARCHITECTURE §8): the `Operator` trait, the band
//! views they read and write, the registry by name, and the value policy they all share. Each
//! operator's parameters are the typed ones of `lightfold_protocol::pipeline` (what a
//! configuration carries, `from_spec`), also read from JSON (pipeline files, `create`).
//!
//! Bands are rectangles of rows held as interleaved f32 per layer (`Layer::channels()` values a
//! pixel), so the stage daemon can stream a frame band by band through the same code. Every
//! operator has a scalar reference (`apply_scalar`, written for clarity) and a fast version
//! (`apply`, chunked loops the compiler vectorises, rayon across spans of a large band) that never
//! calls the reference; the differential tests hold them to the same bits unless an operator
//! documents a bound.
//!
//! Value policy, identical in both versions: a colour value (every layer but depth) that is NaN or
//! not positive reads as +0, +Inf reads as `MAX_VALUE`, and results saturate at `MAX_VALUE`, so no
//! operator ever emits NaN or Inf for colour. Depth has its own rule (see `depth`).

pub mod accumulate;
pub mod blend;
pub mod depth;
pub mod dispatch;
pub mod join;
pub mod material;
pub mod merge;
pub mod output;
pub mod packed_out;
pub(crate) mod params;
pub mod penumbra;
pub mod precision;

use lightfold_protocol::{Layer, OpSpec};
use rayon::prelude::*;
use serde_json::Value;
use std::fmt;

pub use accumulate::{Accumulate, PackedIllumination};
pub use blend::Blend;
pub use depth::{Depth, PackedLayer};
pub use dispatch::Isa;
pub use join::Join;
pub use material::{Material, MaterialStage};
pub use merge::Merge;
pub use output::Output;
pub use packed_out::{PackSummary, PackedOut};
pub use params::{layer_from_name, layer_name};
pub use penumbra::Penumbra;
pub use precision::{LinkFormat, LinkKind, chain_bound, recommended_link_format};

/// The largest colour value an operator emits: sums saturate here instead of reaching +Inf, so a
/// later multiply by a zero material stays 0 rather than NaN.
pub const MAX_VALUE: f32 = f32::MAX;

/// Pixels of one rayon task. Below two spans a band runs on the calling thread: a task costs a few
/// microseconds, about what 30 k pixels of accumulate take (docs/operators.md).
pub const PAR_SPAN: usize = 32 * 1024;

/// One input of an operator for one band: some layers of the same `pixels` pixels.
#[derive(Debug, Clone, Default)]
pub struct BandView<'a> {
    pub pixels: usize,
    pub layers: Vec<(Layer, &'a [f32])>,
}

impl<'a> BandView<'a> {
    pub fn new(pixels: usize) -> Self {
        BandView {
            pixels,
            layers: Vec::new(),
        }
    }

    /// Adds a layer (builder style).
    pub fn with(mut self, layer: Layer, data: &'a [f32]) -> Self {
        self.layers.push((layer, data));
        self
    }

    pub fn layer(&self, layer: Layer) -> Option<&'a [f32]> {
        self.layers
            .iter()
            .find(|(l, _)| *l == layer)
            .map(|(_, d)| *d)
    }
}

/// The output of an operator for one band.
#[derive(Debug, Default)]
pub struct BandMut<'a> {
    pub pixels: usize,
    pub layers: Vec<(Layer, &'a mut [f32])>,
}

impl<'a> BandMut<'a> {
    pub fn new(pixels: usize) -> Self {
        BandMut {
            pixels,
            layers: Vec::new(),
        }
    }

    pub fn with(mut self, layer: Layer, data: &'a mut [f32]) -> Self {
        self.layers.push((layer, data));
        self
    }

    pub fn layer_mut(&mut self, layer: Layer) -> Option<&mut [f32]> {
        self.layers
            .iter_mut()
            .find(|(l, _)| *l == layer)
            .map(|(_, d)| &mut **d)
    }
}

/// The layers one input must or may carry. An absent optional layer reads as all zeros, which lets
/// the daemon pass an empty (range-culled) band without unpacking it.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct InputSpec {
    pub required: Vec<Layer>,
    pub optional: Vec<Layer>,
}

/// What an operator reads on each input (input-index order) and writes.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Signature {
    pub inputs: Vec<InputSpec>,
    pub outputs: Vec<Layer>,
}

#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum OpError {
    #[error("unknown operator {name:?} (known: {})", known.join(", "))]
    UnknownOperator {
        name: String,
        known: Vec<&'static str>,
    },
    #[error("operator {op}: bad parameters: {reason}")]
    BadParam { op: &'static str, reason: String },
    #[error("operator {op}: new parameters would change its inputs or outputs")]
    SignatureChange { op: &'static str },
    #[error("operator {op}: expected {expected} inputs, got {got}")]
    InputCount {
        op: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("operator {op}: input {input} lacks layer {layer:?}")]
    MissingLayer {
        op: &'static str,
        input: usize,
        layer: Layer,
    },
    #[error("operator {op}: input {input} has {got} pixels, the band has {expected}")]
    PixelCount {
        op: &'static str,
        input: usize,
        expected: usize,
        got: usize,
    },
    #[error("operator {op}: input {input} layer {layer:?} holds {got} values, expected {expected}")]
    InputLength {
        op: &'static str,
        input: usize,
        layer: Layer,
        expected: usize,
        got: usize,
    },
    #[error("operator {op}: output lacks layer {layer:?}")]
    MissingOutput { op: &'static str, layer: Layer },
    #[error("operator {op}: output layer {layer:?} holds {got} values, expected {expected}")]
    OutputLength {
        op: &'static str,
        layer: Layer,
        expected: usize,
        got: usize,
    },
    #[error("operator {op}: packed input {input}: {source}")]
    Packed {
        op: &'static str,
        input: usize,
        source: lightfold_protocol::format::FormatError,
    },
    #[error(
        "operator {op}: packed output {layer:?} ({format:?}) holds {actual} bytes, expected {expected}"
    )]
    PackedOut {
        op: &'static str,
        layer: Layer,
        format: lightfold_protocol::PixelFormat,
        expected: usize,
        actual: usize,
    },
    #[error("operator {op}: cannot pack output {layer:?}: {source}")]
    Pack {
        op: &'static str,
        layer: Layer,
        source: lightfold_protocol::format::FormatError,
    },
    #[error("operator {op}: no packed path for layer {layer:?} as {format:?} in this band")]
    PackedFormat {
        op: &'static str,
        layer: Layer,
        format: lightfold_protocol::PixelFormat,
    },
    #[error("this cpu lacks the {isa} instruction set")]
    IsaUnavailable { isa: Isa },
    #[error("operator {op}: {what} holds {got} values, expected {expected}")]
    BufferLength {
        op: &'static str,
        what: &'static str,
        expected: usize,
        got: usize,
    },
}

/// A named, parameterised per-pixel function over input layers.
pub trait Operator: Send + Sync + fmt::Debug {
    fn name(&self) -> &'static str;
    /// Layers required on each input and produced on the output.
    fn signature(&self) -> Signature;
    /// Combines one band (fast version): `inputs[i]` is input i, `out` the output band.
    fn apply(&self, inputs: &[BandView<'_>], out: &mut BandMut<'_>) -> Result<(), OpError>;
    /// The reference the fast version is tested against.
    fn apply_scalar(&self, inputs: &[BandView<'_>], out: &mut BandMut<'_>) -> Result<(), OpError>;
    /// Replaces the parameters named in `params` (a JSON object); the others keep their values.
    /// Fails without changing anything if the result is invalid or would change the signature.
    fn set_params(&mut self, params: &Value) -> Result<(), OpError>;
}

/// Builds an operator from its JSON parameters.
pub type Constructor = fn(&Value) -> Result<Box<dyn Operator>, OpError>;

static REGISTRY: [(&str, Constructor); 8] = [
    (accumulate::NAME, |p| Ok(Box::new(Accumulate::new(p)?))),
    (material::NAME, |p| Ok(Box::new(Material::new(p)?))),
    (depth::NAME, |p| Ok(Box::new(Depth::new(p)?))),
    (join::NAME, |p| Ok(Box::new(Join::new(p)?))),
    (merge::NAME, |p| Ok(Box::new(Merge::new(p)?))),
    (output::NAME, |p| Ok(Box::new(Output::new(p)?))),
    (penumbra::NAME, |p| Ok(Box::new(Penumbra::new(p)?))),
    (blend::NAME, |p| Ok(Box::new(Blend::new(p)?))),
];

/// Builds the operator a configuration's `OpSpec` names, its parameters validated.
pub fn from_spec(spec: &OpSpec) -> Result<Box<dyn Operator>, OpError> {
    Ok(match spec.clone() {
        OpSpec::Accumulate(p) => Box::new(Accumulate::from_params(p)?),
        OpSpec::Material(p) => Box::new(Material::from_params(p)?),
        OpSpec::Depth(p) => Box::new(Depth::from_params(p)?),
        OpSpec::Join(p) => Box::new(Join::from_params(p)?),
        OpSpec::Merge(p) => Box::new(Merge::from_params(p)?),
        OpSpec::Output(p) => Box::new(Output::from_params(p)?),
        OpSpec::Penumbra(p) => Box::new(Penumbra::from_params(p)?),
        OpSpec::Blend(p) => Box::new(Blend::from_params(p)?),
    })
}

/// The typed operator `name` with JSON `params` (`null` means all defaults), as a
/// configuration carries it; not validated (`OpSpec::validate`, `from_spec`).
pub fn spec_from_json(name: &str, params: &Value) -> Result<OpSpec, OpError> {
    use lightfold_protocol::pipeline::OP_NAMES;
    Ok(match name {
        accumulate::NAME => OpSpec::Accumulate(params::parse(accumulate::NAME, params)?),
        material::NAME => OpSpec::Material(params::parse(material::NAME, params)?),
        depth::NAME => OpSpec::Depth(params::parse(depth::NAME, params)?),
        join::NAME => OpSpec::Join(params::parse(join::NAME, params)?),
        merge::NAME => OpSpec::Merge(params::parse(merge::NAME, params)?),
        output::NAME => OpSpec::Output(params::parse(output::NAME, params)?),
        penumbra::NAME => OpSpec::Penumbra(params::parse(penumbra::NAME, params)?),
        blend::NAME => OpSpec::Blend(params::parse(blend::NAME, params)?),
        _ => {
            return Err(OpError::UnknownOperator {
                name: name.to_string(),
                known: OP_NAMES.to_vec(),
            });
        }
    })
}

/// Every operator by name.
pub fn registry() -> &'static [(&'static str, Constructor)] {
    &REGISTRY
}

/// Builds the operator `name` with `params` (`null` means all defaults).
pub fn create(name: &str, params: &Value) -> Result<Box<dyn Operator>, OpError> {
    match REGISTRY.iter().find(|(n, _)| *n == name) {
        Some((_, ctor)) => ctor(params),
        None => Err(OpError::UnknownOperator {
            name: name.to_string(),
            known: REGISTRY.iter().map(|(n, _)| *n).collect(),
        }),
    }
}

/// Checks a band against a signature: input count, pixel counts, layer presence and lengths.
pub fn check_band(
    op: &'static str,
    sig: &Signature,
    inputs: &[BandView<'_>],
    out: &BandMut<'_>,
) -> Result<(), OpError> {
    if inputs.len() != sig.inputs.len() {
        return Err(OpError::InputCount {
            op,
            expected: sig.inputs.len(),
            got: inputs.len(),
        });
    }
    let pixels = out.pixels;
    for (i, (view, spec)) in inputs.iter().zip(&sig.inputs).enumerate() {
        if view.pixels != pixels {
            return Err(OpError::PixelCount {
                op,
                input: i,
                expected: pixels,
                got: view.pixels,
            });
        }
        for &layer in &spec.required {
            if view.layer(layer).is_none() {
                return Err(OpError::MissingLayer {
                    op,
                    input: i,
                    layer,
                });
            }
        }
        for &(layer, data) in &view.layers {
            let expected = pixels * layer.channels();
            if data.len() != expected {
                return Err(OpError::InputLength {
                    op,
                    input: i,
                    layer,
                    expected,
                    got: data.len(),
                });
            }
        }
    }
    for &layer in &sig.outputs {
        let Some((_, data)) = out.layers.iter().find(|(l, _)| *l == layer) else {
            return Err(OpError::MissingOutput { op, layer });
        };
        let expected = pixels * layer.channels();
        if data.len() != expected {
            return Err(OpError::OutputLength {
                op,
                layer,
                expected,
                got: data.len(),
            });
        }
    }
    Ok(())
}

/// The reference reading of a colour value: NaN and non-positive values are +0, +Inf is
/// `MAX_VALUE`. Written as the policy reads; `clamp_fast` is the branch-free twin.
#[inline]
pub fn sanitize(x: f32) -> f32 {
    if x.is_nan() || x <= 0.0 {
        0.0
    } else if x.is_infinite() {
        MAX_VALUE
    } else {
        x
    }
}

/// `sanitize` as two selects the compiler turns into vector compares (NaN fails `x > 0`).
#[inline(always)]
pub(crate) fn clamp_fast(x: f32) -> f32 {
    let x = if x > 0.0 { x } else { 0.0 };
    if x < MAX_VALUE { x } else { MAX_VALUE }
}

/// Saturates a sum of non-negative terms (which may have overflowed to +Inf) at `MAX_VALUE`.
#[inline(always)]
pub(crate) fn saturate(x: f32) -> f32 {
    if x < MAX_VALUE { x } else { MAX_VALUE }
}

/// Runs `f(first_pixel, spans)` over spans of `PAR_SPAN` pixels of every output layer, on the
/// rayon pool when the band has at least two spans and the pool more than one thread.
pub(crate) fn for_spans<F>(pixels: usize, outs: Vec<(usize, &mut [f32])>, f: F)
where
    F: Fn(usize, &mut [&mut [f32]]) + Sync,
{
    if pixels < 2 * PAR_SPAN || rayon::current_num_threads() < 2 {
        let mut all: Vec<&mut [f32]> = outs.into_iter().map(|(_, d)| d).collect();
        f(0, &mut all);
        return;
    }
    let spans = pixels.div_ceil(PAR_SPAN);
    let mut tasks: Vec<Vec<&mut [f32]>> = (0..spans).map(|_| Vec::new()).collect();
    for (channels, data) in outs {
        for (task, chunk) in tasks.iter_mut().zip(data.chunks_mut(PAR_SPAN * channels)) {
            task.push(chunk);
        }
    }
    tasks
        .into_par_iter()
        .enumerate()
        .for_each(|(i, mut task)| f(i * PAR_SPAN, &mut task));
}

/// Pixels processed per inner block: a block of every input and the output stays in L1.
pub(crate) const BLOCK: usize = 256;
