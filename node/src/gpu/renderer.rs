//! The renderer of one node: uploads a scene once, then per frame renders the shadow maps of its
//! K light samples and one eye pass that emits `Σ_λ (c_λ ⊘ c_n)·(i^d_λ, i^s_λ)·s_λ`, eye depth and,
//! on request, the material layers; reads them back as `scene::Image`s with per-phase timings.
//! Shadow maps cover the receivers the camera sees; in walkthrough mode they cover every receiver
//! and each light's are kept while that light, its views and every mesh it may draw stay the
//! same, whatever the camera does: an animated scene re-renders only the maps of lights that
//! moved or whose casters moved ([`Renderer::set_meshes`] poses the geometry).

use super::ambient_mask::AmbientMaskPass;
use super::atlas::Slot;
use super::deferred::{DeferredTargets, render_deferred};
use super::device::{Gpu, SHADOW_MEMORY_BUDGET, SHADOW_TEXEL_BYTES, captured};
use super::eye_pass::{
    EyeDraws, EyeInputs, EyeTargets, FLAG_CONVENTIONAL_Z, FLAG_OBJECT_IDS, FLAG_RECEIVER_PLANE,
    GpuFrame, render_eye,
};
use super::frame::{EyeVariant, LayerSet, NodeFrame, RenderError, RenderOptions, RenderStats};
use super::lights::{
    Fault, Fit, LAYERED_TEXEL_BYTES, LightPlan, Sides, TRANSLUCENT_TEXEL_BYTES, plan_lights_within,
};
use super::occlusion::{self, EyeOcclusion, OcclusionPass};
use super::pack::{self, DevicePacker, PackLayer, PackSource, PackedFrame};
use super::peel::PeelPass;
use super::pipelines::{DrawContext, LightSet, Pipelines};
use super::readback::{ReadRequest, ReadRows, ReadSource, Staging, read};
use super::scene_data::{SceneData, Vertex};
use super::shadow_depth::ShadowDepth;
use super::shadow_pass::{ShadowMaps, layer_count, render_shadow_maps};
use lightfold_protocol::{Layer, PixelFormat};
use lightfold_scene::shadow_views::ShadowView;
use lightfold_scene::{Camera, Image, LightSample, MapSizing, Material, Mesh, Scene, ShadowFilter};
use std::time::Instant;
use wgpu::util::DeviceExt;

/// Constant bias the [`Fault::HugeBias`] negative control forces, in metres.
const HUGE_BIAS: f32 = 0.5;

/// What one light's cached shadow-map layers were rendered from (walkthrough mode).
#[derive(Debug, Clone, PartialEq)]
struct LightMapKey {
    sample: LightSample,
    views: Vec<ShadowView>,
    /// Where its maps lie in the array (layer, square).
    slots: Vec<Slot>,
    casters: Option<Vec<u32>>,
    /// Revision of each mesh it may draw (its casters, or every mesh).
    revisions: Vec<u64>,
}

/// What the whole map array was made for.
#[derive(Debug, Clone, Copy, PartialEq)]
struct MapConfig {
    size: u32,
    fault: Option<Fault>,
}

/// A mesh's axis-aligned box `(min, max)`.
type MeshBox = ([f32; 3], [f32; 3]);

/// Whether this device packs frames (`gpu::pack`), known after the first packed frame.
#[derive(Debug)]
enum PackerState {
    Untried,
    Ready(Box<DevicePacker>),
    Unavailable,
}

/// One node's renderer: pipelines and scene buffers built once, targets and maps reused.
#[derive(Debug)]
pub struct Renderer {
    pipelines: Pipelines,
    scene: SceneData,
    receivers: Vec<([f32; 3], [f32; 3])>,
    vertices: wgpu::Buffer,
    /// The simplified levels' vertices (`SceneData::lods`), where there are any.
    lod_vertices: Option<wgpu::Buffer>,
    /// The eye pipelines' tangents, one per vertex where the scene is normal-mapped (else a
    /// placeholder no pipeline reads).
    tangents: wgpu::Buffer,
    /// Each object's world box (`scene_data::GpuBounds`), posed with the meshes.
    object_bounds: wgpu::Buffer,
    scene_bind_group: wgpu::BindGroup,
    camera: Camera,
    near: f32,
    options: RenderOptions,
    sampler: wgpu::Sampler,
    maps: Option<ShadowMaps>,
    map_config: Option<MapConfig>,
    map_keys: Vec<LightMapKey>,
    /// Per mesh, bumped whenever [`Renderer::set_meshes`] changes its triangles.
    revisions: Vec<u64>,
    /// Boxes shadow views are fitted to instead of the meshes' own (an animation's swept
    /// bounds: views that hold over the motion, so only what moves is rendered again).
    /// One per mesh, `None` for one without triangles.
    fit_bounds: Option<Vec<Option<MeshBox>>>,
    /// Shadow views fitted to the eye meshes only ([`Renderer::set_fit_to_eye_meshes`]).
    fit_eye_only: bool,
    targets: Option<EyeTargets>,
    variant: EyeVariant,
    deferred: Option<DeferredTargets>,
    /// Eq. 7's ambient-mask pass and its output, built when a frame first asks for the mask.
    ambient_mask: Option<AmbientMaskPass>,
    max_lights: u32,
    fit_to_camera: bool,
    cascades: bool,
    object_ids: bool,
    receiver_plane: bool,
    map_sides: Option<Vec<u32>>,
    /// Readback buffers kept from frame to frame.
    staging: Staging,
    packer: PackerState,
    /// The meshes the eye pass draws (`None`: every mesh): a sort-last partition.
    eye_meshes: Option<Vec<u32>>,
    /// The eye pass draws only the meshes whose bounds meet the camera's frustum (the default).
    eye_culling: bool,
    /// Vertices the last eye pass drew.
    eye_vertices: u32,
    /// Eye-pass occlusion culling (`gpu::occlusion`): the mode, its passes once a frame used
    /// them, the chunks visible in the last tested frame (the next frame's occluders), the
    /// frames left in an [`EyeOcclusion::Auto`] pause, and the vertices it left out of the last
    /// eye pass.
    occlusion: EyeOcclusion,
    occlusion_pass: Option<OcclusionPass>,
    occluders: Option<Vec<u32>>,
    occlusion_pause: u32,
    occluded_vertices: u32,
    /// The last eye pass drawn without occluders, in microseconds ([`EyeOcclusion::Auto`]
    /// compares a culled eye pass with it).
    plain_eye_us: Option<u64>,
    /// The last culled eye pass was slower than that ([`occlusion::judge`]).
    occlusion_slower: bool,
    /// The image rows `[y0, y1)` frames render (a sort-first tile); `None`: every row.
    rows: Option<[u32; 2]>,
    /// The eye layer frames render (`NodeConfig::peel`; `None`: the classic eye pass).
    peel: Option<u32>,
    /// The peel passes and their targets, built when a frame first peels.
    peel_pass: Option<PeelPass>,
}

impl Renderer {
    pub fn new(gpu: &Gpu, scene: &Scene, opts: RenderOptions) -> Result<Renderer, RenderError> {
        let device = &gpu.device;
        let max = gpu.limits.max_texture_dimension_2d;
        if opts.shadow_map_size == 0 || opts.shadow_map_size > max {
            return Err(RenderError::ShadowMapSize {
                size: opts.shadow_map_size,
                maximum: max,
            });
        }
        let data = SceneData::with_lod(
            scene,
            opts.chunk_triangles,
            super::lod::Build {
                shadow: opts.shadow_lod,
                guarded: opts.fault != Some(Fault::LodCoarsest),
                eye: opts.eye_lod,
            },
        );
        check_scene_size(gpu, &data)?;
        // Validation and internal errors (a shader the driver rejects or cannot translate, a
        // limit) come back as errors: wgpu's default handler for errors nobody captured panics.
        let depth = ShadowDepth::of(opts.fault);
        let pipelines = build_pipelines(device, scene, &data, &opts, depth)?;
        let buffers = SceneBuffers::upload(gpu, &data)?;
        let scene_bind_group = buffers.bind_group(device, &pipelines.scene_layout);
        // Reversed-Z: a receiver is lit where its depth is at least the stored one (the depth
        // negative controls aside).
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("shadow comparison"),
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            compare: Some(depth.lookup_compare()),
            ..Default::default()
        });
        let lod_vertices = lod_buffer(gpu, &data.lod_vertices)?;
        let near = (data.diagonal * 1e-4).clamp(1e-4, 1e-2);
        // The GPU holds the vertices now; only an animated scene needs them again on the CPU
        // (`set_meshes` compares the posed ones with them). A still scene's would be the largest
        // copy of its geometry left in the node (`docs/scaling.md` § Triangles).
        let mut data = data;
        if scene.animation.is_none() {
            data.vertices = Vec::new();
        }
        data.tangents = Vec::new();
        data.lod_vertices = Vec::new();
        // Levels are simplified again when meshes are posed: an animated scene keeps its
        // meshes' level vertices to redo only the meshes a pose changed; a still scene's are
        // built again whole if it is ever moved.
        if scene.animation.is_none() {
            data.lods.mesh_vertices = Vec::new();
        }
        Ok(Renderer {
            lod_vertices,
            sampler,
            receivers: data.receivers(),
            pipelines,
            scene: data,
            vertices: buffers.vertices,
            tangents: buffers.tangents,
            object_bounds: buffers.object_bounds,
            scene_bind_group,
            camera: scene.camera,
            near,
            options: opts,
            maps: None,
            map_config: None,
            map_keys: Vec::new(),
            revisions: vec![0; scene.meshes.len()],
            fit_bounds: None,
            fit_eye_only: false,
            targets: None,
            max_lights: gpu.max_lights(opts.shadow_map_size),
            fit_to_camera: true,
            cascades: true,
            object_ids: true,
            receiver_plane: true,
            map_sides: None,
            staging: Staging::default(),
            packer: PackerState::Untried,
            variant: EyeVariant::default(),
            deferred: None,
            ambient_mask: None,
            eye_meshes: None,
            eye_culling: true,
            eye_vertices: 0,
            occlusion: EyeOcclusion::default(),
            occlusion_pass: None,
            occluders: None,
            occlusion_pause: 0,
            occluded_vertices: 0,
            plain_eye_us: None,
            occlusion_slower: false,
            rows: None,
            peel: None,
            peel_pass: None,
        })
    }

    pub fn set_camera(&mut self, camera: &Camera) {
        self.camera = *camera;
    }

    /// Replaces the triangles of the scene's meshes with `meshes` (the same meshes posed: same
    /// count, materials and indices; `Scene::pose_meshes`) and marks the ones that changed, so
    /// only the shadow maps they may reach are rendered again.
    pub fn set_meshes(&mut self, gpu: &Gpu, meshes: &[Mesh]) -> Result<(), RenderError> {
        self.pose_meshes(gpu, meshes, None)
    }

    /// [`Renderer::set_meshes`] where the caller knows which meshes changed (`changed[m]`, one
    /// per mesh): objects moved in a still scene, whose unposed vertices the renderer does not
    /// keep to compare with. Only the maps the changed meshes may reach are rendered again.
    pub fn set_moved_meshes(
        &mut self,
        gpu: &Gpu,
        meshes: &[Mesh],
        changed: &[bool],
    ) -> Result<(), RenderError> {
        self.pose_meshes(gpu, meshes, Some(changed))
    }

    fn pose_meshes(
        &mut self,
        gpu: &Gpu,
        meshes: &[Mesh],
        changed: Option<&[bool]>,
    ) -> Result<(), RenderError> {
        if meshes.len() != self.scene.meshes.len() {
            return Err(RenderError::Gpu(format!(
                "posed scene has {} meshes, the renderer {}",
                meshes.len(),
                self.scene.meshes.len()
            )));
        }
        let (vertices, tangents, ranges, chunks) = self.scene.geometry(meshes);
        // Without the CPU copy (a still scene) every mesh counts as changed.
        let kept = self.scene.vertices.len() as u32 == self.scene.vertex_count;
        let same_layout = vertices.len() as u32 == self.scene.vertex_count
            && ranges
                .iter()
                .zip(&self.scene.meshes)
                .all(|(a, b)| (a.first_vertex, a.vertex_count) == (b.first_vertex, b.vertex_count));
        let mut moved = vec![false; ranges.len()];
        for (m, (new, old)) in ranges.iter().zip(&self.scene.meshes).enumerate() {
            // Compared in place as bytes (no copy per mesh per frame).
            fn span<'v>(
                r: &super::scene_data::MeshRange,
                v: &'v [super::scene_data::Vertex],
            ) -> &'v [u8] {
                bytemuck::cast_slice(
                    &v[r.first_vertex as usize..(r.first_vertex + r.vertex_count) as usize],
                )
            }
            // Without the CPU copy, what the caller says changed (or everything).
            let unknown = changed.is_none_or(|c| c.get(m).copied().unwrap_or(true));
            if !same_layout
                || (!kept && unknown)
                || new.bounds != old.bounds
                || (kept && span(new, &vertices) != span(old, &self.scene.vertices))
            {
                self.revisions[m] += 1;
                moved[m] = true;
            }
        }
        // Same mesh count, so the same length: each object's box where its pose put it.
        gpu.queue.write_buffer(
            &self.object_bounds,
            0,
            bytemuck::cast_slice(&super::scene_data::object_bounds(&ranges)),
        );
        if same_layout {
            if !vertices.is_empty() {
                gpu.queue
                    .write_buffer(&self.vertices, 0, bytemuck::cast_slice(&vertices));
            }
            if !tangents.is_empty() {
                gpu.queue
                    .write_buffer(&self.tangents, 0, bytemuck::cast_slice(&tangents));
            }
        } else {
            let bytes: &[u8] = if vertices.is_empty() {
                &[0; 48]
            } else {
                bytemuck::cast_slice(&vertices)
            };
            let size = bytes.len() as u64;
            if size > gpu.limits.max_buffer_size {
                return Err(RenderError::BindingTooLarge {
                    what: "vertices",
                    bytes: size,
                    maximum: gpu.limits.max_buffer_size,
                });
            }
            let tbytes = tangent_bytes(&tangents);
            (self.vertices, self.tangents) = allocate(gpu, "the posed vertices", || {
                let init = |label, contents| {
                    gpu.device
                        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                            label: Some(label),
                            contents,
                            usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
                        })
                };
                (init("vertices", bytes), init("tangents", tbytes))
            })?;
        }
        // The moved meshes' levels simplified again from their pose (the same levels a still
        // scene of that pose gets).
        if self.options.shadow_lod || self.options.eye_lod {
            self.scene.lods.update(&vertices, &ranges, &chunks, &moved);
            let level_vertices = self.scene.lods.layout(&ranges);
            let fits = self
                .lod_vertices
                .as_ref()
                .is_some_and(|b| b.size() == std::mem::size_of_val(&level_vertices[..]) as u64);
            match &self.lod_vertices {
                Some(b) if fits && !level_vertices.is_empty() => {
                    gpu.queue
                        .write_buffer(b, 0, bytemuck::cast_slice(&level_vertices));
                }
                _ => self.lod_vertices = lod_buffer(gpu, &level_vertices)?,
            }
        }
        self.scene.vertex_count = vertices.len() as u32;
        self.scene.vertices = vertices;
        self.scene.meshes = ranges;
        self.scene.chunks = chunks;
        self.refresh_receivers();
        Ok(())
    }

    /// The boxes shadow views are fitted to: every mesh with triangles (or only the eye
    /// meshes, with [`Renderer::set_fit_to_eye_meshes`]), as posed or as `set_fit_bounds` gave.
    fn refresh_receivers(&mut self) {
        let eye: Option<Vec<bool>> =
            self.eye_meshes
                .as_ref()
                .filter(|_| self.fit_eye_only)
                .map(|e| {
                    let mut mask = vec![false; self.scene.meshes.len()];
                    for &m in e {
                        if let Some(k) = mask.get_mut(m as usize) {
                            *k = true;
                        }
                    }
                    mask
                });
        self.receivers = self
            .scene
            .meshes
            .iter()
            .enumerate()
            .filter(|(i, m)| m.vertex_count > 0 && eye.as_ref().is_none_or(|e| e[*i]))
            .filter_map(|(i, m)| match &self.fit_bounds {
                Some(b) => b.get(i).copied().flatten(),
                None => m.bounds,
            })
            .collect();
    }

    /// Fits shadow views to the eye meshes' boxes only (`on`), or to every mesh's (the
    /// default). A sort-last node draws only its part, so maps fitted to that part's receivers
    /// hold every lookup it makes, with fewer texels spent elsewhere and only the casters
    /// between the light and that part drawn (the planner fits the same views:
    /// `docs/planner.md` § Partitions).
    pub fn set_fit_to_eye_meshes(&mut self, on: bool) {
        self.fit_eye_only = on;
        self.refresh_receivers();
    }

    /// Fits shadow views to these boxes (one per mesh, `None` for a mesh without triangles)
    /// rather than to the meshes as posed: `Scene::swept_bounds` for an animation, as the
    /// planner does.
    pub fn set_fit_bounds(&mut self, bounds: Vec<Option<MeshBox>>) {
        self.fit_bounds = Some(bounds);
        self.refresh_receivers();
    }

    /// Whether moving-light frames fit shadow views to the receivers the camera sees (the
    /// default: fewer cube faces) or to the whole scene, as walkthrough mode always does.
    pub fn set_fit_to_camera(&mut self, on: bool) {
        self.fit_to_camera = on;
    }

    /// Whether maps fitted to what the camera sees are split into cascades by eye depth where
    /// that range is deep (the default; `false` gives one frustum per light, as before issue 22).
    pub fn set_cascades(&mut self, on: bool) {
        self.cascades = on;
    }

    /// Whether shadow lookups use the object-ID test (the default): a receiver compares with its
    /// own object's stored depth under the slope bias, and with other objects' under a bias
    /// sized for the texel's offset only, so thin casters cannot hide inside the bias and
    /// shadows start at their casters' feet. `false` gives one bias for every caster, as before
    /// issue 22.
    pub fn set_object_ids(&mut self, on: bool) {
        self.object_ids = on;
    }

    /// With the object-ID test, whether another object's texel is compared with the receiver's
    /// plane where that texel's centre ray meets it (the default) or with the symmetric slope
    /// bound alone, as before issue 46 (which let a wall standing on a floor light the floor
    /// behind it within a texel of its foot).
    pub fn set_receiver_plane(&mut self, on: bool) {
        self.receiver_plane = on;
    }

    /// Each light's map side as a plan gives it (`WireShadow::map_size`), in the order of the
    /// lights [`Renderer::render`] gets; `None` (the default) sizes maps by
    /// [`RenderOptions::map_sizing`].
    pub fn set_map_sides(&mut self, sides: Option<Vec<u32>>) {
        self.map_sides = sides;
    }

    /// Draws only `meshes` in the eye pass (`None`: every mesh), a sort-last partition of the
    /// scene (issue 24): pixels show the nearest surface of those meshes, lit by the frame's
    /// lights with shadows from every caster the frame allows, and are empty (0, depth 0)
    /// where none covers them; glass of every part in front of them tints their material
    /// layers. Shadow maps are unchanged unless [`Renderer::set_fit_to_eye_meshes`] is on.
    /// Indices out of range are ignored.
    pub fn set_eye_meshes(&mut self, meshes: Option<Vec<u32>>) {
        self.eye_meshes = meshes;
        self.refresh_receivers();
    }

    /// Whether the eye pass draws only the meshes whose bounds meet the camera's frustum (the
    /// default; the image is the same either way: a mesh outside makes no fragment).
    pub fn set_eye_culling(&mut self, on: bool) {
        self.eye_culling = on;
    }

    /// Whether the eye pass also leaves out the chunks hidden behind others (`gpu::occlusion`;
    /// [`EyeOcclusion::Auto`] by default). The image is the same either way.
    pub fn set_eye_occlusion(&mut self, occlusion: EyeOcclusion) {
        self.occlusion = occlusion;
        self.occluders = None;
        self.occlusion_pause = 0;
        self.plain_eye_us = None;
        self.occlusion_slower = false;
    }

    /// Vertices occlusion culling left out of the last eye pass (of those frustum culling kept).
    pub fn occluded_vertices(&self) -> u32 {
        self.occluded_vertices
    }

    /// Renders only the image rows `[y0, y1)` from the next frame on (`None`: every row), a
    /// sort-first tile: the eye pass rasterises and lights those rows only (scissored, meshes
    /// culled against the tile's sub-frustum) and reads back only them; every other row of every
    /// layer is zero (depth 0: nothing there). Shadow maps are the same as without a tile.
    /// Checked against the camera's height when a frame renders ([`RenderError::Rows`]).
    pub fn set_rows(&mut self, rows: Option<[u32; 2]>) {
        self.rows = rows;
    }

    /// Which eye layer frames render from the next frame on (`NodeConfig::peel`,
    /// `docs/translucency.md`): `None`, the classic eye pass (filters seen through and
    /// multiplied into the material layers, coverage surfaces as cut-outs); `Some(0)`, the
    /// opaque layer (every translucent surface skipped, nothing multiplied in); `Some(d)`, the
    /// d-th nearest translucent surface in front of the opaque one (depth peeling: `gpu::peel`),
    /// its material layers times its eye coverage, its eye transmittance in
    /// [`NodeFrame::transmittance`]. Peel 0 takes either eye variant; peels d ≥ 1 always take
    /// the forward pass ([`Renderer::frame_variant`]). A
    /// peel deeper than [`crate::gpu::MAX_PEEL`] is refused when a frame renders
    /// ([`RenderError::PeelTooDeep`]).
    pub fn set_peel(&mut self, peel: Option<u32>) {
        self.peel = peel;
    }

    /// The eye layer frames render (see [`Renderer::set_peel`]).
    pub fn peel(&self) -> Option<u32> {
        self.peel
    }

    /// Whether transmittance maps keep two translucent layers: a peeling renderer sees
    /// translucent surfaces behind others (`docs/translucency.md`).
    fn layered_maps(&self) -> bool {
        self.peel.is_some() && self.options.fault != Some(Fault::OneTranslucentLayer)
    }

    /// The rows frames render (see [`Renderer::set_rows`]).
    pub fn rows(&self) -> Option<[u32; 2]> {
        self.rows
    }

    /// Triangles of the simplified levels, shadow and eye (`gpu::lod`).
    pub fn lod_triangles(&self) -> u64 {
        self.scene.lods.triangles()
    }

    /// Vertices the last eye pass drew (three a triangle), after culling.
    pub fn eye_vertices(&self) -> u32 {
        self.eye_vertices
    }

    /// Chooses how the eye pass lights pixels (same images either way, within f32 rounding).
    pub fn set_variant(&mut self, variant: EyeVariant) {
        self.variant = variant;
    }

    pub fn variant(&self) -> EyeVariant {
        self.variant
    }

    pub fn options(&self) -> &RenderOptions {
        &self.options
    }

    /// The eye pass a `w`×`h` frame uses: the chosen variant, except that the deferred pass
    /// falls back to the forward pass (the same image within f32 rounding) when its lit buffer
    /// (32 bytes per pixel, one storage binding) exceeds the device's limits — on lavapipe,
    /// whose storage bindings stop at 128 MiB, above 2048 × 2048. A renderer peeling a
    /// translucent layer ([`Renderer::set_peel`] with d ≥ 1) always takes the forward pass.
    pub fn frame_variant(&self, gpu: &Gpu, w: u32, h: u32) -> EyeVariant {
        if self.peel.is_some_and(|d| d >= 1) {
            return EyeVariant::Forward;
        }
        let lit = u64::from(w) * u64::from(h) * 32;
        let fits =
            lit <= gpu.limits.max_storage_buffer_binding_size && lit <= gpu.limits.max_buffer_size;
        if self.variant == EyeVariant::Deferred && !fits {
            EyeVariant::Forward
        } else {
            self.variant
        }
    }

    /// Renders `lights` (shadowed) for node colour `c_n`. `casters[λ]` lists the mesh indices that
    /// cast into light λ's maps (`None`: every mesh). Whatever the device refuses (a size beyond
    /// its limits, memory it cannot allocate) is an error, never a panic.
    pub fn render(
        &mut self,
        gpu: &Gpu,
        lights: &[LightSample],
        casters: Option<&[Vec<u32>]>,
        c_n: [f32; 3],
        layers: LayerSet,
    ) -> Result<NodeFrame, RenderError> {
        self.guarded(gpu, |r| {
            let (stats, lit_buffer) = r.render_frame(gpu, lights, casters, c_n, layers)?;
            r.read_images(gpu, layers, lit_buffer, stats)
        })
    }

    /// [`Renderer::render`], then the configured `layers` packed in their link formats on the
    /// device (`gpu::pack`): only the packed bytes are read back. `None` when this device or a
    /// format cannot be packed there (see [`Renderer::packs_on_device`]): the caller then renders
    /// with [`Renderer::render`] and packs on the CPU.
    #[allow(clippy::too_many_arguments)]
    pub fn render_packed(
        &mut self,
        gpu: &Gpu,
        lights: &[LightSample],
        casters: Option<&[Vec<u32>]>,
        c_n: [f32; 3],
        layers: &[(Layer, PixelFormat)],
        band_height: u32,
        scale: f32,
    ) -> Result<Option<(PackedFrame, RenderStats)>, RenderError> {
        if !self.packs_on_device(gpu, layers, scale) {
            return Ok(None);
        }
        let set = LayerSet::of(layers.iter().map(|(l, _)| *l));
        self.guarded(gpu, |r| {
            let (mut stats, lit_buffer) = r.render_frame(gpu, lights, casters, c_n, set)?;
            let t = Instant::now();
            let packed = r.pack_layers(gpu, layers, lit_buffer, band_height, scale)?;
            stats.readback_us = t.elapsed().as_micros() as u64;
            stats.read_bytes = packed.read_bytes;
            Ok(Some((packed, stats)))
        })
    }

    /// Whether frames of `layers` at `scale` are packed on this device: the pack pass builds here
    /// (tried once) and every format packs exactly (`DevicePacker::supports`).
    pub fn packs_on_device(
        &mut self,
        gpu: &Gpu,
        layers: &[(Layer, PixelFormat)],
        scale: f32,
    ) -> bool {
        if matches!(self.packer, PackerState::Untried) {
            self.packer = match DevicePacker::new(gpu) {
                Ok(p) => PackerState::Ready(Box::new(p)),
                Err(e) => {
                    tracing::warn!(error = %e, "packing on the CPU: the device cannot pack");
                    PackerState::Unavailable
                }
            };
        }
        let formats: Vec<PixelFormat> = layers.iter().map(|(_, f)| *f).collect();
        matches!(self.packer, PackerState::Ready(_))
            && !layers.is_empty()
            && layers.len() <= pack::MAX_LAYERS
            && layers.iter().all(|(l, f)| {
                *l != Layer::Radiance
                    && f.channels() == l.channels()
                    && DevicePacker::supports(*f, scale)
            })
            && DevicePacker::fits(&gpu.limits, &formats, self.camera.width, self.camera.height)
    }

    /// Runs one frame's device work, turning what the device refuses into an error (wgpu's
    /// handler for errors nobody captures panics) and dropping targets a refused frame may have
    /// left half made.
    fn guarded<T>(
        &mut self,
        gpu: &Gpu,
        frame: impl FnOnce(&mut Self) -> Result<T, RenderError>,
    ) -> Result<T, RenderError> {
        let (out, error) = captured(&gpu.device, || frame(self));
        match (out, error) {
            (Err(e), _) => Err(e),
            (Ok(_), Some(e)) => {
                // Targets and maps may be half made: allocate them afresh next frame.
                self.targets = None;
                self.deferred = None;
                self.ambient_mask = None;
                self.peel_pass = None;
                self.maps = None;
                self.map_config = None;
                self.map_keys.clear();
                Err(RenderError::Gpu(format!(
                    "the device refused the frame: {e}"
                )))
            }
            (Ok(f), None) => Ok(f),
        }
    }

    fn render_frame(
        &mut self,
        gpu: &Gpu,
        lights: &[LightSample],
        casters: Option<&[Vec<u32>]>,
        c_n: [f32; 3],
        layers: LayerSet,
    ) -> Result<(RenderStats, bool), RenderError> {
        let setup = Instant::now();
        let (w, h) = self.check_frame(gpu, lights, casters)?;
        let variant = self.frame_variant(gpu, w, h);
        if variant != self.variant
            && self.peel.is_none_or(|d| d == 0)
            && self
                .targets
                .as_ref()
                .is_none_or(|t| (t.width, t.height) != (w, h))
        {
            tracing::info!(
                width = w,
                height = h,
                "deferred lit buffer exceeds the device's storage-binding limit: forward eye pass"
            );
        }
        let lit = layers.illumination;
        let frame_lights: &[LightSample] = if lit { lights } else { &[] };
        let (plan, transmit) = self.plan_frame(gpu, frame_lights, casters, c_n)?;
        let mut stats = RenderStats {
            passes_per_light: plan.passes_per_light.clone(),
            map_sides: plan.atlas.slots.iter().map(|s| s.side).collect(),
            maps_halved: plan.maps_halved,
            ..Default::default()
        };

        // Shadow maps: in walkthrough mode a light's are kept while nothing they depend on
        // changed (the light, its views, the meshes it may draw, the map size).
        stats.setup_us = setup.elapsed().as_micros() as u64;
        let t0 = Instant::now();
        self.render_maps(gpu, &plan, frame_lights, casters, &transmit, &mut stats)?;
        stats.shadow_us = t0.elapsed().as_micros() as u64;

        // Eye pass.
        let t1 = Instant::now();
        self.render_eye_pass(gpu, &plan, layers, variant, w, h)?;
        stats.eye_us = t1.elapsed().as_micros() as u64;
        let lit_buffer = lit && variant == EyeVariant::Deferred && self.deferred.is_some();
        Ok((stats, lit_buffer))
    }

    /// Refuses a frame of more lights than the maps hold, of casters not one per light, or of
    /// an image size (or its readback) beyond the device's limits; else the image size.
    fn check_frame(
        &self,
        gpu: &Gpu,
        lights: &[LightSample],
        casters: Option<&[Vec<u32>]>,
    ) -> Result<(u32, u32), RenderError> {
        if lights.len() > self.max_lights as usize {
            return Err(RenderError::TooManyLights {
                requested: lights.len(),
                maximum: self.max_lights,
            });
        }
        if let Some(c) = casters
            && c.len() != lights.len()
        {
            return Err(RenderError::Casters {
                lights: lights.len(),
                given: c.len(),
            });
        }
        let (w, h) = (self.camera.width, self.camera.height);
        let max_side = gpu.limits.max_texture_dimension_2d;
        if w == 0 || h == 0 || w > max_side || h > max_side {
            return Err(RenderError::ImageSize {
                width: w,
                height: h,
                maximum: max_side,
            });
        }
        if let Some(rows) = self.rows {
            super::frame::check_rows(rows, h)?;
        }
        if let Some(peel) = self.peel
            && peel > super::peel::MAX_PEEL
        {
            return Err(RenderError::PeelTooDeep {
                peel,
                maximum: super::peel::MAX_PEEL,
            });
        }
        // The largest buffer a frame needs besides the lit buffer: the readback of a 16-byte
        // target. Checked here so the device is never asked for it.
        let readback = u64::from(super::readback::padded_row(w, 16)) * u64::from(h);
        if readback > gpu.limits.max_buffer_size {
            return Err(RenderError::BindingTooLarge {
                what: "the readback of an illumination target",
                bytes: readback,
                maximum: gpu.limits.max_buffer_size,
            });
        }
        Ok((w, h))
    }

    /// The frame's light plan (views fitted and sized, within the shadow-memory budget) and,
    /// per view, whether it gets transmittance maps; a plan beyond the device's texture
    /// limits is an error.
    fn plan_frame(
        &self,
        gpu: &Gpu,
        frame_lights: &[LightSample],
        casters: Option<&[Vec<u32>]>,
        c_n: [f32; 3],
    ) -> Result<(LightPlan, Vec<bool>), RenderError> {
        let opts = self.options;
        // Moving lights: maps cover only what the camera sees. Walkthrough: the maps must outlive
        // camera moves, so they cover every receiver.
        let fit = match (opts.walkthrough || !self.fit_to_camera, self.cascades) {
            (true, _) => Fit::All,
            (false, true) => Fit::Cascaded(&self.camera),
            (false, false) => Fit::Visible(&self.camera),
        };
        let sides = match (&self.map_sides, opts.map_sizing) {
            (Some(given), _) => Sides::Given(given),
            (None, MapSizing::Fixed) => Sides::Uniform(opts.shadow_map_size),
            (None, MapSizing::Mismatch(rule)) => Sides::Mismatch {
                rule,
                camera: &self.camera,
                fallback: opts.shadow_map_size,
            },
        };
        // Views of lights with translucent casters also get transmittance maps, and say so to
        // the lookups (`View::rect.w`); the whole array then takes more bytes per texel.
        let transmit_light = self.transmit_lights(frame_lights.len(), casters);
        // Peeling renderers see translucent surfaces behind others: their views keep two
        // translucent layers (`View::rect.w` = 2; `docs/translucency.md`).
        let layered = self.layered_maps();
        let texel_bytes = if transmit_light.contains(&true) && layered {
            LAYERED_TEXEL_BYTES
        } else if transmit_light.contains(&true) {
            TRANSLUCENT_TEXEL_BYTES
        } else {
            SHADOW_TEXEL_BYTES
        };
        let mut plan = plan_lights_within(
            frame_lights,
            &self.receivers,
            fit,
            c_n,
            sides,
            opts.fault,
            SHADOW_MEMORY_BUDGET / texel_bytes,
        );
        let transmit: Vec<bool> = plan
            .view_light
            .iter()
            .map(|&l| transmit_light.get(l as usize).copied().unwrap_or(false))
            .collect();
        for (v, &t) in plan.views.iter_mut().zip(&transmit) {
            v.rect[3] = match (t, layered) {
                (false, _) => 0.0,
                (true, false) => 1.0,
                (true, true) => 2.0,
            };
        }
        let max_layers = gpu.limits.max_texture_array_layers;
        if layer_count(plan.atlas.layers as usize) > max_layers {
            return Err(RenderError::TooManyViews {
                views: plan.views.len(),
                maximum: max_layers,
            });
        }
        if plan.atlas.side > gpu.limits.max_texture_dimension_2d {
            return Err(RenderError::ShadowMapSize {
                size: plan.atlas.side,
                maximum: gpu.limits.max_texture_dimension_2d,
            });
        }
        Ok((plan, transmit))
    }

    /// The frame's shadow maps: the array (re)allocated where it no longer fits, and the maps of
    /// every light whose key changed (all but in walkthrough mode) rendered again, with what
    /// was drawn and kept in `stats`.
    fn render_maps(
        &mut self,
        gpu: &Gpu,
        plan: &LightPlan,
        frame_lights: &[LightSample],
        casters: Option<&[Vec<u32>]>,
        transmit: &[bool],
        stats: &mut RenderStats,
    ) -> Result<(), RenderError> {
        let opts = self.options;
        let any_transmit = transmit.contains(&true);
        let layered = self.layered_maps();
        let config = MapConfig {
            size: plan.atlas.side.max(1),
            fault: opts.fault,
        };
        let keys = self.light_keys(plan, frame_lights, casters);
        let fits = self
            .maps
            .as_ref()
            .is_some_and(|m| m.fits(config.size, plan.atlas.layers, any_transmit, layered));
        let kept_array = fits && self.map_config == Some(config);
        let fresh: Vec<bool> = keys
            .iter()
            .enumerate()
            .map(|(i, k)| !(opts.walkthrough && kept_array && self.map_keys.get(i) == Some(k)))
            .collect();
        if !fits {
            let layers = layer_count(plan.atlas.layers as usize);
            let depth = ShadowDepth::of(opts.fault);
            self.maps = None;
            self.map_keys.clear();
            self.maps = Some(allocate(gpu, "the shadow maps", || {
                ShadowMaps::new(
                    &gpu.device,
                    config.size,
                    layers,
                    depth,
                    any_transmit,
                    layered,
                )
            })?);
        }
        if fresh.contains(&true) {
            let maps = self.maps.as_ref().expect("allocated above");
            let views: Vec<bool> = plan.view_light.iter().map(|&l| fresh[l as usize]).collect();
            let drawn = render_shadow_maps(
                &self.draw_context(gpu),
                &self.scene,
                maps,
                plan,
                casters,
                &views,
                transmit,
            );
            (stats.shadow_passes, stats.transmit_passes) = (drawn.passes, drawn.transmitted);
            (stats.shadow_vertices, stats.shadow_lod_vertices) =
                (drawn.vertices, drawn.lod_vertices);
            wait(gpu)?;
        }
        stats.maps_kept = fresh.iter().filter(|f| !**f).count() as u32;
        self.map_config = Some(config);
        self.map_keys = keys;
        Ok(())
    }

    /// The eye pass of a `w`×`h` frame lit by `plan` (`variant`: forward or deferred), its
    /// targets (re)allocated where the size changed; waits for the device.
    fn render_eye_pass(
        &mut self,
        gpu: &Gpu,
        plan: &LightPlan,
        layers: LayerSet,
        variant: EyeVariant,
        w: u32,
        h: u32,
    ) -> Result<(), RenderError> {
        let started = Instant::now();
        if !self
            .targets
            .as_ref()
            .is_some_and(|t| t.width == w && t.height == h)
        {
            self.targets = None;
            let format = self.pipelines.illumination_format;
            self.targets = Some(allocate(gpu, "the eye-pass targets", || {
                EyeTargets::new(&gpu.device, w, h, format)
            })?);
        }
        // The light pass is specialised to what this frame's lights are.
        let light_pass = self
            .pipelines
            .light_pass(&gpu.device, LightSet::of(&plan.lights))?;
        let frame = self.frame_uniform(plan);
        let rows = self.raster_rows(h);
        let candidates = self.eye_candidates(&self.cull_view_proj(&frame.view_proj, h));
        let step = self.occlusion_step(candidates.as_deref());
        let targets = self.targets.as_ref().expect("allocated above");
        let maps = self.maps.as_ref().expect("allocated with the shadow maps");
        let inputs = EyeInputs {
            frame,
            lights: &plan.lights,
            views: &plan.views,
            maps,
            sampler: &self.sampler,
            material_layers: layers.any_material(),
            vertex_count: self.scene.vertex_count,
        };
        let far_corner = self.options.fault == Some(Fault::OcclusionFarCorner);
        let test = |boxes| occlusion::Test {
            view_proj: frame.view_proj,
            width: w,
            height: h,
            boxes,
            rows,
            far_corner,
        };
        let mut pass = match step {
            OcclusionStep::Off => None,
            _ => Some(
                self.occlusion_pass
                    .take()
                    .unwrap_or_else(|| OcclusionPass::new(&gpu.device, &self.pipelines)),
            ),
        };
        let boxes: Vec<_> = match (&step, &candidates) {
            (OcclusionStep::Off, _) | (_, None) => Vec::new(),
            (_, Some(c)) => c.iter().map(|e| e.bounds).collect(),
        };
        // With occluders: draw them, test every candidate, keep those that may show.
        let mut shown = None;
        if let (OcclusionStep::Occluders(occluders), Some(c), Some(pass)) =
            (&step, &candidates, pass.as_mut())
        {
            let draws = EyeDraws {
                rows,
                ..eye_draws_of(
                    c.iter()
                        .filter(|e| occluders.binary_search(&e.chunk).is_ok()),
                )
            };
            let visible = pass.occluded_by(&self.draw_context(gpu), &inputs, &draws, &test(&boxes));
            shown = Some(visible?);
        }
        let draws = EyeDraws {
            rows,
            ..match (&candidates, &shown) {
                (None, _) => EyeDraws {
                    scene: std::iter::once(0..self.scene.vertex_count).collect(),
                    ..EyeDraws::default()
                },
                (Some(c), None) => eye_draws_of(c.iter()),
                (Some(c), Some(v)) => {
                    eye_draws_of(c.iter().zip(v).filter(|(_, v)| **v).map(|(e, _)| e))
                }
            }
        };
        self.eye_vertices = draws.vertices();
        if variant == EyeVariant::Deferred {
            if !self
                .deferred
                .as_ref()
                .is_some_and(|d| d.width == w && d.height == h)
            {
                self.deferred = None;
                self.deferred = Some(allocate(gpu, "the deferred G-buffer", || {
                    DeferredTargets::new(&gpu.device, w, h)
                })?);
            }
            let deferred = self.deferred.as_ref().expect("allocated above");
            // Peel 0 brings its G-buffer rasters (deferred frames peel nothing deeper).
            if self.peel.is_some() && self.peel_pass.is_none() {
                self.peel_pass = Some(PeelPass::new(&gpu.device, &self.pipelines));
            }
            let peel0 = self
                .peel_pass
                .as_ref()
                .filter(|_| self.peel.is_some())
                .map(PeelPass::gbuffer);
            render_deferred(
                &self.draw_context(gpu),
                &draws,
                targets,
                deferred,
                &inputs,
                &light_pass,
                peel0,
            );
        } else if let Some(depth) = self.peel {
            let mut peel = match self.peel_pass.take() {
                Some(p) => p,
                None => PeelPass::new(&gpu.device, &self.pipelines),
            };
            let cx = self.draw_context(gpu);
            if depth == 0 {
                peel.render_opaque(&cx, &draws, targets, &inputs);
            } else {
                allocate(gpu, "the peel targets", || {
                    peel.ensure_targets(&gpu.device, w, h)
                })?;
                peel.render_translucent(&cx, &draws, targets, &inputs, depth);
            }
            self.peel_pass = Some(peel);
        } else {
            render_eye(&self.draw_context(gpu), &draws, targets, &inputs);
        }
        // Without occluders: test the candidates against the eye pass's own depth, for the next
        // frame's.
        if let (OcclusionStep::After, Some(pass)) = (&step, pass.as_mut()) {
            let visible = pass.visible_in(
                &self.draw_context(gpu),
                &targets.depth_buffer,
                &test(&boxes),
            );
            shown = Some(visible?);
        }
        if let Some(p) = pass {
            self.occlusion_pass = Some(p);
        }
        if layers.ambient_mask {
            let [m_diffuse, _, m_ambient, _] = &targets.materials;
            self.ambient_mask
                .get_or_insert_with(|| AmbientMaskPass::new(&gpu.device))
                .run(&gpu.device, &gpu.queue, m_diffuse, m_ambient);
        }
        wait(gpu)?;
        self.occlusion_result(
            step,
            candidates.as_deref(),
            shown.as_deref(),
            started.elapsed().as_micros() as u64,
        );
        Ok(())
    }

    /// Reads the frame's requested layers back as f32 images (`lit_buffer`: the illumination is
    /// in the deferred pass's lit buffer, else in the forward pass's two targets).
    fn read_images(
        &mut self,
        gpu: &Gpu,
        layers: LayerSet,
        lit_buffer: bool,
        mut stats: RenderStats,
    ) -> Result<NodeFrame, RenderError> {
        let (targets, deferred) = match (&self.targets, &self.deferred) {
            (Some(t), d) => (t, d),
            (None, _) => return Err(RenderError::Gpu("no frame was rendered".into())),
        };
        let (w, h) = (targets.width, targets.height);
        let lit = layers.illumination;
        let t2 = Instant::now();
        let mut sources: Vec<ReadSource<'_>> = Vec::new();
        match deferred {
            Some(d) if lit && lit_buffer => sources.push(ReadSource::Lit(&d.illumination)),
            _ => {}
        }
        if lit && !lit_buffer {
            sources.push(ReadSource::Texture(req(&targets.diffuse, 3)));
            sources.push(ReadSource::Texture(req(&targets.specular, 3)));
        }
        let m = &targets.materials;
        let mask = mask_output(self.ambient_mask.as_ref(), layers)?;
        for (want, tex, channels) in [
            (layers.diffuse, &m[0], 3),
            (layers.specular, &m[1], 3),
            (layers.ambient, &m[2], 3),
            (layers.emissive, &m[3], 3),
            (layers.depth, &targets.depth, 1),
        ] {
            if want {
                sources.push(ReadSource::Texture(req(tex, channels)));
            }
        }
        if let Some(mask) = mask {
            sources.push(ReadSource::Texture(req(mask, 3)));
        }
        let transmittance = transmittance_output(self.peel, self.peel_pass.as_ref(), layers)?;
        if let Some(t) = transmittance {
            sources.push(ReadSource::Texture(req(t, 3)));
        }
        let rows = ReadRows::of(self.rows, h);
        let mut data =
            read(&gpu.device, &gpu.queue, &mut self.staging, &sources, rows)?.into_iter();
        let image = |data: Vec<f32>, channels| Image {
            width: w,
            height: h,
            channels,
            data,
        };
        let mut out = NodeFrame {
            illumination: None,
            diffuse: None,
            specular: None,
            ambient: None,
            emissive: None,
            depth: None,
            ambient_mask: None,
            transmittance: None,
            stats: RenderStats::default(),
        };
        if lit {
            let il = if lit_buffer {
                data.next().unwrap_or_default()
            } else {
                let (d, s) = (
                    data.next().unwrap_or_default(),
                    data.next().unwrap_or_default(),
                );
                let mut il = Vec::with_capacity(d.len() * 2);
                for (a, b) in d.chunks_exact(3).zip(s.chunks_exact(3)) {
                    il.extend_from_slice(a);
                    il.extend_from_slice(b);
                }
                il
            };
            out.illumination = Some(image(il, 6));
        }
        for (want, slot) in [
            (layers.diffuse, &mut out.diffuse),
            (layers.specular, &mut out.specular),
            (layers.ambient, &mut out.ambient),
            (layers.emissive, &mut out.emissive),
        ] {
            if want {
                *slot = Some(image(data.next().unwrap_or_default(), 3));
            }
        }
        if layers.depth {
            out.depth = Some(image(data.next().unwrap_or_default(), 1));
        }
        if layers.ambient_mask {
            out.ambient_mask = Some(image(data.next().unwrap_or_default(), 3));
        }
        if layers.transmittance {
            out.transmittance = Some(image(data.next().unwrap_or_default(), 3));
        }
        stats.readback_us = t2.elapsed().as_micros() as u64;
        stats.read_bytes = self.staging.bytes();
        out.stats = stats;
        Ok(out)
    }

    /// Packs the frame's `layers` on the device (see [`Renderer::render_packed`]).
    fn pack_layers(
        &mut self,
        gpu: &Gpu,
        layers: &[(Layer, PixelFormat)],
        lit_buffer: bool,
        band_height: u32,
        scale: f32,
    ) -> Result<PackedFrame, RenderError> {
        let PackerState::Ready(packer) = &mut self.packer else {
            return Err(RenderError::Gpu("the device cannot pack".into()));
        };
        let Some(targets) = &self.targets else {
            return Err(RenderError::Gpu("no frame was rendered".into()));
        };
        let m = &targets.materials;
        let set = LayerSet::of(layers.iter().map(|l| l.0));
        let mask = mask_output(self.ambient_mask.as_ref(), set)?;
        let transmittance = transmittance_output(self.peel, self.peel_pass.as_ref(), set)?;
        let sources = layers
            .iter()
            .map(|&(layer, format)| {
                let source = match layer {
                    Layer::Illumination => match &self.deferred {
                        Some(d) if lit_buffer => PackSource::Lit(&d.illumination),
                        _ => PackSource::Split(&targets.diffuse, &targets.specular),
                    },
                    Layer::Diffuse => PackSource::Texture(&m[0]),
                    Layer::Specular => PackSource::Texture(&m[1]),
                    Layer::Ambient => PackSource::Texture(&m[2]),
                    Layer::Emissive => PackSource::Texture(&m[3]),
                    Layer::Depth => PackSource::Texture(&targets.depth),
                    Layer::AmbientMask => match mask {
                        Some(mask) => PackSource::Texture(mask),
                        None => {
                            return Err(RenderError::Gpu("no ambient mask was rendered".into()));
                        }
                    },
                    Layer::Transmittance => match transmittance {
                        Some(t) => PackSource::Texture(t),
                        None => {
                            return Err(RenderError::Gpu("no transmittance was rendered".into()));
                        }
                    },
                    Layer::Radiance => {
                        return Err(RenderError::Gpu("a node renders no radiance layer".into()));
                    }
                };
                Ok(PackLayer { source, format })
            })
            .collect::<Result<Vec<_>, RenderError>>()?;
        packer.pack_rows(
            gpu,
            &sources,
            [targets.width, targets.height],
            band_height,
            scale,
            self.rows,
        )
    }

    /// The rows the eye pass rasterises for a tile of an `h`-row image ([`Renderer::set_rows`]),
    /// one row low under [`Fault::TileRowsOffByOne`]; `None` without a tile.
    fn raster_rows(&self, h: u32) -> Option<[u32; 2]> {
        let [y0, y1] = self.rows?;
        if self.options.fault == Some(Fault::TileRowsOffByOne) {
            return Some([(y0 + 1).min(h - 1), (y1 + 1).min(h)]);
        }
        Some([y0, y1])
    }

    /// The view-projection eye culling tests meshes against: the camera's, or a tile's
    /// sub-frustum (`lights::tile_view_proj`; flipped under [`Fault::TileFrustumFlipped`]).
    fn cull_view_proj(&self, view_proj: &[[f32; 4]; 4], h: u32) -> [[f32; 4]; 4] {
        match self.rows {
            None => *view_proj,
            Some([y0, y1]) if self.options.fault == Some(Fault::TileFrustumFlipped) => {
                super::lights::tile_view_proj(view_proj, [h - y1, h - y0], h)
            }
            Some(rows) => super::lights::tile_view_proj(view_proj, rows, h),
        }
    }

    /// The chunks the eye pass may draw: every mesh's, or those of [`Renderer::set_eye_meshes`],
    /// less (with eye culling) those whose bounds miss the frustum of `view_proj`; a chunk with
    /// a lossless eye level (`gpu::lod`) from the level buffer. `None`: every vertex of the
    /// scene, with nothing to choose (no culling, partition, level or occlusion culling).
    fn eye_candidates(&self, view_proj: &[[f32; 4]; 4]) -> Option<Vec<EyeChunk>> {
        let partial = self.options.fault == Some(Fault::EyeCullPartial);
        let lossy = self.options.fault == Some(Fault::EyeLodLossy);
        let lods = &self.scene.lods;
        let levels = self.lod_vertices.is_some() && if lossy { lods.any() } else { lods.has_eye() };
        let occlusion = self.occlusion != EyeOcclusion::Off && self.peel.is_none();
        if self.eye_meshes.is_none() && !self.eye_culling && !partial && !levels && !occlusion {
            return None;
        }
        let shown = |(lo, hi): ([f32; 3], [f32; 3])| {
            if partial {
                super::lights::box_wholly_in_eye_view(view_proj, lo, hi)
            } else {
                !self.eye_culling || super::lights::box_in_eye_view(view_proj, lo, hi)
            }
        };
        let chosen: Box<dyn Iterator<Item = &super::scene_data::MeshRange>> = match &self.eye_meshes
        {
            Some(meshes) => Box::new(
                meshes
                    .iter()
                    .filter_map(|&m| self.scene.meshes.get(m as usize)),
            ),
            None => Box::new(self.scene.meshes.iter()),
        };
        let mut chunks = Vec::new();
        for r in chosen {
            let first = r.first_chunk as usize;
            for (k, c) in self.scene.mesh_chunks(r).iter().enumerate() {
                if c.vertex_count == 0 || !shown(c.bounds) {
                    continue;
                }
                let level = if !levels {
                    None
                } else if lossy {
                    lods.levels.get(first + k).and_then(|l| l.first())
                } else {
                    lods.eye_level(first + k)
                };
                chunks.push(EyeChunk {
                    chunk: (first + k) as u32,
                    bounds: c.bounds,
                    level: level.is_some(),
                    range: match level {
                        Some(l) => l.first_vertex..l.first_vertex + l.vertex_count,
                        None => c.first_vertex..c.first_vertex + c.vertex_count,
                    },
                });
            }
        }
        Some(chunks)
    }

    /// What occlusion culling does this frame: test against last frame's visible chunks, test
    /// after the eye pass (no occluders yet), or nothing (off, paused, a peel, every vertex
    /// drawn, or more boxes than one test takes).
    fn occlusion_step(&mut self, candidates: Option<&[EyeChunk]>) -> OcclusionStep {
        let testable = candidates.is_some_and(|c| {
            c.len() <= occlusion::MAX_BOXES
                && (self.occlusion == EyeOcclusion::Always
                    || c.iter()
                        .map(|e| u64::from(e.range.end - e.range.start))
                        .sum::<u64>()
                        >= occlusion::AUTO_MIN_VERTICES)
        });
        if self.occlusion == EyeOcclusion::Off || self.peel.is_some() || !testable {
            self.occluders = None;
            return OcclusionStep::Off;
        }
        if self.occlusion_pause > 0 {
            self.occlusion_pause -= 1;
            return OcclusionStep::Off;
        }
        match self.occluders.take() {
            Some(o) => OcclusionStep::Occluders(o),
            None => OcclusionStep::After,
        }
    }

    /// Keeps what this frame's test found: the visible chunks as the next frame's occluders, or
    /// (under [`EyeOcclusion::Auto`], where culling does not pay: [`occlusion::judge`]) a pause.
    /// `eye_us`: this frame's eye pass, occluders and test included.
    fn occlusion_result(
        &mut self,
        step: OcclusionStep,
        candidates: Option<&[EyeChunk]>,
        shown: Option<&[bool]>,
        eye_us: u64,
    ) {
        self.occluded_vertices = 0;
        let culled = matches!(step, OcclusionStep::Occluders(_));
        if !culled {
            self.plain_eye_us = Some(eye_us);
        }
        let (Some(c), Some(v)) = (candidates, shown) else {
            return;
        };
        let (mut hidden, mut all) = (0u64, 0u64);
        for (e, shown) in c.iter().zip(v) {
            let n = u64::from(e.range.end - e.range.start);
            all += n;
            hidden += if *shown { 0 } else { n };
        }
        if culled {
            self.occluded_vertices = hidden as u32;
        }
        let timing = culled.then_some(eye_us).zip(self.plain_eye_us);
        if self.occlusion == EyeOcclusion::Auto {
            let judgement = occlusion::judge(hidden, all, timing, self.occlusion_slower);
            self.occlusion_slower = judgement == occlusion::Judgement::Slower;
            if judgement == occlusion::Judgement::Pause {
                self.occluders = None;
                self.occlusion_pause = occlusion::AUTO_PAUSE;
                return;
            }
        }
        let mut visible: Vec<u32> = c
            .iter()
            .zip(v)
            .filter(|(_, v)| **v)
            .map(|(e, _)| e.chunk)
            .collect();
        visible.sort_unstable();
        self.occluders = Some(visible);
    }

    /// Per light of the frame, whether it has translucent casters (`casters[λ]`, or any mesh
    /// when `None`), so its views get transmittance maps. None without translucent meshes.
    fn transmit_lights(&self, lights: usize, casters: Option<&[Vec<u32>]>) -> Vec<bool> {
        let translucent = |m: &u32| {
            self.scene
                .meshes
                .get(*m as usize)
                .is_some_and(|r| r.translucent && r.vertex_count > 0)
        };
        if !self.pipelines.translucent {
            return vec![false; lights];
        }
        match casters {
            Some(c) => c.iter().map(|c| c.iter().any(translucent)).collect(),
            None => {
                let any = (0..self.scene.meshes.len() as u32).any(|m| translucent(&m));
                vec![any; lights]
            }
        }
    }

    /// What each light's maps are rendered from this frame.
    fn light_keys(
        &self,
        plan: &LightPlan,
        lights: &[LightSample],
        casters: Option<&[Vec<u32>]>,
    ) -> Vec<LightMapKey> {
        let mut first = 0usize;
        lights
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let count = plan.passes_per_light.get(i).copied().unwrap_or(0) as usize;
                let views = plan.geometry[first..first + count].to_vec();
                let slots = plan.atlas.slots[first..first + count].to_vec();
                first += count;
                let own = casters.and_then(|c| c.get(i)).cloned();
                let revisions = match &own {
                    Some(c) => c
                        .iter()
                        .map(|&m| self.revisions.get(m as usize).copied().unwrap_or(0))
                        .collect(),
                    None => self.revisions.clone(),
                };
                LightMapKey {
                    sample: *s,
                    views,
                    slots,
                    casters: own,
                    revisions,
                }
            })
            .collect()
    }

    fn draw_context<'a>(&'a self, gpu: &'a Gpu) -> DrawContext<'a> {
        DrawContext {
            device: &gpu.device,
            queue: &gpu.queue,
            pipelines: &self.pipelines,
            scene_bind_group: &self.scene_bind_group,
            vertices: &self.vertices,
            lod: self
                .lod_vertices
                .as_ref()
                .filter(|_| self.scene.lods.any())
                .map(|b| (b, self.options.fault == Some(Fault::LodCoarsest))),
            tangents: self.scene.normal_mapped.then_some(&self.tangents),
        }
    }

    fn frame_uniform(&self, plan: &LightPlan) -> GpuFrame {
        let o = &self.options;
        let (mut depth_bias, mut slope_bias) = (o.depth_bias, o.slope_bias);
        match o.fault {
            Some(Fault::NoBias) => (depth_bias, slope_bias) = (0.0, 0.0),
            Some(Fault::HugeBias) => depth_bias = HUGE_BIAS,
            _ => {}
        }
        // The filter itself is compiled into the pipelines; its footprint scales the slope bias.
        let kernel_radius = match o.filter {
            ShadowFilter::None => 0.5,
            ShadowFilter::Pcf2x2 => 1.0,
            ShadowFilter::Pcf { taps } => (taps.clamp(1, 15) - 1) as f32 * 0.5 + 1.0,
            // Samples without a cell get the 2×2 footprint; the cell kernel sets its own
            // receiver's bias per lookup (`cell_filter` in lighting.wgsl).
            ShadowFilter::Cell { .. } => 1.0,
        };
        let mut flags = 0;
        if self.object_ids {
            flags |= FLAG_OBJECT_IDS;
        }
        if self.receiver_plane {
            flags |= FLAG_RECEIVER_PLANE;
        }
        if ShadowDepth::of(o.fault) == ShadowDepth::Conventional32 {
            flags |= FLAG_CONVENTIONAL_Z;
        }
        GpuFrame {
            light_count: plan.lights.len() as u32,
            map_size: plan.atlas.side.max(1) as f32,
            depth_bias,
            slope_bias,
            kernel_radius,
            flags,
            ..GpuFrame::for_camera(&self.camera, self.near)
        }
    }
}

fn req(texture: &wgpu::Texture, keep_channels: usize) -> ReadRequest<'_> {
    ReadRequest {
        texture,
        keep_channels,
    }
}

fn allocate<T>(gpu: &Gpu, what: &'static str, make: impl FnOnce() -> T) -> Result<T, RenderError> {
    gpu.allocate(what, |_| make())
}
/// Refuses a scene whose texels, materials or metallic-roughness parameters exceed the
/// device's storage-binding limit, or whose vertices its buffer limit.
fn check_scene_size(gpu: &Gpu, data: &SceneData) -> Result<(), RenderError> {
    let storage_max = gpu.limits.max_storage_buffer_binding_size;
    for (what, bytes) in [
        ("texture texels", data.texels.len() as u64 * 4),
        (
            "materials",
            std::mem::size_of_val(&data.materials[..]) as u64,
        ),
        (
            "metallic-roughness parameters",
            std::mem::size_of_val(&data.pbr[..]) as u64,
        ),
    ] {
        if bytes > storage_max {
            return Err(RenderError::BindingTooLarge {
                what,
                bytes,
                maximum: storage_max,
            });
        }
    }
    let vertex_bytes = std::mem::size_of_val(&data.vertices[..]) as u64;
    if vertex_bytes > gpu.limits.max_buffer_size {
        return Err(RenderError::BindingTooLarge {
            what: "vertices",
            bytes: vertex_bytes,
            maximum: gpu.limits.max_buffer_size,
        });
    }
    Ok(())
}

/// The pipelines for `scene` (its translucent casters, filters, metallic-roughness materials
/// and tangents), with the invalid pipeline of [`Fault::InvalidPipeline`]; what the device
/// refuses is an error.
fn build_pipelines(
    device: &wgpu::Device,
    scene: &Scene,
    data: &SceneData,
    opts: &RenderOptions,
    depth: ShadowDepth,
) -> Result<Pipelines, RenderError> {
    let translucent = data.meshes.iter().any(|m| m.translucent);
    let filters = scene.materials.iter().any(Material::is_filter);
    let metallic_roughness = scene.materials.iter().any(|m| m.pbr.is_some());
    let (pipelines, error) = captured(device, || {
        let pipelines = Pipelines::new(
            device,
            opts.filter,
            depth,
            translucent,
            filters,
            metallic_roughness,
            data.normal_mapped,
        );
        if opts.fault == Some(Fault::InvalidPipeline) {
            pipelines.invalid_pipeline(device);
        }
        pipelines
    });
    if let Some(e) = error {
        return Err(RenderError::Gpu(format!(
            "creating the pipelines failed: {e}"
        )));
    }
    Ok(pipelines)
}

/// The scene's buffers on the device: vertex buffers and what the scene bind group holds.
#[derive(Debug)]
struct SceneBuffers {
    vertices: wgpu::Buffer,
    tangents: wgpu::Buffer,
    materials: wgpu::Buffer,
    pbr: wgpu::Buffer,
    textures: wgpu::Buffer,
    texels: wgpu::Buffer,
    object_bounds: wgpu::Buffer,
    ltc: wgpu::Buffer,
}

impl SceneBuffers {
    /// Uploads `data`'s vertices, tangents, materials, textures and object bounds, and the
    /// LTC table; memory the device cannot allocate is an error.
    fn upload(gpu: &Gpu, data: &SceneData) -> Result<SceneBuffers, RenderError> {
        let device = &gpu.device;
        let init = |label: &str, contents: &[u8], usage| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage,
            })
        };
        // A vertex buffer cannot be empty either.
        let vbytes: &[u8] = if data.vertices.is_empty() {
            &[0; 48]
        } else {
            bytemuck::cast_slice(&data.vertices)
        };
        let tbytes = tangent_bytes(&data.tangents);
        allocate(gpu, "the scene buffers", || SceneBuffers {
            vertices: init(
                "vertices",
                vbytes,
                wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
            ),
            tangents: init(
                "tangents",
                tbytes,
                wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
            ),
            materials: init(
                "materials",
                bytemuck::cast_slice(&data.materials),
                wgpu::BufferUsages::STORAGE,
            ),
            pbr: init(
                "metallic-roughness",
                bytemuck::cast_slice(&data.pbr),
                wgpu::BufferUsages::STORAGE,
            ),
            textures: init(
                "textures",
                bytemuck::cast_slice(&data.textures),
                wgpu::BufferUsages::STORAGE,
            ),
            texels: init(
                "texels",
                bytemuck::cast_slice(&data.texels),
                wgpu::BufferUsages::STORAGE,
            ),
            object_bounds: init(
                "object bounds",
                bytemuck::cast_slice(&data.object_bounds),
                wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            ),
            ltc: init(
                "ltc table",
                bytemuck::cast_slice(lightfold_scene::ltc::table()),
                wgpu::BufferUsages::STORAGE,
            ),
        })
    }

    /// The scene bind group (group 0 of every pipeline) of `layout` over these buffers.
    fn bind_group(&self, device: &wgpu::Device, layout: &wgpu::BindGroupLayout) -> wgpu::BindGroup {
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("scene"),
            layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: self.materials.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: self.textures.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: self.texels.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 3,
                    resource: self.pbr.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: self.object_bounds.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 5,
                    resource: self.ltc.as_entire_binding(),
                },
            ],
        })
    }
}

/// The ambient mask `pass` rendered for a frame of `layers`, when they ask for it (`None`
/// otherwise); an error if they asked for it and none was rendered.
fn mask_output(
    pass: Option<&AmbientMaskPass>,
    layers: LayerSet,
) -> Result<Option<&wgpu::Texture>, RenderError> {
    if !layers.ambient_mask {
        return Ok(None);
    }
    pass.and_then(AmbientMaskPass::output)
        .map(Some)
        .ok_or_else(|| RenderError::Gpu("no ambient mask was rendered".into()))
}

/// The eye transmittance target of a renderer peeling `peel` with `pass`, when `layers` ask for
/// it (`None` otherwise); an error when they ask for it and the frame peeled no translucent
/// layer.
fn transmittance_output(
    peel: Option<u32>,
    pass: Option<&PeelPass>,
    layers: LayerSet,
) -> Result<Option<&wgpu::Texture>, RenderError> {
    if !layers.transmittance {
        return Ok(None);
    }
    match (peel, pass) {
        (Some(d), Some(p)) if d >= 1 => p
            .transmittance()
            .map(Some)
            .ok_or_else(|| RenderError::Gpu("no transmittance was rendered".into())),
        _ => Err(RenderError::Gpu(
            "a transmittance layer needs a translucent peel (peel >= 1)".into(),
        )),
    }
}

/// One chunk the eye pass may draw: its index in the scene's chunks, its bounds and its vertex
/// range (in the level buffer where `level`).
#[derive(Debug, Clone)]
struct EyeChunk {
    chunk: u32,
    bounds: ([f32; 3], [f32; 3]),
    level: bool,
    range: std::ops::Range<u32>,
}

/// The eye pass's draws of `chunks`, contiguous ranges merged.
fn eye_draws_of<'a>(chunks: impl Iterator<Item = &'a EyeChunk>) -> EyeDraws {
    let (mut scene, mut levels) = (Vec::new(), Vec::new());
    for c in chunks {
        if c.level {
            levels.push(c.range.clone());
        } else {
            scene.push(c.range.clone());
        }
    }
    EyeDraws {
        scene: super::scene_data::merged(scene),
        levels: super::scene_data::merged(levels),
        rows: None,
    }
}

/// What occlusion culling does in one frame (`Renderer::occlusion_step`).
#[derive(Debug)]
enum OcclusionStep {
    Off,
    /// Draw these chunks (sorted) as occluders and test every candidate against them.
    Occluders(Vec<u32>),
    /// Draw every candidate, then test them against the eye pass's depth for the next frame.
    After,
}

fn wait(gpu: &Gpu) -> Result<(), RenderError> {
    gpu.device
        .poll(wgpu::PollType::wait_indefinitely())
        .map(|_| ())
        .map_err(|e| RenderError::Gpu(format!("device wait: {e}")))
}

/// The bytes of the tangent buffer: the tangents, or a placeholder where the scene has none
/// (a buffer cannot be empty; no pipeline reads it then).
fn tangent_bytes(tangents: &[super::scene_data::Tangent]) -> &[u8] {
    if tangents.is_empty() {
        &[0; 16]
    } else {
        bytemuck::cast_slice(tangents)
    }
}

/// The level buffer (`gpu::lod`) holding `vertices`, or `None` without any.
fn lod_buffer(gpu: &Gpu, vertices: &[Vertex]) -> Result<Option<wgpu::Buffer>, RenderError> {
    if vertices.is_empty() {
        return Ok(None);
    }
    let bytes: &[u8] = bytemuck::cast_slice(vertices);
    if bytes.len() as u64 > gpu.limits.max_buffer_size {
        return Err(RenderError::BindingTooLarge {
            what: "simplified levels",
            bytes: bytes.len() as u64,
            maximum: gpu.limits.max_buffer_size,
        });
    }
    Ok(Some(allocate(gpu, "the simplified levels", || {
        gpu.device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("lod vertices"),
                contents: bytes,
                usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
            })
    })?))
}
