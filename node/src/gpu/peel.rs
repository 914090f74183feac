//! Peeled eye layers (`NodeConfig::peel`, `docs/translucency.md`): the opaque layer (peel 0) and
//! the d-th nearest translucent surface in front of it (peel d ≥ 1), from the peel module
//! (`shaders/wgsl/peel.wgsl`, the forward module with the peel entry points after it). Built and
//! allocated only when a renderer is first asked for a peel. Peel 0 runs in either eye variant
//! (its G-buffer rasters from the deferred module with `peel_gbuffer.wgsl`, the classic light
//! pass after them); peels d ≥ 1 always run forward: a deferred translucent layer would need
//! its G-buffer, eye depth, four material and its transmittance targets in one raster, nine
//! colour attachments where devices guarantee eight.
//!
//! Peel d ≥ 1 is depth peeling, d passes in one submission. Pass k = 1..=d: a depth-only raster
//! of the opaque surfaces into the cleared eye depth buffer (translucent materials, single-sided
//! back faces and masked-out texels rejected, as peel 0 rejects them), then a raster of the
//! translucent fragments depth-tested against it and written (so the nearest wins), each kept
//! only where its eye depth lies beyond pass k − 1's by more than
//! [`lightfold_shaders::PEEL_EPSILON`] of it. Passes k < d write that eye depth into one of two
//! `R32Uint` targets (ping-pong, the next pass reads it); pass d writes the layer: illumination,
//! eye depth, the material layers times its eye coverage and its eye transmittance (`Rgba16Float`,
//! cleared to 1: 1 where there is no such layer, as everything else there is 0).

use super::eye_pass::{
    EyeDraws, EyeInputs, EyeTargets, attachments, begin_depth_pass, draw_eye, eye_bind_group,
    record_raster, scissor,
};
use super::pipelines::{
    DrawContext, EYE_DEPTH_FORMAT, GBUFFER_FORMAT, ILLUMINATION_FORMAT, MATERIAL_FORMAT, Pipelines,
    color_target,
};
use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

/// The deepest peel a node renders (`NodeConfig::peel`; `configure` refuses deeper ones): each
/// peel costs two rasters of the scene.
pub const MAX_PEEL: u32 = 8;

/// The eye transmittance target's format (the material targets').
pub(super) const TRANSMITTANCE_FORMAT: wgpu::TextureFormat = MATERIAL_FORMAT;

/// `PeelParams` in `peel.wgsl` (uniform layout).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct GpuPeel {
    first: u32,
    epsilon: f32,
    pad: [u32; 2],
}

/// The peel pipelines, and the targets of the last size asked for.
#[derive(Debug)]
pub(super) struct PeelPass {
    /// Peel 0 (forward group layouts): without and with the material layers.
    opaque_illumination: wgpu::RenderPipeline,
    opaque_layers: wgpu::RenderPipeline,
    /// Peel 0's G-buffer rasters (deferred variant): without and with the material layers.
    gbuffer: [wgpu::RenderPipeline; 2],
    /// Peel d ≥ 1 (with group 2): the opaque surfaces' depth, a pass's eye depth, the layer.
    opaque_depth: wgpu::RenderPipeline,
    depth: wgpu::RenderPipeline,
    layers: wgpu::RenderPipeline,
    group_layout: wgpu::BindGroupLayout,
    targets: Option<PeelTargets>,
}

/// The transmittance target and the two peel-depth targets of one image size.
#[derive(Debug)]
struct PeelTargets {
    width: u32,
    height: u32,
    transmittance: wgpu::Texture,
    ping: [wgpu::Texture; 2],
}

fn texture(
    device: &wgpu::Device,
    label: &str,
    [w, h]: [u32; 2],
    format: wgpu::TextureFormat,
    usage: wgpu::TextureUsages,
) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width: w,
            height: h,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage,
        view_formats: &[],
    })
}

impl PeelPass {
    /// Compiles the peel module of the renderer's scene and its pipelines.
    pub(super) fn new(device: &wgpu::Device, p: &Pipelines) -> PeelPass {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("peel eye passes"),
            source: wgpu::ShaderSource::Wgsl(
                lightfold_shaders::peel_module(p.metallic_roughness, p.normal_mapped).into(),
            ),
        });
        let group_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("peel"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Uint,
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
            ],
        });
        let forward = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("peel 0"),
            bind_group_layouts: &[Some(&p.scene_layout), Some(&p.eye_layout)],
            immediate_size: 0,
        });
        let peeled = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("peel passes"),
            bind_group_layouts: &[
                Some(&p.scene_layout),
                Some(&p.eye_layout),
                Some(&group_layout),
            ],
            immediate_size: 0,
        });
        let gbuffer_module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("peel 0 g-buffer"),
            source: wgpu::ShaderSource::Wgsl(
                lightfold_shaders::peel_deferred_module(p.metallic_roughness, p.normal_mapped)
                    .into(),
            ),
        });
        let gbuffer_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("peel 0 g-buffer"),
            bind_group_layouts: &[Some(&p.scene_layout), Some(&p.chunk_layout)],
            immediate_size: 0,
        });
        let rasters = p.eye_rasters(device);
        let raster = |module: &wgpu::ShaderModule,
                      layout: &wgpu::PipelineLayout,
                      fs: &str,
                      targets: &[Option<wgpu::ColorTargetState>]| {
            rasters.pipeline(module, layout, fs, targets, true)
        };
        let pipeline = |layout: &wgpu::PipelineLayout,
                        fs: &str,
                        targets: &[Option<wgpu::ColorTargetState>]| {
            raster(&module, layout, fs, targets)
        };
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
        let gbuffer = [
            raster(
                &gbuffer_module,
                &gbuffer_layout,
                "fs_gbuffer_peel",
                &gbuffer_targets[..4],
            ),
            raster(
                &gbuffer_module,
                &gbuffer_layout,
                "fs_gbuffer_layers_peel",
                &gbuffer_targets,
            ),
        ];
        let illumination = [
            color_target(ILLUMINATION_FORMAT),
            color_target(ILLUMINATION_FORMAT),
            color_target(EYE_DEPTH_FORMAT),
        ];
        let layers = [
            color_target(ILLUMINATION_FORMAT),
            color_target(ILLUMINATION_FORMAT),
            color_target(EYE_DEPTH_FORMAT),
            color_target(MATERIAL_FORMAT),
            color_target(MATERIAL_FORMAT),
            color_target(MATERIAL_FORMAT),
            color_target(MATERIAL_FORMAT),
            color_target(TRANSMITTANCE_FORMAT),
        ];
        PeelPass {
            opaque_illumination: pipeline(&forward, "fs_peel_opaque_illumination", &illumination),
            opaque_layers: pipeline(&forward, "fs_peel_opaque_layers", &layers[..7]),
            gbuffer,
            opaque_depth: pipeline(&peeled, "fs_peel_opaque", &[]),
            depth: pipeline(&peeled, "fs_peel_depth", &[color_target(EYE_DEPTH_FORMAT)]),
            layers: pipeline(&peeled, "fs_peel_layers", &layers),
            group_layout,
            targets: None,
        }
    }

    /// Allocates the peel targets for a `w`×`h` frame where the size changed.
    pub(super) fn ensure_targets(&mut self, device: &wgpu::Device, w: u32, h: u32) {
        if self
            .targets
            .as_ref()
            .is_some_and(|t| (t.width, t.height) == (w, h))
        {
            return;
        }
        self.targets = None;
        let sampled = wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING;
        self.targets = Some(PeelTargets {
            width: w,
            height: h,
            transmittance: texture(
                device,
                "eye transmittance",
                [w, h],
                TRANSMITTANCE_FORMAT,
                sampled | wgpu::TextureUsages::COPY_SRC,
            ),
            ping: ["peel depth 0", "peel depth 1"]
                .map(|l| texture(device, l, [w, h], EYE_DEPTH_FORMAT, sampled)),
        });
    }

    /// Peel 0's G-buffer rasters (without, with the material layers) for
    /// `deferred::render_deferred`.
    pub(super) fn gbuffer(&self) -> [&wgpu::RenderPipeline; 2] {
        [&self.gbuffer[0], &self.gbuffer[1]]
    }

    /// The eye transmittance of the last translucent layer rendered at this size.
    pub(super) fn transmittance(&self) -> Option<&wgpu::Texture> {
        self.targets.as_ref().map(|t| &t.transmittance)
    }

    /// Records and submits peel 0, the opaque layer: the forward pass with every translucent
    /// material rejected and no filters' pass.
    pub(super) fn render_opaque(
        &self,
        cx: &DrawContext<'_>,
        draws: &EyeDraws,
        targets: &EyeTargets,
        inputs: &EyeInputs<'_>,
    ) {
        let bind_group = eye_bind_group(cx, inputs);
        let mut colour = vec![&targets.diffuse, &targets.specular, &targets.depth];
        let pipeline = if inputs.material_layers {
            colour.extend(targets.materials.iter());
            &self.opaque_layers
        } else {
            &self.opaque_illumination
        };
        let mut encoder = cx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("peel 0"),
            });
        record_raster(
            cx,
            &mut encoder,
            pipeline,
            &bind_group,
            &colour,
            &targets.depth_buffer,
            draws,
        );
        cx.queue.submit([encoder.finish()]);
    }

    /// Records and submits the `depth` (≥ 1) peel passes of a translucent layer into `targets`
    /// and this pass's transmittance target ([`PeelPass::ensure_targets`] first).
    pub(super) fn render_translucent(
        &self,
        cx: &DrawContext<'_>,
        draws: &EyeDraws,
        targets: &EyeTargets,
        inputs: &EyeInputs<'_>,
        depth: u32,
    ) {
        let Some(own) = &self.targets else {
            return;
        };
        let view = |t: &wgpu::Texture| t.create_view(&Default::default());
        let eye_group = eye_bind_group(cx, inputs);
        let ping = own.ping.each_ref().map(view);
        let depth_view = view(&targets.depth_buffer);
        let mut layer_views: Vec<wgpu::TextureView> = [
            &targets.diffuse,
            &targets.specular,
            &targets.depth,
            &targets.materials[0],
            &targets.materials[1],
            &targets.materials[2],
            &targets.materials[3],
        ]
        .into_iter()
        .map(view)
        .collect();
        layer_views.push(view(&own.transmittance));
        let mut encoder = cx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("peel passes"),
            });
        for k in 1..=depth {
            let params = GpuPeel {
                first: u32::from(k == 1),
                epsilon: lightfold_shaders::PEEL_EPSILON,
                pad: [0; 2],
            };
            let uniform = cx
                .device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("peel"),
                    contents: bytemuck::bytes_of(&params),
                    usage: wgpu::BufferUsages::UNIFORM,
                });
            // Pass k reads pass k − 1's depth from ping[k % 2] (unread in pass 1) and, before
            // the last, writes its own to the other.
            let peel_group = cx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("peel"),
                layout: &self.group_layout,
                entries: &[
                    wgpu::BindGroupEntry {
                        binding: 0,
                        resource: wgpu::BindingResource::TextureView(&ping[(k % 2) as usize]),
                    },
                    wgpu::BindGroupEntry {
                        binding: 1,
                        resource: uniform.as_entire_binding(),
                    },
                ],
            });
            {
                let mut pass = begin_depth_pass(
                    &mut encoder,
                    "peel: opaque depth",
                    &depth_view,
                    draws.rows,
                    targets.width,
                );
                pass.set_pipeline(&self.opaque_depth);
                pass.set_bind_group(0, cx.scene_bind_group, &[]);
                pass.set_bind_group(1, &eye_group, &[]);
                pass.set_bind_group(2, &peel_group, &[]);
                draw_eye(cx, &mut pass, draws);
            }
            let last = k == depth;
            let mut colour = if last {
                attachments(&layer_views, wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT))
            } else {
                attachments(
                    std::slice::from_ref(&ping[((k - 1) % 2) as usize]),
                    wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                )
            };
            if last && let Some(Some(t)) = colour.last_mut() {
                // No layer: everything passes.
                t.ops.load = wgpu::LoadOp::Clear(wgpu::Color::WHITE);
            }
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("peel: translucent"),
                color_attachments: &colour,
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &depth_view,
                    depth_ops: Some(wgpu::Operations {
                        load: wgpu::LoadOp::Load,
                        store: wgpu::StoreOp::Discard,
                    }),
                    stencil_ops: None,
                }),
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            scissor(&mut pass, draws.rows, targets.width);
            pass.set_pipeline(if last { &self.layers } else { &self.depth });
            pass.set_bind_group(0, cx.scene_bind_group, &[]);
            pass.set_bind_group(1, &eye_group, &[]);
            pass.set_bind_group(2, &peel_group, &[]);
            draw_eye(cx, &mut pass, draws);
        }
        cx.queue.submit([encoder.finish()]);
    }
}
