//! A compositor stage's work described as data: a list of operator stages, each naming its
//! operator, its parameters and where each of its inputs comes from (a link input of the stage
//! or an earlier operator's output), parsed from TOML or JSON, validated once (operators,
//! references, input counts, layers) and then run band by band with reused scratch buffers.
//!
//! ```toml
//! version = 1
//! [[inputs]]                      # input:0, the upstream partial sum
//! layers = ["illumination"]
//! [[inputs]]                      # input:1, a node with its material layer
//! layers = ["illumination", "diffuse"]
//! [[stages]]
//! name = "sum"
//! operator = "accumulate"
//! params = { colors = [[1.0, 0.9, 0.8]] }
//! inputs = ["input:0", "input:1"]
//! [[stages]]                      # the last stage is the output
//! name = "shade"
//! operator = "material"
//! params = { stage = "single" }
//! inputs = ["sum", "input:1"]
//! ```

use crate::ops::params::de_layers;
use crate::ops::{self, BandMut, BandView, OpError, Operator};
use lightfold_protocol::{Layer, OpSource, OpSpec};
use serde::Deserialize;
use serde_json::Value;

/// The pipeline file version this code reads.
pub const PIPELINE_VERSION: u32 = 1;

#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    #[error("pipeline description: {reason}")]
    Parse { reason: String },
    #[error("pipeline version {found} is not supported (expected {expected})")]
    Version { found: u32, expected: u32 },
    #[error("pipeline has no stages")]
    NoStages,
    #[error("pipeline input {input} declares no layers")]
    EmptyInput { input: usize },
    #[error("stage name {name:?} is empty, repeated, or contains ':'")]
    BadName { name: String },
    #[error("stage {stage}: {source}")]
    Operator { stage: String, source: OpError },
    #[error("stage {stage}: input {reference:?} is neither a pipeline input nor an earlier stage")]
    UnknownRef { stage: String, reference: String },
    #[error("stage {stage}: the operator takes {expected} inputs, {got} are wired")]
    InputCount {
        stage: String,
        expected: usize,
        got: usize,
    },
    #[error("stage {stage}: input {input} ({reference}) does not carry {layer:?}")]
    MissingLayer {
        stage: String,
        input: usize,
        reference: String,
        layer: Layer,
    },
    #[error("operator list leaves stage inputs {unused:?} unused")]
    UnusedInputs { unused: Vec<usize> },
    #[error("the pipeline takes {expected} input bands, got {got}")]
    BandInputs { expected: usize, got: usize },
    #[error("no stage named {name:?}")]
    NoSuchStage { name: String },
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileInput {
    #[serde(deserialize_with = "de_layers")]
    layers: Vec<Layer>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileStage {
    name: String,
    operator: String,
    #[serde(default)]
    params: Value,
    inputs: Vec<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    version: u32,
    inputs: Vec<FileInput>,
    stages: Vec<FileStage>,
}

/// Where a stage input comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Source {
    /// Link input `n` of the compositor stage.
    Input(usize),
    /// The output of an earlier operator stage.
    Stage(usize),
}

/// One operator stage of a pipeline.
#[derive(Debug)]
pub struct Stage {
    pub name: String,
    pub op: Box<dyn Operator>,
    pub sources: Vec<Source>,
}

/// A validated pipeline (see the module documentation).
#[derive(Debug)]
pub struct Pipeline {
    inputs: Vec<Vec<Layer>>,
    stages: Vec<Stage>,
}

/// Buffers for the intermediate stages' outputs, kept between bands.
#[derive(Debug, Default)]
pub struct Scratch {
    bufs: Vec<Vec<(Layer, Vec<f32>)>>,
}

impl Pipeline {
    pub fn from_toml(text: &str) -> Result<Pipeline, PipelineError> {
        let file: File = toml::from_str(text).map_err(|e| PipelineError::Parse {
            reason: e.to_string(),
        })?;
        Pipeline::from_file(file)
    }

    pub fn from_json(text: &str) -> Result<Pipeline, PipelineError> {
        let file: File = serde_json::from_str(text).map_err(|e| PipelineError::Parse {
            reason: e.to_string(),
        })?;
        Pipeline::from_file(file)
    }

    fn from_file(file: File) -> Result<Pipeline, PipelineError> {
        if file.version != PIPELINE_VERSION {
            return Err(PipelineError::Version {
                found: file.version,
                expected: PIPELINE_VERSION,
            });
        }
        let inputs: Vec<Vec<Layer>> = file.inputs.into_iter().map(|i| i.layers).collect();
        let mut stages: Vec<Stage> = Vec::new();
        for s in file.stages {
            if s.name.is_empty() || s.name.contains(':') || stages.iter().any(|t| t.name == s.name)
            {
                return Err(PipelineError::BadName { name: s.name });
            }
            let sources = s
                .inputs
                .iter()
                .map(|r| resolve(r, inputs.len(), &stages))
                .collect::<Option<Vec<_>>>();
            let Some(sources) = sources else {
                let reference = s
                    .inputs
                    .iter()
                    .find(|r| resolve(r, inputs.len(), &stages).is_none())
                    .cloned()
                    .unwrap_or_default();
                return Err(PipelineError::UnknownRef {
                    stage: s.name,
                    reference,
                });
            };
            let op =
                ops::create(&s.operator, &s.params).map_err(|source| PipelineError::Operator {
                    stage: s.name.clone(),
                    source,
                })?;
            stages.push(Stage {
                name: s.name,
                op,
                sources,
            });
        }
        Pipeline::validate(inputs, stages)
    }

    /// Builds a pipeline from a compositor configuration's ordered operator list
    /// (`CompositorConfig::ops`: typed operators). The first operator takes the first
    /// link inputs, as many as it has; each later operator takes the previous output as its input
    /// 0 and the next unused link inputs after it. Every link input must be used. Wiring beyond
    /// this convention (one link feeding two operators) needs `from_wiring` or a pipeline file.
    pub fn from_ops(ops: &[OpSpec], inputs: &[Vec<Layer>]) -> Result<Pipeline, PipelineError> {
        let mut stages: Vec<Stage> = Vec::new();
        let mut next = 0;
        for (k, spec) in ops.iter().enumerate() {
            let (stage, op) = op_stage(k, spec)?;
            let wanted = op.signature().inputs.len();
            let mut sources = Vec::with_capacity(wanted);
            if k > 0 && wanted > 0 {
                sources.push(Source::Stage(k - 1));
            }
            while sources.len() < wanted && next < inputs.len() {
                sources.push(Source::Input(next));
                next += 1;
            }
            stages.push(Stage {
                name: stage,
                op,
                sources,
            });
        }
        if next < inputs.len() {
            return Err(PipelineError::UnusedInputs {
                unused: (next..inputs.len()).collect(),
            });
        }
        Pipeline::validate(inputs.to_vec(), stages)
    }

    /// `from_ops` with each operator's inputs wired explicitly (`CompositorConfig::wiring`): an
    /// input may feed several operators, an operator may read any earlier one. Empty `wiring`
    /// is the fold of `from_ops`. Every stage input must be read.
    pub fn from_wiring(
        ops: &[OpSpec],
        wiring: &[Vec<OpSource>],
        inputs: &[Vec<Layer>],
    ) -> Result<Pipeline, PipelineError> {
        if wiring.is_empty() {
            return Pipeline::from_ops(ops, inputs);
        }
        if wiring.len() != ops.len() {
            return Err(PipelineError::Parse {
                reason: format!("{} operators but wiring for {}", ops.len(), wiring.len()),
            });
        }
        let mut read = vec![false; inputs.len()];
        let mut stages: Vec<Stage> = Vec::new();
        for (k, (spec, wires)) in ops.iter().zip(wiring).enumerate() {
            let (stage, op) = op_stage(k, spec)?;
            let sources = wires
                .iter()
                .map(|w| match *w {
                    OpSource::Input(i) if (i as usize) < inputs.len() => {
                        read[i as usize] = true;
                        Ok(Source::Input(i as usize))
                    }
                    OpSource::Op(j) if (j as usize) < k => Ok(Source::Stage(j as usize)),
                    OpSource::Input(i) => Err(format!("input:{i}")),
                    OpSource::Op(j) => Err(format!("operator {j}")),
                })
                .collect::<Result<Vec<_>, String>>()
                .map_err(|reference| PipelineError::UnknownRef {
                    stage: stage.clone(),
                    reference,
                })?;
            stages.push(Stage {
                name: stage,
                op,
                sources,
            });
        }
        let unused: Vec<usize> = (0..inputs.len()).filter(|&i| !read[i]).collect();
        if !unused.is_empty() {
            return Err(PipelineError::UnusedInputs { unused });
        }
        Pipeline::validate(inputs.to_vec(), stages)
    }

    /// Checks input counts and that every required layer is carried by its source.
    fn validate(inputs: Vec<Vec<Layer>>, stages: Vec<Stage>) -> Result<Pipeline, PipelineError> {
        if stages.is_empty() {
            return Err(PipelineError::NoStages);
        }
        if let Some(input) = inputs.iter().position(Vec::is_empty) {
            return Err(PipelineError::EmptyInput { input });
        }
        for (k, stage) in stages.iter().enumerate() {
            let sig = stage.op.signature();
            if sig.inputs.len() != stage.sources.len() {
                return Err(PipelineError::InputCount {
                    stage: stage.name.clone(),
                    expected: sig.inputs.len(),
                    got: stage.sources.len(),
                });
            }
            for (i, (spec, src)) in sig.inputs.iter().zip(&stage.sources).enumerate() {
                let carried = match *src {
                    Source::Input(n) => inputs[n].clone(),
                    Source::Stage(j) => {
                        debug_assert!(j < k, "sources are resolved against earlier stages");
                        stages[j].op.signature().outputs
                    }
                };
                if let Some(&layer) = spec.required.iter().find(|l| !carried.contains(l)) {
                    return Err(PipelineError::MissingLayer {
                        stage: stage.name.clone(),
                        input: i,
                        reference: describe(*src, &stages),
                        layer,
                    });
                }
            }
        }
        Ok(Pipeline { inputs, stages })
    }

    /// The layers each link input carries, in input-index order.
    pub fn input_layers(&self) -> &[Vec<Layer>] {
        &self.inputs
    }

    /// The layers the pipeline emits (those of its last stage).
    pub fn output_layers(&self) -> Vec<Layer> {
        self.stages
            .last()
            .expect("validated")
            .op
            .signature()
            .outputs
    }

    pub fn stages(&self) -> &[Stage] {
        &self.stages
    }

    /// Changes the parameters of stage `name` at run time (e.g. per-frame light colours).
    pub fn set_params(&mut self, name: &str, params: &Value) -> Result<(), PipelineError> {
        let stage = self
            .stages
            .iter_mut()
            .find(|s| s.name == name)
            .ok_or_else(|| PipelineError::NoSuchStage { name: name.into() })?;
        stage
            .op
            .set_params(params)
            .map_err(|source| PipelineError::Operator {
                stage: name.into(),
                source,
            })
    }

    /// Runs every stage over one band with the fast operators; `out` receives the last stage's
    /// layers.
    pub fn run(
        &self,
        inputs: &[BandView<'_>],
        out: &mut BandMut<'_>,
        scratch: &mut Scratch,
    ) -> Result<(), PipelineError> {
        self.run_with(inputs, out, scratch, false)
    }

    /// `run` with the scalar reference operators.
    pub fn run_scalar(
        &self,
        inputs: &[BandView<'_>],
        out: &mut BandMut<'_>,
        scratch: &mut Scratch,
    ) -> Result<(), PipelineError> {
        self.run_with(inputs, out, scratch, true)
    }

    fn run_with(
        &self,
        inputs: &[BandView<'_>],
        out: &mut BandMut<'_>,
        scratch: &mut Scratch,
        scalar: bool,
    ) -> Result<(), PipelineError> {
        if inputs.len() != self.inputs.len() {
            return Err(PipelineError::BandInputs {
                expected: self.inputs.len(),
                got: inputs.len(),
            });
        }
        let pixels = out.pixels;
        let last = self.stages.len() - 1;
        scratch.bufs.resize_with(last, Vec::new);
        for (buf, stage) in scratch.bufs.iter_mut().zip(&self.stages) {
            let outputs = stage.op.signature().outputs;
            buf.resize_with(outputs.len(), || (Layer::Radiance, Vec::new()));
            for ((l, v), want) in buf.iter_mut().zip(outputs) {
                *l = want;
                v.resize(pixels * want.channels(), 0.0);
            }
        }
        for (k, stage) in self.stages.iter().enumerate() {
            let (done, rest) = scratch.bufs.split_at_mut(k.min(last));
            let views: Vec<BandView<'_>> = stage
                .sources
                .iter()
                .map(|s| match *s {
                    Source::Input(n) => inputs[n].clone(),
                    Source::Stage(j) => BandView {
                        pixels,
                        layers: done[j].iter().map(|(l, v)| (*l, v.as_slice())).collect(),
                    },
                })
                .collect();
            let wrap = |source| PipelineError::Operator {
                stage: stage.name.clone(),
                source,
            };
            let apply = |target: &mut BandMut<'_>| {
                if scalar {
                    stage.op.apply_scalar(&views, target)
                } else {
                    stage.op.apply(&views, target)
                }
            };
            if k == last {
                apply(out).map_err(wrap)?;
            } else {
                let mut own = BandMut {
                    pixels,
                    layers: rest[0]
                        .iter_mut()
                        .map(|(l, v)| (*l, v.as_mut_slice()))
                        .collect(),
                };
                apply(&mut own).map_err(wrap)?;
            }
        }
        Ok(())
    }
}

/// Resolves `input:N` or the name of an earlier stage.
fn resolve(reference: &str, inputs: usize, earlier: &[Stage]) -> Option<Source> {
    if let Some(n) = reference.strip_prefix("input:") {
        return n.parse().ok().filter(|n| *n < inputs).map(Source::Input);
    }
    earlier
        .iter()
        .position(|s| s.name == reference)
        .map(Source::Stage)
}

/// Operator `k` of an operator list, named by its index, built from its typed parameters.
fn op_stage(k: usize, spec: &OpSpec) -> Result<(String, Box<dyn Operator>), PipelineError> {
    let stage = k.to_string();
    let op = ops::from_spec(spec).map_err(|source| PipelineError::Operator {
        stage: stage.clone(),
        source,
    })?;
    Ok((stage, op))
}

fn describe(src: Source, stages: &[Stage]) -> String {
    match src {
        Source::Input(n) => format!("input:{n}"),
        Source::Stage(j) => stages[j].name.clone(),
    }
}
