//! Eq. 7's per-pixel ambient mask on the device (`shaders/wgsl/ambient_mask.wgsl`): after the
//! eye pass, one compute pass writes `I^a = m^a ⊘ m^d` per channel from the m^d and m^a targets
//! into an `Rgba16Float` texture of its own, which is read back and packed like the material
//! targets. Exactly 1 where `m^a = m^d`, exactly 0 where either is 0. Built and allocated only
//! when a frame asks for the mask.

use super::pipelines::MATERIAL_FORMAT;

/// Pixels per workgroup side (`@workgroup_size(8, 8)`).
const WORKGROUP: u32 = 8;

/// The mask pass and its output texture (allocated at the frame's size on first use).
#[derive(Debug)]
pub(super) struct AmbientMaskPass {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    output: Option<wgpu::Texture>,
}

impl AmbientMaskPass {
    pub(super) fn new(device: &wgpu::Device) -> AmbientMaskPass {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("ambient mask"),
            source: wgpu::ShaderSource::Wgsl(lightfold_shaders::AMBIENT_MASK_WGSL.into()),
        });
        let sampled = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Texture {
                sample_type: wgpu::TextureSampleType::Float { filterable: false },
                view_dimension: wgpu::TextureViewDimension::D2,
                multisampled: false,
            },
            count: None,
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("ambient mask"),
            entries: &[
                sampled(0),
                sampled(1),
                wgpu::BindGroupLayoutEntry {
                    binding: 2,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::StorageTexture {
                        access: wgpu::StorageTextureAccess::WriteOnly,
                        format: MATERIAL_FORMAT,
                        view_dimension: wgpu::TextureViewDimension::D2,
                    },
                    count: None,
                },
            ],
        });
        let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("ambient mask"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("cs_ambient_mask"),
            layout: Some(&pl),
            module: &module,
            entry_point: Some("cs_ambient_mask"),
            compilation_options: Default::default(),
            cache: None,
        });
        AmbientMaskPass {
            pipeline,
            layout,
            output: None,
        }
    }

    /// The mask of the last frame [`AmbientMaskPass::run`] wrote.
    pub(super) fn output(&self) -> Option<&wgpu::Texture> {
        self.output.as_ref()
    }

    /// Writes the mask of `m_diffuse` and `m_ambient` (material targets of one size) into the
    /// output texture, (re)allocated at that size, and submits the pass.
    pub(super) fn run(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        m_diffuse: &wgpu::Texture,
        m_ambient: &wgpu::Texture,
    ) {
        let size = m_diffuse.size();
        if self.output.as_ref().is_none_or(|t| t.size() != size) {
            self.output = Some(device.create_texture(&wgpu::TextureDescriptor {
                label: Some("ambient mask"),
                size,
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: MATERIAL_FORMAT,
                usage: wgpu::TextureUsages::STORAGE_BINDING | wgpu::TextureUsages::COPY_SRC,
                view_formats: &[],
            }));
        }
        let output = self.output.as_ref().expect("allocated above");
        let view = |t: &wgpu::Texture| t.create_view(&wgpu::TextureViewDescriptor::default());
        let (d, a, o) = (view(m_diffuse), view(m_ambient), view(output));
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("ambient mask"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::TextureView(&d),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&a),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: wgpu::BindingResource::TextureView(&o),
                },
            ],
        });
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("ambient mask"),
        });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("ambient mask"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, &group, &[]);
            pass.dispatch_workgroups(
                size.width.div_ceil(WORKGROUP),
                size.height.div_ceil(WORKGROUP),
                1,
            );
        }
        queue.submit([encoder.finish()]);
    }
}
