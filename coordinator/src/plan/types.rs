//! The planner's inputs (cluster, options) and its output, the `Plan`: plain data, serialisable,
//! printed by `Display` in `display.rs`.

use lightfold_protocol::{Capabilities, Layer, PixelFormat};
use lightfold_scene::{Camera, LightSample, ShadowFilter};
use serde::{Deserialize, Serialize};

/// One daemon the planner may use: its id, the address it was dialled at, and what it reported.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DaemonSpec {
    pub id: String,
    pub address: String,
    pub capabilities: Option<Capabilities>,
}

impl DaemonSpec {
    /// The address other daemons dial for data: the advertised one when reported. A daemon bound
    /// to a wildcard address (`0.0.0.0:7300`, `[::]:7300`) without `--advertise` reports that
    /// wildcard, which no other host can dial: its host is replaced by the host the coordinator
    /// reached the daemon at, keeping the advertised port.
    pub fn data_address(&self) -> String {
        let advertised = match &self.capabilities {
            Some(c) if !c.advertise.is_empty() => &c.advertise,
            _ => return self.address.clone(),
        };
        match advertised.parse::<std::net::SocketAddr>() {
            Ok(a) if a.ip().is_unspecified() => match host_of(&self.address) {
                Some(host) if host.contains(':') => format!("[{host}]:{}", a.port()),
                Some(host) => format!("{host}:{}", a.port()),
                None => advertised.clone(),
            },
            _ => advertised.clone(),
        }
    }
}

/// The host part of `host:port` or `[v6]:port`, without brackets.
fn host_of(address: &str) -> Option<&str> {
    let (host, port) = address.rsplit_once(':')?;
    port.parse::<u16>().ok()?;
    let host = host
        .strip_prefix('[')
        .and_then(|h| h.strip_suffix(']'))
        .unwrap_or(host);
    (!host.is_empty()).then_some(host)
}

/// The daemons available to a plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClusterSpec {
    pub nodes: Vec<DaemonSpec>,
    pub compositors: Vec<DaemonSpec>,
    /// The coordinator's data address, where the sink compositor sends final bands.
    pub sink: String,
}

impl ClusterSpec {
    /// A synthetic cluster of local daemons without capabilities (for `lightfold plan` and tests):
    /// `node-i` at `127.0.0.1:7300+i`, `comp-j` at `127.0.0.1:7500+j`, sink `127.0.0.1:7400`.
    pub fn local(nodes: usize, compositors: usize) -> ClusterSpec {
        let spec = |prefix: &str, base: usize, i: usize| DaemonSpec {
            id: format!("{prefix}-{i}"),
            address: format!("127.0.0.1:{}", base + i),
            capabilities: None,
        };
        ClusterSpec {
            nodes: (0..nodes).map(|i| spec("node", 7300, i)).collect(),
            compositors: (0..compositors).map(|i| spec("comp", 7500, i)).collect(),
            sink: "127.0.0.1:7400".to_string(),
        }
    }

    /// The cluster a cluster file names (ids `node-i`, `comp-j` where it gives none), its
    /// daemons not yet asked what they are.
    pub fn from_file(file: &crate::cluster::ClusterFile) -> ClusterSpec {
        let spec = |prefix: &str, entries: &[crate::cluster::DaemonEntry]| {
            entries
                .iter()
                .enumerate()
                .map(|(i, e)| DaemonSpec {
                    id: e.id.clone().unwrap_or_else(|| format!("{prefix}-{i}")),
                    address: e.address.clone(),
                    capabilities: None,
                })
                .collect()
        };
        ClusterSpec {
            nodes: spec("node", &file.nodes),
            compositors: spec("comp", &file.compositors),
            sink: file
                .sink_advertise
                .clone()
                .unwrap_or_else(|| file.sink_listen.clone()),
        }
    }

    /// Every render node reporting a device that takes at most `max_lights` lights and
    /// `memory_bytes` of memory (0: unknown), nothing measured — what a real node reports at
    /// registration (the planner raises K only up to it). `replace`: also over what a node
    /// reports already.
    pub fn with_synthetic_nodes(
        mut self,
        max_lights: u32,
        memory_bytes: u64,
        replace: bool,
    ) -> Self {
        for n in &mut self.nodes {
            if replace || n.capabilities.is_none() {
                n.capabilities = Some(Capabilities {
                    max_lights,
                    memory_bytes,
                    ..Capabilities::unmeasured(lightfold_protocol::Role::Node, &n.id)
                });
            }
        }
        self
    }
}

/// How compositor stages are connected.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
pub enum Topology {
    /// A linear pipeline like the paper's: each stage adds its nodes to the upstream sum.
    #[default]
    Chain,
    /// Leaf stages accumulate nodes; stages above join pairs of partial sums.
    Tree,
    /// The planner chooses: a tree where a chain would have [`AUTO_TREE_STAGES`] stages or more
    /// (there the tree's fewer hops gave the lower latency: `docs/scaling.md`), else a chain.
    /// Plans record what was chosen.
    Auto,
}

/// The fewest chain stages at which [`Topology::Auto`] builds a tree instead. Measured with
/// `harness/examples/scale_out.rs` (`docs/scaling.md`): the tree's latency was lower at 8, 16 and
/// 32 nodes, the chain's at 4.
pub const AUTO_TREE_STAGES: usize = 8;

impl Topology {
    /// `Auto` resolved for a plan of `nodes` render nodes on `compositors` compositors.
    pub fn resolve(self, nodes: usize, compositors: usize) -> Topology {
        match self {
            Topology::Auto if nodes.min(compositors) >= AUTO_TREE_STAGES => Topology::Tree,
            Topology::Auto => Topology::Chain,
            t => t,
        }
    }
}

impl std::str::FromStr for Topology {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "chain" => Ok(Topology::Chain),
            "tree" => Ok(Topology::Tree),
            "auto" => Ok(Topology::Auto),
            other => Err(format!("unknown topology {other:?} (chain, tree or auto)")),
        }
    }
}

impl std::fmt::Display for Topology {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Topology::Chain => "chain",
            Topology::Tree => "tree",
            Topology::Auto => "auto",
        })
    }
}

/// Pixel formats per kind of link (ARCHITECTURE §7).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct FormatChoice {
    /// Illumination node → compositor.
    pub node: PixelFormat,
    /// Compositor → compositor (accumulated illumination).
    pub chain: PixelFormat,
    /// Sink compositor → coordinator (final radiance).
    pub sink: PixelFormat,
    /// Material colours `m^d`, `m^s`, `m^a` in [0, 1] (a layer whose every value 8-bit sRGB
    /// holds exactly travels as `rgba8srgb` instead: `plan/material.rs`).
    pub material: PixelFormat,
    /// Material layers that may exceed 1 (emissive radiance, colours above 1).
    pub material_hdr: PixelFormat,
}

impl Default for FormatChoice {
    /// Link formats from the compositor's precision study (`docs/precision.md`); material layers
    /// as half floats, the format nodes render them in (`Rgba16Float` targets), so they arrive
    /// exactly as `lightfold render` multiplies them. 8-bit sRGB scaled a constant colour by up
    /// to 0.8 % (0.5 grey: ×1.0058), a bias of the whole image that `render` does not have.
    fn default() -> Self {
        use lightfold_protocol::pipeline::{LinkKind, recommended_link_format};
        FormatChoice {
            node: recommended_link_format(LinkKind::NodeToCompositor),
            chain: recommended_link_format(LinkKind::CompositorToCompositor),
            sink: recommended_link_format(LinkKind::SinkToCoordinator),
            material: PixelFormat::F16x4,
            material_hdr: PixelFormat::F16x4,
        }
    }
}

/// How shadow-map sizes are chosen.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub enum MapSizing {
    /// The scene's own rule (`Quality::map_sizing`: by default each light's maps from the
    /// mismatch factor, `Quality::shadow_map_size` for every map when the scene fixes it): what
    /// `lightfold render` uses, so the cluster and `render` agree by default.
    #[default]
    Scene,
    /// From the eye/light resolution mismatch factor `m` (seed 002): the power of two in
    /// `[min, max]` nearest (in log₂) to the size giving `m = target` at the median lit point.
    Mismatch { min: u32, max: u32, target: f32 },
    /// The same size for every map.
    Fixed(u32),
}

impl MapSizing {
    /// `--shadow-map-size`: the size asked for, else the scene's.
    pub fn from_request(requested: Option<u32>) -> MapSizing {
        requested.map_or(MapSizing::Scene, MapSizing::Fixed)
    }

    /// The one rule `lightfold render` and the planner share: the size every shadow map gets,
    /// or `None` where the mismatch factor sizes each light's maps.
    pub fn uniform_size(self, quality: &lightfold_scene::Quality) -> Option<u32> {
        match self.resolve(quality) {
            MapSizing::Fixed(n) => Some(n),
            _ => None,
        }
    }

    /// `Scene` replaced by the scene's rule (what the per-light sizing in `plan/shadow.rs`
    /// reads): its fixed size, or its mismatch bounds and target.
    pub fn resolve(self, quality: &lightfold_scene::Quality) -> MapSizing {
        match (self, quality.map_sizing) {
            (MapSizing::Scene, lightfold_scene::MapSizing::Fixed) => {
                MapSizing::Fixed(quality.shadow_map_size)
            }
            (MapSizing::Scene, lightfold_scene::MapSizing::Mismatch(m)) => MapSizing::Mismatch {
                min: m.min,
                max: m.max,
                target: m.target,
            },
            (other, _) => other,
        }
    }

    /// The mismatch rule with its default bounds and target (opt-in, through `PlanOptions`).
    pub fn mismatch() -> MapSizing {
        MapSizing::Mismatch {
            min: MIN_MAP_SIZE,
            max: MAX_MAP_SIZE,
            target: DEFAULT_TARGET_MISMATCH,
        }
    }
}

/// What the planner learned about the cluster and the scene, apart from what a user asks for
/// (the rest of [`PlanOptions`]): the live loop and calibration set it, never a flag.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Learned {
    /// Multiplies every node's cost model: its fixed cost per frame and its cost per light (1:
    /// as the nodes registered them, or the defaults). The live loop sets both from measured
    /// frames under a frame budget (`control::Live`, `docs/planner.md` § Frame budgets), so the
    /// budget is met by what frames take.
    pub cost_scale: CostScale,
    /// The error model the target and the budget's concessions read: a calibration of the
    /// planned scene (`lightfold calibrate`, `lightfold_quality::calibrate`), or `None` for the
    /// default scene's sweep ([`super::ErrorModel::balls`]).
    pub error_model: Option<super::ErrorModel>,
}

/// What the planner is asked for, and what it learned ([`Learned`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanOptions {
    /// Lights per node, the paper's K (raised up to the device limit when nodes are short).
    pub lights_per_node: u32,
    pub topology: Topology,
    /// Budget on the radiance (exposure-scaled, 1 = display white) that culled samples may add to
    /// any pixel in total; 0 drops only samples that provably add nothing.
    pub epsilon: f32,
    /// No culling: every sample, every material stage, every caster, full cube maps.
    pub force_all: bool,
    pub band_height: u32,
    pub formats: FormatChoice,
    pub epoch: u64,
    pub walkthrough: bool,
    pub map_sizing: MapSizing,
    /// Frames each compositor input buffers before backpressure.
    pub frames_in_flight: u32,
    /// Render the material layers on a node of their own (the paper's layout, one more eye
    /// pass) even where they could be extra targets of an illumination node at the last stage.
    #[serde(default)]
    pub material_own_node: bool,
    /// A frame-time budget (µs, by the nodes' cost model): K becomes the largest that keeps the
    /// slowest node within it, so the plan uses as few nodes as the budget allows (K from
    /// `lights_per_node` is then ignored). When no K fits, quality is lowered step by step
    /// (`plan/budget.rs`: map sizes, samples per area light, ε) and `Plan::concessions` says
    /// what was given up; the fastest estimate, over the budget, when nothing more helps.
    #[serde(default)]
    pub frame_budget_us: Option<u64>,
    /// Antialiasing (`--aa N`): the control loop (`control::Live`) plans and renders the scene at
    /// N × its camera's width and height, and the coordinator's sink box-resolves every N × N
    /// block of the final radiance (after the material stage) as a frame completes, so frames
    /// are delivered at the camera's size. 1 (the default) renders one sample per pixel; the
    /// planner itself (`plan()`) plans the camera it is given.
    #[serde(default = "one")]
    pub supersample: u32,
    /// An error target (`--target-psnr`, penumbra PSNR in dB against the area-light truth): the
    /// area lights' sample counts are halved or doubled to the fewest the planner's error model
    /// expects to reach it (`plan/budget.rs`); a frame budget may then lower them further.
    #[serde(default)]
    pub target_penumbra_db: Option<f32>,
    /// What the planner learned rather than what it was asked: the nodes' measured cost and the
    /// scene's error model ([`Learned`]).
    #[serde(default)]
    pub learned: Learned,
    /// The screen-space penumbra filter (`--penumbra-filter`, the compositor's `penumbra`
    /// operator): the last stage filters the illumination sum before the material multiply,
    /// with the eye depth the material layers' node adds (`depth32`); bands are raised to at
    /// least the filter's halo. `Plan::penumbra_radius` is what was chosen.
    #[serde(default)]
    pub penumbra_filter: PenumbraFilter,
    /// Sort-last partitions (`--partitions P`, `docs/planner.md` § Partitions): the meshes are
    /// split into P spatially coherent parts (`scene::partition`), every light group is rendered
    /// once per part by a node drawing only that part's eye pass (shadows still from every
    /// caster), and the stages depth-compose the parts. 1 draws the whole scene on every node;
    /// 0 (the default) chooses: more than 1 only when the scene's geometry would not fit the
    /// memory the nodes reported (`plan::partitions_for`).
    #[serde(default)]
    pub partitions: u32,
    /// Sort-first tiles (`--tiles T`, `docs/planner.md` § Tiles): the image is split into T
    /// bands of rows, every light group is rendered once per tile by a node drawing only those
    /// rows (every mesh, or with partitions its part's, with those meshes' shadow maps), and the
    /// stages put the tiles together as they depth-compose sort-last parts (a tile's node leaves
    /// the other rows empty). The coordinator moves the rows between tiles from the nodes'
    /// measured eye passes (`control::tiles`). 1: no tiles; 0 (the default) chooses by the cost
    /// model (`plan/decompose.rs`): the tile count whose estimated frame is at least
    /// [`TILES_MIN_GAIN`] shorter than the untiled one (with the partitions resolved).
    #[serde(default)]
    pub tiles: u32,
    /// Peeled translucency (`--peels`, `docs/translucency.md` § Peeled layers): the eye sees
    /// the scene's translucent surfaces as D layers in front of the opaque one, each rendered
    /// and lit by its own light groups and blended back to front at the stages. Off (the
    /// default): glass is seen through and only tints (the classic eye pass).
    #[serde(default)]
    pub peels: Peels,
    /// Plan nodes that share one GPU (`Capabilities::device`) as one node per device with
    /// their lights together, when the cost model says that is faster (`plan/shared.rs`).
    pub merge_shared_devices: bool,
}

/// When the planner adds the screen-space penumbra filter, and its radius.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PenumbraFilter {
    /// Never.
    Off,
    /// Where a frame budget or an error target lowers the samples per area light below the
    /// scene's, at the radius the error model expects to give back the most
    /// (`budget::filter_radius`); otherwise the scene renders as it asks.
    #[default]
    Budget,
    /// At every sample count where the error model expects a gain (16 or fewer samples per area
    /// light on the sweep it was fitted to), at its radius.
    Auto,
    /// This radius (1 to 8), always.
    Radius(u32),
}

fn one() -> u32 {
    1
}

/// Factors on the nodes' registered cost model (`PlanOptions::cost_scale`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CostScale {
    pub fixed: f64,
    pub light: f64,
}

impl Default for CostScale {
    fn default() -> Self {
        CostScale {
            fixed: 1.0,
            light: 1.0,
        }
    }
}

impl CostScale {
    /// Both parts × `k`.
    pub fn uniform(k: f64) -> CostScale {
        CostScale { fixed: k, light: k }
    }
}

/// Default ε: about a quarter of one 8-bit sRGB code value at mid-grey (a step there is ≈ 4e-3
/// linear), so culling cannot move a PNG pixel of a lit surface by a visible amount.
pub const DEFAULT_EPSILON: f32 = 1e-3;
/// Default band height in rows.
pub const DEFAULT_BAND_HEIGHT: u32 = 32;
/// Shadow-map size bounds and the size used when the mismatch factor has nothing to measure.
pub const MIN_MAP_SIZE: u32 = 256;
/// The shared limit of every input (`lightfold_scene::limits`).
pub const MAX_MAP_SIZE: u32 = lightfold_scene::limits::MAX_SHADOW_MAP_SIZE;
pub const DEFAULT_MAP_SIZE: u32 = 512;
/// Default target mismatch: a shadow texel may span two image pixels. The bilinear 2×2 PCF lookup
/// turns a texel step into a ramp one texel wide, so this blurs an edge over at most two pixels —
/// far less than the penumbra of an area light sampled by many points — instead of stair steps.
pub const DEFAULT_TARGET_MISMATCH: f32 = 2.0;

impl Default for PlanOptions {
    fn default() -> Self {
        PlanOptions {
            lights_per_node: lightfold_scene::defaults::LIGHTS_PER_NODE,
            topology: Topology::Chain,
            epsilon: DEFAULT_EPSILON,
            force_all: false,
            band_height: DEFAULT_BAND_HEIGHT,
            formats: FormatChoice::default(),
            epoch: 1,
            walkthrough: false,
            map_sizing: MapSizing::Scene,
            frames_in_flight: 2,
            material_own_node: false,
            frame_budget_us: None,
            supersample: 1,
            target_penumbra_db: None,
            learned: Learned::default(),
            penumbra_filter: PenumbraFilter::Budget,
            partitions: 0,
            tiles: 0,
            peels: Peels::Off,
            merge_shared_devices: true,
        }
    }
}

/// Most translucent layers a plan peels (`Peels`): each takes as many render nodes as the
/// opaque layer.
pub const MAX_PEELS: u32 = 4;

/// How many translucent eye layers a plan peels (`PlanOptions::peels`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Peels {
    /// None: filters tint what lies behind them, coverage surfaces are cut-outs.
    #[default]
    Off,
    /// The scene's depth complexity in view (the most translucent surfaces in front of an
    /// opaque one along any eye ray of a coarse grid), capped at [`MAX_PEELS`]; none where no
    /// translucent surface is in view.
    Auto,
    /// This many (1 to [`MAX_PEELS`]).
    Layers(u32),
}

/// What a plan peeled, and why (`Plan::peels`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PeelChoice {
    /// Translucent layers peeled (each a cell of light groups: `NodePlan::peel`).
    pub layers: u32,
    /// The most translucent surfaces in front of an opaque one the planner found along an eye
    /// ray (`None` where the count was asked for, not measured).
    pub depth_complexity: Option<u32>,
    /// The choice in words, as `lightfold plan` prints it.
    pub why: String,
}

/// Why a sample is not rendered.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum DropReason {
    /// Zero intensity, zero colour or a degenerate direction: it emits nothing.
    ZeroEmission,
    /// A non-finite intensity, colour, position or direction (shading yields zero or garbage).
    NonFinite,
    /// No geometry is in view.
    NoVisibleReceiver,
    /// Every visible receiver is beyond its range, outside its cone or behind its lobe.
    Unreached {
        out_of_range: u32,
        outside_cone: u32,
        behind: u32,
    },
    /// Its contribution to any pixel is at most `bound` (exposure-scaled radiance), within ε.
    BelowEpsilon { bound: f32 },
}

/// The shadow geometry of one light, as `scene::shadow_views` fits it to the receivers (the node
/// makes the same call, so these are the passes it renders).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum ShadowViews {
    /// The sample reaches no receiver: no map.
    None,
    /// `count` perspective frusta fitted to the receivers (two when one would be too wide),
    /// the widest `fov_deg` across its wider side.
    Frustum { count: u8, fov_deg: f32 },
    /// One orthographic view (directional light).
    Ortho,
    /// Cube-map faces in the sample's frame (+Z its axis), bit i for face i in the order
    /// +X, −X, +Y, −Y, +Z, −Z.
    Cube { faces: u8 },
    /// `cascades` near frusta, each fitted to a slice of the eye depths the camera sees
    /// (`scene::shadow_views::camera_views`), then `base` views fitted to all it sees.
    Cascaded { cascades: u8, base: u8 },
}

impl ShadowViews {
    /// Shadow passes this geometry costs.
    pub fn count(&self) -> usize {
        match self {
            ShadowViews::None => 0,
            ShadowViews::Frustum { count, .. } => *count as usize,
            ShadowViews::Ortho => 1,
            ShadowViews::Cube { faces } => faces.count_ones() as usize,
            ShadowViews::Cascaded { cascades, base } => *cascades as usize + *base as usize,
        }
    }
}

/// The shadow map of one light.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShadowPlan {
    pub views: ShadowViews,
    pub map_size: u32,
    /// Mesh indices drawn into the map.
    pub casters: Vec<u32>,
    /// Whether the light also gets transmittance maps: some of its casters are translucent
    /// (`docs/translucency.md`). The node decides the same from the casters and the scene.
    #[serde(default)]
    pub transmittance: bool,
}

/// One render node's work.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NodePlan {
    pub node: String,
    /// Indices into `Plan::samples`.
    pub lights: Vec<usize>,
    /// The node colour `c_n` applied by `accumulate` (the node emits `Σ (c_λ ⊘ c_n)·i·s`).
    pub color: [f32; 3],
    /// One per light, in the order of `lights`.
    pub shadows: Vec<ShadowPlan>,
    pub layers: Vec<(Layer, PixelFormat)>,
    /// The compositor stage this node streams to, and its input index there.
    pub downstream: String,
    pub input_index: u32,
    pub est_cost_us: u64,
    /// The sort-last part whose eye pass this node draws (an index into `Plan::partitions`);
    /// `None`: the whole scene.
    #[serde(default)]
    pub part: Option<usize>,
    /// The sort-first tile whose rows this node draws (an index into `Plan::tiles`); `None`:
    /// every row.
    #[serde(default)]
    pub tile: Option<usize>,
    /// Peeled translucency: the eye layer this node renders (`NodeConfig::peel`: 0 the opaque
    /// layer, d ≥ 1 the d-th translucent surface in front of it); `None` without peeling.
    #[serde(default)]
    pub peel: Option<u32>,
    /// The content hash of the scene this node is sent when it is not the plan's (a sort-last
    /// node gets only what it draws: `scene::partition::keep_meshes`); set by the control loop.
    #[serde(default)]
    pub scene: Option<[u8; 32]>,
}

/// Where an input of a stage comes from.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum Source {
    Node(String),
    Stage(String),
}

/// One input of a stage, in input-index order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InputRef {
    pub source: Source,
    pub layers: Vec<(Layer, PixelFormat)>,
}

/// Where a stage sends its output.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum Downstream {
    Stage(String),
    Sink,
}

/// One compositor stage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StagePlan {
    pub compositor: String,
    /// Operators in order, with their typed parameters (`CompositorConfig::ops`).
    pub ops: Vec<lightfold_protocol::OpSpec>,
    /// Per operator, where each input comes from; empty: the fold (`CompositorConfig::wiring`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub wiring: Vec<Vec<lightfold_protocol::OpSource>>,
    pub inputs: Vec<InputRef>,
    pub outputs: Vec<(Layer, PixelFormat)>,
    pub downstream: Downstream,
    /// This stage's input index at its downstream stage (0 for the sink).
    pub input_index: u32,
}

/// How the material equation is evaluated (paper §3).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum MaterialMode {
    /// Eq. 4–5: one specular colour for every visible material, pre-multiplied in `accumulate`;
    /// the material stage computes `E + A⊙c^a + D⊙p^d + p^s` with the layers present.
    UniformSpecular { specular: [f32; 3] },
    /// A specular layer travels and the material stage multiplies it.
    General,
}

/// Where the material layers are rendered.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum MaterialPlacement {
    /// No material layer is needed (nothing visible).
    None,
    /// Extra render targets of this illumination node.
    ExtraTargets { node: String },
    /// Sort-last partitions: extra render targets of each part's first node, which also sends
    /// its part's eye depth (in part order).
    PerPart { nodes: Vec<String> },
    /// A node of its own (one eye pass, no shadows).
    OwnNode { node: String },
}

/// Which material layers exist and how the final stage combines them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MaterialPlan {
    pub mode: MaterialMode,
    pub layers: Vec<(Layer, PixelFormat)>,
    /// Global ambient `c^a`.
    pub ambient: [f32; 3],
    /// Eq. 6–7: `c^a` is added to the diffuse sum in `accumulate` (every visible material has
    /// `m^a = m^d`, or eq. 7's mask reproduces `m^a`), so no ambient layer travels.
    pub fold_ambient: bool,
    /// Eq. 7: the folding node renders the ambient mask `I^a` (`Layer::AmbientMask`) and sends
    /// it in this format; `None` with eq. 6 (`I^a = 1`) or no fold.
    #[serde(default)]
    pub ambient_mask: Option<PixelFormat>,
    pub placement: MaterialPlacement,
    /// Why each layer is present or absent, for the printout.
    pub notes: Vec<String>,
}

/// One data link and its cost.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LinkPlan {
    pub from: String,
    /// Daemon id of the consumer, or `"sink"`.
    pub to: String,
    pub address: String,
    pub layers: Vec<(Layer, PixelFormat)>,
    /// Pixel bytes plus band headers for one full frame.
    pub bytes_per_frame: u64,
}

/// One step of accuracy a plan gave up to meet its frame budget (`plan/budget.rs`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Concession {
    pub knob: Knob,
    /// The knob's setting before and after the step, as printed (`16`, `8`; `512²–2048²`).
    pub from: String,
    pub to: String,
    /// The plan's estimated frame time after the step (µs).
    pub est_frame_us: u64,
    /// Expected change of penumbra PSNR against the area-light truth by the planner's error
    /// model (dB, ≤ 0; `None` where the model has no figure: ε's loss is a bound instead).
    pub expected_db: Option<f32>,
}

/// The sample count an error target chose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TargetChoice {
    /// The target, penumbra PSNR (dB) against the area-light truth.
    pub target_db: f32,
    /// Largest samples per area light before and after.
    pub from: u32,
    pub to: u32,
    /// The error model's penumbra PSNR at `to` (`ErrorModel`).
    pub expected_db: f32,
    /// Whether the model expects the target at all (else `to` is the most its sweep measured,
    /// 256, or the scene's own count when that is more).
    pub reachable: bool,
    /// The penumbra filter's radius the model's figure assumes (0: none).
    #[serde(default)]
    pub penumbra_radius: u32,
    /// The mismatch rule's smallest shadow map as the target raised it (0: unchanged).
    #[serde(default)]
    pub map_floor: u32,
    /// Whether the target chose the cell filter (`ShadowFilter::Cell`) for the nodes.
    #[serde(default)]
    pub cell_filter: bool,
    /// Whether the figure comes from a calibration of this scene (else the default scene's
    /// sweep, whose level other scenes do not share).
    #[serde(default)]
    pub calibrated: bool,
    /// Area lights raised above `to` for the glossy highlights they light (`plan::gloss`).
    #[serde(default)]
    pub gloss: Vec<super::gloss::GlossRaise>,
}

/// The quality knobs a frame budget can lower, in the order the planner lowers them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Knob {
    /// The largest shadow map the mismatch rule may give, halved down to its floor (or a larger
    /// fixed size halved down to the default).
    ShadowMaps,
    /// Point samples per area light, halved down to one.
    SamplesPerAreaLight,
    /// ε, the radiance culled samples may add to a pixel, ×4 up to `budget::MAX_EPSILON`: the
    /// least important samples (by their bound on what the camera sees) are dropped.
    Epsilon,
}

/// Render nodes sharing devices, planned as one node per device (`plan/shared.rs`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct SharedDevices {
    /// Devices two or more nodes reported, and those nodes.
    pub devices: usize,
    pub nodes: usize,
    /// K of the ordinary plan, and the most of its nodes one device would have run.
    pub k_separate: u32,
    pub stacked: u32,
    /// The ordinary plan's estimate with a device's nodes one after another, microseconds.
    pub est_separate_us: u64,
}

/// Render nodes sharing one machine's CPU (software rasterisers), estimated one after another
/// (`plan/cpu_hosts.rs`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct CpuShared {
    /// Machines whose CPU two or more of the plan's nodes render on, and those nodes.
    pub machines: usize,
    pub nodes: usize,
    /// The slowest node's own estimate, microseconds (the frame's, were they on separate machines).
    pub est_slowest_node_us: u64,
}

/// Everything the cluster does for one scene and view.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    /// The penumbra filter's radius at the last stage (0: none), as `PlanOptions::penumbra_filter`
    /// and the budget resolved it.
    #[serde(default)]
    pub penumbra_radius: u32,
    pub epoch: u64,
    pub scene_hash: [u8; 32],
    pub scene_name: String,
    pub width: u32,
    pub height: u32,
    pub band_height: u32,
    pub camera: Camera,
    pub exposure: f32,
    pub topology: Topology,
    /// Lights per node actually used (K, or raised when nodes are short).
    pub k: u32,
    /// Every sample of the scene, with stable indices.
    pub samples: Vec<LightSample>,
    pub active: Vec<usize>,
    pub dropped: Vec<(usize, DropReason)>,
    pub epsilon: f32,
    /// Sum of the bounds of samples dropped under ε (≤ ε).
    pub epsilon_used: f32,
    pub nodes: Vec<NodePlan>,
    /// Nodes of the cluster the plan leaves idle.
    pub idle_nodes: Vec<String>,
    pub stages: Vec<StagePlan>,
    pub material: MaterialPlan,
    pub links: Vec<LinkPlan>,
    pub sink: String,
    pub walkthrough: bool,
    pub frames_in_flight: u32,
    /// Shadow lookup settings from the scene's quality options.
    pub filter: ShadowFilter,
    pub depth_bias: f32,
    pub slope_bias: f32,
    /// Estimated frame time: the slowest node.
    pub est_frame_us: u64,
    /// The frame budget the plan was asked to meet (`PlanOptions::frame_budget_us`).
    #[serde(default)]
    pub frame_budget_us: Option<u64>,
    /// What the plan gave up to meet its frame budget, in the order given up (empty without a
    /// budget, or when the requested quality fits it; `plan/budget.rs`).
    #[serde(default)]
    pub concessions: Vec<Concession>,
    /// How an error target set the samples per area light (`PlanOptions::target_penumbra_db`).
    #[serde(default)]
    pub target: Option<TargetChoice>,
    /// Data addresses of the daemons the plan uses, by id.
    pub addresses: Vec<(String, String)>,
    /// The sort-last parts (mesh indices, ascending) when the plan partitions the scene; empty
    /// when every node draws it whole.
    #[serde(default)]
    pub partitions: Vec<Vec<u32>>,
    /// The sort-first tiles (image rows `[y0, y1)`, top to bottom, covering every row once)
    /// when the plan tiles the image; empty otherwise. `NodePlan::part` indexes these then.
    /// The rows the plan starts with: the coordinator balances them frame by frame.
    #[serde(default)]
    pub tiles: Vec<[u32; 2]>,
    /// Set when nodes sharing a device are planned as one node per device.
    #[serde(default)]
    pub shared_devices: Option<SharedDevices>,
    /// Nodes rendering on one machine's CPU, whose frames the estimate adds up.
    #[serde(default)]
    pub cpu_shared: Option<CpuShared>,
    /// How the planner chose between sort-first tiles and an untiled image, when it chose
    /// (`PlanOptions::tiles` 0); `None` when the options fixed it.
    #[serde(default)]
    pub decomposition: Option<Decomposition>,
    /// Peeled translucency: how many translucent layers the plan peels and why (`None`: not
    /// peeled).
    #[serde(default)]
    pub peels: Option<PeelChoice>,
}

/// The share by which a tiled plan's estimated frame must beat the untiled one for an automatic
/// plan to tile: what the cost model leaves out (compositing more streams, the balancer's first
/// frames before the rows fit the content) is not worth a smaller gain.
pub const TILES_MIN_GAIN: f64 = 0.1;

/// An automatic plan's choice between sort-first tiles and an untiled image (`plan/decompose.rs`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Decomposition {
    /// Every tile count planned (1: untiled), in that order, with what its plan estimated.
    pub candidates: Vec<TileCandidate>,
    /// The choice in words, as `lightfold plan` prints it.
    pub why: String,
}

/// One tile count an automatic plan weighed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TileCandidate {
    pub tiles: u32,
    /// The plan's estimated frame: the slowest node, or the nodes one machine's CPU or one
    /// shared GPU runs, one after another.
    pub est_frame_us: u64,
    /// Accuracy steps its frame budget gave up (fewer wins before a shorter frame).
    pub concessions: usize,
    /// Render nodes it uses.
    pub nodes: usize,
}

#[cfg(test)]
mod tests {
    use super::DaemonSpec;
    use lightfold_protocol::{Capabilities, Role};

    fn spec(dialled: &str, advertise: &str) -> DaemonSpec {
        DaemonSpec {
            id: "node-0".into(),
            address: dialled.into(),
            capabilities: Some(Capabilities {
                advertise: advertise.into(),
                max_lights: 16,
                max_texture_size: 4096,
                threads: 1,
                ..Capabilities::unmeasured(Role::Node, "node-0")
            }),
        }
    }

    #[test]
    fn wildcard_advertisements_take_the_dialled_host() {
        let cases = [
            (
                "render-3.lightfold:7300",
                "0.0.0.0:7301",
                "render-3.lightfold:7301",
            ),
            ("10.0.0.7:7300", "[::]:7300", "10.0.0.7:7300"),
            ("[fd00::7]:7300", "0.0.0.0:7300", "[fd00::7]:7300"),
            (
                "10.0.0.7:7300",
                "node-a.example:7300",
                "node-a.example:7300",
            ),
            ("10.0.0.7:7300", "192.168.1.4:7300", "192.168.1.4:7300"),
            ("10.0.0.7:7300", "", "10.0.0.7:7300"),
        ];
        for (dialled, advertised, want) in cases {
            assert_eq!(
                spec(dialled, advertised).data_address(),
                want,
                "{advertised}"
            );
        }
    }
}
