//! Shadow maps: one Depth32Float texture array holding every view of every light of a frame (each
//! view a square of a layer, `atlas`), beside it an R32Uint array of the object (mesh index + 1) each texel's depth
//! belongs to, and the depth passes that fill both, drawing per view only the casters the caller
//! allows that can reach the view's frustum. (The depth negative controls change the encoding:
//! `ShadowDepth`.) Translucent casters draw into two more arrays instead (`docs/translucency.md`):
//! the nearest translucent caster's depth, and the product of the transmittance of those in front
//! of the nearest opaque caster (seed 001's separate transparent and opaque depths).

use super::lights::{LightPlan, box_in_view, mat_mul};
use super::lod;
use super::pipelines::{DrawContext, VIEW_UNIFORM_STRIDE};
use super::scene_data::SceneData;
use super::shadow_depth::ShadowDepth;
use wgpu::util::DeviceExt;

/// The shadow-map array and a render view per layer.
#[derive(Debug)]
pub(super) struct ShadowMaps {
    pub size: u32,
    pub layers: u32,
    pub depth: ShadowDepth,
    _texture: wgpu::Texture,
    pub array_view: wgpu::TextureView,
    layer_views: Vec<wgpu::TextureView>,
    _ids: wgpu::Texture,
    /// The object IDs, layer for layer with `array_view`.
    pub id_view: wgpu::TextureView,
    id_layer_views: Vec<wgpu::TextureView>,
    /// Translucent casters' maps, layer for layer with `array_view` where the frame needs them;
    /// otherwise 1 × 1 stand-ins the lookups never read (the bindings need something).
    pub translucent: TranslucentMaps,
}

/// The transmittance maps and the nearest translucent caster's depth.
#[derive(Debug)]
pub(super) struct TranslucentMaps {
    /// Whether these are full-size maps (else the 1 × 1 stand-ins).
    pub full: bool,
    /// Two translucent layers per view (peeling renderers): both arrays hold twice the layers,
    /// layer `layers + l` (`layers` the shadow maps' count) the second layer of layer l: the
    /// second-nearest translucent caster's depth, and the nearest one's own transmittance T1
    /// (layer l keeps the product of all of them in front of the nearest opaque caster).
    pub layered: bool,
    _transmit: wgpu::Texture,
    pub transmit_view: wgpu::TextureView,
    transmit_layer_views: Vec<wgpu::TextureView>,
    _depth: wgpu::Texture,
    pub depth_view: wgpu::TextureView,
    depth_layer_views: Vec<wgpu::TextureView>,
}

/// Format of the transmittance maps: the RGB product of the translucent casters' transmittance
/// in front of the nearest opaque one. f16 blends on every backend and keeps a red pane's
/// 0.1 to 0.05 % (8 bits would round it to 0.102: a 2 % darker or lighter tint).
pub(super) const TRANSMIT_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba16Float;

fn array_texture(
    device: &wgpu::Device,
    label: &str,
    size: u32,
    layers: u32,
    format: wgpu::TextureFormat,
) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width: size,
            height: size,
            depth_or_array_layers: layers,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
        view_formats: &[],
    })
}

impl TranslucentMaps {
    /// Full-size maps of `size`² × `layers` (`full`), or the 1 × 1 stand-ins.
    fn new(
        device: &wgpu::Device,
        size: u32,
        layers: u32,
        depth: ShadowDepth,
        full: bool,
        layered: bool,
    ) -> TranslucentMaps {
        let layered = full && layered;
        let (size, layers) = match (full, layered) {
            (false, _) => (1, 2),
            (true, false) => (size, layers),
            // The lookups find layer l's second at l + (the array's layers) / 2.
            (true, true) if (2 * layers).is_multiple_of(6) => (size, 2 * layers + 1),
            (true, true) => (size, 2 * layers),
        };
        let transmit = array_texture(device, "transmittance maps", size, layers, TRANSMIT_FORMAT);
        let depth_texture =
            array_texture(device, "translucent depth", size, layers, depth.format());
        let (transmit_view, transmit_layer_views) =
            array_views(&transmit, layers, "transmittance maps");
        let (depth_view, depth_layer_views) =
            array_views(&depth_texture, layers, "translucent depth");
        TranslucentMaps {
            full,
            layered,
            _transmit: transmit,
            transmit_view,
            transmit_layer_views,
            _depth: depth_texture,
            depth_view,
            depth_layer_views,
        }
    }
}

/// Format of the object-ID layers: mesh index + 1, 0 where no caster drew.
pub(super) const OBJECT_ID_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::R32Uint;

fn array_views(
    texture: &wgpu::Texture,
    layers: u32,
    label: &str,
) -> (wgpu::TextureView, Vec<wgpu::TextureView>) {
    let array = texture.create_view(&wgpu::TextureViewDescriptor {
        label: Some(label),
        dimension: Some(wgpu::TextureViewDimension::D2Array),
        ..Default::default()
    });
    let layer_views = (0..layers)
        .map(|l| {
            texture.create_view(&wgpu::TextureViewDescriptor {
                label: Some(label),
                dimension: Some(wgpu::TextureViewDimension::D2),
                base_array_layer: l,
                array_layer_count: Some(1),
                ..Default::default()
            })
        })
        .collect();
    (array, layer_views)
}

/// Layers to allocate for `views` layers of maps. GL turns arrays of 1 layer or a multiple of 6 layers into
/// a 2D texture or a cube map and misreads them (docs/platform.md), so those counts get one spare layer
/// on every backend.
pub(super) fn layer_count(views: usize) -> u32 {
    let n = views.max(1) as u32;
    if n == 1 || n.is_multiple_of(6) {
        n + 1
    } else {
        n
    }
}

impl ShadowMaps {
    /// `translucent`: also allocate the translucent casters' maps at full size, with two
    /// translucent layers where `layered` (peeling renderers).
    pub(super) fn new(
        device: &wgpu::Device,
        size: u32,
        layers: u32,
        depth: ShadowDepth,
        translucent: bool,
        layered: bool,
    ) -> ShadowMaps {
        let depth_texture = array_texture(device, "shadow maps", size, layers, depth.format());
        let ids = array_texture(
            device,
            "shadow map object ids",
            size,
            layers,
            OBJECT_ID_FORMAT,
        );
        let (array_view, layer_views) = array_views(&depth_texture, layers, "shadow maps");
        let (id_view, id_layer_views) = array_views(&ids, layers, "shadow map object ids");
        ShadowMaps {
            size,
            layers,
            depth,
            _texture: depth_texture,
            array_view,
            layer_views,
            _ids: ids,
            id_view,
            id_layer_views,
            translucent: TranslucentMaps::new(device, size, layers, depth, translucent, layered),
        }
    }

    /// Whether this array has `layers` layers (before padding) of `size`², with the
    /// translucent casters' maps where `translucent` asks for them, of two layers exactly
    /// where `layered` does.
    pub(super) fn fits(&self, size: u32, layers: u32, translucent: bool, layered: bool) -> bool {
        self.size == size
            && self.layers >= layer_count(layers as usize)
            && (self.translucent.full || !translucent)
            && (!translucent || self.translucent.layered == layered)
    }
}

/// One render pass over a layer: `colour` cleared to the given colour (if any), `depth` loaded by
/// `depth_load` and kept.
fn layer_pass<'e>(
    encoder: &'e mut wgpu::CommandEncoder,
    label: &str,
    colour: Option<(&wgpu::TextureView, wgpu::Color)>,
    depth: &wgpu::TextureView,
    depth_load: wgpu::LoadOp<f32>,
) -> wgpu::RenderPass<'e> {
    let colour: Vec<_> = colour
        .map(|(view, clear)| wgpu::RenderPassColorAttachment {
            view,
            depth_slice: None,
            resolve_target: None,
            ops: wgpu::Operations {
                load: wgpu::LoadOp::Clear(clear),
                store: wgpu::StoreOp::Store,
            },
        })
        .into_iter()
        .map(Some)
        .collect();
    encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some(label),
        color_attachments: &colour,
        depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
            view: depth,
            depth_ops: Some(wgpu::Operations {
                load: depth_load,
                store: wgpu::StoreOp::Store,
            }),
            stencil_ops: None,
        }),
        timestamp_writes: None,
        occlusion_query_set: None,
        multiview_mask: None,
    })
}

/// A run of a caster's vertices a view draws, with its material's pipeline choice.
struct Piece {
    vertices: std::ops::Range<u32>,
    masked: bool,
    translucent: bool,
    /// From the simplified levels' buffer (`gpu::lod`), not the scene's.
    lod: bool,
}

/// Records and submits one render pass per layer holding a view of `plan` that `render[view]`
/// asks for, drawing every view of that layer into its square (the other layers are kept).
/// `casters[λ]` lists the meshes that may cast into light λ's maps (`None`: all); translucent
/// ones draw into the translucent maps, in two more passes per layer, for the views
/// `transmit[view]` marks (those of lights with translucent casters). Returns the number of
/// views drawn and of those with transmittance maps, and the vertices drawn (opaque and masked;
/// from simplified levels).
pub(super) fn render_shadow_maps(
    cx: &DrawContext<'_>,
    scene: &SceneData,
    maps: &ShadowMaps,
    plan: &LightPlan,
    casters: Option<&[Vec<u32>]>,
    render: &[bool],
    transmit: &[bool],
) -> ShadowDrawn {
    if plan.views.is_empty() || !render.contains(&true) {
        return ShadowDrawn::default();
    }
    // Kept to the end, beside the bind group that reads it.
    let (_uniform_buffer, view_bind_group) = view_uniforms(cx, maps, plan);
    let mut encoder = cx
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("shadow passes"),
        });
    let shadows = ShadowFrame {
        cx,
        scene,
        maps,
        plan,
        casters,
        transmit,
        all: (0..scene.meshes.len() as u32).collect(),
        view_bind_group,
        drawn_vertices: std::cell::Cell::new((0u64, 0u64)),
    };
    // A pass clears its whole layer, so every view in a layer that holds one to render is drawn
    // again (the others are what they were: same light, views and casters).
    let mut layers: Vec<u32> = plan
        .views
        .iter()
        .enumerate()
        .filter(|(i, _)| render.get(*i).copied().unwrap_or(true))
        .map(|(_, v)| v.layer)
        .collect();
    layers.sort_unstable();
    layers.dedup();
    let (mut passes, mut transmitted) = (0, 0);
    for layer in layers {
        let (Some(target), Some(ids)) = (
            maps.layer_views.get(layer as usize),
            maps.id_layer_views.get(layer as usize),
        ) else {
            continue;
        };
        passes += shadows.opaque_pass(&mut encoder, layer, target, ids);
        transmitted += shadows.translucent_passes(&mut encoder, layer, target);
    }
    cx.queue.submit([encoder.finish()]);
    let (vertices, lod_vertices) = shadows.drawn_vertices.get();
    ShadowDrawn {
        passes,
        transmitted,
        vertices,
        lod_vertices,
    }
}

/// Every view's view-projection in a uniform buffer, one per [`VIEW_UNIFORM_STRIDE`], and the
/// bind group that reads one of them at a dynamic offset.
fn view_uniforms(
    cx: &DrawContext<'_>,
    maps: &ShadowMaps,
    plan: &LightPlan,
) -> (wgpu::Buffer, wgpu::BindGroup) {
    let mut uniforms = vec![0u8; VIEW_UNIFORM_STRIDE as usize * plan.views.len()];
    for (i, v) in plan.geometry.iter().enumerate() {
        let vp = mat_mul(&maps.depth.projection(&v.proj), &v.view);
        let at = i * VIEW_UNIFORM_STRIDE as usize;
        uniforms[at..at + 64].copy_from_slice(bytemuck::cast_slice(&vp));
    }
    let uniform_buffer = cx
        .device
        .create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("shadow view uniforms"),
            contents: &uniforms,
            usage: wgpu::BufferUsages::UNIFORM,
        });
    let view_bind_group = cx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("shadow view"),
        layout: &cx.pipelines.shadow_layout,
        entries: &[wgpu::BindGroupEntry {
            binding: 0,
            resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                buffer: &uniform_buffer,
                offset: 0,
                size: wgpu::BufferSize::new(64),
            }),
        }],
    });
    (uniform_buffer, view_bind_group)
}

/// What one frame's shadow passes record with, and the vertices they drew.
struct ShadowFrame<'a> {
    cx: &'a DrawContext<'a>,
    scene: &'a SceneData,
    maps: &'a ShadowMaps,
    plan: &'a LightPlan,
    casters: Option<&'a [Vec<u32>]>,
    transmit: &'a [bool],
    /// Every mesh (the casters of a light `casters` does not list).
    all: Vec<u32>,
    view_bind_group: wgpu::BindGroup,
    /// Vertices drawn of opaque and masked casters, and of them from simplified levels.
    drawn_vertices: std::cell::Cell<(u64, u64)>,
}

impl ShadowFrame<'_> {
    /// What view i draws: the chunks of its light's casters that can reach its frustum.
    fn drawn(&self, i: usize) -> Vec<Piece> {
        let (cx, scene, plan) = (self.cx, self.scene, self.plan);
        let meshes = &scene.meshes;
        let light = plan.view_light[i] as usize;
        let allowed: &[u32] = self
            .casters
            .and_then(|c| c.get(light))
            .map_or(&self.all, |c| c);
        allowed
            .iter()
            .filter_map(|&m| meshes.get(m as usize))
            .filter(|m| {
                m.bounds.is_some_and(|(lo, hi)| {
                    m.vertex_count > 0 && box_in_view(&plan.geometry[i], lo, hi)
                })
            })
            .flat_map(|m| {
                let first = m.first_chunk as usize;
                scene
                    .mesh_chunks(m)
                    .iter()
                    .enumerate()
                    .filter(|(_, c)| box_in_view(&plan.geometry[i], c.bounds.0, c.bounds.1))
                    .map(move |(k, c)| {
                        // The coarsest level whose error fits the view's texels at the chunk.
                        let level = cx.lod.and_then(|(_, coarsest)| {
                            if coarsest {
                                return scene.lods.coarsest(first + k);
                            }
                            let side = plan.views[i].rect[2];
                            let texel =
                                lod::texel_at(&plan.geometry[i], side, c.bounds.0, c.bounds.1);
                            scene.lods.pick(first + k, texel)
                        });
                        let (first_vertex, count) = level
                            .map_or((c.first_vertex, c.vertex_count), |l| {
                                (l.first_vertex, l.vertex_count)
                            });
                        Piece {
                            vertices: first_vertex..first_vertex + count,
                            masked: m.masked,
                            translucent: m.translucent,
                            lod: level.is_some(),
                        }
                    })
            })
            .collect()
    }

    /// Each view of `layer` (those `include` allows) in its square of the layer (`atlas::Slot`):
    /// clip space maps onto it alone; `draw` records its meshes. Returns the views drawn.
    fn views_of(
        &self,
        pass: &mut wgpu::RenderPass<'_>,
        layer: u32,
        include: &dyn Fn(usize) -> bool,
        draw: &dyn Fn(&mut wgpu::RenderPass<'_>, &[Piece]),
    ) -> u32 {
        let cx = self.cx;
        let mut count = 0;
        pass.set_bind_group(0, cx.scene_bind_group, &[]);
        pass.set_vertex_buffer(0, cx.vertices.slice(..));
        for (i, v) in self.plan.views.iter().enumerate() {
            if v.layer != layer || !include(i) {
                continue;
            }
            count += 1;
            let [x, y, side, _] = v.rect;
            pass.set_viewport(x, y, side, side, 0.0, 1.0);
            pass.set_scissor_rect(x as u32, y as u32, side as u32, side as u32);
            pass.set_bind_group(
                1,
                &self.view_bind_group,
                &[(i as u64 * VIEW_UNIFORM_STRIDE) as u32],
            );
            draw(pass, &self.drawn(i));
        }
        count
    }

    /// The opaque and masked casters of every view of `layer` into its depth (`target`) and
    /// object IDs (`ids`), both cleared first. Returns the views drawn.
    fn opaque_pass(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        layer: u32,
        target: &wgpu::TextureView,
        ids: &wgpu::TextureView,
    ) -> u32 {
        let cx = self.cx;
        // "Nothing in front" (0 in reversed-Z), so uncovered texels are lit.
        let mut pass = layer_pass(
            encoder,
            "shadow pass",
            Some((ids, wgpu::Color::TRANSPARENT)),
            target,
            wgpu::LoadOp::Clear(self.maps.depth.clear()),
        );
        self.views_of(&mut pass, layer, &|_| true, &|pass, drawn| {
            for masked in [false, true] {
                pass.set_pipeline(if masked {
                    &cx.pipelines.shadow_masked
                } else {
                    &cx.pipelines.shadow_opaque
                });
                for lod in [false, true] {
                    let mut set = drawn
                        .iter()
                        .filter(|m| m.masked == masked && !m.translucent && m.lod == lod)
                        .peekable();
                    if set.peek().is_none() {
                        continue;
                    }
                    match cx.lod {
                        Some((buffer, _)) if lod => pass.set_vertex_buffer(0, buffer.slice(..)),
                        _ => pass.set_vertex_buffer(0, cx.vertices.slice(..)),
                    }
                    for m in set {
                        let n = u64::from(m.vertices.end - m.vertices.start);
                        let (all, simplified) = self.drawn_vertices.get();
                        self.drawn_vertices
                            .set((all + n, simplified + if lod { n } else { 0 }));
                        draw_range(pass, m);
                    }
                }
            }
            pass.set_vertex_buffer(0, cx.vertices.slice(..));
        })
    }

    /// Where `layer` holds a view with transmittance maps (and they are full size), the
    /// nearest translucent caster's depth and their transmittance behind the opaque casters'
    /// depth (`target`). Returns the views with transmittance maps drawn.
    fn translucent_passes(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        layer: u32,
        target: &wgpu::TextureView,
    ) -> u32 {
        let (cx, plan) = (self.cx, self.plan);
        let has_transmit = |i: usize| self.transmit.get(i).copied().unwrap_or(false);
        let tm = &self.maps.translucent;
        let in_layer = |i: usize| plan.views[i].layer == layer && has_transmit(i);
        if !tm.full || !(0..plan.views.len()).any(in_layer) {
            return 0;
        }
        let (Some(transmit_target), Some(translucent_depth)) = (
            tm.transmit_layer_views.get(layer as usize),
            tm.depth_layer_views.get(layer as usize),
        ) else {
            return 0;
        };
        let translucent_only = |pass: &mut wgpu::RenderPass<'_>, drawn: &[Piece]| {
            for m in drawn.iter().filter(|m| m.translucent) {
                draw_range(pass, m);
            }
        };
        let transmitted = if tm.layered {
            let Some(drawn) = self.two_layers(encoder, layer, &has_transmit) else {
                return 0;
            };
            drawn
        } else {
            // The nearest translucent caster's depth.
            let mut pass = layer_pass(
                encoder,
                "translucent depth pass",
                None,
                translucent_depth,
                wgpu::LoadOp::Clear(self.maps.depth.clear()),
            );
            pass.set_pipeline(&cx.pipelines.shadow_translucent_depth);
            self.views_of(&mut pass, layer, &has_transmit, &|pass, drawn| {
                pass.set_pipeline(&cx.pipelines.shadow_translucent_depth);
                translucent_only(pass, drawn);
            })
        };
        // Their transmittance, multiplied in behind the opaque casters' depth (tested, kept).
        let mut pass = layer_pass(
            encoder,
            "transmittance pass",
            Some((transmit_target, wgpu::Color::WHITE)),
            target,
            wgpu::LoadOp::Load,
        );
        self.views_of(&mut pass, layer, &has_transmit, &|pass, drawn| {
            pass.set_pipeline(&cx.pipelines.shadow_transmit);
            translucent_only(pass, drawn);
        });
        transmitted
    }

    /// The translucent layers of `layer`'s views with transmittance maps (`include`) in a
    /// layered array: the nearest translucent caster's depth (layer l) with its own
    /// transmittance T1 (layer L + l, cleared to 1), then the second-nearest's depth (layer
    /// L + l): a second peel in light space, beyond the first's depth at the texel. Returns
    /// the views drawn (`None`: the array lacks the layers).
    fn two_layers(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        layer: u32,
        include: &dyn Fn(usize) -> bool,
    ) -> Option<u32> {
        let (cx, tm) = (self.cx, &self.maps.translucent);
        let second = (self.maps.layers + layer) as usize;
        let (first_depth, t1, second_depth) = (
            tm.depth_layer_views.get(layer as usize)?,
            tm.transmit_layer_views.get(second)?,
            tm.depth_layer_views.get(second)?,
        );
        let translucent_only = |pass: &mut wgpu::RenderPass<'_>, drawn: &[Piece]| {
            for m in drawn.iter().filter(|m| m.translucent) {
                draw_range(pass, m);
            }
        };
        let transmitted;
        {
            let mut pass = layer_pass(
                encoder,
                "first translucent layer pass",
                Some((t1, wgpu::Color::WHITE)),
                first_depth,
                wgpu::LoadOp::Clear(self.maps.depth.clear()),
            );
            transmitted = self.views_of(&mut pass, layer, include, &|pass, drawn| {
                pass.set_pipeline(&cx.pipelines.shadow_translucent_first);
                translucent_only(pass, drawn);
            });
        }
        let first = cx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("first translucent depth"),
            layout: &cx.pipelines.second_layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: wgpu::BindingResource::TextureView(first_depth),
            }],
        });
        let mut pass = layer_pass(
            encoder,
            "second translucent layer pass",
            None,
            second_depth,
            wgpu::LoadOp::Clear(self.maps.depth.clear()),
        );
        pass.set_bind_group(2, &first, &[]);
        self.views_of(&mut pass, layer, include, &|pass, drawn| {
            pass.set_pipeline(&cx.pipelines.shadow_translucent_second);
            translucent_only(pass, drawn);
        });
        Some(transmitted)
    }
}

/// Draws a piece's vertices.
fn draw_range(pass: &mut wgpu::RenderPass<'_>, m: &Piece) {
    pass.draw(m.vertices.clone(), 0..1);
}

/// What [`render_shadow_maps`] drew.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(super) struct ShadowDrawn {
    /// Views drawn, and of those with transmittance maps.
    pub passes: u32,
    pub transmitted: u32,
    /// Vertices of opaque and masked casters drawn, and of them from simplified levels.
    pub vertices: u64,
    pub lod_vertices: u64,
}
