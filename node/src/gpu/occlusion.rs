//! Occlusion culling for the eye pass (issue 48, `docs/scaling.md` § Occlusion culling).
//!
//! Frustum culling keeps every chunk the camera's frustum reaches; in a street, a room or behind
//! a hill most of them are hidden behind nearer surfaces and still cost the eye pass their
//! vertices and, since its fragment stage can discard (single-sided backs, masked texels), their
//! fragments. A frame that culls by occlusion:
//!
//! 1. draws the chunks visible in the last tested frame (the *occluders*) depth-only with the eye
//!    pass's own vertex stage and rejection (`fs_occluder`), so the depth they leave is never
//!    nearer than the eye pass's;
//! 2. reduces that depth to a hierarchical depth (HZB: each texel the farthest depth of the pixels
//!    it covers) and tests every candidate chunk's box against it (`shaders/wgsl/occlusion.wgsl`):
//!    a box whose nearest point is farther than the farthest occluder over every pixel it can
//!    cover is hidden;
//! 3. the eye pass draws the chunks that passed, in their usual order.
//!
//! A hidden chunk could only have drawn fragments behind surfaces the eye pass draws anyway, so
//! the picture is the same bit for bit (`node/tests/it/gpu_modes.rs`). The chunks that passed
//! are the next frame's occluders. A frame without occluders (the first, or after a pause) draws
//! every candidate and tests them afterwards against the eye pass's own depth, which costs no
//! second raster. Under [`EyeOcclusion::Auto`] (the default) frames whose candidates hold fewer
//! than [`AUTO_MIN_VERTICES`] are not tested, and culling pauses for [`AUTO_PAUSE`] frames after
//! a test that hid less than [`AUTO_MIN_HIDDEN`] of the candidates' vertices or two culled eye
//! passes in a row slower than the last one without ([`judge`]): an open view pays a reduction and a test now and
//! then, never the occluders' raster, and a device whose eye pass is bound by its pixels stops
//! drawing occluders it gains nothing from.

use super::eye_pass::{EyeDraws, EyeInputs, begin_depth_pass, draw_eye, eye_bind_group};
use super::frame::RenderError;
use super::pipelines::{DrawContext, Pipelines};
use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

/// Whether the eye pass culls chunks hidden behind others.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum EyeOcclusion {
    /// Never: every chunk in the frustum is drawn.
    Off,
    /// Where it pays: frames of fewer than [`AUTO_MIN_VERTICES`] candidate vertices are not
    /// tested, and culling pauses for [`AUTO_PAUSE`] frames after a test hid less than
    /// [`AUTO_MIN_HIDDEN`] of the candidates' vertices or two culled eye passes in a row were
    /// slower than the last one without ([`judge`]; the default).
    #[default]
    Auto,
    /// Every frame, whatever it hides (tests, measurements).
    Always,
}

/// Under [`EyeOcclusion::Auto`], the share of the candidates' vertices a test must hide for the
/// next frame to draw occluders and cull; below it culling pauses. Drawing the occluders costs
/// about their share of the eye pass's raster without its shading (`docs/scaling.md`).
pub const AUTO_MIN_HIDDEN: f32 = 0.25;

/// Under [`EyeOcclusion::Auto`], the fewest vertices among a frame's candidates for it to be
/// tested at all (16 k triangles): below it the eye pass's vertex work is too small to repay
/// the test, and small scenes never compile the occlusion passes. Above it, measured eye-pass
/// times decide ([`judge`]).
pub const AUTO_MIN_VERTICES: u64 = 3 * 16_384;

/// Frames [`EyeOcclusion::Auto`] pauses for before testing again.
pub const AUTO_PAUSE: u32 = 15;

/// Most boxes one test takes (its dispatch's workgroup count and binding limits); a frame with
/// more candidates draws them all.
pub(super) const MAX_BOXES: usize = 65_535 * TEST_WORKGROUP as usize;

/// What [`EyeOcclusion::Auto`] does after a test ([`judge`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Judgement {
    /// Keep culling.
    Keep,
    /// Keep culling, but this culled eye pass was slower than the last one without: a second in
    /// a row pauses.
    Slower,
    /// Pause for [`AUTO_PAUSE`] frames.
    Pause,
}

/// Whether [`EyeOcclusion::Auto`] keeps culling after a test that hid `hidden` of `all` candidate
/// vertices: it must hide at least [`AUTO_MIN_HIDDEN`] of them, and where the frame drew
/// occluders, its eye pass (`timing.0`, occluders and test included, µs) must not be slower than
/// the last one drawn without (`timing.1`) twice in a row (`slower_before`: the last culled one
/// was): on a device whose eye pass is bound by its pixels, hiding vertices saves nothing and the
/// occluders' raster is a loss. One slow frame (a first use, a hiccup) does not pause.
pub(super) fn judge(
    hidden: u64,
    all: u64,
    timing: Option<(u64, u64)>,
    slower_before: bool,
) -> Judgement {
    if hidden == 0 || (hidden as f64) < f64::from(AUTO_MIN_HIDDEN) * all as f64 {
        return Judgement::Pause;
    }
    match timing {
        Some((culled, plain)) if culled > plain => {
            if slower_before {
                Judgement::Pause
            } else {
                Judgement::Slower
            }
        }
        _ => Judgement::Keep,
    }
}

/// A box is hidden only where its nearest depth is below the farthest occluder depth by more
/// than this share (the occluders' and the eye pass's pipelines may round a vertex apart).
const MARGIN: f32 = 1e-5;

/// Threads per workgroup of `cs_test`, texels per workgroup side of the reductions.
const TEST_WORKGROUP: u32 = 64;
const REDUCE_WORKGROUP: u32 = 8;

/// Levels of the hierarchical depth a test reads at most (`MAX_LEVELS` in `occlusion.wgsl`):
/// level 0 at 2 pixels a texel, so images up to 2^16 pixels a side.
const MAX_LEVELS: usize = 16;

/// `Level` in `occlusion.wgsl`: where a level starts in the pyramid buffer, and its size.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, Default)]
struct Level {
    offset: u32,
    width: u32,
    height: u32,
    _pad: u32,
}

/// `Reduce` in `occlusion.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct ReduceParams {
    src: Level,
    dst: Level,
    pixels: [u32; 2],
    _pad: [u32; 2],
}

/// The levels of the hierarchical depth of a `w`×`h` depth buffer: level 0 a texel per 2×2
/// pixels, each next level half the one before rounded up, down to one texel; packed one after
/// the other. Texel x of level l covers pixels [x·2^(l+1), (x+1)·2^(l+1)).
fn levels(w: u32, h: u32) -> Vec<Level> {
    let mut out = Vec::new();
    let (mut lw, mut lh, mut offset) = (w.div_ceil(2).max(1), h.div_ceil(2).max(1), 0);
    loop {
        out.push(Level {
            offset,
            width: lw,
            height: lh,
            _pad: 0,
        });
        offset += lw * lh;
        if lw == 1 && lh == 1 {
            return out;
        }
        (lw, lh) = (lw.div_ceil(2), lh.div_ceil(2));
    }
}

/// `Test` in `occlusion.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct TestParams {
    view_proj: [[f32; 4]; 4],
    size: [f32; 2],
    count: u32,
    levels: u32,
    far_corner: u32,
    margin: f32,
    rows: [u32; 2],
    level: [Level; MAX_LEVELS],
}

/// `Bounds` in `occlusion.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct GpuBounds {
    lo: [f32; 4],
    hi: [f32; 4],
}

/// What one test is asked: the image the depth belongs to, the view-projection it was drawn
/// with, and the boxes.
#[derive(Debug)]
pub(super) struct Test<'a> {
    pub view_proj: [[f32; 4]; 4],
    pub width: u32,
    pub height: u32,
    pub boxes: &'a [([f32; 3], [f32; 3])],
    /// The rows `[y0, y1)` the eye pass rasterises (a sort-first tile; `None`: every row): a box
    /// is hidden where it is hidden in them.
    pub rows: Option<[u32; 2]>,
    /// `Fault::OcclusionFarCorner`.
    pub far_corner: bool,
}

/// The occlusion pass's pipelines and its targets (allocated at the frame's size on first use).
#[derive(Debug)]
pub(super) struct OcclusionPass {
    occluder: wgpu::RenderPipeline,
    reduce_depth: wgpu::ComputePipeline,
    reduce: wgpu::ComputePipeline,
    test: wgpu::ComputePipeline,
    /// The occluders' depth, the eye pass's size.
    depth: Option<wgpu::Texture>,
    /// The hierarchical depth's levels ([`levels`]), kept while the image size is.
    hzb: Option<wgpu::Buffer>,
}

impl OcclusionPass {
    /// Compiles the occluders' raster (from the scene's forward module, as its eye rasters are
    /// built) and the reductions and test.
    pub(super) fn new(device: &wgpu::Device, p: &Pipelines) -> OcclusionPass {
        let (forward, _) = lightfold_shaders::eye_modules(p.metallic_roughness, p.normal_mapped);
        let eye_module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("occluders"),
            source: wgpu::ShaderSource::Wgsl(forward.into()),
        });
        let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("occluders"),
            bind_group_layouts: &[Some(&p.scene_layout), Some(&p.eye_layout)],
            immediate_size: 0,
        });
        let occluder =
            p.eye_rasters(device)
                .pipeline(&eye_module, &layout, "fs_occluder", &[], true);
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("occlusion"),
            source: wgpu::ShaderSource::Wgsl(lightfold_shaders::OCCLUSION_WGSL.into()),
        });
        let compute = |entry: &str| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: None,
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        OcclusionPass {
            occluder,
            reduce_depth: compute("cs_reduce_depth"),
            reduce: compute("cs_reduce"),
            test: compute("cs_test"),
            depth: None,
            hzb: None,
        }
    }

    /// Draws `occluders` depth-only into the pass's own depth target (`w`×`h`, cleared to
    /// "nothing": 0), then tests `test`'s boxes against it; whether each is visible.
    pub(super) fn occluded_by(
        &mut self,
        cx: &DrawContext<'_>,
        inputs: &EyeInputs<'_>,
        occluders: &EyeDraws,
        test: &Test<'_>,
    ) -> Result<Vec<bool>, RenderError> {
        let (w, h) = (test.width, test.height);
        if self
            .depth
            .as_ref()
            .is_none_or(|d| d.width() != w || d.height() != h)
        {
            self.depth = Some(cx.device.create_texture(&wgpu::TextureDescriptor {
                label: Some("occluder depth"),
                size: wgpu::Extent3d {
                    width: w,
                    height: h,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: super::pipelines::DEPTH_FORMAT,
                usage: wgpu::TextureUsages::RENDER_ATTACHMENT
                    | wgpu::TextureUsages::TEXTURE_BINDING,
                view_formats: &[],
            }));
        }
        let depth = self.depth.take().expect("allocated above");
        let bind_group = eye_bind_group(cx, inputs);
        let mut encoder = cx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("occluders"),
            });
        {
            let view = depth.create_view(&Default::default());
            let mut pass = begin_depth_pass(&mut encoder, "occluders", &view, occluders.rows, w);
            pass.set_pipeline(&self.occluder);
            pass.set_bind_group(0, cx.scene_bind_group, &[]);
            pass.set_bind_group(1, &bind_group, &[]);
            draw_eye(cx, &mut pass, occluders);
        }
        let visible = self.test_into(cx, encoder, &depth, test);
        self.depth = Some(depth);
        visible
    }

    /// Tests `test`'s boxes against `depth` (a reversed-Z `Depth32Float` target of the test's
    /// size, e.g. the eye pass's own depth buffer after it ran); whether each is visible.
    pub(super) fn visible_in(
        &mut self,
        cx: &DrawContext<'_>,
        depth: &wgpu::Texture,
        test: &Test<'_>,
    ) -> Result<Vec<bool>, RenderError> {
        let encoder = cx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("occlusion test"),
            });
        self.test_into(cx, encoder, depth, test)
    }

    /// Records the reduction of `depth` and the test into `encoder`, submits it and reads the
    /// answers back.
    fn test_into(
        &mut self,
        cx: &DrawContext<'_>,
        mut encoder: wgpu::CommandEncoder,
        depth: &wgpu::Texture,
        test: &Test<'_>,
    ) -> Result<Vec<bool>, RenderError> {
        if test.boxes.is_empty() {
            cx.queue.submit([encoder.finish()]);
            return Ok(Vec::new());
        }
        let (w, h) = (test.width, test.height);
        let pyramid = levels(w, h);
        if pyramid.len() > MAX_LEVELS {
            // Larger than any device's image: nothing is tested, everything shows.
            cx.queue.submit([encoder.finish()]);
            return Ok(vec![true; test.boxes.len()]);
        }
        let texels: u64 = pyramid.iter().map(|l| u64::from(l.width * l.height)).sum();
        if self.hzb.as_ref().is_none_or(|b| b.size() != texels * 4) {
            self.hzb = Some(cx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("hierarchical depth"),
                size: texels * 4,
                usage: wgpu::BufferUsages::STORAGE,
                mapped_at_creation: false,
            }));
        }
        let hzb = self.hzb.as_ref().expect("allocated above");
        let depth_view = depth.create_view(&Default::default());
        let buffer = |label: &str, contents: &[u8], usage| {
            cx.device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some(label),
                    contents,
                    usage,
                })
        };
        let mut groups = Vec::with_capacity(pyramid.len());
        for (k, dst) in pyramid.iter().enumerate() {
            let first = k == 0;
            let pipeline = if first {
                &self.reduce_depth
            } else {
                &self.reduce
            };
            let params = ReduceParams {
                src: if first {
                    Level::default()
                } else {
                    pyramid[k - 1]
                },
                dst: *dst,
                pixels: [w, h],
                _pad: [0; 2],
            };
            let uniform = buffer(
                "hierarchical depth level",
                bytemuck::bytes_of(&params),
                wgpu::BufferUsages::UNIFORM,
            );
            let mut entries = vec![
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: uniform.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 2,
                    resource: hzb.as_entire_binding(),
                },
            ];
            if first {
                entries.push(wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&depth_view),
                });
            }
            let group = cx.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("hierarchical depth level"),
                layout: &pipeline.get_bind_group_layout(0),
                entries: &entries,
            });
            groups.push((pipeline, group, [dst.width, dst.height]));
        }
        let boxes: Vec<GpuBounds> = test
            .boxes
            .iter()
            .map(|&(lo, hi)| GpuBounds {
                lo: [lo[0], lo[1], lo[2], 0.0],
                hi: [hi[0], hi[1], hi[2], 0.0],
            })
            .collect();
        let count = boxes.len() as u32;
        let params = TestParams {
            view_proj: test.view_proj,
            size: [w as f32, h as f32],
            count,
            levels: pyramid.len() as u32,
            far_corner: u32::from(test.far_corner),
            margin: MARGIN,
            rows: test.rows.unwrap_or([0, h]),
            level: std::array::from_fn(|k| pyramid.get(k).copied().unwrap_or_default()),
        };
        let uniform = buffer(
            "occlusion test",
            bytemuck::bytes_of(&params),
            wgpu::BufferUsages::UNIFORM,
        );
        let boxes = buffer(
            "candidate boxes",
            bytemuck::cast_slice(&boxes),
            wgpu::BufferUsages::STORAGE,
        );
        let bytes = u64::from(count) * 4;
        let visible = cx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("visible"),
            size: bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let readback = cx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("visible readback"),
            size: bytes,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let test_group = cx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("occlusion test"),
            layout: &self.test.get_bind_group_layout(0),
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 4,
                    resource: uniform.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 5,
                    resource: hzb.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 6,
                    resource: boxes.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 7,
                    resource: visible.as_entire_binding(),
                },
            ],
        });
        for (pipeline, group, [dw, dh]) in &groups {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("hierarchical depth level"),
                timestamp_writes: None,
            });
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, group, &[]);
            pass.dispatch_workgroups(
                dw.div_ceil(REDUCE_WORKGROUP),
                dh.div_ceil(REDUCE_WORKGROUP),
                1,
            );
        }
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("occlusion test"),
                timestamp_writes: None,
            });
            pass.set_pipeline(&self.test);
            pass.set_bind_group(0, &test_group, &[]);
            pass.dispatch_workgroups(count.div_ceil(TEST_WORKGROUP), 1, 1);
        }
        encoder.copy_buffer_to_buffer(&visible, 0, &readback, 0, bytes);
        cx.queue.submit([encoder.finish()]);
        super::pack::map_for_reading(cx.device, &readback, bytes, "the occlusion test")?;
        let answers = {
            let mapped = readback
                .slice(..bytes)
                .get_mapped_range()
                .map_err(|e| RenderError::Gpu(format!("mapped range: {e}")))?;
            bytemuck::cast_slice::<u8, u32>(&mapped)
                .iter()
                .map(|&v| v != 0)
                .collect()
        };
        readback.unmap();
        Ok(answers)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every level covers the image exactly: level l is ⌈w / 2^(l+1)⌉ × ⌈h / 2^(l+1)⌉ texels
    /// (so texel x covers pixels [x·2^(l+1), (x+1)·2^(l+1))), packed without gaps, ending at one
    /// texel, within what a test reads.
    #[test]
    fn auto_culls_where_it_hides_enough_and_is_no_slower() {
        use Judgement::*;
        // Hides a quarter or more: kept until a culled frame is timed.
        assert_eq!(judge(25, 100, None, false), Keep);
        assert_eq!(judge(24, 100, None, false), Pause);
        assert_eq!(judge(0, 0, None, false), Pause);
        // Timed: kept while no slower than the last plain eye pass; slower twice in a row pauses.
        assert_eq!(judge(80, 100, Some((900, 1000)), true), Keep);
        assert_eq!(judge(80, 100, Some((1000, 1000)), false), Keep);
        assert_eq!(judge(80, 100, Some((1100, 1000)), false), Slower);
        assert_eq!(judge(80, 100, Some((1100, 1000)), true), Pause);
        assert_eq!(judge(10, 100, Some((500, 1000)), false), Pause);
    }

    #[test]
    fn levels_cover_the_image() {
        for (w, h) in [
            (1, 1),
            (2, 1),
            (200, 150),
            (800, 600),
            (1920, 1080),
            (3840, 2160),
        ] {
            let l = levels(w, h);
            let mut offset = 0;
            for (k, level) in l.iter().enumerate() {
                let span = 2u32 << k;
                assert_eq!(
                    (level.width, level.height),
                    (w.div_ceil(span), h.div_ceil(span)),
                    "{w}×{h} level {k}"
                );
                assert_eq!(level.offset, offset);
                offset += level.width * level.height;
            }
            let top = l.last().unwrap();
            assert_eq!((top.width, top.height), (1, 1));
            assert!(l.len() <= MAX_LEVELS);
        }
        assert_eq!(levels(65_536, 2).len(), MAX_LEVELS);
    }
}
