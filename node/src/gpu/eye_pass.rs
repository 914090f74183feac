//! The eye pass: one raster of the scene from the camera that sums the node's K lights with their
//! shadow lookups into the illumination targets, writes eye depth, and (when asked) the material
//! layers as extra render targets of the same pass.

use super::lights::{GpuLight, GpuView, mat_mul};
use super::pipelines::{DEPTH_FORMAT, DrawContext, EYE_DEPTH_FORMAT, MATERIAL_FORMAT};
use super::shadow_pass::ShadowMaps;
use bytemuck::{Pod, Zeroable};
use lightfold_scene::Camera;
use std::ops::Range;
use wgpu::util::DeviceExt;

/// `Frame` in `eye.wgsl` (uniform layout).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub(super) struct GpuFrame {
    pub view_proj: [[f32; 4]; 4],
    pub camera: [f32; 3],
    pub light_count: u32,
    pub forward: [f32; 3],
    pub map_size: f32,
    pub depth_bias: f32,
    pub slope_bias: f32,
    /// Deferred light pass: nonzero when this dispatch adds to an earlier one's result.
    pub accumulate: u32,
    /// Index in the frame's views of a deferred chunk's view 0 (each view carries its layer).
    pub view_base: u32,
    pub kernel_radius: f32,
    pub width: u32,
    pub height: u32,
    /// [`FLAG_OBJECT_IDS`], [`FLAG_CONVENTIONAL_Z`].
    pub flags: u32,
}

/// `Frame::flags`: shadow lookups compare against other objects' casters with a bias sized for
/// their offset from the receiver (the object-ID test), and against the receiver's own surface
/// with the slope bias.
pub(super) const FLAG_OBJECT_IDS: u32 = 1;
/// `Frame::flags`: shadow depths are conventional Z (near 0), a depth negative control.
pub(super) const FLAG_CONVENTIONAL_Z: u32 = 2;
/// `Frame::flags`: with the object-ID test, another object's texel is compared with the
/// receiver's plane where that texel's centre ray meets it (receiver-plane depth bias), within
/// the symmetric slope bound; without it, with the bound alone (before issue 46).
pub(super) const FLAG_RECEIVER_PLANE: u32 = 4;

impl GpuFrame {
    /// Camera part of the frame; light and filter fields are filled by the caller.
    pub(super) fn for_camera(camera: &Camera, near: f32) -> GpuFrame {
        let f = camera.frame();
        GpuFrame {
            view_proj: mat_mul(&camera.projection_reversed_z(near), &camera.view_matrix()),
            camera: camera.position,
            light_count: 0,
            forward: f.forward,
            map_size: 1.0,
            depth_bias: 0.0,
            slope_bias: 0.0,
            accumulate: 0,
            view_base: 0,
            kernel_radius: 1.0,
            width: camera.width,
            height: camera.height,
            flags: 0,
        }
    }
}

/// The eye pass's render targets at one image size.
#[derive(Debug)]
pub(super) struct EyeTargets {
    pub width: u32,
    pub height: u32,
    pub diffuse: wgpu::Texture,
    pub specular: wgpu::Texture,
    pub depth: wgpu::Texture,
    /// m^d, m^s, m^a, e.
    pub materials: [wgpu::Texture; 4],
    pub depth_buffer: wgpu::Texture,
}

fn target(
    device: &wgpu::Device,
    label: &str,
    w: u32,
    h: u32,
    format: wgpu::TextureFormat,
) -> wgpu::Texture {
    // Depth buffers are never read back (GL cannot copy them); colour targets are. The depth
    // buffer is read by occlusion culling's test after the pass (`gpu::occlusion`), material
    // targets by the ambient-mask pass (`gpu::ambient_mask`).
    let usage = if format == DEPTH_FORMAT {
        wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING
    } else if format == MATERIAL_FORMAT {
        wgpu::TextureUsages::RENDER_ATTACHMENT
            | wgpu::TextureUsages::COPY_SRC
            | wgpu::TextureUsages::TEXTURE_BINDING
    } else {
        wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC
    };
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

impl EyeTargets {
    pub(super) fn new(
        device: &wgpu::Device,
        w: u32,
        h: u32,
        illumination: wgpu::TextureFormat,
    ) -> Self {
        EyeTargets {
            width: w,
            height: h,
            diffuse: target(device, "illumination diffuse", w, h, illumination),
            specular: target(device, "illumination specular", w, h, illumination),
            depth: target(device, "eye depth", w, h, EYE_DEPTH_FORMAT),
            materials: ["m^d", "m^s", "m^a", "e"].map(|l| target(device, l, w, h, MATERIAL_FORMAT)),
            depth_buffer: target(device, "eye depth buffer", w, h, DEPTH_FORMAT),
        }
    }
}

/// Inputs of one eye pass.
#[derive(Debug)]
pub(super) struct EyeInputs<'a> {
    pub frame: GpuFrame,
    pub lights: &'a [GpuLight],
    pub views: &'a [GpuView],
    pub maps: &'a ShadowMaps,
    pub sampler: &'a wgpu::Sampler,
    pub material_layers: bool,
    /// Every vertex of the scene: the filters' pass draws every filter in front of this pass's
    /// surfaces, whichever partition they belong to, so sort-last parts tint alike.
    pub vertex_count: u32,
}

/// Restricts `pass` to the rows `[y0, y1)` of a `width`-pixel-wide target (nothing for `None`).
pub(super) fn scissor(pass: &mut wgpu::RenderPass<'_>, rows: Option<[u32; 2]>, width: u32) {
    if let Some([y0, y1]) = rows {
        pass.set_scissor_rect(0, y0, width, y1.saturating_sub(y0));
    }
}

/// The forward pass's uniform, light and view buffers bound as group 1 (storage buffers).
pub(super) fn eye_bind_group(cx: &DrawContext<'_>, inputs: &EyeInputs<'_>) -> wgpu::BindGroup {
    // Storage bindings cannot be empty: pad with one unused record.
    let lights: Vec<GpuLight> = if inputs.lights.is_empty() {
        vec![GpuLight::zeroed()]
    } else {
        inputs.lights.to_vec()
    };
    let views: Vec<GpuView> = if inputs.views.is_empty() {
        vec![GpuView::zeroed()]
    } else {
        inputs.views.to_vec()
    };
    light_group(
        cx,
        &cx.pipelines.eye_layout,
        inputs,
        &inputs.frame,
        (&lights, &views),
        wgpu::BufferUsages::STORAGE,
    )
}

/// Group 1 of an eye pass: `frame` and the light and view records in buffers of `usage`.
pub(super) fn light_group(
    cx: &DrawContext<'_>,
    layout: &wgpu::BindGroupLayout,
    inputs: &EyeInputs<'_>,
    frame: &GpuFrame,
    (lights, views): (&[GpuLight], &[GpuView]),
    usage: wgpu::BufferUsages,
) -> wgpu::BindGroup {
    let buffer = |label: &str, bytes: &[u8], usage| {
        cx.device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: bytes,
                usage,
            })
    };
    let frame_buf = buffer(
        "frame",
        bytemuck::bytes_of(frame),
        wgpu::BufferUsages::UNIFORM,
    );
    let light_buf = buffer("lights", bytemuck::cast_slice(lights), usage);
    let view_buf = buffer("views", bytemuck::cast_slice(views), usage);
    cx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("eye"),
        layout,
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: frame_buf.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: light_buf.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 2,
                resource: view_buf.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 3,
                resource: wgpu::BindingResource::TextureView(&inputs.maps.array_view),
            },
            wgpu::BindGroupEntry {
                binding: 4,
                resource: wgpu::BindingResource::Sampler(inputs.sampler),
            },
            wgpu::BindGroupEntry {
                binding: 5,
                resource: wgpu::BindingResource::TextureView(&inputs.maps.id_view),
            },
            wgpu::BindGroupEntry {
                binding: 6,
                resource: wgpu::BindingResource::TextureView(
                    &inputs.maps.translucent.transmit_view,
                ),
            },
            wgpu::BindGroupEntry {
                binding: 7,
                resource: wgpu::BindingResource::TextureView(&inputs.maps.translucent.depth_view),
            },
        ],
    })
}

/// Colour attachments over `views`, each loaded by `load` and stored.
pub(super) fn attachments(
    views: &[wgpu::TextureView],
    load: wgpu::LoadOp<wgpu::Color>,
) -> Vec<Option<wgpu::RenderPassColorAttachment<'_>>> {
    views
        .iter()
        .map(|v| {
            Some(wgpu::RenderPassColorAttachment {
                view: v,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load,
                    store: wgpu::StoreOp::Store,
                },
            })
        })
        .collect()
}

/// Begins a depth-only eye raster into `depth` (reversed-Z, cleared to "nothing": 0, stored),
/// scissored to `rows` of a `width`-pixel-wide target: the peel passes' opaque depth, occlusion
/// culling's occluders.
pub(super) fn begin_depth_pass<'e>(
    encoder: &'e mut wgpu::CommandEncoder,
    label: &str,
    depth: &wgpu::TextureView,
    rows: Option<[u32; 2]>,
    width: u32,
) -> wgpu::RenderPass<'e> {
    let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some(label),
        color_attachments: &[],
        depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
            view: depth,
            depth_ops: Some(wgpu::Operations {
                load: wgpu::LoadOp::Clear(0.0),
                store: wgpu::StoreOp::Store,
            }),
            stencil_ops: None,
        }),
        timestamp_writes: None,
        occlusion_query_set: None,
        multiview_mask: None,
    });
    scissor(&mut pass, rows, width);
    pass
}

/// Records one raster of the scene from the camera into `colour` (cleared to zero) with a
/// reversed-Z depth buffer (kept for the filters' pass, [`record_filters`], and occlusion
/// culling's test, `gpu::occlusion`).
pub(super) fn record_raster(
    cx: &DrawContext<'_>,
    encoder: &mut wgpu::CommandEncoder,
    pipeline: &wgpu::RenderPipeline,
    bind_group: &wgpu::BindGroup,
    colour: &[&wgpu::Texture],
    depth_buffer: &wgpu::Texture,
    draws: &EyeDraws,
) {
    let view = |t: &wgpu::Texture| t.create_view(&Default::default());
    let views: Vec<wgpu::TextureView> = colour.iter().map(|t| view(t)).collect();
    let attachments = attachments(&views, wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT));
    let depth_view = view(depth_buffer);
    let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some("eye raster"),
        color_attachments: &attachments,
        depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
            view: &depth_view,
            depth_ops: Some(wgpu::Operations {
                load: wgpu::LoadOp::Clear(0.0),
                store: wgpu::StoreOp::Store,
            }),
            stencil_ops: None,
        }),
        timestamp_writes: None,
        occlusion_query_set: None,
        multiview_mask: None,
    });
    scissor(&mut pass, draws.rows, depth_buffer.width());
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, cx.scene_bind_group, &[]);
    pass.set_bind_group(1, bind_group, &[]);
    draw_eye(cx, &mut pass, draws);
}

/// Draws `draws` into `pass` (pipeline and bind groups set): the scene's vertex ranges, then the
/// lossless levels'.
pub(super) fn draw_eye(cx: &DrawContext<'_>, pass: &mut wgpu::RenderPass<'_>, draws: &EyeDraws) {
    pass.set_vertex_buffer(0, cx.vertices.slice(..));
    if let Some(t) = cx.tangents {
        pass.set_vertex_buffer(1, t.slice(..));
    }
    for r in draws.scene.iter().filter(|r| !r.is_empty()) {
        pass.draw(r.clone(), 0..1);
    }
    // Lossless levels (`gpu::lod`) from their own buffer; never in a normal-mapped scene, so no
    // tangent buffer is bound against them.
    if let Some((levels, _)) = cx.lod
        && !draws.levels.is_empty()
    {
        pass.set_vertex_buffer(0, levels.slice(..));
        for r in draws.levels.iter().filter(|r| !r.is_empty()) {
            pass.draw(r.clone(), 0..1);
        }
    }
}

/// What the eye pass draws: vertex ranges of the scene's buffer, and of the level buffer
/// (`gpu::lod`'s lossless eye levels), and where.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub(super) struct EyeDraws {
    pub scene: Vec<Range<u32>>,
    pub levels: Vec<Range<u32>>,
    /// The image rows `[y0, y1)` the pass rasterises and lights (a sort-first tile, scissored;
    /// every target is cleared whole, so the other rows stay zero); `None`: every row.
    pub rows: Option<[u32; 2]>,
}

impl EyeDraws {
    /// Vertices drawn.
    pub(super) fn vertices(&self) -> u32 {
        self.scene
            .iter()
            .chain(&self.levels)
            .map(|r| r.end - r.start)
            .sum()
    }
}

/// Records and submits the forward eye pass over the vertex ranges `draws` (every mesh, or a
/// partition's: [`super::Renderer::set_eye_meshes`]).
pub(super) fn render_eye(
    cx: &DrawContext<'_>,
    draws: &EyeDraws,
    targets: &EyeTargets,
    inputs: &EyeInputs<'_>,
) {
    let bind_group = eye_bind_group(cx, inputs);
    let mut colour = vec![&targets.diffuse, &targets.specular, &targets.depth];
    if inputs.material_layers {
        colour.extend(targets.materials.iter());
    }
    let pipeline = if inputs.material_layers {
        &cx.pipelines.eye_layers
    } else {
        &cx.pipelines.eye_illumination
    };
    let mut encoder = cx
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("eye pass"),
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
    if inputs.material_layers {
        record_filters(
            cx,
            &mut encoder,
            0,
            &bind_group,
            targets,
            inputs.vertex_count,
            draws.rows,
        );
    }
    cx.queue.submit([encoder.finish()]);
}

/// Records the filters' pass over the material layers (`fs_eye_filter`: each filter in front of
/// the visible surface multiplies its transmittance in), when the scene has filters: over every
/// vertex, so every filter in front counts whichever sort-last part drew the surface. `variant`
/// 0 is the forward pass's group layout, 1 the deferred raster's.
pub(super) fn record_filters(
    cx: &DrawContext<'_>,
    encoder: &mut wgpu::CommandEncoder,
    variant: usize,
    bind_group: &wgpu::BindGroup,
    targets: &EyeTargets,
    vertex_count: u32,
    rows: Option<[u32; 2]>,
) {
    let Some(pipelines) = &cx.pipelines.eye_filter else {
        return;
    };
    let view = |t: &wgpu::Texture| t.create_view(&Default::default());
    let views: Vec<wgpu::TextureView> = targets.materials.iter().map(view).collect();
    let attachments = attachments(&views, wgpu::LoadOp::Load);
    let depth_view = view(&targets.depth_buffer);
    let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some("eye filters"),
        color_attachments: &attachments,
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
    scissor(&mut pass, rows, targets.width);
    pass.set_pipeline(&pipelines[variant.min(1)]);
    pass.set_bind_group(0, cx.scene_bind_group, &[]);
    pass.set_bind_group(1, bind_group, &[]);
    pass.set_vertex_buffer(0, cx.vertices.slice(..));
    if let Some(t) = cx.tangents {
        pass.set_vertex_buffer(1, t.slice(..));
    }
    if vertex_count > 0 {
        pass.draw(0..vertex_count, 0..1);
    }
}
