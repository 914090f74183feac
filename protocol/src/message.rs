//! Control messages (serde + bincode 2.x with an explicit size limit; ARCHITECTURE §6).
//!
//! The coordinator dials every daemon; after the handshake the daemon sends `Register`, the
//! coordinator sends the scene (by content hash, in chunks) and a configuration, then drives frames.
//! Types here are plain data: the `scene` crate's types are mirrored as `Wire*` so this crate stays
//! free of scene loading.

use serde::{Deserialize, Serialize};

/// A content hash (SHA-256) naming a scene blob.
pub type Hash = [u8; 32];

/// Which part of the cluster a peer is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Role {
    Coordinator,
    Node,
    Compositor,
    Viewer,
}

/// The image layers that travel between processes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum Layer {
    /// Diffuse RGB + specular RGB illumination (`I^d`, `I^s`), six channels.
    Illumination,
    /// `m^d`, three channels.
    Diffuse,
    /// `m^s`, three channels.
    Specular,
    /// `m^a`, three channels.
    Ambient,
    /// `e`, three channels.
    Emissive,
    /// Eye depth, one channel.
    Depth,
    /// Final radiance RGB (after the material stage), three channels.
    Radiance,
    /// Eq. 7's per-pixel ambient mask `I^a = m^a ⊘ m^d`, three channels: per channel 1 where
    /// `m^a = m^d`, 0 where `m^a` or `m^d` is 0, their ratio elsewhere. `accumulate` reads it
    /// from its folding input (`AmbientMask::Layer`).
    AmbientMask,
    /// A translucent eye layer's transmittance `T` for the eye (`docs/translucency.md` § Peeled
    /// layers), three channels in [0, 1]: what of the light behind the layer passes through
    /// it. `blend` reads it beside the layer's radiance.
    Transmittance,
}

impl Layer {
    pub const ALL: [Layer; 9] = [
        Layer::Illumination,
        Layer::Diffuse,
        Layer::Specular,
        Layer::Ambient,
        Layer::Emissive,
        Layer::Depth,
        Layer::Radiance,
        Layer::AmbientMask,
        Layer::Transmittance,
    ];

    /// f32 channels per pixel of this layer in memory.
    pub fn channels(self) -> usize {
        match self {
            Layer::Illumination => 6,
            Layer::Depth => 1,
            _ => 3,
        }
    }
}

/// The image size render nodes calibrate at: `Capabilities::cost_per_light_us` and
/// `fixed_cost_us` are measured at it, and the planner scales them to a plan's size.
pub const CALIBRATION_SIZE: (u32, u32) = (320, 240);

/// What a daemon can do, reported when it registers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Capabilities {
    pub role: Role,
    pub daemon_id: String,
    /// The address other daemons should dial for data links.
    pub advertise: String,
    /// Adapter name and backend, empty for compositors.
    pub adapter: String,
    pub backend: String,
    /// The hardware device a render node renders on, as `host/bus-or-ids/adapter`: nodes that
    /// report the same one share a GPU (their device work runs one after another), and the
    /// planner may give one of them all their lights (`docs/planner.md`). Empty: unknown, a
    /// compositor, or a software rasteriser (whose "device" is the CPU cores the processes share
    /// anyway).
    pub device: String,
    /// The machine whose CPU cores a software-rasterising render node renders on: the kernel's
    /// boot id, which every process, network namespace and container on one machine shares.
    /// Nodes that report the same one share those cores, so their frames run one after another
    /// as far as the planner's cost model is concerned (`docs/planner.md` § Nodes sharing a
    /// machine's CPU). Empty: a GPU node, a compositor, or unknown.
    pub cpu_host: String,
    /// Largest K the device supports (0 for compositors).
    pub max_lights: u32,
    pub max_texture_size: u32,
    pub formats: Vec<crate::format::PixelFormat>,
    /// Measured cost of one light (shadow pass + share of the eye pass) at `CALIBRATION_SIZE`,
    /// microseconds; 0 unknown.
    pub cost_per_light_us: u64,
    /// Measured fixed cost of a frame (eye pass, readback) at `CALIBRATION_SIZE`, microseconds;
    /// 0 unknown.
    pub fixed_cost_us: u64,
    pub threads: u32,
    pub version: String,
    /// Memory a render node can give a scene and its maps, bytes (the machine's, or its
    /// container's limit, or what the node was told); 0 unknown, and for compositors. The
    /// planner partitions scenes too large for it (`docs/planner.md` § Partitions).
    pub memory_bytes: u64,
    /// Measured cost of the eye pass per triangle drawn, nanoseconds; 0 unknown (and for
    /// compositors). The planner partitions a scene whose eye pass alone would not fit a frame
    /// budget (`docs/planner.md` § Partitions).
    pub eye_ns_per_triangle: u64,
}

impl Capabilities {
    /// A daemon of `role` called `daemon_id` that reports nothing else: no advertised address,
    /// adapter, formats or version, and every measured figure 0 (unknown). Callers set what
    /// they know with struct update syntax.
    pub fn unmeasured(role: Role, daemon_id: &str) -> Capabilities {
        Capabilities {
            role,
            daemon_id: daemon_id.to_string(),
            advertise: String::new(),
            adapter: String::new(),
            backend: String::new(),
            device: String::new(),
            cpu_host: String::new(),
            max_lights: 0,
            max_texture_size: 0,
            formats: Vec::new(),
            cost_per_light_us: 0,
            fixed_cost_us: 0,
            threads: 0,
            version: String::new(),
            memory_bytes: 0,
            eye_ns_per_triangle: 0,
        }
    }
}

/// A point-light sample as carried by the plan (mirrors `scene::LightSample`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WireLight {
    pub position: [f32; 3],
    pub direction: [f32; 3],
    /// 0 isotropic, 1 cosine lobe, 2 two-sided lobe, 3 spot, 4 directional, 5 bounce (a
    /// virtual point light of indirect light).
    pub kind: u8,
    /// Spot cosines (outer, inner); for a bounce light, its falloff clamp (metres) and 0; zero
    /// otherwise.
    pub cone: [f32; 2],
    pub intensity: f32,
    pub color: [f32; 3],
    /// Range window; 0 is unbounded.
    pub range: f32,
    /// Source light index.
    pub light: u32,
    /// Index of the sample in the scene's full sample list (stable across plans).
    pub sample: u32,
    /// The area light's shape where glossy specular is integrated over it in closed form.
    pub area: Option<WireArea>,
    /// Width of the sample's cell of its light (metres; radians for a soft sun; 0: no cell), for
    /// the cell filter (protocol version 15).
    pub cell: f32,
}

/// An area light's shape (mirrors `scene::AreaShape`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WireArea {
    /// 0 parallelogram `center ± u ± v`, 1 ellipse `center + cos φ·u + sin φ·v`, 2 sphere of
    /// radius `u[0]` (`v` zero).
    pub kind: u8,
    pub center: [f32; 3],
    pub u: [f32; 3],
    pub v: [f32; 3],
}

/// Camera as carried by frame requests (mirrors `scene::Camera`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WireCamera {
    pub position: [f32; 3],
    pub target: [f32; 3],
    pub up: [f32; 3],
    pub fov_y_deg: f32,
    pub width: u32,
    pub height: u32,
}

/// One shadow-map request for a light: the faces to render and the map size.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WireShadow {
    /// Index into `NodeConfig::lights`.
    pub light: u32,
    pub map_size: u32,
    /// Mesh indices that cast into this light's map (empty: none needed).
    pub casters: Vec<u32>,
}

/// A mesh of the node's scene moved (protocol version 13): its positions are transformed by
/// `matrix` (column-major, world to world), its normals by the inverse transpose
/// (`scene::moves::apply_matrix`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WireMove {
    pub mesh: u32,
    pub matrix: [f32; 16],
}

/// `NodeConfig::filter` at and above this: the cell filter, with `filter − CELL_FILTER` taps
/// per axis.
pub const CELL_FILTER: u32 = 256;

/// A node's configuration for one plan epoch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NodeConfig {
    pub epoch: u64,
    pub scene: Hash,
    pub lights: Vec<WireLight>,
    pub shadows: Vec<WireShadow>,
    /// The node's light colour `c_n`; the node emits `Σ (c_λ ⊘ c_n)·i·s`.
    pub color: [f32; 3],
    /// Layers this node renders and streams (illumination and/or material layers).
    pub layers: Vec<(Layer, crate::format::PixelFormat)>,
    /// Scale for fixed-point formats (per frame; may be updated by `RenderFrame`).
    pub scale: f32,
    pub band_height: u32,
    pub camera: WireCamera,
    /// Keep shadow maps between frames while lights and geometry do not move.
    pub walkthrough: bool,
    /// Where to send bands (a compositor's data address), and this node's input index there.
    pub downstream: String,
    pub input_index: u32,
    /// Shadow filter: 0 none, 1 PCF 2×2, n in 2..=15 an n×n grid of 2×2 lookups,
    /// [`CELL_FILTER`] + n the cell filter with n×n taps (protocol version 15).
    pub filter: u32,
    pub depth_bias: f32,
    pub slope_bias: f32,
    /// The meshes this node draws in its eye pass, a sort-last part of the scene (protocol
    /// version 6); `None`: every mesh. Shadows still come from each light's casters.
    pub eye_meshes: Option<Vec<u32>>,
    /// Meshes moved from where the scene has them (objects a viewer moved in a live session),
    /// each at most once; empty: none. Animated scenes never have any.
    pub moves: Vec<WireMove>,
    /// Sort-first tiles (protocol version 16): the image rows `[y0, y1)` this node renders, a
    /// tile of the image; every other row is empty (no illumination, no material, depth 0:
    /// nothing there) and goes out as empty bands. `None`: every row. `FrameParams::rows` moves
    /// them from one frame on (the coordinator's load balancing).
    pub rows: Option<[u32; 2]>,
    /// Peeled translucency (protocol version 18, `docs/translucency.md` § Peeled layers): which
    /// eye layer this node renders. `None`: the classic eye pass (filters seen through, their
    /// transmittance multiplied into the material layers; coverage surfaces as cut-outs).
    /// `Some(0)`: the opaque layer of a peeled plan (every translucent surface skipped, nothing
    /// multiplied: `blend` applies the layers in front). `Some(d)`, d ≥ 1: the d-th nearest
    /// translucent surface in front of the opaque one, its material layers premultiplied by its
    /// coverage, with its eye transmittance (`Layer::Transmittance`).
    pub peel: Option<u32>,
}

/// One input of a compositor stage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageInput {
    /// Daemon id expected on this input (authenticated in the handshake).
    pub peer: String,
    pub layers: Vec<(Layer, crate::format::PixelFormat)>,
}

/// Where one input of a stage's operator comes from, when a configuration wires its operators
/// explicitly (`CompositorConfig::wiring`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum OpSource {
    /// Stage input `i` (`CompositorConfig::inputs[i]`).
    Input(u32),
    /// The output of an earlier operator `k` (`CompositorConfig::ops[k]`).
    Op(u32),
}

/// A compositor's configuration for one plan epoch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CompositorConfig {
    pub epoch: u64,
    pub width: u32,
    pub height: u32,
    pub band_height: u32,
    /// Inputs in input-index order.
    pub inputs: Vec<StageInput>,
    /// Operators applied in order to each band, each with its typed parameters (protocol version
    /// 14; before, a registry name and JSON parameter text).
    pub ops: Vec<crate::pipeline::OpSpec>,
    /// Per operator, where each of its inputs comes from. Empty: the fold (operator 0 reads the
    /// first stage inputs, each next one the previous output and then the next inputs). Explicit
    /// wiring lets two operators read the same input (a node's illumination into `accumulate`,
    /// its material layers into `material`).
    pub wiring: Vec<Vec<OpSource>>,
    /// Layers and formats this stage emits downstream.
    pub outputs: Vec<(Layer, crate::format::PixelFormat)>,
    /// Downstream address (next compositor or the coordinator's sink listener).
    pub downstream: String,
    pub input_index: u32,
    /// Frames buffered per input before backpressure applies.
    pub frames_in_flight: u32,
}

/// Per-frame parameters: colours and scale change without re-rendering; the scene time poses
/// an animated scene.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameParams {
    /// New node colour `c_n` per compositor input, if changed (compositors apply it).
    pub colors: Vec<(u32, [f32; 3])>,
    pub scale: Option<f32>,
    /// Scene time in seconds: nodes pose their cached copy of an animated scene at it
    /// (`Scene::pose`); `None` is the rest pose.
    pub time: Option<f32>,
    /// Lights in place of configured ones (protocol version 14): an animated scene's virtual
    /// point lights traced again at `time`, or lights a viewer moved where the plan stayed the
    /// same. Each replaces the node's light of the same `sample` index and kind, at most once (a
    /// node checks them); empty: the last frame's.
    pub lights: Vec<WireLight>,
    /// A tiled node's new rows `[y0, y1)` from this frame on (protocol version 16; see
    /// `NodeConfig::rows`); `None`: the last frame's.
    pub rows: Option<[u32; 2]>,
}

/// Per-frame timing a daemon reports back.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct FrameStats {
    pub epoch: u64,
    pub frame: u64,
    pub daemon_id: String,
    /// A node's CPU work of the frame outside its device passes: camera and pose updates,
    /// checks, light planning (microseconds).
    pub setup_us: u64,
    pub shadow_us: u64,
    pub eye_us: u64,
    pub readback_us: u64,
    /// Bytes a node copied from its device to the host for the frame.
    pub read_bytes: u64,
    /// A node rendered this frame while it sent the previous one (the request had arrived).
    pub prefetched: bool,
    pub pack_us: u64,
    pub send_us: u64,
    pub composite_us: u64,
    pub total_us: u64,
    pub shadow_passes: u32,
    /// Lights whose shadow maps were kept from the previous frame (walkthrough mode).
    pub maps_kept: u32,
    /// Posing an animated scene at the frame's time, microseconds.
    pub pose_us: u64,
    pub lights_rendered: Vec<u32>,
    pub bytes_out: u64,
    pub empty_bands: u32,
    pub saturated: u64,
    /// Largest finite value of the illumination a node packed this frame, before packing (0
    /// when it sent none, and from compositors): what the coordinator sets the node's next
    /// `seed64` scale from.
    pub peak: f32,
    /// The scale a node's bands carried this frame (`seed64`'s range; ignored by the other
    /// formats); 0 from compositors.
    pub scale: f32,
    pub peak_rss_bytes: u64,
}

/// Typed error codes that travel in `Message::Error`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ErrorCode {
    UnknownScene,
    UnsupportedFormat,
    UnknownOperator,
    BadConfig,
    BandMismatch,
    RenderFailed,
    Timeout,
    PeerLost,
    Internal,
    /// A `Claim` refused: another coordinator session holds this daemon (pass `take_over`).
    Busy,
    /// Sent to a coordinator whose session another coordinator has taken over.
    TakenOver,
}

/// Every control message.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Message {
    /// Daemon → coordinator, first message after the handshake.
    Register(Capabilities),
    /// Coordinator → node: a scene of this hash and size is next; answer `SceneNeed`.
    SceneOffer {
        hash: Hash,
        size: u64,
    },
    /// Node → coordinator: whether the scene must be sent (false: cached).
    SceneNeed {
        hash: Hash,
        need: bool,
    },
    SceneChunk {
        hash: Hash,
        offset: u64,
        data: Vec<u8>,
        last: bool,
    },
    /// Node → coordinator: the scene is loaded.
    SceneReady {
        hash: Hash,
        triangles: u64,
    },
    ConfigureNode(NodeConfig),
    ConfigureCompositor(CompositorConfig),
    /// Daemon → coordinator: configuration applied.
    Configured {
        epoch: u64,
    },
    /// Coordinator → daemons: render / composite this frame.
    RenderFrame {
        epoch: u64,
        frame: u64,
        camera: Option<WireCamera>,
        params: FrameParams,
    },
    FrameDone(FrameStats),
    /// Daemon → coordinator: something was refused or failed. `epoch` and `frame` say what it is
    /// about — a configuration (`epoch`), a frame of an epoch (both), or the link itself (neither:
    /// a claim, a message the daemon does not take) — so a coordinator never takes the failure
    /// of a frame of an epoch it has left for one of the epoch it runs.
    Error {
        code: ErrorCode,
        message: String,
        epoch: Option<u64>,
        frame: Option<u64>,
    },
    Ping {
        seq: u64,
    },
    Pong {
        seq: u64,
    },
    Shutdown,
    /// Coordinator → daemon, right after `Register`: the coordinator session this control link
    /// belongs to (random per coordinator start). A daemon held by another session's open control
    /// link refuses with `Error { code: Busy }` unless `take_over` is set; then the old session
    /// is told `Error { code: TakenOver }` and closed. A link of the same session (a coordinator
    /// re-dialling a daemon it lost) replaces the old link. Links that never claim (test drivers,
    /// `lightfold bench`) hold nothing.
    Claim {
        session: u64,
        take_over: bool,
    },
    /// Daemon → coordinator: the claim is granted.
    Claimed {
        session: u64,
    },
    /// Coordinator → daemon: the plan of `epoch` leaves this daemon out. It drops what it holds
    /// of earlier epochs — a frame in progress or queued, its data links — and waits, registered,
    /// for a configuration; it answers nothing. (A stage dropped by a re-plan used to wait out its
    /// input deadline on the old epoch's frame.)
    Release {
        epoch: u64,
    },
}

impl Message {
    /// An error about the link itself (neither a configuration nor a frame).
    pub fn error(code: ErrorCode, message: impl Into<String>) -> Message {
        Message::Error {
            code,
            message: message.into(),
            epoch: None,
            frame: None,
        }
    }

    /// An error about the configuration of `epoch`.
    pub fn epoch_error(epoch: u64, code: ErrorCode, message: impl Into<String>) -> Message {
        Message::Error {
            code,
            message: message.into(),
            epoch: Some(epoch),
            frame: None,
        }
    }

    /// An error about `frame` of `epoch`.
    pub fn frame_error(
        epoch: u64,
        frame: u64,
        code: ErrorCode,
        message: impl Into<String>,
    ) -> Message {
        Message::Error {
            code,
            message: message.into(),
            epoch: Some(epoch),
            frame: Some(frame),
        }
    }
}
