//! What a frame is asked for and what it returns: render options (shadow filter, bias, walkthrough,
//! deliberate faults), the set of layers, the frame's images and per-phase statistics, and the
//! renderer's errors.

use super::lights::Fault;
use lightfold_scene::shading::{MaterialLayers, compose_frame};
use lightfold_scene::{Image, MapSizing, Quality, ShadowFilter};

/// How a renderer draws shadows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderOptions {
    /// Every map's side under [`MapSizing::Fixed`]; the side of a light the mismatch rule finds
    /// nothing lit for under [`MapSizing::Mismatch`].
    pub shadow_map_size: u32,
    /// How each light's maps are sized (`Quality::map_sizing`).
    pub map_sizing: MapSizing,
    pub filter: ShadowFilter,
    /// Constant bias in metres along the light ray.
    pub depth_bias: f32,
    /// Slope-scaled bias, in texel footprints of the filter kernel per unit of `tan θ`.
    pub slope_bias: f32,
    /// Keep shadow maps between frames while lights and casters do not change. The maps then
    /// cover every receiver, as the camera may move (see `Renderer::set_fit_to_camera`).
    pub walkthrough: bool,
    /// Triangles per chunk of a large mesh, the unit the eye and shadow passes cull
    /// ([`crate::gpu::scene_data::CHUNK_TRIANGLES`]; 0: every mesh whole).
    pub chunk_triangles: u32,
    /// Draw opaque meshes' chunks in shadow views at a simplified level whose error fits half a
    /// texel there (`gpu::lod`; the default).
    pub shadow_lod: bool,
    /// Draw opaque chunks in the eye pass at their lossless level where they have one: coplanar
    /// runs of a finely divided flat surface merged, nothing that moves a position, normal or
    /// UV (`gpu::lod`; the default).
    pub eye_lod: bool,
    /// A deliberate mistake for negative-control tests.
    pub fault: Option<Fault>,
}

impl RenderOptions {
    /// Every map `side`², whatever the scene's sizing.
    pub fn fixed_maps(self, side: u32) -> RenderOptions {
        RenderOptions {
            shadow_map_size: side,
            map_sizing: MapSizing::Fixed,
            ..self
        }
    }

    pub fn from_quality(q: &Quality) -> RenderOptions {
        RenderOptions {
            shadow_map_size: q.shadow_map_size,
            map_sizing: q.map_sizing,
            filter: q.filter,
            depth_bias: q.depth_bias,
            slope_bias: q.slope_bias,
            walkthrough: false,
            chunk_triangles: super::scene_data::CHUNK_TRIANGLES,
            shadow_lod: true,
            eye_lod: true,
            fault: None,
        }
    }
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions::from_quality(&Quality::default())
    }
}

/// How the eye pass lights pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum EyeVariant {
    /// One raster that lights every fragment it shades (a little faster for K = 1).
    Forward,
    /// A G-buffer raster, then one compute pass lights each pixel once: the default, 20–25 %
    /// faster than forward for K ≥ 4 on lavapipe (`docs/gpu.md`).
    #[default]
    Deferred,
}

/// Which layers a frame produces.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LayerSet {
    pub illumination: bool,
    pub diffuse: bool,
    pub specular: bool,
    pub ambient: bool,
    pub emissive: bool,
    pub depth: bool,
    /// Eq. 7's `I^a = m^a ⊘ m^d` (`Layer::AmbientMask`), computed from the m^d and m^a targets
    /// after the eye pass (`gpu::ambient_mask`).
    pub ambient_mask: bool,
    /// A translucent eye layer's transmittance `T` (`Layer::Transmittance`), rendered by a
    /// renderer peeling a translucent layer (`Renderer::set_peel` with d ≥ 1).
    pub transmittance: bool,
}

impl LayerSet {
    /// Illumination only (an illumination node's usual job).
    pub fn illumination() -> LayerSet {
        LayerSet {
            illumination: true,
            ..Default::default()
        }
    }

    /// Illumination, the material layers of eq. 2 and depth: what a whole frame's radiance
    /// needs ([`NodeFrame::radiance`]). Not eq. 7's mask, which only a folding node sends.
    pub fn all() -> LayerSet {
        LayerSet {
            illumination: true,
            diffuse: true,
            specular: true,
            ambient: true,
            emissive: true,
            depth: true,
            ambient_mask: false,
            transmittance: false,
        }
    }

    /// The set holding `layers` (radiance is never a node's and is ignored).
    pub fn of(layers: impl IntoIterator<Item = lightfold_protocol::Layer>) -> LayerSet {
        use lightfold_protocol::Layer;
        let mut set = LayerSet::default();
        for l in layers {
            match l {
                Layer::Illumination => set.illumination = true,
                Layer::Diffuse => set.diffuse = true,
                Layer::Specular => set.specular = true,
                Layer::Ambient => set.ambient = true,
                Layer::Emissive => set.emissive = true,
                Layer::Depth => set.depth = true,
                Layer::AmbientMask => set.ambient_mask = true,
                Layer::Transmittance => set.transmittance = true,
                Layer::Radiance => {}
            }
        }
        set
    }

    pub(crate) fn any_material(&self) -> bool {
        self.diffuse || self.specular || self.ambient || self.emissive || self.ambient_mask
    }
}

/// What one frame of a node produced.
#[derive(Debug, Clone, PartialEq)]
pub struct NodeFrame {
    /// 6 channels: diffuse RGB then specular RGB.
    pub illumination: Option<Image>,
    /// 3 channels each: m^d (texture applied), m^s, m^a, e.
    pub diffuse: Option<Image>,
    pub specular: Option<Image>,
    pub ambient: Option<Image>,
    pub emissive: Option<Image>,
    /// 3 channels: eq. 7's `I^a = m^a ⊘ m^d` per channel (1 where `m^a = m^d`, 0 where either is
    /// 0).
    pub ambient_mask: Option<Image>,
    /// 1 channel: eye-space distance along the camera's forward axis, 0 for background.
    pub depth: Option<Image>,
    /// 3 channels: a peeled translucent layer's eye transmittance `T` (1 where the layer has no
    /// surface); the material layers of such a frame are premultiplied by its eye coverage.
    pub transmittance: Option<Image>,
    pub stats: RenderStats,
}

/// Counters and wall-clock time per phase (each phase waits for the device).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RenderStats {
    /// Depth passes rendered this frame (0 when walkthrough mode reused the maps).
    pub shadow_passes: u32,
    /// Lights whose maps walkthrough mode kept from the previous frame.
    pub maps_kept: u32,
    /// Posing an animated scene at the frame's time and uploading its vertices, microseconds.
    pub pose_us: u64,
    /// Views (maps) each light needs, whether or not they were re-rendered.
    pub passes_per_light: Vec<u32>,
    /// Side of each view's map, in view order (lights in order, each light's views in order).
    pub map_sides: Vec<u32>,
    /// Maps halved to keep the frame's maps within the device's shadow budget.
    pub maps_halved: u32,
    /// Views whose transmittance maps were rendered this frame (their lights have translucent
    /// casters; `docs/translucency.md`).
    pub transmit_passes: u32,
    /// Vertices the shadow passes drew this frame (opaque and masked casters), and those of them
    /// from simplified levels (`gpu::lod`).
    pub shadow_vertices: u64,
    pub shadow_lod_vertices: u64,
    /// CPU work of the frame before its first pass: checks, light planning, map keys.
    pub setup_us: u64,
    pub shadow_us: u64,
    pub eye_us: u64,
    /// Reading the frame back: the f32 readback, or the device pack and its readback.
    pub readback_us: u64,
    /// Bytes copied from the device to the host for the frame.
    pub read_bytes: u64,
}

#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error("{requested} lights requested, this device takes at most {maximum}")]
    TooManyLights { requested: usize, maximum: u32 },
    #[error("{views} shadow views needed, the device has {maximum} texture-array layers")]
    TooManyViews { views: usize, maximum: u32 },
    #[error("shadow map size {size} outside 1..={maximum}")]
    ShadowMapSize { size: u32, maximum: u32 },
    #[error("image {width}x{height} outside 1..={maximum} per side")]
    ImageSize {
        width: u32,
        height: u32,
        maximum: u32,
    },
    #[error("caster lists given for {given} lights, frame has {lights}")]
    Casters { lights: usize, given: usize },
    #[error("{what} takes {bytes} bytes, binding limit is {maximum}")]
    BindingTooLarge {
        what: &'static str,
        bytes: u64,
        maximum: u64,
    },
    #[error("the device cannot allocate {what}: {message}")]
    Allocation { what: &'static str, message: String },
    #[error("rows {y0}..{y1} are not a tile of the {height}-row image (need y0 < y1 <= {height})")]
    Rows { y0: u32, y1: u32, height: u32 },
    #[error("peel {peel} is deeper than a renderer peels (at most {maximum})")]
    PeelTooDeep { peel: u32, maximum: u32 },
    #[error("gpu: {0}")]
    Gpu(String),
}

/// Checks a sort-first tile, image rows `[y0, y1)` of an image `height` rows tall: at least one
/// row, none below the image.
pub fn check_rows([y0, y1]: [u32; 2], height: u32) -> Result<(), RenderError> {
    if y0 < y1 && y1 <= height {
        Ok(())
    } else {
        Err(RenderError::Rows { y0, y1, height })
    }
}

/// A material layer [`NodeFrame::radiance`] needs was not rendered.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("the {0} layer was not rendered")]
pub struct MissingLayer(pub &'static str);

impl NodeFrame {
    /// Paper eq. 2 from this frame's material layers and `illumination` (6 channels, summed over
    /// every node with `c_n` white): `e + m^a⊙c^a + m^d⊙I^d + m^s⊙I^s`, the global ambient `c^a`
    /// only where there is a surface (depth 0 is background); [`compose_frame`].
    pub fn radiance(&self, illumination: &Image, ambient: [f32; 3]) -> Result<Image, MissingLayer> {
        fn layer<'a>(
            img: &'a Option<Image>,
            name: &'static str,
        ) -> Result<&'a Image, MissingLayer> {
            img.as_ref().ok_or(MissingLayer(name))
        }
        let (md, ms, ma, e) = (
            layer(&self.diffuse, "m^d")?,
            layer(&self.specular, "m^s")?,
            layer(&self.ambient, "m^a")?,
            layer(&self.emissive, "e")?,
        );
        let depth = layer(&self.depth, "depth")?;
        let m = MaterialLayers {
            diffuse: md,
            specular: ms,
            ambient: ma,
            emissive: e,
        };
        let covered = |i: usize| depth.data[i] > 0.0;
        Ok(compose_frame(illumination, [1.0; 3], m, ambient, covered))
    }
}
