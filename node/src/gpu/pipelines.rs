//! Bind-group layouts and render pipelines, built once per renderer from the `shaders` crate:
//! depth-only and alpha-masked shadow pipelines (reversed-Z, depth clamp, no culling: every
//! triangle casts), and the eye pipelines with or without the material-layer targets.

use super::scene_data::Vertex;

/// Depth format of shadow maps and of the eye pass.
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// Material layers as render targets (f16 keeps 4 of them within the per-sample byte limit).
pub const MATERIAL_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;
/// Eye depth target: f32 bits in a u32, since GL cannot render to 32-bit float formats.
pub const EYE_DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Uint;
/// Illumination targets: f32 bits in u32s, exact on every backend (GL has no Rgba32Float
/// target and f16 would cost the 1e-3 accuracy margin).
pub const ILLUMINATION_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Uint;
/// Stride of per-view uniforms for dynamic offsets (the largest alignment any device asks for).
pub const VIEW_UNIFORM_STRIDE: u64 = 256;

/// What every pass records with: the device, its queue, the pipelines and the scene's buffers.
#[derive(Debug, Clone, Copy)]
pub struct DrawContext<'a> {
    pub device: &'a wgpu::Device,
    pub queue: &'a wgpu::Queue,
    pub pipelines: &'a Pipelines,
    pub scene_bind_group: &'a wgpu::BindGroup,
    pub vertices: &'a wgpu::Buffer,
}

/// Everything built from the shader sources.
#[derive(Debug)]
pub struct Pipelines {
    pub scene_layout: wgpu::BindGroupLayout,
    pub shadow_layout: wgpu::BindGroupLayout,
    pub eye_layout: wgpu::BindGroupLayout,
    pub shadow_opaque: wgpu::RenderPipeline,
    pub shadow_masked: wgpu::RenderPipeline,
    pub eye_illumination: wgpu::RenderPipeline,
    pub eye_layers: wgpu::RenderPipeline,
    pub illumination_format: wgpu::TextureFormat,
    /// Deferred variant: G-buffer rasters (without / with material layers) and the light pass.
    pub deferred_layout: wgpu::BindGroupLayout,
    pub gbuffer: wgpu::RenderPipeline,
    pub gbuffer_layers: wgpu::RenderPipeline,
    pub deferred_lights: wgpu::ComputePipeline,
}

/// G-buffer targets: position + material, shading normal, geometric normal (f32 bits).
pub const GBUFFER_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Uint;

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

const VERTEX_ATTRIBUTES: [wgpu::VertexAttribute; 5] = wgpu::vertex_attr_array![
    0 => Float32x3, 1 => Float32x3, 2 => Float32x3, 3 => Float32x2, 4 => Uint32
];

fn vertex_layout() -> wgpu::VertexBufferLayout<'static> {
    wgpu::VertexBufferLayout {
        array_stride: std::mem::size_of::<Vertex>() as u64,
        step_mode: wgpu::VertexStepMode::Vertex,
        attributes: &VERTEX_ATTRIBUTES,
    }
}

fn depth_state(write: bool) -> wgpu::DepthStencilState {
    wgpu::DepthStencilState {
        format: DEPTH_FORMAT,
        depth_write_enabled: Some(write),
        // Reversed-Z: larger is nearer.
        depth_compare: Some(wgpu::CompareFunction::Greater),
        stencil: wgpu::StencilState::default(),
        bias: wgpu::DepthBiasState::default(),
    }
}

impl Pipelines {
    pub fn new(device: &wgpu::Device) -> Pipelines {
        // Lighting runs in fragment shaders (forward) and in a compute shader (deferred).
        let fragment = wgpu::ShaderStages::FRAGMENT | wgpu::ShaderStages::COMPUTE;
        let vf = wgpu::ShaderStages::VERTEX_FRAGMENT | wgpu::ShaderStages::COMPUTE;
        let scene_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("scene"),
            entries: &[
                storage_entry(0, fragment),
                storage_entry(1, fragment),
                storage_entry(2, fragment),
            ],
        });
        let shadow_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
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
        let comparison = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: fragment,
            ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Comparison),
            count: None,
        };
        let eye_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("eye"),
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
                storage_entry(1, fragment),
                storage_entry(2, fragment),
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
            ],
        });

        let shadow_module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("shadow.wgsl"),
            source: wgpu::ShaderSource::Wgsl(lightfold_shaders::SHADOW_WGSL.into()),
        });
        let eye_module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("eye.wgsl"),
            source: wgpu::ShaderSource::Wgsl(lightfold_shaders::EYE_WGSL.into()),
        });
        let shadow_pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("shadow"),
            bind_group_layouts: &[Some(&scene_layout), Some(&shadow_layout)],
            immediate_size: 0,
        });
        let eye_pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("eye"),
            bind_group_layouts: &[Some(&scene_layout), Some(&eye_layout)],
            immediate_size: 0,
        });

        let shadow_primitive = wgpu::PrimitiveState {
            cull_mode: None,
            // Casters between the light and the fitted near plane clamp to depth 1 instead of
            // being clipped away.
            unclipped_depth: true,
            ..Default::default()
        };
        let shadow = |vs: &str, fs: Option<&str>| {
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(vs),
                layout: Some(&shadow_pl),
                vertex: wgpu::VertexState {
                    module: &shadow_module,
                    entry_point: Some(vs),
                    compilation_options: Default::default(),
                    buffers: &[Some(vertex_layout())],
                },
                primitive: shadow_primitive,
                depth_stencil: Some(depth_state(true)),
                multisample: Default::default(),
                fragment: fs.map(|fs| wgpu::FragmentState {
                    module: &shadow_module,
                    entry_point: Some(fs),
                    compilation_options: Default::default(),
                    targets: &[],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let shadow_opaque = shadow("vs_depth", None);
        let shadow_masked = shadow("vs_masked", Some("fs_masked"));

        let illumination_format = ILLUMINATION_FORMAT;
        let target = |f: wgpu::TextureFormat| {
            Some(wgpu::ColorTargetState {
                format: f,
                blend: None,
                write_mask: wgpu::ColorWrites::ALL,
            })
        };
        let illum_targets = [
            target(illumination_format),
            target(illumination_format),
            target(EYE_DEPTH_FORMAT),
        ];
        let layer_targets = [
            target(illumination_format),
            target(illumination_format),
            target(EYE_DEPTH_FORMAT),
            target(MATERIAL_FORMAT),
            target(MATERIAL_FORMAT),
            target(MATERIAL_FORMAT),
            target(MATERIAL_FORMAT),
        ];
        let eye = |fs: &str, targets: &[Option<wgpu::ColorTargetState>]| {
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(fs),
                layout: Some(&eye_pl),
                vertex: wgpu::VertexState {
                    module: &eye_module,
                    entry_point: Some("vs_eye"),
                    compilation_options: Default::default(),
                    buffers: &[Some(vertex_layout())],
                },
                // Sidedness is decided per material in the shader (single-sided back faces discard).
                primitive: wgpu::PrimitiveState::default(),
                depth_stencil: Some(depth_state(true)),
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &eye_module,
                    entry_point: Some(fs),
                    compilation_options: Default::default(),
                    targets,
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        let eye_illumination = eye("fs_illumination", &illum_targets);
        let eye_layers = eye("fs_layers", &layer_targets);
        let gbuffer_targets = [
            target(GBUFFER_FORMAT),
            target(GBUFFER_FORMAT),
            target(GBUFFER_FORMAT),
            target(EYE_DEPTH_FORMAT),
            target(MATERIAL_FORMAT),
            target(MATERIAL_FORMAT),
            target(MATERIAL_FORMAT),
            target(MATERIAL_FORMAT),
        ];
        let gbuffer = eye("fs_gbuffer", &gbuffer_targets[..4]);
        let gbuffer_layers = eye("fs_gbuffer_layers", &gbuffer_targets);
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
                Some(&scene_layout),
                Some(&eye_layout),
                Some(&deferred_layout),
            ],
            immediate_size: 0,
        });
        let deferred_lights = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("cs_lights"),
            layout: Some(&deferred_pl),
            module: &eye_module,
            entry_point: Some("cs_lights"),
            compilation_options: Default::default(),
            cache: None,
        });
        Pipelines {
            scene_layout,
            shadow_layout,
            eye_layout,
            shadow_opaque,
            shadow_masked,
            eye_illumination,
            eye_layers,
            illumination_format,
            deferred_layout,
            gbuffer,
            gbuffer_layers,
            deferred_lights,
        }
    }
}
