//! The deferred variant of the eye pass: one raster writes a G-buffer (position, normals and
//! material per pixel as f32 bits, plus eye depth and the material layers), then a compute pass
//! lights every pixel with the K samples into a storage buffer, one dispatch per chunk of
//! [`CHUNK_LIGHTS`] lights (their records in uniform buffers, which lavapipe reads far faster than
//! storage buffers), each adding to the last in light order. Same maths as the forward pass; no
//! fragment of a hidden surface is ever lit.

use super::eye_pass::{
    EyeInputs, EyeTargets, GpuFrame, light_group, record_filters, record_raster,
};
use super::lights::{GpuLight, GpuView, chunk_lights};
use super::pipelines::{DrawContext, GBUFFER_FORMAT};
use bytemuck::Zeroable;
use lightfold_shaders::{CHUNK_LIGHTS, CHUNK_VIEWS};

/// Workgroup edge of `cs_lights`.
const WORKGROUP: u32 = 8;

/// The G-buffer and the lit result at one image size.
#[derive(Debug)]
pub(super) struct DeferredTargets {
    pub width: u32,
    pub height: u32,
    gbuffer: [wgpu::Texture; 3],
    /// Two vec4<f32> per pixel: diffuse then specular illumination.
    pub illumination: wgpu::Buffer,
}

impl DeferredTargets {
    pub(super) fn new(device: &wgpu::Device, w: u32, h: u32) -> DeferredTargets {
        let gbuffer = [
            "g-buffer position",
            "g-buffer normal",
            "g-buffer geometric normal",
        ]
        .map(|label| {
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
                format: GBUFFER_FORMAT,
                usage: wgpu::TextureUsages::RENDER_ATTACHMENT
                    | wgpu::TextureUsages::TEXTURE_BINDING,
                view_formats: &[],
            })
        });
        let illumination = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("deferred illumination"),
            size: w as u64 * h as u64 * 32,
            // COPY_DST: a tile's rows below it are cleared.
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        DeferredTargets {
            width: w,
            height: h,
            gbuffer,
            illumination,
        }
    }
}

/// Group 1 of each light dispatch: its chunk of lights and views, padded to the sizes the
/// shader declares, and the frame with the chunk's light count.
fn chunk_groups(
    cx: &DrawContext<'_>,
    inputs: &EyeInputs<'_>,
    rows: Option<[u32; 2]>,
) -> Vec<wgpu::BindGroup> {
    chunk_lights(inputs.lights, inputs.views, CHUNK_LIGHTS)
        .into_iter()
        .enumerate()
        .map(|(i, mut chunk)| {
            debug_assert!(
                chunk.views.len() <= CHUNK_VIEWS,
                "at most six views per light"
            );
            let frame = GpuFrame {
                light_count: chunk.lights.len() as u32,
                accumulate: u32::from(i > 0),
                view_base: chunk.first_view,
                // A tile lights no row below its own (`cs_lights` stops at `height`).
                height: rows.map_or(inputs.frame.height, |r| r[1]),
                ..inputs.frame
            };
            chunk.lights.resize(CHUNK_LIGHTS, GpuLight::zeroed());
            chunk.views.resize(CHUNK_VIEWS, GpuView::zeroed());
            light_group(
                cx,
                &cx.pipelines.chunk_layout,
                inputs,
                &frame,
                (&chunk.lights, &chunk.views),
                wgpu::BufferUsages::UNIFORM,
            )
        })
        .collect()
}

/// Records and submits the G-buffer raster and the light dispatches of `light_pass`; `peel0`:
/// peel 0's G-buffer rasters (without, with the material layers) in place of the classic ones,
/// and no filters' pass.
pub(super) fn render_deferred(
    cx: &DrawContext<'_>,
    draws: &super::eye_pass::EyeDraws,
    targets: &EyeTargets,
    deferred: &DeferredTargets,
    inputs: &EyeInputs<'_>,
    light_pass: &wgpu::ComputePipeline,
    peel0: Option<[&wgpu::RenderPipeline; 2]>,
) {
    let groups = chunk_groups(cx, inputs, draws.rows);
    let g = &deferred.gbuffer;
    let mut colour = vec![&g[0], &g[1], &g[2], &targets.depth];
    if inputs.material_layers {
        colour.extend(targets.materials.iter());
    }
    // Peel 0 (`gpu::peel`) brings its own G-buffer rasters, which reject every translucent
    // material, and multiplies no filter in.
    let [gbuffer, gbuffer_layers] =
        peel0.unwrap_or([&cx.pipelines.gbuffer, &cx.pipelines.gbuffer_layers]);
    let pipeline = if inputs.material_layers {
        gbuffer_layers
    } else {
        gbuffer
    };
    let mut encoder = cx
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("deferred eye pass"),
        });
    record_raster(
        cx,
        &mut encoder,
        pipeline,
        &groups[0],
        &colour,
        &targets.depth_buffer,
        draws,
    );
    if inputs.material_layers && peel0.is_none() {
        record_filters(
            cx,
            &mut encoder,
            1,
            &groups[0],
            targets,
            inputs.vertex_count,
            draws.rows,
        );
    }
    let view = |t: &wgpu::Texture| t.create_view(&Default::default());
    let views = [view(&g[0]), view(&g[1]), view(&g[2])];
    let gbuffer_group = cx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("g-buffer"),
        layout: &cx.pipelines.deferred_layout,
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: wgpu::BindingResource::TextureView(&views[0]),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: wgpu::BindingResource::TextureView(&views[1]),
            },
            wgpu::BindGroupEntry {
                binding: 2,
                resource: wgpu::BindingResource::TextureView(&views[2]),
            },
            wgpu::BindGroupEntry {
                binding: 3,
                resource: deferred.illumination.as_entire_binding(),
            },
        ],
    });
    // Rows below a tile are not lit: zero them (those above it are lit from the cleared
    // G-buffer, background, which writes zeros: the shader has no row offset).
    let end = draws.rows.map_or(deferred.height, |r| r[1]);
    if end < deferred.height {
        let row = u64::from(deferred.width) * 32;
        encoder.clear_buffer(&deferred.illumination, u64::from(end) * row, None);
    }
    {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("deferred lights"),
            timestamp_writes: None,
        });
        pass.set_pipeline(light_pass);
        pass.set_bind_group(0, cx.scene_bind_group, &[]);
        pass.set_bind_group(2, &gbuffer_group, &[]);
        for group in &groups {
            pass.set_bind_group(1, group, &[]);
            pass.dispatch_workgroups(
                deferred.width.div_ceil(WORKGROUP),
                end.div_ceil(WORKGROUP),
                1,
            );
        }
    }
    cx.queue.submit([encoder.finish()]);
}
