//! The compositing vocabulary the planner and the compositor share: each operator's typed
//! parameters (`OpSpec`, carried by `CompositorConfig::ops`), their validation, layer names, the
//! link format recommended per kind of link, and the penumbra filter's shape (its largest radius,
//! the halo rows a band needs, the parameters a planned filter gets).
//!
//! One definition of each: the compositor builds its operators from these types and validates
//! them with `OpSpec::validate`, and the coordinator plans with the same facts, so neither copies
//! the other and the coordinator does not depend on the compositor.
//!
//! The parameters travel in the control messages' bincode encoding; in human-readable formats
//! (the compositor's JSON parameters and pipeline files, `lightfold plan --json`) a layer is its
//! lowercase name and a node colour an RGB triple or `{diffuse, specular}`.

use crate::format::PixelFormat;
use crate::message::Layer;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// Most inputs one operator may declare (`inputs` of `depth` and `join`, entries of
/// `accumulate`'s colours and `merge`'s inputs): far above any stage, and a bound on what a
/// signature allocates for a configuration from the network.
pub const MAX_OP_INPUTS: usize = 4096;

/// Why an operator's parameters are refused: the operator's registry name and the reason.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("operator {op}: bad parameters: {reason}")]
pub struct ParamError {
    pub op: &'static str,
    pub reason: String,
}

/// One operator of a compositor stage with its parameters (`CompositorConfig::ops`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum OpSpec {
    Accumulate(AccumulateParams),
    Material(MaterialParams),
    Depth(DepthParams),
    Join(JoinParams),
    Merge(MergeParams),
    Output(OutputParams),
    Penumbra(PenumbraParams),
    Blend(BlendParams),
}

/// Every operator's registry name, in `OpSpec` order.
pub const OP_NAMES: [&str; 8] = [
    "accumulate",
    "material",
    "depth",
    "join",
    "merge",
    "output",
    "penumbra",
    "blend",
];

impl OpSpec {
    /// The operator's registry name.
    pub fn name(&self) -> &'static str {
        match self {
            OpSpec::Accumulate(_) => AccumulateParams::NAME,
            OpSpec::Material(_) => MaterialParams::NAME,
            OpSpec::Depth(_) => DepthParams::NAME,
            OpSpec::Join(_) => JoinParams::NAME,
            OpSpec::Merge(_) => MergeParams::NAME,
            OpSpec::Output(_) => OutputParams::NAME,
            OpSpec::Penumbra(_) => PenumbraParams::NAME,
            OpSpec::Blend(_) => BlendParams::NAME,
        }
    }

    /// Checks the parameters' ranges and consistency (finite, non-negative colours, radii,
    /// input counts, …): what the compositor refuses a configuration for.
    pub fn validate(&self) -> Result<(), ParamError> {
        match self {
            OpSpec::Accumulate(p) => p.validate(),
            OpSpec::Material(p) => p.validate(),
            OpSpec::Depth(p) => p.validate(),
            OpSpec::Join(p) => p.validate(),
            OpSpec::Merge(p) => p.validate(),
            OpSpec::Output(p) => p.validate(),
            OpSpec::Penumbra(p) => p.validate(),
            OpSpec::Blend(p) => p.validate(),
        }
    }
}

fn bad(op: &'static str, reason: String) -> ParamError {
    ParamError { op, reason }
}

/// A colour parameter must be finite and non-negative: it multiplies sanitised values, and a
/// negative or NaN factor would break the operators' never-NaN, never-negative policy.
pub fn check_rgb(op: &'static str, what: &str, rgb: [f32; 3]) -> Result<(), ParamError> {
    if rgb.iter().all(|c| c.is_finite() && *c >= 0.0) {
        Ok(())
    } else {
        Err(bad(
            op,
            format!("{what} must be finite and non-negative, got {rgb:?}"),
        ))
    }
}

fn check_inputs(op: &'static str, what: &str, n: usize) -> Result<(), ParamError> {
    if n > MAX_OP_INPUTS {
        return Err(bad(
            op,
            format!("{what} lists {n} inputs, at most {MAX_OP_INPUTS}"),
        ));
    }
    Ok(())
}

// ----- layers by name -----

/// The lowercase name of a layer, as pipeline files and parameters spell it.
pub fn layer_name(layer: Layer) -> &'static str {
    match layer {
        Layer::Illumination => "illumination",
        Layer::Diffuse => "diffuse",
        Layer::Specular => "specular",
        Layer::Ambient => "ambient",
        Layer::Emissive => "emissive",
        Layer::Depth => "depth",
        Layer::Radiance => "radiance",
        Layer::AmbientMask => "ambient_mask",
        Layer::Transmittance => "transmittance",
    }
}

/// A layer by its lowercase name.
pub fn layer_from_name(name: &str) -> Option<Layer> {
    Layer::ALL.into_iter().find(|l| layer_name(*l) == name)
}

/// A layer in operator parameters: its lowercase name in human-readable formats, the `Layer`
/// enum's own encoding in bincode.
mod by_name {
    use super::*;

    pub(super) struct Named(pub Layer);

    impl Serialize for Named {
        fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
            if s.is_human_readable() {
                s.serialize_str(layer_name(self.0))
            } else {
                self.0.serialize(s)
            }
        }
    }

    impl<'de> Deserialize<'de> for Named {
        fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            if d.is_human_readable() {
                let s = String::deserialize(d)?;
                layer_from_name(&s)
                    .map(Named)
                    .ok_or_else(|| serde::de::Error::custom(format!("unknown layer {s:?}")))
            } else {
                Layer::deserialize(d).map(Named)
            }
        }
    }

    pub(super) fn ser<S: Serializer>(l: &Layer, s: S) -> Result<S::Ok, S::Error> {
        Named(*l).serialize(s)
    }

    pub(super) fn de<'de, D: Deserializer<'de>>(d: D) -> Result<Layer, D::Error> {
        Named::deserialize(d).map(|n| n.0)
    }

    pub(super) fn ser_vec<S: Serializer>(ls: &[Layer], s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(ls.iter().map(|l| Named(*l)))
    }

    pub(super) fn de_vec<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<Layer>, D::Error> {
        let v: Vec<Named> = Deserialize::deserialize(d)?;
        Ok(v.into_iter().map(|n| n.0).collect())
    }

    pub(super) fn ser_vecs<S: Serializer>(ls: &[Vec<Layer>], s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(
            ls.iter()
                .map(|v| v.iter().map(|l| Named(*l)).collect::<Vec<_>>()),
        )
    }

    pub(super) fn de_vecs<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<Vec<Layer>>, D::Error> {
        let v: Vec<Vec<Named>> = Deserialize::deserialize(d)?;
        Ok(v.into_iter()
            .map(|v| v.into_iter().map(|n| n.0).collect())
            .collect())
    }
}

// ----- accumulate -----

/// A node's light colour: one colour for diffuse and specular, or the paper's separate pair.
/// Human-readable formats write `[r, g, b]` or `{"diffuse": …, "specular": …}`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum NodeColor {
    Rgb([f32; 3]),
    Split {
        diffuse: [f32; 3],
        specular: [f32; 3],
    },
}

impl NodeColor {
    /// (diffuse, specular) colour.
    pub fn pair(self) -> ([f32; 3], [f32; 3]) {
        match self {
            NodeColor::Rgb(c) => (c, c),
            NodeColor::Split { diffuse, specular } => (diffuse, specular),
        }
    }
}

/// `NodeColor` in human-readable formats: told apart by shape.
#[derive(Serialize, Deserialize)]
#[serde(untagged)]
enum UntaggedColor {
    Rgb([f32; 3]),
    Split {
        diffuse: [f32; 3],
        specular: [f32; 3],
    },
}

/// `NodeColor` in bincode: tagged by variant.
#[derive(Serialize, Deserialize)]
enum TaggedColor {
    Rgb([f32; 3]),
    Split {
        diffuse: [f32; 3],
        specular: [f32; 3],
    },
}

impl Serialize for NodeColor {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match (*self, s.is_human_readable()) {
            (NodeColor::Rgb(c), true) => UntaggedColor::Rgb(c).serialize(s),
            (NodeColor::Split { diffuse, specular }, true) => {
                UntaggedColor::Split { diffuse, specular }.serialize(s)
            }
            (NodeColor::Rgb(c), false) => TaggedColor::Rgb(c).serialize(s),
            (NodeColor::Split { diffuse, specular }, false) => {
                TaggedColor::Split { diffuse, specular }.serialize(s)
            }
        }
    }
}

impl<'de> Deserialize<'de> for NodeColor {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        Ok(if d.is_human_readable() {
            match UntaggedColor::deserialize(d)? {
                UntaggedColor::Rgb(c) => NodeColor::Rgb(c),
                UntaggedColor::Split { diffuse, specular } => {
                    NodeColor::Split { diffuse, specular }
                }
            }
        } else {
            match TaggedColor::deserialize(d)? {
                TaggedColor::Rgb(c) => NodeColor::Rgb(c),
                TaggedColor::Split { diffuse, specular } => NodeColor::Split { diffuse, specular },
            }
        })
    }
}

/// Where eq. 7's `I^a` comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AmbientMask {
    /// `I^a = 1` at every pixel.
    #[default]
    Uniform,
    /// `I^a` per pixel and channel from the `ambient_mask` layer (`Layer::AmbientMask`) of the
    /// folding input (eq. 7).
    Layer,
}

/// The eq. 6 folding: input `input` (a local node whose `c_n^d` is the ambient colour) adds
/// `c_n^d ⊙ I^a` to the diffuse sum.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AmbientFold {
    pub input: u32,
    #[serde(default)]
    pub mask: AmbientMask,
}

fn yes() -> bool {
    true
}

/// `accumulate`: `p_n = p_{n−1} + c_n ⊙ I_n` over an optional upstream sum and local nodes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AccumulateParams {
    /// `c_n` of each local input, in input order.
    pub colors: Vec<NodeColor>,
    /// Whether input 0 is the upstream partial sum.
    #[serde(default = "yes")]
    pub upstream: bool,
    /// Eq. 4's uniform `m^s`.
    #[serde(default)]
    pub specular_color: Option<[f32; 3]>,
    #[serde(default)]
    pub ambient: Option<AmbientFold>,
}

impl AccumulateParams {
    pub const NAME: &'static str = "accumulate";

    /// Local input `j`'s input index.
    pub fn input_of(&self, j: usize) -> usize {
        j + usize::from(self.upstream)
    }

    pub fn validate(&self) -> Result<(), ParamError> {
        let op = Self::NAME;
        if self.colors.is_empty() {
            return Err(bad(op, "colors must list at least one local node".into()));
        }
        check_inputs(op, "colors", self.colors.len())?;
        check_rgb(
            op,
            "specular_color",
            self.specular_color.unwrap_or([1.0; 3]),
        )?;
        let first = usize::from(self.upstream);
        for (j, color) in self.colors.iter().enumerate() {
            let (cd, cs) = color.pair();
            check_rgb(op, &format!("diffuse colour of input {}", first + j), cd)?;
            check_rgb(op, &format!("specular colour of input {}", first + j), cs)?;
        }
        if let Some(a) = self.ambient
            && !(first..first + self.colors.len()).contains(&(a.input as usize))
        {
            return Err(bad(
                op,
                format!("ambient.input {} is not a local node input", a.input),
            ));
        }
        Ok(())
    }
}

// ----- material -----

/// Which material node a `material` operator is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MaterialStage {
    Specular,
    Diffuse,
    Ambient,
    Emissive,
    Single,
}

/// `material`: a material node turning the illumination sum into radiance.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialParams {
    pub stage: MaterialStage,
    /// `c^a`: required by `ambient`, optional for `single`.
    #[serde(default)]
    pub ambient_color: Option<[f32; 3]>,
    /// `single` only: multiply the specular sum by an `m^s` layer (false: eq. 4 pre-multiplied).
    #[serde(default)]
    pub specular: bool,
    /// `single` only: add an emissive layer.
    #[serde(default)]
    pub emissive: bool,
}

impl MaterialParams {
    pub const NAME: &'static str = "material";

    pub fn validate(&self) -> Result<(), ParamError> {
        let op = Self::NAME;
        if self.stage != MaterialStage::Single && (self.specular || self.emissive) {
            return Err(bad(
                op,
                "specular and emissive flags belong to the single stage".into(),
            ));
        }
        match (self.stage, self.ambient_color) {
            (MaterialStage::Ambient, None) => {
                Err(bad(op, "the ambient stage needs ambient_color".into()))
            }
            (MaterialStage::Ambient | MaterialStage::Single, Some(ca)) => {
                check_rgb(op, "ambient_color", ca)
            }
            (_, Some(_)) => Err(bad(
                op,
                "ambient_color belongs to the ambient or single stage".into(),
            )),
            _ => Ok(()),
        }
    }
}

// ----- depth -----

fn illumination() -> Layer {
    Layer::Illumination
}

fn illumination_only() -> Vec<Layer> {
    vec![Layer::Illumination]
}

/// `depth`: nearest-z select of sort-last compositing.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DepthParams {
    pub inputs: u32,
    /// Colour layers carried with the depth.
    #[serde(
        default = "illumination_only",
        serialize_with = "by_name::ser_vec",
        deserialize_with = "by_name::de_vec"
    )]
    pub layers: Vec<Layer>,
    #[serde(default)]
    pub reversed_z: bool,
    /// Linear depth where 0 marks an empty pixel (a node's eye depth).
    #[serde(default)]
    pub zero_is_empty: bool,
}

impl DepthParams {
    pub const NAME: &'static str = "depth";

    pub fn validate(&self) -> Result<(), ParamError> {
        let op = Self::NAME;
        if self.inputs == 0 {
            return Err(bad(op, "inputs must be at least 1".into()));
        }
        check_inputs(op, "inputs", self.inputs as usize)?;
        for (i, l) in self.layers.iter().enumerate() {
            if *l == Layer::Depth || self.layers[..i].contains(l) {
                return Err(bad(
                    op,
                    format!("layers lists {l:?} twice or carries depth"),
                ));
            }
        }
        if self.reversed_z && self.zero_is_empty {
            return Err(bad(
                op,
                "zero_is_empty reads linear depth: it excludes reversed_z".into(),
            ));
        }
        Ok(())
    }
}

// ----- join -----

/// `join`: N inputs of one layer summed into one, in input-index order.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JoinParams {
    pub inputs: u32,
    #[serde(
        default = "illumination",
        serialize_with = "by_name::ser",
        deserialize_with = "by_name::de"
    )]
    pub layer: Layer,
}

impl JoinParams {
    pub const NAME: &'static str = "join";

    pub fn validate(&self) -> Result<(), ParamError> {
        let op = Self::NAME;
        if self.inputs == 0 {
            return Err(bad(op, "inputs must be at least 1".into()));
        }
        check_inputs(op, "inputs", self.inputs as usize)?;
        if self.layer == Layer::Depth {
            return Err(bad(
                op,
                "depth cannot be summed; use the depth operator".into(),
            ));
        }
        Ok(())
    }
}

// ----- blend -----

/// `blend`: premultiplied "over" with a per-channel transmittance, back to front. Input 0 is
/// the back (`radiance`); inputs 1.. each give a layer in front of everything before it
/// (`radiance`, premultiplied by its coverage, and `transmittance`), the last the nearest:
/// `out = R_0`, then for each front input i in order `out = R_i + T_i ⊙ out`. A scalar alpha's
/// "over" is `T = 1 − α` in every channel.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BlendParams {
    /// Inputs in all: the back and the layers in front of it (at least 2).
    pub inputs: u32,
}

impl BlendParams {
    pub const NAME: &'static str = "blend";

    pub fn validate(&self) -> Result<(), ParamError> {
        let op = Self::NAME;
        if self.inputs < 2 {
            return Err(bad(
                op,
                format!(
                    "inputs must be at least 2 (a back and a layer over it), got {}",
                    self.inputs
                ),
            ));
        }
        check_inputs(op, "inputs", self.inputs as usize)
    }
}

// ----- merge -----

/// `merge`: layers of several inputs put together into one stream; input i gives `inputs[i]`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MergeParams {
    /// Per input, the layers it gives.
    #[serde(
        serialize_with = "by_name::ser_vecs",
        deserialize_with = "by_name::de_vecs"
    )]
    pub inputs: Vec<Vec<Layer>>,
}

impl MergeParams {
    pub const NAME: &'static str = "merge";

    pub fn validate(&self) -> Result<(), ParamError> {
        let op = Self::NAME;
        if self.inputs.is_empty() {
            return Err(bad(op, "inputs must name at least one input".into()));
        }
        check_inputs(op, "inputs", self.inputs.len())?;
        let mut seen: Vec<Layer> = Vec::new();
        for (i, layers) in self.inputs.iter().enumerate() {
            if layers.is_empty() {
                return Err(bad(op, format!("input {i} gives no layer")));
            }
            for &l in layers {
                if seen.contains(&l) {
                    return Err(bad(
                        op,
                        format!("layer {} comes from two inputs", layer_name(l)),
                    ));
                }
                seen.push(l);
            }
        }
        Ok(())
    }
}

// ----- output -----

fn one() -> f32 {
    1.0
}

/// `output`: the sink's last step (linear radiance; the exposure of its sRGB encoding).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputParams {
    #[serde(default = "one")]
    pub exposure: f32,
}

impl Default for OutputParams {
    fn default() -> Self {
        OutputParams { exposure: 1.0 }
    }
}

impl OutputParams {
    pub const NAME: &'static str = "output";

    pub fn validate(&self) -> Result<(), ParamError> {
        if !(self.exposure.is_finite() && self.exposure >= 0.0) {
            return Err(bad(
                Self::NAME,
                format!(
                    "exposure must be finite and non-negative, got {}",
                    self.exposure
                ),
            ));
        }
        Ok(())
    }
}

// ----- penumbra -----

/// Largest penumbra radius accepted: a 17×17 window.
pub const PENUMBRA_MAX_RADIUS: u32 = 8;
/// Default penumbra radius: seed 003's 7×7 window.
pub const PENUMBRA_DEFAULT_RADIUS: u32 = 3;
/// Default tolerance on the penumbra filter's plane prediction, relative to the pixel's inverse
/// depth.
pub const PENUMBRA_DEFAULT_DEPTH_TOLERANCE: f32 = 0.002;
/// The crease a planned penumbra filter stops at: taps on a face whose plane differs from the
/// pixel's by this much, as the camera sees it, weigh nothing; by half as much or less, fully
/// (`crease_tolerance`).
pub const CREASE_DEG: f32 = 12.0;

/// `crease_tolerance` for a pinhole camera of vertical field of view `fov_y_deg` over `height`
/// pixels: tan([`CREASE_DEG`]) over the focal length in pixels. A plane with camera-space normal
/// n has 1/z = (n·(u/f, v/f, 1))/k, so its relative slope per pixel g/(1/z) is
/// (n_x, n_y)/(f·n·ray): two faces of a crease differ there by about tan(angle)/f.
pub fn crease_tolerance(fov_y_deg: f32, height: u32) -> f32 {
    let focal = 0.5 * height.max(1) as f32 / (0.5 * fov_y_deg.to_radians()).tan();
    CREASE_DEG.to_radians().tan() / focal
}

/// Rows of each neighbouring band a band needs for a penumbra filter of `radius` to give the
/// whole frame's values: the radius, and at least the two rows a pixel's slope is read from; with
/// the crease test (`crease`), two more, for the slopes of the taps `radius` rows away.
pub fn halo_rows(radius: u32, crease: bool) -> u32 {
    if crease { radius + 2 } else { radius.max(2) }
}

/// How a penumbra window's taps are weighted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Kernel {
    /// Every tap alike (seed 003's average).
    Box,
    /// `(r + 1 − |dx|)·(r + 1 − |dy|)`: a quarter of the box's blur for the same window, so it
    /// smooths the steps between samples with less loss of the penumbra's own shape (the
    /// default: it measured closer to the truth on `balls`, docs/accuracy/).
    #[default]
    Tent,
}

fn default_radius() -> u32 {
    PENUMBRA_DEFAULT_RADIUS
}

fn default_tolerance() -> f32 {
    PENUMBRA_DEFAULT_DEPTH_TOLERANCE
}

/// `penumbra`: the screen-space penumbra filter over the illumination sum.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PenumbraParams {
    /// Pixels per row of the bands the operator sees (the image width).
    pub width: u32,
    #[serde(default = "default_radius")]
    pub radius: u32,
    #[serde(default = "default_tolerance")]
    pub depth_tolerance: f32,
    /// Largest difference of relative slope (per pixel, of 1/z over 1/z) between a pixel and a
    /// tap on its plane ([`crease_tolerance`]). `None`: no crease test (the plane prediction
    /// alone).
    #[serde(default)]
    pub crease_tolerance: Option<f32>,
    /// Filter the specular channels too.
    #[serde(default)]
    pub specular: bool,
    #[serde(default)]
    pub kernel: Kernel,
}

impl PenumbraParams {
    pub const NAME: &'static str = "penumbra";

    /// The parameters a planned filter of `radius` gets for a `width × height` image seen with a
    /// vertical field of view of `fov_y_deg`: the crease test at [`crease_tolerance`] of that
    /// camera, defaults otherwise.
    pub fn planned(width: u32, height: u32, radius: u32, fov_y_deg: f32) -> PenumbraParams {
        PenumbraParams {
            width,
            radius,
            depth_tolerance: PENUMBRA_DEFAULT_DEPTH_TOLERANCE,
            crease_tolerance: Some(crease_tolerance(fov_y_deg, height)),
            specular: false,
            kernel: Kernel::default(),
        }
    }

    /// Rows of each neighbouring band a band needs ([`halo_rows`]).
    pub fn halo(&self) -> u32 {
        halo_rows(self.radius, self.crease_tolerance.is_some())
    }

    pub fn validate(&self) -> Result<(), ParamError> {
        let op = Self::NAME;
        if self.width == 0 {
            return Err(bad(op, "width must be at least 1".into()));
        }
        if !(1..=PENUMBRA_MAX_RADIUS).contains(&self.radius) {
            return Err(bad(
                op,
                format!(
                    "radius must be in 1..={PENUMBRA_MAX_RADIUS}, got {}",
                    self.radius
                ),
            ));
        }
        if !(self.depth_tolerance.is_finite() && self.depth_tolerance > 0.0) {
            return Err(bad(
                op,
                format!(
                    "depth_tolerance must be finite and positive, got {}",
                    self.depth_tolerance
                ),
            ));
        }
        if let Some(t) = self.crease_tolerance
            && !(t.is_finite() && t > 0.0)
        {
            return Err(bad(
                op,
                format!("crease_tolerance must be finite and positive, got {t}"),
            ));
        }
        Ok(())
    }
}

// ----- links -----

/// The kinds of pixel links in a cluster.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LinkKind {
    /// A render node's illumination band into its compositor (packed once, unpacked once).
    NodeToCompositor,
    /// A partial sum from one compositor to the next (re-packed at every hop of a chain).
    CompositorToCompositor,
    /// The sink compositor's final radiance to the coordinator.
    SinkToCoordinator,
}

/// The link format the planner should choose by default (docs/precision.md):
/// - node → compositor: `rgb9e5x2`. One quantisation per node; HDR range at 8 bytes a pixel with
///   a relative error of at most 2^-9 of each triple's largest channel, and no scale to plan.
/// - compositor → compositor: `f16x6`. It keeps 1e4 : 1 HDR and dark content over a 32-hop chain
///   (RMS error under 1e-3, nothing saturated, no dark pixel lost); `seed64` at a fixed scale
///   saturates the highlights and zeroes the darks, and `rgb9e5x2` re-quantised at every hop loses
///   the dim channel of a coloured triple.
/// - sink → coordinator: `f32x3`, the final radiance in full precision (EXR holds it as is).
pub fn recommended_link_format(hop: LinkKind) -> PixelFormat {
    match hop {
        LinkKind::NodeToCompositor => PixelFormat::Rgb9e5x2,
        LinkKind::CompositorToCompositor => PixelFormat::F16x6,
        LinkKind::SinkToCoordinator => PixelFormat::F32x3,
    }
}
