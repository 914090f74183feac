//! Bind-group layouts and pipelines, built once per renderer from the `shaders` crate: opaque and
//! alpha-masked shadow pipelines writing depth and object ID (reversed-Z, depth clamp, no
//! culling: every triangle casts),
//! the forward and G-buffer eye rasters with or without the material-layer targets, and the
//! deferred light pass, compiled per set of sample kinds on first use. The shadow filter is
//! fixed per renderer and compiled in as a pipeline constant.

use lightfold_scene::ShadowFilter;
use lightfold_shaders::{
    OVERRIDE_LIGHT_KINDS, OVERRIDE_LIGHT_RANGES, OVERRIDE_SHADOW_FILTER, OVERRIDE_SHADOW_TAPS,
    OVERRIDE_TRANSLUCENT, OVERRIDE_VIEW_MODES,
};
use std::collections::HashMap;

use super::frame::RenderError;
use super::lights::{GpuLight, MODE_CASCADE};
use super::scene_data::Vertex;
use super::shadow_depth::ShadowDepth;
use super::shadow_pass::{OBJECT_ID_FORMAT, TRANSMIT_FORMAT};

/// Depth format of the eye pass (and of shadow maps, but for the depth negative controls).
pub(super) const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// Material layers as render targets (f16 keeps 4 of them within the per-sample byte limit).
pub(super) const MATERIAL_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;
/// Eye depth target: f32 bits in a u32, since GL cannot render to 32-bit float formats.
pub(super) const EYE_DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Uint;
/// Illumination targets: f32 bits in u32s, exact on every backend (GL has no Rgba32Float
/// target and f16 would cost the 1e-3 accuracy margin).
pub(super) const ILLUMINATION_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Uint;
/// Stride of per-view uniforms for dynamic offsets (the largest alignment any device asks for).
pub(super) const VIEW_UNIFORM_STRIDE: u64 = 256;

/// What every pass records with: the device, its queue, the pipelines and the scene's buffers.
#[derive(Debug, Clone, Copy)]
pub(super) struct DrawContext<'a> {
    pub device: &'a wgpu::Device,
    pub queue: &'a wgpu::Queue,
    pub pipelines: &'a Pipelines,
    pub scene_bind_group: &'a wgpu::BindGroup,
    pub vertices: &'a wgpu::Buffer,
    /// The simplified levels' vertices (`gpu::lod`, shadow and eye levels) where the scene has
    /// some, and whether shadow views draw the coarsest whatever its error
    /// (`Fault::LodCoarsest`).
    pub lod: Option<(&'a wgpu::Buffer, bool)>,
    /// The eye pipelines' tangents where the scene is normal-mapped (`tangent_layout`).
    pub tangents: Option<&'a wgpu::Buffer>,
}

/// Everything built from the shader sources.
#[derive(Debug)]
pub(super) struct Pipelines {
    pub scene_layout: wgpu::BindGroupLayout,
    pub shadow_layout: wgpu::BindGroupLayout,
    /// Group 1 of the forward pass: lights and views in storage buffers.
    pub eye_layout: wgpu::BindGroupLayout,
    /// Group 1 of the deferred variant: one chunk of lights and views in uniform buffers.
    pub chunk_layout: wgpu::BindGroupLayout,
    pub shadow_opaque: wgpu::RenderPipeline,
    pub shadow_masked: wgpu::RenderPipeline,
    /// Translucent casters: their nearest depth, and their transmittance multiplied into the
    /// transmittance map behind the opaque depth test (`docs/translucency.md`).
    pub shadow_translucent_depth: wgpu::RenderPipeline,
    pub shadow_transmit: wgpu::RenderPipeline,
    /// Two translucent layers per view (peeling renderers): the nearest translucent caster's
    /// depth with its own transmittance, and the second-nearest's depth (group 2: the first's
    /// depth, `second_layout`).
    pub shadow_translucent_first: wgpu::RenderPipeline,
    pub shadow_translucent_second: wgpu::RenderPipeline,
    pub second_layout: wgpu::BindGroupLayout,
    /// Whether the eye pipelines read transmittance maps (the scene has translucent casters).
    pub translucent: bool,
    pub eye_illumination: wgpu::RenderPipeline,
    pub eye_layers: wgpu::RenderPipeline,
    /// The filters' eye pass over the material layers (forward, deferred group layouts), where
    /// the scene has filters (`docs/translucency.md`).
    pub eye_filter: Option<[wgpu::RenderPipeline; 2]>,
    pub illumination_format: wgpu::TextureFormat,
    /// Deferred variant: G-buffer rasters (without / with material layers) and the light pass.
    pub deferred_layout: wgpu::BindGroupLayout,
    pub gbuffer: wgpu::RenderPipeline,
    pub gbuffer_layers: wgpu::RenderPipeline,
    deferred_module: wgpu::ShaderModule,
    deferred_pl: wgpu::PipelineLayout,
    /// The shadow filter's constants and `TRANSLUCENT`.
    filter: [(&'static str, f64); 3],
    /// `cs_lights` per set of lights it handles.
    light_passes: HashMap<LightSet, wgpu::ComputePipeline>,
    /// Which eye module the scene's pipelines are built from (the peel passes build theirs from
    /// the same choice: `gpu::peel`).
    pub metallic_roughness: bool,
    pub normal_mapped: bool,
}

/// G-buffer targets: position + material, shading normal, geometric normal (f32 bits).
pub(super) const GBUFFER_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Uint;

fn storage_entry(binding: u32, visibility: wgpu::ShaderStages) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only: true },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

const VERTEX_ATTRIBUTES: [wgpu::VertexAttribute; 6] = wgpu::vertex_attr_array![
    0 => Float32x3, 1 => Float32x3, 2 => Float32x3, 3 => Float32x2, 4 => Uint32, 5 => Uint32
];

const TANGENT_ATTRIBUTES: [wgpu::VertexAttribute; 1] = wgpu::vertex_attr_array![6 => Float32x4];

/// The eye pipelines' second vertex buffer where the scene is normal-mapped: a tangent per
/// vertex (`eye_vertex_mapped.wgsl`).
pub(super) fn tangent_layout() -> wgpu::VertexBufferLayout<'static> {
    wgpu::VertexBufferLayout {
        array_stride: std::mem::size_of::<super::scene_data::Tangent>() as u64,
        step_mode: wgpu::VertexStepMode::Vertex,
        attributes: &TANGENT_ATTRIBUTES,
    }
}

pub(super) fn vertex_layout() -> wgpu::VertexBufferLayout<'static> {
    wgpu::VertexBufferLayout {
        array_stride: std::mem::size_of::<Vertex>() as u64,
        step_mode: wgpu::VertexStepMode::Vertex,
        attributes: &VERTEX_ATTRIBUTES,
    }
}

pub(super) fn depth_state(write: bool) -> wgpu::DepthStencilState {
    wgpu::DepthStencilState {
        format: DEPTH_FORMAT,
        depth_write_enabled: Some(write),
        // Reversed-Z: larger is nearer.
        depth_compare: Some(wgpu::CompareFunction::Greater),
        stencil: wgpu::StencilState::default(),
        bias: wgpu::DepthBiasState::default(),
    }
}

/// What a light pass is compiled for: bit masks of the sample kinds (`GpuLight::kind`) and view
/// modes (`GpuLight::cube`) of its lights, and whether any has a range window. Code for what a
/// frame lacks folds away (a CPU rasteriser would run it, masked).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(super) struct LightSet {
    pub kinds: u32,
    pub modes: u32,
    pub ranges: bool,
}

impl LightSet {
    pub(super) fn of(lights: &[GpuLight]) -> LightSet {
        let bit = |v: u32| 1u32 << v.min(31);
        LightSet {
            kinds: lights.iter().fold(0, |m, l| m | bit(l.kind)),
            modes: lights.iter().fold(0, |m, l| {
                m | bit(l.cube) | if l.cascades > 0 { bit(MODE_CASCADE) } else { 0 }
            }),
            ranges: lights.iter().any(|l| l.range > 0.0),
        }
    }
}

/// The filter's pipeline constants: `FILTER_*` of `lighting.wgsl` and taps per axis; and whether
/// lookups read transmittance maps.
fn filter_constants(filter: ShadowFilter, translucent: bool) -> [(&'static str, f64); 3] {
    let (mode, taps) = match filter {
        ShadowFilter::None => (0, 1),
        ShadowFilter::Pcf2x2 => (1, 1),
        ShadowFilter::Pcf { taps } => (2, taps.clamp(1, 15)),
        ShadowFilter::Cell { taps } => (3, taps.clamp(2, 15)),
    };
    [
        (OVERRIDE_SHADOW_FILTER, f64::from(mode)),
        (OVERRIDE_SHADOW_TAPS, f64::from(taps)),
        (OVERRIDE_TRANSLUCENT, f64::from(u8::from(translucent))),
    ]
}

/// The bind-group layouts the pipeline layouts are made of.
#[derive(Debug)]
struct GroupLayouts {
    scene: wgpu::BindGroupLayout,
    shadow: wgpu::BindGroupLayout,
    /// Group 1 of the forward pass: lights and views in storage buffers.
    eye: wgpu::BindGroupLayout,
    /// Group 1 of the deferred variant: one chunk of lights and views in uniform buffers.
    chunk: wgpu::BindGroupLayout,
}

impl GroupLayouts {
    /// The scene's, the shadow views' and the eye passes' bind-group layouts.
    fn new(device: &wgpu::Device) -> GroupLayouts {
        // Lighting runs in fragment shaders (forward) and in a compute shader (deferred).
        let fragment = wgpu::ShaderStages::FRAGMENT | wgpu::ShaderStages::COMPUTE;
        let scene = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("scene"),
            entries: &[
                storage_entry(0, fragment),
                storage_entry(1, fragment),
                storage_entry(2, fragment),
                storage_entry(3, fragment),
                storage_entry(4, fragment),
                // The fitted table of closed-form glossy specular (`scene::ltc`).
                storage_entry(5, fragment),
            ],
        });
        let shadow = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("shadow view"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::VERTEX,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: true,
                    min_binding_size: wgpu::BufferSize::new(64),
                },
                count: None,
            }],
        });
        let eye = eye_group_layout(
            device,
            "eye",
            wgpu::BufferBindingType::Storage { read_only: true },
        );
        let chunk = eye_group_layout(device, "light chunk", wgpu::BufferBindingType::Uniform);
        GroupLayouts {
            scene,
            shadow,
            eye,
            chunk,
        }
    }
}

/// Group 1 of an eye pass, `label`: the frame uniform, lights and views in `data` buffers, the
/// shadow maps with their comparison sampler, object IDs, transmittance and translucent depth.
fn eye_group_layout(
    device: &wgpu::Device,
    label: &str,
    data: wgpu::BufferBindingType,
) -> wgpu::BindGroupLayout {
    // Lighting runs in fragment shaders (forward) and in a compute shader (deferred).
    let fragment = wgpu::ShaderStages::FRAGMENT | wgpu::ShaderStages::COMPUTE;
    let vf = wgpu::ShaderStages::VERTEX_FRAGMENT | wgpu::ShaderStages::COMPUTE;
    let comparison = |binding| wgpu::BindGroupLayoutEntry {
        binding,
        visibility: fragment,
        ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Comparison),
        count: None,
    };
    let data_entry = |binding| wgpu::BindGroupLayoutEntry {
        binding,
        visibility: fragment,
        ty: wgpu::BindingType::Buffer {
            ty: data,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    };
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some(label),
        entries: &[
            wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: vf,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            },
            data_entry(1),
            data_entry(2),
            wgpu::BindGroupLayoutEntry {
                binding: 3,
                visibility: fragment,
                ty: wgpu::BindingType::Texture {
                    sample_type: wgpu::TextureSampleType::Depth,
                    view_dimension: wgpu::TextureViewDimension::D2Array,
                    multisampled: false,
                },
                count: None,
            },
            comparison(4),
            wgpu::BindGroupLayoutEntry {
                binding: 5,
                visibility: fragment,
                ty: wgpu::BindingType::Texture {
                    sample_type: wgpu::TextureSampleType::Uint,
                    view_dimension: wgpu::TextureViewDimension::D2Array,
                    multisampled: false,
                },
                count: None,
            },
            wgpu::BindGroupLayoutEntry {
                binding: 6,
                visibility: fragment,
                ty: wgpu::BindingType::Texture {
                    sample_type: wgpu::TextureSampleType::Float { filterable: false },
                    view_dimension: wgpu::TextureViewDimension::D2Array,
                    multisampled: false,
                },
                count: None,
            },
            wgpu::BindGroupLayoutEntry {
                binding: 7,
                visibility: fragment,
                ty: wgpu::BindingType::Texture {
                    sample_type: wgpu::TextureSampleType::Depth,
                    view_dimension: wgpu::TextureViewDimension::D2Array,
                    multisampled: false,
                },
                count: None,
            },
        ],
    })
}

/// The shader modules: the shadow passes', the forward eye pass's and the deferred one's.
#[derive(Debug)]
struct Modules {
    shadow: wgpu::ShaderModule,
    forward: wgpu::ShaderModule,
    deferred: wgpu::ShaderModule,
}

impl Modules {
    /// Compiles `shadow.wgsl` and the eye modules `forward_wgsl` and `deferred_wgsl`.
    fn new(device: &wgpu::Device, forward_wgsl: &str, deferred_wgsl: &str) -> Modules {
        let shadow = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("shadow.wgsl"),
            source: wgpu::ShaderSource::Wgsl(lightfold_shaders::SHADOW_WGSL.into()),
        });
        let forward = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("forward eye pass"),
            source: wgpu::ShaderSource::Wgsl(forward_wgsl.into()),
        });
        let deferred = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("deferred eye pass"),
            source: wgpu::ShaderSource::Wgsl(deferred_wgsl.into()),
        });
        Modules {
            shadow,
            forward,
            deferred,
        }
    }
}

/// The render pipelines' layouts: the shadow passes', the forward eye pass's and the G-buffer's.
#[derive(Debug)]
struct RasterLayouts {
    shadow: wgpu::PipelineLayout,
    forward: wgpu::PipelineLayout,
    gbuffer: wgpu::PipelineLayout,
}

impl RasterLayouts {
    /// The scene's group followed by the shadow view's, the eye group or a light chunk.
    fn new(device: &wgpu::Device, groups: &GroupLayouts) -> RasterLayouts {
        let shadow = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("shadow"),
            bind_group_layouts: &[Some(&groups.scene), Some(&groups.shadow)],
            immediate_size: 0,
        });
        let forward = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("forward eye pass"),
            bind_group_layouts: &[Some(&groups.scene), Some(&groups.eye)],
            immediate_size: 0,
        });
        let gbuffer = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("g-buffer"),
            bind_group_layouts: &[Some(&groups.scene), Some(&groups.chunk)],
            immediate_size: 0,
        });
        RasterLayouts {
            shadow,
            forward,
            gbuffer,
        }
    }
}

/// A colour target written as is (no blending).
pub(super) fn color_target(format: wgpu::TextureFormat) -> Option<wgpu::ColorTargetState> {
    Some(wgpu::ColorTargetState {
        format,
        blend: None,
        write_mask: wgpu::ColorWrites::ALL,
    })
}

/// dst·src: the target starts at 1 and each fragment multiplies its value in, in any order.
fn multiply_blend() -> wgpu::BlendState {
    let multiply = wgpu::BlendComponent {
        src_factor: wgpu::BlendFactor::Zero,
        dst_factor: wgpu::BlendFactor::Src,
        operation: wgpu::BlendOperation::Add,
    };
    wgpu::BlendState {
        color: multiply,
        alpha: multiply,
    }
}

/// The shadow passes' pipelines.
#[derive(Debug)]
struct ShadowPipelines {
    opaque: wgpu::RenderPipeline,
    masked: wgpu::RenderPipeline,
    translucent_depth: wgpu::RenderPipeline,
    transmit: wgpu::RenderPipeline,
    translucent_first: wgpu::RenderPipeline,
    translucent_second: wgpu::RenderPipeline,
}

/// What every shadow pipeline is built from: the device, `shadow.wgsl`, the shadow layout and
/// the depth encoding.
#[derive(Debug, Clone, Copy)]
struct ShadowRasters<'a> {
    device: &'a wgpu::Device,
    module: &'a wgpu::ShaderModule,
    layout: &'a wgpu::PipelineLayout,
    /// The second translucent layer's: the shadow layout and the first layer's depth.
    second_layout: &'a wgpu::PipelineLayout,
    depth: ShadowDepth,
}

impl ShadowRasters<'_> {
    /// One shadow pipeline of entry points `vs` and `fs`. `write`: the pass writes depth (else
    /// it only tests against the opaque casters'); `target`: its colour target, if any, and how
    /// fragments blend into it.
    fn pipeline(
        &self,
        vs: &str,
        fs: &str,
        write: bool,
        target: Option<wgpu::ColorTargetState>,
    ) -> wgpu::RenderPipeline {
        self.pipeline_in(self.layout, vs, fs, write, target, &[])
    }

    /// [`Self::pipeline`] of pipeline layout `layout` and pipeline constants `constants`.
    fn pipeline_in(
        &self,
        layout: &wgpu::PipelineLayout,
        vs: &str,
        fs: &str,
        write: bool,
        target: Option<wgpu::ColorTargetState>,
        constants: &[(&str, f64)],
    ) -> wgpu::RenderPipeline {
        let shadow_primitive = wgpu::PrimitiveState {
            cull_mode: None,
            // Casters between the light and the fitted near plane clamp to depth 1 instead of
            // being clipped away.
            unclipped_depth: true,
            ..Default::default()
        };
        self.device
            .create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(fs),
                layout: Some(layout),
                vertex: wgpu::VertexState {
                    module: self.module,
                    entry_point: Some(vs),
                    compilation_options: Default::default(),
                    buffers: &[Some(vertex_layout())],
                },
                primitive: shadow_primitive,
                depth_stencil: Some(wgpu::DepthStencilState {
                    format: self.depth.format(),
                    depth_compare: Some(self.depth.write_compare()),
                    ..depth_state(write)
                }),
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module: self.module,
                    entry_point: Some(fs),
                    compilation_options: wgpu::PipelineCompilationOptions {
                        constants,
                        ..Default::default()
                    },
                    targets: &target.into_iter().map(Some).collect::<Vec<_>>(),
                }),
                multiview_mask: None,
                cache: None,
            })
    }

    /// The opaque and alpha-masked casters' pipelines (depth and object IDs), then the
    /// translucent casters' depth and transmittance pipelines.
    fn pipelines(&self) -> ShadowPipelines {
        let ids = Some(wgpu::ColorTargetState {
            format: OBJECT_ID_FORMAT,
            blend: None,
            write_mask: wgpu::ColorWrites::ALL,
        });
        let opaque = self.pipeline("vs_depth", "fs_depth", true, ids.clone());
        let masked = self.pipeline("vs_masked", "fs_masked", true, ids);
        let translucent_depth = self.pipeline("vs_masked", "fs_translucent_depth", true, None);
        // dst·src: the map starts at 1 and each translucent fragment multiplies its
        // transmittance in, in any order.
        let transmit = self.pipeline(
            "vs_masked",
            "fs_transmit",
            false,
            Some(wgpu::ColorTargetState {
                format: TRANSMIT_FORMAT,
                blend: Some(multiply_blend()),
                write_mask: wgpu::ColorWrites::ALL,
            }),
        );
        let translucent_first = self.pipeline(
            "vs_masked",
            "fs_translucent_first",
            true,
            color_target(TRANSMIT_FORMAT),
        );
        let step = if self.depth.format() == wgpu::TextureFormat::Depth16Unorm {
            1.0 / 65535.0
        } else {
            0.0
        };
        let translucent_second = self.pipeline_in(
            self.second_layout,
            "vs_masked",
            "fs_translucent_second",
            true,
            None,
            &[
                ("REVERSED_Z", f64::from(u8::from(self.depth.reversed()))),
                ("DEPTH_STEP", step),
            ],
        );
        ShadowPipelines {
            opaque,
            masked,
            translucent_depth,
            transmit,
            translucent_first,
            translucent_second,
        }
    }
}

/// The eye rasters: forward and G-buffer, without and with the material layers, and the
/// filters' pass where the scene has filters.
#[derive(Debug)]
struct EyePipelines {
    illumination: wgpu::RenderPipeline,
    layers: wgpu::RenderPipeline,
    gbuffer: wgpu::RenderPipeline,
    gbuffer_layers: wgpu::RenderPipeline,
    filter: Option<[wgpu::RenderPipeline; 2]>,
}

/// What every eye raster is built with: the device, the shadow filter's pipeline constants and
/// whether the vertex stage reads a tangent per vertex.
/// The renderer's own passes build theirs through [`Pipelines::eye_rasters`].
#[derive(Debug, Clone, Copy)]
pub(super) struct EyeRasters<'a> {
    device: &'a wgpu::Device,
    filter: &'a [(&'static str, f64); 3],
    normal_mapped: bool,
}

impl EyeRasters<'_> {
    /// One eye raster of `module`'s `vs_eye` and `fs` into `targets`. `write`: the raster
    /// writes depth (the filters' pass only tests against it).
    pub(super) fn pipeline(
        &self,
        module: &wgpu::ShaderModule,
        layout: &wgpu::PipelineLayout,
        fs: &str,
        targets: &[Option<wgpu::ColorTargetState>],
        write: bool,
    ) -> wgpu::RenderPipeline {
        let eye_buffers = [Some(vertex_layout()), Some(tangent_layout())];
        self.device
            .create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(fs),
                layout: Some(layout),
                vertex: wgpu::VertexState {
                    module,
                    entry_point: Some("vs_eye"),
                    compilation_options: Default::default(),
                    buffers: if self.normal_mapped {
                        &eye_buffers[..]
                    } else {
                        &eye_buffers[..1]
                    },
                },
                // Sidedness is decided per material in the shader (single-sided back faces discard).
                primitive: wgpu::PrimitiveState::default(),
                depth_stencil: Some(depth_state(write)),
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module,
                    entry_point: Some(fs),
                    compilation_options: wgpu::PipelineCompilationOptions {
                        constants: self.filter,
                        ..Default::default()
                    },
                    targets,
                }),
                multiview_mask: None,
                cache: None,
            })
    }

    /// The forward and G-buffer rasters, without and with the material layers, then (with
    /// `filters`) the filters' pass for each.
    fn pipelines(&self, modules: &Modules, layouts: &RasterLayouts, filters: bool) -> EyePipelines {
        let illum_targets = [
            color_target(ILLUMINATION_FORMAT),
            color_target(ILLUMINATION_FORMAT),
            color_target(EYE_DEPTH_FORMAT),
        ];
        let layer_targets = [
            color_target(ILLUMINATION_FORMAT),
            color_target(ILLUMINATION_FORMAT),
            color_target(EYE_DEPTH_FORMAT),
            color_target(MATERIAL_FORMAT),
            color_target(MATERIAL_FORMAT),
            color_target(MATERIAL_FORMAT),
            color_target(MATERIAL_FORMAT),
        ];
        let forward = |fs, targets: &[_]| {
            self.pipeline(&modules.forward, &layouts.forward, fs, targets, true)
        };
        let illumination = forward("fs_illumination", &illum_targets);
        let layers = forward("fs_layers", &layer_targets);
        let gbuffer_targets = [
            color_target(GBUFFER_FORMAT),
            color_target(GBUFFER_FORMAT),
            color_target(GBUFFER_FORMAT),
            color_target(EYE_DEPTH_FORMAT),
            color_target(MATERIAL_FORMAT),
            color_target(MATERIAL_FORMAT),
            color_target(MATERIAL_FORMAT),
            color_target(MATERIAL_FORMAT),
        ];
        let gbuffer = self.pipeline(
            &modules.deferred,
            &layouts.gbuffer,
            "fs_gbuffer",
            &gbuffer_targets[..4],
            true,
        );
        let gbuffer_layers = self.pipeline(
            &modules.deferred,
            &layouts.gbuffer,
            "fs_gbuffer_layers",
            &gbuffer_targets,
            true,
        );
        let filter = filters.then(|| self.filter_pipelines(modules, layouts));
        EyePipelines {
            illumination,
            layers,
            gbuffer,
            gbuffer_layers,
            filter,
        }
    }

    /// The filters' eye pass over the material layers, with the forward and the deferred
    /// group layouts.
    fn filter_pipelines(
        &self,
        modules: &Modules,
        layouts: &RasterLayouts,
    ) -> [wgpu::RenderPipeline; 2] {
        // dst·src into each material layer, behind the eye depth test (kept, not written).
        let filter_target = Some(wgpu::ColorTargetState {
            format: MATERIAL_FORMAT,
            blend: Some(multiply_blend()),
            write_mask: wgpu::ColorWrites::ALL,
        });
        let filter_targets = [
            filter_target.clone(),
            filter_target.clone(),
            filter_target.clone(),
            filter_target,
        ];
        [
            self.pipeline(
                &modules.forward,
                &layouts.forward,
                "fs_eye_filter",
                &filter_targets,
                false,
            ),
            self.pipeline(
                &modules.deferred,
                &layouts.gbuffer,
                "fs_eye_filter",
                &filter_targets,
                false,
            ),
        ]
    }
}

/// The deferred light pass's group 2 (the G-buffer and the lit buffer) and its pipeline layout.
fn deferred_layouts(
    device: &wgpu::Device,
    groups: &GroupLayouts,
) -> (wgpu::BindGroupLayout, wgpu::PipelineLayout) {
    let gbuffer_entry = |binding| wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Uint,
            view_dimension: wgpu::TextureViewDimension::D2,
            multisampled: false,
        },
        count: None,
    };
    let deferred_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("deferred"),
        entries: &[
            gbuffer_entry(0),
            gbuffer_entry(1),
            gbuffer_entry(2),
            wgpu::BindGroupLayoutEntry {
                binding: 3,
                visibility: wgpu::ShaderStages::COMPUTE,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Storage { read_only: false },
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            },
        ],
    });
    let deferred_pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("deferred lights"),
        bind_group_layouts: &[
            Some(&groups.scene),
            Some(&groups.chunk),
            Some(&deferred_layout),
        ],
        immediate_size: 0,
    });
    (deferred_layout, deferred_pl)
}

impl Pipelines {
    /// `translucent`: the scene has translucent casters, so lookups read transmittance maps
    /// (a scene without compiles them out and renders as before they existed); `filters`: some
    /// are filters, which eye rays see through (`docs/translucency.md`); `metallic_roughness`:
    /// some material is (else the eye modules hold none of the glTF BRDF's code); `normal_mapped`: the eye
    /// pipelines read a tangent per vertex (`eye_vertex_mapped.wgsl`; else none).
    pub(super) fn new(
        device: &wgpu::Device,
        filter: ShadowFilter,
        depth: ShadowDepth,
        translucent: bool,
        filters: bool,
        metallic_roughness: bool,
        normal_mapped: bool,
    ) -> Pipelines {
        let filter = filter_constants(filter, translucent);
        let (forward_wgsl, deferred_wgsl) =
            lightfold_shaders::eye_modules(metallic_roughness, normal_mapped);
        let groups = GroupLayouts::new(device);
        let modules = Modules::new(device, forward_wgsl, deferred_wgsl);
        let layouts = RasterLayouts::new(device, &groups);
        let second_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("first translucent depth"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Texture {
                    sample_type: wgpu::TextureSampleType::Depth,
                    view_dimension: wgpu::TextureViewDimension::D2,
                    multisampled: false,
                },
                count: None,
            }],
        });
        let second_pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("second translucent layer"),
            bind_group_layouts: &[
                Some(&groups.scene),
                Some(&groups.shadow),
                Some(&second_layout),
            ],
            immediate_size: 0,
        });
        let shadow = ShadowRasters {
            device,
            module: &modules.shadow,
            layout: &layouts.shadow,
            second_layout: &second_pl,
            depth,
        }
        .pipelines();
        let eye = EyeRasters {
            device,
            filter: &filter,
            normal_mapped,
        }
        .pipelines(&modules, &layouts, filters);
        let (deferred_layout, deferred_pl) = deferred_layouts(device, &groups);
        Pipelines {
            scene_layout: groups.scene,
            shadow_layout: groups.shadow,
            eye_layout: groups.eye,
            chunk_layout: groups.chunk,
            shadow_opaque: shadow.opaque,
            shadow_masked: shadow.masked,
            shadow_translucent_depth: shadow.translucent_depth,
            shadow_transmit: shadow.transmit,
            shadow_translucent_first: shadow.translucent_first,
            shadow_translucent_second: shadow.translucent_second,
            second_layout,
            translucent,
            eye_illumination: eye.illumination,
            eye_layers: eye.layers,
            eye_filter: eye.filter,
            illumination_format: ILLUMINATION_FORMAT,
            deferred_layout,
            gbuffer: eye.gbuffer,
            gbuffer_layers: eye.gbuffer_layers,
            deferred_module: modules.deferred,
            deferred_pl,
            filter,
            light_passes: HashMap::new(),
            metallic_roughness,
            normal_mapped,
        }
    }

    /// Builds eye rasters as the scene's own are built (its constants and vertex buffers), for
    /// the passes that compile modules of their own (`gpu::peel`, `gpu::occlusion`).
    pub(super) fn eye_rasters<'a>(&'a self, device: &'a wgpu::Device) -> EyeRasters<'a> {
        EyeRasters {
            device,
            filter: &self.filter,
            normal_mapped: self.normal_mapped,
        }
    }

    /// The deferred light pass for `lights`, compiled on first use (a handle: clones share the
    /// pipeline). A pipeline the device rejects is an error and is not kept.
    pub(super) fn light_pass(
        &mut self,
        device: &wgpu::Device,
        lights: LightSet,
    ) -> Result<wgpu::ComputePipeline, RenderError> {
        let (module, layout, filter) = (&self.deferred_module, &self.deferred_pl, self.filter);
        if let Some(p) = self.light_passes.get(&lights) {
            return Ok(p.clone());
        }
        let (pipeline, error) = super::device::captured(device, || {
            let constants = [
                filter[0],
                filter[1],
                filter[2],
                (OVERRIDE_LIGHT_KINDS, f64::from(lights.kinds)),
                (OVERRIDE_VIEW_MODES, f64::from(lights.modes)),
                (OVERRIDE_LIGHT_RANGES, f64::from(u8::from(lights.ranges))),
            ];
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some("cs_lights"),
                layout: Some(layout),
                module,
                entry_point: Some("cs_lights"),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants: &constants,
                    ..Default::default()
                },
                cache: None,
            })
        });
        if let Some(e) = error {
            return Err(RenderError::Gpu(format!(
                "compiling the light pass failed: {e}"
            )));
        }
        self.light_passes.insert(lights, pipeline.clone());
        Ok(pipeline)
    }

    /// A compute pipeline naming an entry point the deferred shader lacks
    /// (`Fault::InvalidPipeline`).
    pub(super) fn invalid_pipeline(&self, device: &wgpu::Device) {
        let _ = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("deliberately invalid"),
            layout: Some(&self.deferred_pl),
            module: &self.deferred_module,
            entry_point: Some("no_such_entry_point"),
            compilation_options: Default::default(),
            cache: None,
        });
    }
}
