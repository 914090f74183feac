//! A `CompositorConfig` checked and resolved into a `StagePlan`: the band grid, which stage inputs
//! each operator reads, the operators themselves, and the byte budget of each input's queue. All
//! pure, so a bad configuration is refused with a typed error before anything runs.
//!
//! Operators are chained as `Pipeline::from_ops` does it, a fold: operator 0 reads the first
//! stage inputs; operator k > 0 reads the previous operator's output as its input 0 and the next
//! unused stage inputs. Every stage input is read by exactly one operator. With no operator the
//! stage relays its one input.

use crate::ops::{Accumulate, Depth, OpError};
use crate::pipeline::{Pipeline, PipelineError, Source};
use lightfold_protocol::pipeline::{AccumulateParams, NodeColor};
use lightfold_protocol::{CompositorConfig, ErrorCode, Layer, OpSpec, PixelFormat};

/// Largest image side a stage accepts (keeps every size computation far from overflow).
pub(super) const MAX_SIDE: u32 = 1 << 15;
/// Most frames an input may buffer, whatever the configuration asks.
pub const MAX_FRAMES_IN_FLIGHT: u32 = 16;
/// Bytes a queued band costs beyond its payload (header, bookkeeping), so that even empty bands
/// count against the budget.
pub const BAND_OVERHEAD: u64 = 128;

/// Why a configuration is refused.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("image size {width}x{height} is outside 1..={MAX_SIDE}")]
    BadSize { width: u32, height: u32 },
    #[error("band height {0} must be at least 1")]
    BadBandHeight(u32),
    #[error("frames_in_flight {0} is outside 1..={MAX_FRAMES_IN_FLIGHT}")]
    BadFramesInFlight(u32),
    #[error("a stage needs at least one input")]
    NoInputs,
    #[error("input {input} and input {other} are both daemon {peer:?}")]
    DuplicatePeer {
        input: usize,
        other: usize,
        peer: String,
    },
    #[error("input {input} names an invalid daemon id {peer:?}")]
    BadPeer { input: usize, peer: String },
    #[error("input {input} carries no layer")]
    NoLayers { input: usize },
    #[error("{place} lists layer {layer:?} twice")]
    DuplicateLayer { place: String, layer: Layer },
    #[error(
        "{place}: format {format:?} packs {format_channels} channels, layer {layer:?} has {layer_channels}"
    )]
    FormatLayer {
        place: String,
        layer: Layer,
        format: PixelFormat,
        format_channels: usize,
        layer_channels: usize,
    },
    #[error("operators: {0}")]
    Pipeline(#[from] PipelineError),
    #[error("a stage without operators relays exactly one input, this one has {0}")]
    RelayInputs(usize),
    #[error("the stage emits no layer")]
    NoOutputs,
    #[error("output layer {layer:?} is not produced (the stage makes {made:?})")]
    OutputNotMade { layer: Layer, made: Vec<Layer> },
    #[error("a band of {bytes} bytes does not fit the maximum frame of {max} bytes")]
    BandTooLarge { bytes: u64, max: usize },
    #[error("downstream address is empty")]
    NoDownstream,
    #[error("operator {op} reads rows {width} pixels wide, the image is {image} wide")]
    FilterWidth { op: usize, width: u32, image: u32 },
    #[error(
        "operator {op} needs {radius} rows of each neighbouring band, bands here are {rows} rows"
    )]
    FilterBands { op: usize, radius: u32, rows: u32 },
}

impl ConfigError {
    /// The code the coordinator sees in `Message::Error`.
    pub fn code(&self) -> ErrorCode {
        match self {
            ConfigError::Pipeline(PipelineError::Operator {
                source: OpError::UnknownOperator { .. },
                ..
            }) => ErrorCode::UnknownOperator,
            ConfigError::FormatLayer { .. } => ErrorCode::UnsupportedFormat,
            _ => ErrorCode::BadConfig,
        }
    }
}

/// The operators of a stage: the pipeline (`None` for a relay) and, when the stage is one
/// `accumulate` over illumination-only inputs, the same operator for the fused unpack-and-add
/// path (`Accumulate::apply_packed`, bit-identical to unpacking and running the pipeline); a lone
/// `depth` whose layers travel in formats it selects as bits, the same operator for its packed
/// path (`Depth::apply_packed`, likewise bit-identical).
#[derive(Debug, Default)]
pub struct Operators {
    pub pipeline: Option<Pipeline>,
    pub fused: Option<Accumulate>,
    pub depth: Option<Depth>,
}

/// A checked configuration, ready to run.
#[derive(Debug)]
pub struct StagePlan {
    pub config: CompositorConfig,
    pub bands: u32,
    /// Per stage input: the operator stage reading it and as which of its inputs.
    pub readers: Vec<Option<(usize, usize)>>,
    /// Per stage input: the layers its reader requires (an empty band of any other layer is left
    /// out of the view instead of being expanded to zeros).
    pub required: Vec<Vec<Layer>>,
    /// Layers the stage can emit (the last operator's, or the relayed input's).
    pub produced: Vec<Layer>,
    /// Queue budget of each input in bytes: `frames_in_flight` whole frames of its layers.
    pub input_budget: Vec<u64>,
    /// Rows of each neighbouring band a band is combined with (the largest `penumbra` radius; 0
    /// without one): the stage runs its operators over the band and this halo, then sends the
    /// band's own rows (`compute::combine`).
    pub halo: u32,
}

/// The halo the stage's `penumbra` operators need, checked against the image and its bands.
fn filter_halo(c: &CompositorConfig, band_rows: u32, bands: u32) -> Result<u32, ConfigError> {
    let mut halo = 0;
    for (op, spec) in c.ops.iter().enumerate() {
        let OpSpec::Penumbra(params) = spec else {
            continue;
        };
        let filter = crate::ops::Penumbra::from_params(params.clone()).map_err(|e| {
            ConfigError::Pipeline(PipelineError::Operator {
                stage: op.to_string(),
                source: e,
            })
        })?;
        if filter.width() != c.width {
            return Err(ConfigError::FilterWidth {
                op,
                width: filter.width(),
                image: c.width,
            });
        }
        if bands > 1 && band_rows < filter.halo() {
            return Err(ConfigError::FilterBands {
                op,
                radius: filter.halo(),
                rows: band_rows,
            });
        }
        halo = halo.max(filter.halo());
    }
    Ok(halo)
}

/// Checks the configuration's image size, bands, frames in flight, downstream address, inputs
/// and output formats, and that a band in the widest format fits a link frame of `max_frame`
/// bytes. Returns the rows of a full band.
fn check_shape(c: &CompositorConfig, max_frame: usize) -> Result<u32, ConfigError> {
    if !(1..=MAX_SIDE).contains(&c.width) || !(1..=MAX_SIDE).contains(&c.height) {
        return Err(ConfigError::BadSize {
            width: c.width,
            height: c.height,
        });
    }
    if c.band_height == 0 {
        return Err(ConfigError::BadBandHeight(c.band_height));
    }
    if !(1..=MAX_FRAMES_IN_FLIGHT).contains(&c.frames_in_flight) {
        return Err(ConfigError::BadFramesInFlight(c.frames_in_flight));
    }
    if c.downstream.trim().is_empty() {
        return Err(ConfigError::NoDownstream);
    }
    check_inputs(c)?;
    check_formats(&c.outputs, "outputs")?;
    let band_rows = c.band_height.min(c.height);
    let widest = c
        .inputs
        .iter()
        .flat_map(|i| &i.layers)
        .chain(&c.outputs)
        .map(|(_, f)| f.bytes_per_pixel() as u64)
        .max()
        .unwrap_or(0);
    let band_bytes = u64::from(c.width) * u64::from(band_rows) * widest;
    let band_frame = band_bytes + lightfold_protocol::BAND_HEADER_LEN as u64 + 1;
    if band_frame > max_frame as u64 {
        return Err(ConfigError::BandTooLarge {
            bytes: band_bytes,
            max: max_frame,
        });
    }
    Ok(band_rows)
}

/// How a stage's operators read its inputs ([`wire`]).
struct Wiring {
    /// The operators (`None`: a relay).
    pipeline: Option<Pipeline>,
    /// Layers the stage can emit.
    produced: Vec<Layer>,
    /// Per stage input: the operator reading it and as which of its inputs.
    readers: Vec<Option<(usize, usize)>>,
    /// Per stage input: the layers its reader requires.
    required: Vec<Vec<Layer>>,
}

/// Builds the stage's pipeline from its operators and wiring, or checks that a stage without
/// operators relays exactly one input, and records which operator reads each input and the
/// layers it requires there.
fn wire(c: &CompositorConfig) -> Result<Wiring, ConfigError> {
    let input_layers: Vec<Vec<Layer>> = c
        .inputs
        .iter()
        .map(|i| i.layers.iter().map(|l| l.0).collect())
        .collect();
    let mut readers = vec![None; c.inputs.len()];
    let mut required = vec![Vec::new(); c.inputs.len()];
    let (pipeline, produced) = if c.ops.is_empty() {
        if c.inputs.len() != 1 {
            return Err(ConfigError::RelayInputs(c.inputs.len()));
        }
        required[0] = input_layers[0].clone();
        (None, input_layers[0].clone())
    } else {
        let p = Pipeline::from_wiring(&c.ops, &c.wiring, &input_layers)?;
        for (k, stage) in p.stages().iter().enumerate() {
            let sig = stage.op.signature();
            for (j, src) in stage.sources.iter().enumerate() {
                if let Source::Input(n) = *src {
                    // An input read by two operators (explicit wiring): its colour belongs to
                    // the first (the `accumulate`), and it needs what either requires.
                    readers[n].get_or_insert((k, j));
                    for &l in &sig.inputs[j].required {
                        if !required[n].contains(&l) {
                            required[n].push(l);
                        }
                    }
                }
            }
        }
        let produced = p.output_layers();
        (Some(p), produced)
    };
    Ok(Wiring {
        pipeline,
        produced,
        readers,
        required,
    })
}

/// The operator for the fused unpack-and-add path: the stage's one `accumulate` (or `join` of
/// illumination sums) over illumination-only inputs read in order; `None` otherwise.
fn fused_accumulate(c: &CompositorConfig) -> Option<Accumulate> {
    // The fused paths read the stage inputs in order, as the fold does; explicit wiring may
    // not, so it keeps the general path.
    let fold = c.wiring.is_empty();
    let illumination_only = c
        .inputs
        .iter()
        .all(|i| i.layers.len() == 1 && i.layers[0].0 == Layer::Illumination);
    match c.ops.as_slice() {
        [OpSpec::Accumulate(p)] if fold && illumination_only => {
            Accumulate::from_params(p.clone()).ok()
        }
        [OpSpec::Join(p)] if fold && illumination_only && p.layer == Layer::Illumination => {
            // A join of illumination sums is an accumulate of white, non-folding local terms:
            // 0 + 1·x is x, added in input order, saturated once, so the fused path gives the
            // join's bits (tests compare the two).
            Accumulate::from_params(AccumulateParams {
                colors: vec![NodeColor::Rgb([1.0; 3]); c.inputs.len()],
                upstream: false,
                specular_color: None,
                ambient: None,
            })
            .ok()
        }
        _ => None,
    }
}

/// The operator for the packed depth path: the stage's one `depth`, read in order, when its
/// layers travel in formats it selects as bits; `None` otherwise.
fn packed_depth(c: &CompositorConfig) -> Option<Depth> {
    let fold = c.wiring.is_empty();
    match c.ops.as_slice() {
        [OpSpec::Depth(p)] if fold => {
            let layers: Vec<Vec<(Layer, PixelFormat)>> =
                c.inputs.iter().map(|i| i.layers.clone()).collect();
            Depth::from_params(p.clone())
                .ok()
                .filter(|d| d.packed_supported(&layers, &c.outputs))
        }
        _ => None,
    }
}

/// Each input's queue budget in bytes: `frames_in_flight` whole frames of its layers, each
/// band counting its overhead.
fn input_budget(c: &CompositorConfig, bands: u32) -> Vec<u64> {
    c.inputs
        .iter()
        .map(|i| {
            let per_frame: u64 = i
                .layers
                .iter()
                .map(|(_, f)| {
                    u64::from(c.width) * u64::from(c.height) * f.bytes_per_pixel() as u64
                        + u64::from(bands) * BAND_OVERHEAD
                })
                .sum();
            per_frame * u64::from(c.frames_in_flight)
        })
        .collect()
}

impl StagePlan {
    /// Checks `config` and builds its operators (`None`: a relay). `max_frame` is the link's
    /// frame limit.
    pub fn new(
        config: CompositorConfig,
        max_frame: usize,
    ) -> Result<(StagePlan, Operators), ConfigError> {
        let c = &config;
        let band_rows = check_shape(c, max_frame)?;
        let Wiring {
            pipeline,
            produced,
            readers,
            required,
        } = wire(c)?;
        if c.outputs.is_empty() {
            return Err(ConfigError::NoOutputs);
        }
        for &(layer, _) in &c.outputs {
            if !produced.contains(&layer) {
                return Err(ConfigError::OutputNotMade {
                    layer,
                    made: produced.clone(),
                });
            }
        }
        let fused = fused_accumulate(c);
        let depth = packed_depth(c);
        let bands = c.height.div_ceil(c.band_height);
        let halo = filter_halo(c, band_rows, bands)?;
        let input_budget = input_budget(c, bands);
        let plan = StagePlan {
            bands,
            readers,
            required,
            produced,
            input_budget,
            halo,
            config,
        };
        Ok((
            plan,
            Operators {
                pipeline,
                fused,
                depth,
            },
        ))
    }

    pub fn epoch(&self) -> u64 {
        self.config.epoch
    }

    /// Rows `(y0, height)` of band `b`.
    pub fn band_rows(&self, b: u32) -> (u32, u32) {
        let y0 = b * self.config.band_height;
        (y0, self.config.band_height.min(self.config.height - y0))
    }
}

fn check_inputs(c: &CompositorConfig) -> Result<(), ConfigError> {
    if c.inputs.is_empty() {
        return Err(ConfigError::NoInputs);
    }
    for (input, i) in c.inputs.iter().enumerate() {
        if lightfold_protocol::handshake::check_daemon_id(&i.peer).is_err() {
            return Err(ConfigError::BadPeer {
                input,
                peer: i.peer.clone(),
            });
        }
        if let Some(other) = c.inputs[..input].iter().position(|o| o.peer == i.peer) {
            return Err(ConfigError::DuplicatePeer {
                input,
                other,
                peer: i.peer.clone(),
            });
        }
        if i.layers.is_empty() {
            return Err(ConfigError::NoLayers { input });
        }
        check_formats(&i.layers, &format!("input {input}"))?;
    }
    Ok(())
}

fn check_formats(layers: &[(Layer, PixelFormat)], place: &str) -> Result<(), ConfigError> {
    for (k, &(layer, format)) in layers.iter().enumerate() {
        if layers[..k].iter().any(|(l, _)| *l == layer) {
            return Err(ConfigError::DuplicateLayer {
                place: place.to_string(),
                layer,
            });
        }
        if format.channels() != layer.channels() {
            return Err(ConfigError::FormatLayer {
                place: place.to_string(),
                layer,
                format,
                format_channels: format.channels(),
                layer_channels: layer.channels(),
            });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightfold_protocol::pipeline::{DepthParams, JoinParams, MaterialParams, MaterialStage};
    use lightfold_protocol::{OpSource, StageInput};

    fn input(peer: &str, layers: &[(Layer, PixelFormat)]) -> StageInput {
        StageInput {
            peer: peer.into(),
            layers: layers.to_vec(),
        }
    }

    fn config() -> CompositorConfig {
        let ill = [(Layer::Illumination, PixelFormat::F16x6)];
        let mat = [(Layer::Diffuse, PixelFormat::Rgba8Linear)];
        CompositorConfig {
            epoch: 3,
            width: 33,
            height: 17,
            band_height: 5,
            inputs: vec![input("up", &ill), input("n1", &ill), input("m", &mat)],
            ops: vec![
                OpSpec::Accumulate(AccumulateParams {
                    colors: vec![NodeColor::Rgb([1.0; 3])],
                    upstream: true,
                    specular_color: None,
                    ambient: None,
                }),
                OpSpec::Material(MaterialParams {
                    stage: MaterialStage::Diffuse,
                    ambient_color: None,
                    specular: false,
                    emissive: false,
                }),
            ],
            outputs: vec![(Layer::Radiance, PixelFormat::F32x3)],
            downstream: "127.0.0.1:1".into(),
            input_index: 0,
            wiring: Vec::new(),
            frames_in_flight: 2,
        }
    }

    #[test]
    fn a_fold_of_two_operators_reads_every_input_once() {
        let (plan, ops) = StagePlan::new(config(), 1 << 20).unwrap();
        assert_eq!(ops.pipeline.unwrap().stages().len(), 2);
        assert!(ops.fused.is_none(), "two operators are not one accumulate");
        assert_eq!(plan.bands, 4);
        assert_eq!(plan.band_rows(3), (15, 2));
        assert_eq!(plan.readers, vec![Some((0, 0)), Some((0, 1)), Some((1, 1))]);
        assert_eq!(plan.required[2], vec![Layer::Diffuse]);
        assert_eq!(plan.produced, vec![Layer::Radiance]);
        let frame = 33 * 17 * 12 + 4 * BAND_OVERHEAD;
        assert_eq!(plan.input_budget[0], 2 * frame);
    }

    #[test]
    fn a_lone_join_of_illumination_takes_the_fused_accumulate() {
        let ill = [(Layer::Illumination, PixelFormat::F16x6)];
        let mut c = config();
        c.inputs = vec![input("a", &ill), input("b", &ill)];
        c.ops = vec![OpSpec::Join(JoinParams {
            inputs: 2,
            layer: Layer::Illumination,
        })];
        c.outputs = ill.to_vec();
        assert!(
            StagePlan::new(c.clone(), 1 << 20)
                .unwrap()
                .1
                .fused
                .is_some()
        );
        // Another layer, or explicit wiring, keeps the general path.
        let dif = [(Layer::Diffuse, PixelFormat::F16x4)];
        let mut d = c.clone();
        d.inputs = vec![input("a", &dif), input("b", &dif)];
        d.ops = vec![OpSpec::Join(JoinParams {
            inputs: 2,
            layer: Layer::Diffuse,
        })];
        d.outputs = dif.to_vec();
        assert!(StagePlan::new(d, 1 << 20).unwrap().1.fused.is_none());
        c.wiring = vec![vec![OpSource::Input(1), OpSource::Input(0)]];
        assert!(StagePlan::new(c, 1 << 20).unwrap().1.fused.is_none());
    }

    #[test]
    fn a_lone_depth_takes_the_packed_path_only_for_formats_it_selects_as_bits() {
        let depth = |ill: PixelFormat| {
            let layers = [
                (Layer::Illumination, ill),
                (Layer::Depth, PixelFormat::DepthF32),
            ];
            let mut c = config();
            c.inputs = vec![input("a", &layers), input("b", &layers)];
            c.ops = vec![OpSpec::Depth(DepthParams {
                inputs: 2,
                layers: vec![Layer::Illumination],
                reversed_z: false,
                zero_is_empty: false,
            })];
            c.outputs = layers.to_vec();
            StagePlan::new(c, 1 << 20).unwrap().1
        };
        let ops = depth(PixelFormat::F16x6);
        assert!(ops.depth.is_some() && ops.pipeline.is_some() && ops.fused.is_none());
        // rgb9e5x2 shares an exponent per triple: the select is not a copy of bits.
        assert!(depth(PixelFormat::Rgb9e5x2).depth.is_none());
        assert!(StagePlan::new(config(), 1 << 20).unwrap().1.depth.is_none());
    }

    #[test]
    fn bad_configurations_are_refused_with_their_reason() {
        let mut c = config();
        c.ops[1] = OpSpec::Material(MaterialParams {
            stage: MaterialStage::Ambient,
            ambient_color: Some([0.1, f32::NAN, 0.1]),
            specular: false,
            emissive: false,
        });
        let e = StagePlan::new(c, 1 << 20).unwrap_err();
        assert_eq!(e.code(), ErrorCode::BadConfig);
        assert!(
            e.to_string()
                .contains("ambient_color must be finite and non-negative"),
            "{e}"
        );

        let mut c = config();
        c.inputs[1].layers[0].1 = PixelFormat::F16x4;
        let e = StagePlan::new(c, 1 << 20).unwrap_err();
        assert_eq!(e.code(), ErrorCode::UnsupportedFormat);

        let mut c = config();
        c.inputs.pop();
        let e = StagePlan::new(c, 1 << 20).unwrap_err();
        assert!(matches!(e, ConfigError::Pipeline(_)), "{e}");

        let mut c = config();
        c.inputs[2].layers[0].0 = Layer::Specular;
        let e = StagePlan::new(c, 1 << 20).unwrap_err();
        assert!(
            matches!(
                e,
                ConfigError::Pipeline(PipelineError::MissingLayer {
                    layer: Layer::Diffuse,
                    ..
                })
            ),
            "{e}"
        );

        let mut c = config();
        c.outputs = vec![(Layer::Illumination, PixelFormat::F16x6)];
        let e = StagePlan::new(c, 1 << 20).unwrap_err();
        assert!(matches!(e, ConfigError::OutputNotMade { .. }), "{e}");

        let mut c = config();
        c.inputs[1].peer = "up".into();
        assert!(matches!(
            StagePlan::new(c, 1 << 20).unwrap_err(),
            ConfigError::DuplicatePeer { .. }
        ));

        let e = StagePlan::new(config(), 1000).unwrap_err();
        assert!(matches!(e, ConfigError::BandTooLarge { .. }), "{e}");
    }

    #[test]
    fn a_stage_without_operators_relays_one_input() {
        let mut c = config();
        c.ops.clear();
        c.inputs.truncate(1);
        c.outputs = vec![(Layer::Illumination, PixelFormat::F32x6)];
        let (plan, ops) = StagePlan::new(c, 1 << 20).unwrap();
        assert!(ops.pipeline.is_none() && ops.fused.is_none());
        assert_eq!(plan.produced, vec![Layer::Illumination]);
    }
}
