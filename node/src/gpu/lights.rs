//! Per-frame light data: each sample λ packed for the shaders with its weight `c_λ ⊘ c_n`, and its
//! shadow views (from `scene::shadow_views`) packed as layers of one depth-texture array. Pure CPU
//! code, so the packing and the deliberate faults of the negative controls are testable alone.

use super::atlas::{Atlas, fit_budget};
use super::device::{SHADOW_MEMORY_BUDGET, SHADOW_TEXEL_BYTES};
use super::shadow_depth::ShadowDepth;
use bytemuck::{Pod, Zeroable};
use lightfold_scene::shading::V3;
use lightfold_scene::shadow_views::{
    Mismatch, ShadowView, ShadowViewKind, camera_views, cube_frame, mismatch_size, probes,
    shadow_views, visible_receivers,
};
use lightfold_scene::{AreaShape, Camera, LightSample, SampleKind};

/// Deliberate mistakes for negative-control tests: each must make the comparison with the CPU
/// reference fail. Never set outside tests.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fault {
    /// Depth and slope bias forced to 0 (shadow acne).
    NoBias,
    /// A 0.5 m constant bias (shadows detach from their casters).
    HugeBias,
    /// Lights with several views keep only the one looking most along their axis (for a cube,
    /// the face a single 90° frustum would be).
    MissingFace,
    /// The light colour is multiplied in as `c_λ` instead of `c_λ ⊘ c_n` (applied twice downstream).
    ColourNotDivided,
    /// One pipeline is created from an entry point the shader lacks: the device's validation
    /// error must come back as a `RenderError`, not a panic.
    InvalidPipeline,
    /// Shadow maps in `Depth16Unorm` (still reversed-Z): depth steps of 2^-16 instead of a
    /// float's relative 2^-24.
    Depth16,
    /// Shadow maps with conventional Z (near 0, far 1) in `Depth32Float`.
    ConventionalZ,
    /// The eye pass draws only meshes wholly inside the view (a wrong culling: meshes the
    /// image's border cuts vanish).
    EyeCullPartial,
    /// Eye-pass occlusion culling tests a box's farthest corner instead of its nearest, so boxes
    /// only partly behind the occluders are left out (`gpu::occlusion`).
    OcclusionFarCorner,
    /// Levels are simplified without the area guard and shadow views draw every chunk at its
    /// coarsest, whatever its error (`gpu::lod`).
    LodCoarsest,
    /// The eye pass draws each chunk's first shadow level (lossy: it moves the surface) instead
    /// of its lossless eye level (`gpu::lod`).
    EyeLodLossy,
    /// A sort-first tile's raster and light pass cover rows `[y0 + 1, y1 + 1)`, one row below
    /// its own (`Renderer::set_rows`).
    TileRowsOffByOne,
    /// A sort-first tile's eye culling takes its rows from the bottom of the image (a flipped
    /// sub-frustum: meshes in the tile are culled, others drawn).
    TileFrustumFlipped,
    /// A peeling renderer's transmittance maps keep one translucent layer, as a classic one's
    /// do: a translucent surface behind another is tinted by itself too.
    OneTranslucentLayer,
}

/// `Light` in `shading.wgsl` (std430).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct GpuLight {
    pub position: [f32; 3],
    pub kind: u32,
    pub direction: [f32; 3],
    pub intensity: f32,
    pub weight: [f32; 3],
    pub range: f32,
    pub cos_outer: f32,
    pub cos_inner: f32,
    pub first_view: u32,
    pub view_count: u32,
    /// How a point picks its view: [`MODE_SINGLE`], [`MODE_CUBE`] (dominant axis of its direction
    /// in the frame `cube_x`, `cube_x × cube_z`, `cube_z`, then its face) or [`MODE_SPLIT`] (side
    /// of the plane with normal `cube_x`: face 0 where `cube_x·d ≥ 0`, else face 1).
    pub cube_x: [f32; 3],
    pub cube: u32,
    pub cube_z: [f32; 3],
    /// Near cascades before the views picked by `cube`: views `first_view..first_view +
    /// cascades`, nearest first, a point taking the first whose [`GpuView::cascade_to`] exceeds
    /// its eye depth; past the last, `cube` picks among the rest.
    pub cascades: u32,
    /// View index of each face (`CubeFace::index` order), two to a word, low half first; see
    /// [`GpuLight::face`].
    pub faces: [u32; 4],
    /// The area light's shape for closed-form glossy specular ([`AREA_NONE`], [`AREA_RECT`],
    /// [`AREA_DISK`], [`AREA_SPHERE`]; `scene::ltc`), its centre and its half axes `area_u`,
    /// `area_v` (a sphere's radius in `area_u[0]`).
    pub area_center: [f32; 3],
    pub area_kind: u32,
    pub area_u: [f32; 3],
    /// Width of the sample's cell of its light (`LightSample::cell`): the cell filter's kernel.
    pub cell: f32,
    pub area_v: [f32; 3],
    pub area_pad1: u32,
}

/// Values of [`GpuLight::area_kind`].
pub const AREA_NONE: u32 = 0;
pub const AREA_RECT: u32 = 1;
pub const AREA_DISK: u32 = 2;
pub const AREA_SPHERE: u32 = 3;

/// A cube face with no receivers, hence no view.
pub const NO_VIEW: u32 = u32::MAX;
/// [`NO_VIEW`] as stored in [`GpuLight::faces`].
const FACE_NONE: u32 = 0xffff;

impl GpuLight {
    /// View of face `face` (0..6), [`NO_VIEW`] where none.
    pub fn face(&self, face: usize) -> u32 {
        let v = (self.faces[face / 2] >> (16 * (face % 2))) & 0xffff;
        if v == FACE_NONE { NO_VIEW } else { v }
    }

    /// Sets face `face` (0..6) to view `view` (below 65 535, or [`NO_VIEW`]). Views are layers of
    /// one texture array, so a frame with more is refused before it renders (`TooManyViews`;
    /// devices offer 2 048 layers or fewer).
    pub fn set_face(&mut self, face: usize, view: u32) {
        let v = if view == NO_VIEW {
            FACE_NONE
        } else {
            view.min(FACE_NONE - 1)
        };
        let shift = 16 * (face % 2);
        let w = &mut self.faces[face / 2];
        *w = (*w & !(0xffff << shift)) | (v << shift);
    }
}

/// View selection modes of [`GpuLight::cube`].
pub const MODE_SINGLE: u32 = 0;
pub const MODE_CUBE: u32 = 1;
pub const MODE_SPLIT: u32 = 2;
/// Not a value of [`GpuLight::cube`]: the bit a light pass compiles in for lights with near
/// cascades ([`GpuLight::cascades`]).
pub const MODE_CASCADE: u32 = 3;

/// `View` in `eye.wgsl` (std430). The projection is stored as its eight non-zero entries:
/// `clip = (p00·x + p20·z + p30, p11·y + p21·z + p31, p22·z + p32, ortho ? 1 : −z)`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct GpuView {
    pub view: [[f32; 4]; 4],
    /// `(p00, p20, p30, p11)`.
    pub proj_a: [f32; 4],
    /// `(p21, p31, p22, p32)`.
    pub proj_b: [f32; 4],
    pub texel: f32,
    pub ortho: u32,
    pub layer: u32,
    /// For a near cascade ([`GpuLight::cascades`]): the eye depth where it ends; infinite (and
    /// unread) for other views.
    pub cascade_to: f32,
    /// The map's square in its layer, in texels: `(x, y, side, 0)` (`atlas::Slot`).
    pub rect: [f32; 4],
}

/// Everything the shadow and eye passes need to know about this frame's lights.
#[derive(Debug, Clone, Default)]
pub struct LightPlan {
    pub lights: Vec<GpuLight>,
    pub views: Vec<GpuView>,
    /// The geometry of each view (same order as `views`) and the light it belongs to.
    pub geometry: Vec<ShadowView>,
    pub view_light: Vec<u32>,
    pub passes_per_light: Vec<u32>,
    /// Where each view's map lies in the texture array (slots in view order).
    pub atlas: Atlas,
    /// Maps halved to keep the array within [`MAP_TEXEL_BUDGET`].
    pub maps_halved: u32,
}

/// `c_λ / c_n` per channel; a channel the node colour lacks contributes nothing (as the reference).
pub fn colour_weight(c: V3, c_n: V3) -> V3 {
    std::array::from_fn(|k| {
        if c_n[k] != 0.0 && c_n[k].is_finite() {
            c[k] / c_n[k]
        } else {
            0.0
        }
    })
}

/// What a frame's shadow views are fitted to.
#[derive(Debug, Clone, Copy)]
pub enum Fit<'a> {
    /// Every receiver: walkthrough maps, which outlive camera moves.
    All,
    /// What the camera sees, one frustum (or split pair, or cube faces) per light: the fit
    /// before issue 22, kept to measure against.
    Visible(&'a Camera),
    /// What the camera sees, split into cascades by eye depth where that spans a deep range
    /// (`scene::shadow_views::camera_views`): the default, as the planner counts passes.
    Cascaded(&'a Camera),
}

impl Fit<'_> {
    fn views(self, sample: &LightSample, receivers: &[(V3, V3)]) -> Vec<ShadowView> {
        match self {
            Fit::All => shadow_views(sample, receivers),
            Fit::Visible(c) => shadow_views(sample, &visible_receivers(c, receivers)),
            Fit::Cascaded(c) => camera_views(sample, receivers, c),
        }
    }
}

/// How big each light's maps are.
#[derive(Debug, Clone, Copy)]
pub enum Sides<'a> {
    /// Every map `n`².
    Uniform(u32),
    /// Sample λ's maps `sides[λ]`² (a plan's per-light sizes; the last size past the end).
    Given(&'a [u32]),
    /// From the mismatch factor where `camera` sees each light's receivers
    /// (`scene::shadow_views::mismatch_size`), `fallback` where it sees none lit.
    Mismatch {
        rule: Mismatch,
        camera: &'a Camera,
        fallback: u32,
    },
}

/// Texels the shadow maps of one frame may take ([`SHADOW_MEMORY_BUDGET`] at
/// [`SHADOW_TEXEL_BYTES`] each): above it the largest maps are halved ([`atlas::fit_budget`]).
pub const MAP_TEXEL_BUDGET: u64 = SHADOW_MEMORY_BUDGET / SHADOW_TEXEL_BYTES;

/// Bytes of one texel when the frame also has transmittance maps: the depth and object ID, a
/// translucent depth (4) and an `Rgba16Float` transmittance (8) (`shadow_pass::TranslucentMaps`).
pub const TRANSLUCENT_TEXEL_BYTES: u64 = SHADOW_TEXEL_BYTES + 12;
/// Bytes of one texel when the transmittance maps have two translucent layers (peeling
/// renderers): the second layer's depth (4) and the first layer's own transmittance (8) more.
pub const LAYERED_TEXEL_BYTES: u64 = TRANSLUCENT_TEXEL_BYTES + 12;

/// Packs `samples` and their shadow views, fitted by `fit` to `receivers` (every mesh's box),
/// each light's views on maps of the side `sides` gives it, all packed into one texture array
/// ([`Atlas`]) of at most `budget` texels.
pub fn plan_lights(
    samples: &[LightSample],
    receivers: &[(V3, V3)],
    fit: Fit<'_>,
    c_n: V3,
    sides: Sides<'_>,
    fault: Option<Fault>,
) -> LightPlan {
    plan_lights_within(samples, receivers, fit, c_n, sides, fault, MAP_TEXEL_BUDGET)
}

/// [`plan_lights`] with maps of at most `budget` texels (a frame with transmittance maps spends
/// more bytes per texel: [`TRANSLUCENT_TEXEL_BYTES`]).
pub fn plan_lights_within(
    samples: &[LightSample],
    receivers: &[(V3, V3)],
    fit: Fit<'_>,
    c_n: V3,
    sides: Sides<'_>,
    fault: Option<Fault>,
    budget: u64,
) -> LightPlan {
    let mut plan = LightPlan::default();
    let mut view_sides = Vec::new();
    let probes = match sides {
        Sides::Mismatch { camera, .. } => probes(camera, receivers),
        _ => Vec::new(),
    };
    for (i, s) in samples.iter().enumerate() {
        let mut views = fit.views(s, receivers);
        if fault == Some(Fault::MissingFace) {
            views.retain(|v| v.eye_depth.is_none());
        }
        if fault == Some(Fault::MissingFace) && views.len() > 1 {
            // Keep the view looking most along the sample's axis: a single frustum's coverage.
            let axis = cube_frame(s)[2];
            let along = |v: &ShadowView| {
                -(v.view[0][2] * axis[0] + v.view[1][2] * axis[1] + v.view[2][2] * axis[2])
            };
            let best = views
                .iter()
                .copied()
                .max_by(|a, b| along(a).total_cmp(&along(b)))
                .expect("more than one view");
            views = vec![best];
        }
        let map_size = match sides {
            Sides::Uniform(n) => n,
            Sides::Given(given) => given.get(i).or(given.last()).copied().unwrap_or(1),
            Sides::Mismatch {
                rule,
                camera,
                fallback,
            } => mismatch_size(s, &views, &probes, receivers, camera, rule, fallback),
        }
        .max(1);
        let first_view = plan.views.len() as u32;
        let mut faces = [NO_VIEW; 6];
        for v in &views {
            let e = v.extent;
            let p = &ShadowDepth::of(fault).projection(&v.proj);
            if let ShadowViewKind::CubeFace(f) = v.kind {
                faces[f.index()] = plan.views.len() as u32;
            }
            plan.views.push(GpuView {
                view: v.view,
                proj_a: [p[0][0], p[2][0], p[3][0], p[1][1]],
                proj_b: [p[2][1], p[3][1], p[2][2], p[3][2]],
                // The extent's span, divided by the side the atlas gives below.
                texel: (e[1] - e[0]).max(e[3] - e[2]),
                ortho: v.is_ortho() as u32,
                layer: 0,
                cascade_to: v.eye_depth.map_or(f32::INFINITY, |d| d[1]),
                rect: [0.0; 4],
            });
            view_sides.push(map_size);
            plan.geometry.push(*v);
            plan.view_light.push(i as u32);
        }
        plan.passes_per_light.push(views.len() as u32);
        let weight = if fault == Some(Fault::ColourNotDivided) {
            s.color
        } else {
            colour_weight(s.color, c_n)
        };
        let mut light = gpu_light(s, weight, first_view, views.len() as u32);
        // Near cascades come first; the views fitted to everything (`base`) pick as before.
        let cascades = views.iter().take_while(|v| v.eye_depth.is_some()).count();
        let base = &views[cascades..];
        let cascades = cascades as u32;
        if base
            .iter()
            .any(|v| matches!(v.kind, ShadowViewKind::CubeFace(_)))
        {
            let [x, _, z] = cube_frame(s);
            (light.cube, light.cube_x, light.cube_z) = (MODE_CUBE, x, z);
            for (f, v) in faces.into_iter().enumerate() {
                light.set_face(f, v);
            }
        } else if let [a, _] = base
            && let Some(n) = a.half_space
        {
            let first = first_view + cascades;
            (light.cube, light.cube_x) = (MODE_SPLIT, n);
            light.set_face(0, first);
            light.set_face(1, first + 1);
        }
        light.cascades = cascades;
        plan.lights.push(light);
    }
    plan.maps_halved = fit_budget(&mut view_sides, budget, 1);
    plan.atlas = Atlas::pack(&view_sides);
    for (v, slot) in plan.views.iter_mut().zip(&plan.atlas.slots) {
        v.layer = slot.layer;
        v.rect = [slot.x as f32, slot.y as f32, slot.side as f32, 0.0];
        v.texel /= slot.side as f32;
    }
    plan
}

fn gpu_light(s: &LightSample, weight: V3, first_view: u32, view_count: u32) -> GpuLight {
    let (kind, cos_outer, cos_inner) = match s.kind {
        SampleKind::Isotropic => (0, 0.0, 0.0),
        SampleKind::CosineLobe => (1, 0.0, 0.0),
        SampleKind::TwoSidedLobe => (2, 0.0, 0.0),
        SampleKind::Spot {
            cos_outer,
            cos_inner,
        } => (3, cos_outer, cos_inner),
        SampleKind::Directional => (4, 0.0, 0.0),
        SampleKind::Bounce { clamp } => (5, clamp, 0.0),
    };
    let (area_kind, area_center, area_u, area_v) = match s.area {
        None => (AREA_NONE, [0.0; 3], [0.0; 3], [0.0; 3]),
        Some(AreaShape::Rect { center, u, v }) => (AREA_RECT, center, u, v),
        Some(AreaShape::Disk { center, u, v }) => (AREA_DISK, center, u, v),
        Some(AreaShape::Sphere { center, radius }) => {
            (AREA_SPHERE, center, [radius, 0.0, 0.0], [0.0; 3])
        }
    };
    GpuLight {
        position: s.position,
        kind,
        direction: s.direction,
        intensity: s.intensity,
        weight,
        range: match s.range {
            Some(r) if r > 0.0 => r,
            _ => 0.0,
        },
        cos_outer,
        cos_inner,
        first_view,
        view_count,
        cube_x: [0.0; 3],
        cube: 0,
        cube_z: [0.0; 3],
        cascades: 0,
        faces: [u32::MAX; 4],
        area_center,
        area_kind,
        area_u,
        cell: if s.cell.is_finite() {
            s.cell.max(0.0)
        } else {
            0.0
        },
        area_v,
        area_pad1: 0,
    }
}

/// One dispatch's share of a plan: at most `max_lights` lights with their views, view indices
/// (`first_view`, `faces`) rebased to the chunk; layers stay those of the whole array.
#[derive(Debug, Clone)]
pub struct LightChunk {
    pub lights: Vec<GpuLight>,
    pub views: Vec<GpuView>,
    /// Index (and layer) in the whole plan of the chunk's view 0.
    pub first_view: u32,
}

/// Splits `lights` (with `views`, numbered across all lights as [`plan_lights`] does) into chunks
/// of at most `max_lights` lights, in order. No lights gives one empty chunk.
pub fn chunk_lights(lights: &[GpuLight], views: &[GpuView], max_lights: usize) -> Vec<LightChunk> {
    if lights.is_empty() {
        return vec![LightChunk {
            lights: Vec::new(),
            views: Vec::new(),
            first_view: 0,
        }];
    }
    lights
        .chunks(max_lights.max(1))
        .map(|part| {
            let first = part[0].first_view;
            let end = part
                .iter()
                .map(|l| l.first_view + l.view_count)
                .max()
                .unwrap_or(first);
            let rebased = part
                .iter()
                .map(|l| {
                    let mut l = *l;
                    l.first_view -= first;
                    for f in 0..6 {
                        let v = l.face(f);
                        if v != NO_VIEW {
                            l.set_face(f, v - first);
                        }
                    }
                    l
                })
                .collect();
            let range = first as usize..(end as usize).min(views.len());
            LightChunk {
                lights: rebased,
                views: views
                    .get(range)
                    .map(<[GpuView]>::to_vec)
                    .unwrap_or_default(),
                first_view: first,
            }
        })
        .collect()
}

/// Whether the box may be seen by a view: false only when all eight corners are outside one clip
/// plane (left, right, bottom, top, or beyond far). Casters in front of near are kept (they are
/// depth-clamped into the map).
pub fn box_in_view(view: &ShadowView, lo: V3, hi: V3) -> bool {
    let vp = mat_mul(&view.proj, &view.view);
    // Beyond the far plane (reversed Z: depth below 0); nearer than the near plane is kept
    // (depth clamp).
    !outside_a_plane(&box_corners_clip(&vp, lo, hi), |c| c[2] < 0.0)
}

/// Whether the box `lo`–`hi` may show in an eye view of reversed-Z projection with an infinite
/// far plane (`Camera::projection_reversed_z`): some part of it is not beyond one of the four
/// side planes or in front of the near plane. Conservative: a box that misses the frustum only
/// diagonally is kept.
pub fn box_in_eye_view(view_proj: &[[f32; 4]; 4], lo: V3, hi: V3) -> bool {
    !outside_a_plane(&box_corners_clip(view_proj, lo, hi), |c| c[2] > c[3])
}

/// The view-projection of a sort-first tile, image rows `[y0, y1)` of a `height`-row image: the
/// camera's `view_proj` with clip y remapped so the tile's rows span −1..1, an off-centre
/// sub-frustum for [`box_in_eye_view`] (x, depth and w unchanged). Row 0 is the top (clip
/// y = +w).
pub fn tile_view_proj(view_proj: &[[f32; 4]; 4], [y0, y1]: [u32; 2], height: u32) -> [[f32; 4]; 4] {
    let h = height.max(1) as f32;
    // NDC y of the tile's top and bottom edges.
    let (top, bottom) = (1.0 - 2.0 * y0 as f32 / h, 1.0 - 2.0 * y1 as f32 / h);
    let (centre, half) = (
        (top + bottom) * 0.5,
        ((top - bottom) * 0.5).max(f32::MIN_POSITIVE),
    );
    // y' = (y − centre·w) / half, column-major.
    let mut remap = [[0.0; 4]; 4];
    for (i, col) in remap.iter_mut().enumerate() {
        col[i] = 1.0;
    }
    remap[1][1] = 1.0 / half;
    remap[3][1] = -centre / half;
    mat_mul(&remap, view_proj)
}

/// Whether the box `lo`–`hi` lies wholly inside the eye view (every corner within every plane):
/// what a wrong culling that drops partly visible meshes keeps (`Fault::EyeCullPartial`).
pub fn box_wholly_in_eye_view(view_proj: &[[f32; 4]; 4], lo: V3, hi: V3) -> bool {
    box_corners_clip(view_proj, lo, hi).iter().all(|c| {
        c[3] > 0.0 && c[0].abs() <= c[3] && c[1].abs() <= c[3] && c[2] <= c[3] && c[2] >= 0.0
    })
}

/// The eight corners of the box `lo`–`hi` in clip space.
fn box_corners_clip(vp: &[[f32; 4]; 4], lo: V3, hi: V3) -> [[f32; 4]; 8] {
    std::array::from_fn(|i| {
        let p = [
            if i & 1 == 0 { lo[0] } else { hi[0] },
            if i & 2 == 0 { lo[1] } else { hi[1] },
            if i & 4 == 0 { lo[2] } else { hi[2] },
        ];
        std::array::from_fn(|r| vp[0][r] * p[0] + vp[1][r] * p[1] + vp[2][r] * p[2] + vp[3][r])
    })
}

/// Whether every corner lies beyond the same one of the four side planes, or all pass `depth`
/// (beyond a depth plane).
fn outside_a_plane(corners: &[[f32; 4]; 8], depth: impl Fn(&[f32; 4]) -> bool) -> bool {
    let beyond = |t: &dyn Fn(&[f32; 4]) -> bool| corners.iter().all(t);
    beyond(&|c| c[0] < -c[3])
        || beyond(&|c| c[0] > c[3])
        || beyond(&|c| c[1] < -c[3])
        || beyond(&|c| c[1] > c[3])
        || beyond(&depth)
}

/// Column-major `a · b`.
pub fn mat_mul(a: &[[f32; 4]; 4], b: &[[f32; 4]; 4]) -> [[f32; 4]; 4] {
    std::array::from_fn(|c| std::array::from_fn(|r| (0..4).map(|k| a[k][r] * b[c][k]).sum()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lobe(position: V3) -> LightSample {
        LightSample {
            position,
            direction: [0.0, -1.0, 0.0],
            kind: SampleKind::CosineLobe,
            intensity: 2.0,
            color: [1.0, 0.5, 0.25],
            range: None,
            light: 0,
            area: None,
            cell: 0.0,
        }
    }

    const ROOM: [(V3, V3); 2] = [
        ([-2.0, 0.0, -2.0], [2.0, 0.0, 2.0]),
        ([-2.0, 0.0, -2.0], [2.0, 3.0, -2.0]),
    ];

    #[test]
    fn layouts_match_the_wgsl_structs() {
        assert_eq!(std::mem::size_of::<GpuLight>(), 160);
        assert_eq!(std::mem::size_of::<GpuView>(), 128);
    }

    #[test]
    fn views_are_numbered_across_lights_and_weights_divide_by_c_n() {
        let samples = [lobe([0.0, 2.9, 0.0]), lobe([0.0, 10.0, 5.0])];
        let p = plan_lights(
            &samples,
            &ROOM,
            Fit::All,
            [2.0, 1.0, 0.0],
            Sides::Uniform(512),
            None,
        );
        assert_eq!(p.lights.len(), 2);
        assert_eq!(
            p.passes_per_light.iter().sum::<u32>() as usize,
            p.views.len()
        );
        assert!(
            p.passes_per_light[0] > 1,
            "ceiling light next to a wall needs faces"
        );
        assert_eq!(p.lights[1].first_view, p.passes_per_light[0]);
        // The multi-view light maps each view it needs to its layer.
        assert_ne!(p.lights[0].cube, MODE_SINGLE);
        let mapped: Vec<u32> = (0..6)
            .map(|f| p.lights[0].face(f))
            .filter(|&f| f != NO_VIEW)
            .collect();
        assert_eq!(mapped.len() as u32, p.passes_per_light[0]);
        for (i, v) in p.views.iter().enumerate() {
            assert_eq!(v.layer as usize, i);
        }
        assert_eq!(p.lights[0].weight, [0.5, 0.5, 0.0]);
        let bad = plan_lights(
            &samples,
            &ROOM,
            Fit::All,
            [2.0, 1.0, 0.0],
            Sides::Uniform(512),
            Some(Fault::ColourNotDivided),
        );
        assert_eq!(bad.lights[0].weight, [1.0, 0.5, 0.25]);
        let dropped = plan_lights(
            &samples,
            &ROOM,
            Fit::All,
            [1.0; 3],
            Sides::Uniform(512),
            Some(Fault::MissingFace),
        );
        assert_eq!(dropped.passes_per_light[0], 1);
    }

    #[test]
    fn a_light_inside_closed_walls_uses_cube_faces() {
        let walls = [
            ([-2.0, 0.0, -2.0], [2.0, 0.0, 2.0]),
            ([-2.0, 0.0, -2.0], [2.0, 3.0, -2.0]),
            ([-2.0, 0.0, 2.0], [2.0, 3.0, 2.0]),
            ([-2.0, 0.0, -2.0], [-2.0, 3.0, 2.0]),
            ([2.0, 0.0, -2.0], [2.0, 3.0, 2.0]),
        ];
        let p = plan_lights(
            &[lobe([0.0, 2.9, 0.0])],
            &walls,
            Fit::All,
            [1.0; 3],
            Sides::Uniform(512),
            None,
        );
        assert_eq!(p.lights[0].cube, MODE_CUBE);
        assert_eq!(p.passes_per_light[0], 5);
        let faces: Vec<u32> = (0..6).map(|f| p.lights[0].face(f)).collect();
        assert_eq!(faces.iter().filter(|&&f| f != NO_VIEW).count(), 5);
        assert_eq!(faces[5], NO_VIEW, "nothing behind the lobe");
    }

    #[test]
    fn faces_pack_two_to_a_word() {
        let mut l = GpuLight::zeroed();
        l.faces = [u32::MAX; 4];
        assert!((0..6).all(|f| l.face(f) == NO_VIEW));
        for (f, v) in [(0, 7), (1, 0), (2, 65_534), (5, 300)] {
            l.set_face(f, v);
        }
        assert_eq!(
            (0..6).map(|f| l.face(f)).collect::<Vec<_>>(),
            [7, 0, 65_534, NO_VIEW, NO_VIEW, 300]
        );
        l.set_face(0, NO_VIEW);
        assert_eq!((l.face(0), l.face(1)), (NO_VIEW, 0));
    }

    #[test]
    fn degenerate_samples_do_not_panic() {
        let mut bad = lobe([f32::NAN, 1.0, 0.0]);
        let p = plan_lights(
            &[bad],
            &ROOM,
            Fit::All,
            [1.0; 3],
            Sides::Uniform(512),
            Some(Fault::MissingFace),
        );
        assert_eq!(p.lights.len(), 1);
        bad.position = [0.0, 1.0, 0.0];
        bad.direction = [0.0; 3];
        bad.intensity = f32::INFINITY;
        let p = plan_lights(
            &[bad],
            &ROOM,
            Fit::All,
            [0.0, f32::NAN, 1.0],
            Sides::Uniform(0),
            None,
        );
        assert_eq!(p.lights[0].weight[..2], [0.0, 0.0]);
        assert!(
            plan_lights(&[bad], &[], Fit::All, [1.0; 3], Sides::Uniform(512), None)
                .views
                .is_empty()
        );
    }

    #[test]
    fn chunks_rebase_view_indices_and_keep_layers() {
        let samples: Vec<LightSample> = (0..5)
            .map(|i| lobe([i as f32 * 0.3 - 0.6, 2.9, 0.0]))
            .collect();
        let p = plan_lights(
            &samples,
            &ROOM,
            Fit::All,
            [1.0; 3],
            Sides::Uniform(512),
            None,
        );
        let chunks = chunk_lights(&p.lights, &p.views, 2);
        assert_eq!(
            chunks.iter().map(|c| c.lights.len()).collect::<Vec<_>>(),
            [2, 2, 1]
        );
        let mut next_light = 0;
        for c in &chunks {
            for (k, l) in c.lights.iter().enumerate() {
                let whole = &p.lights[next_light + k];
                for j in 0..l.view_count {
                    let local = &c.views[(l.first_view + j) as usize];
                    let global = &p.views[(whole.first_view + j) as usize];
                    assert_eq!(local.layer, global.layer);
                    // The shader takes view i's layer as first_view + i.
                    assert_eq!(c.first_view + l.first_view + j, global.layer);
                }
                for face in 0..6 {
                    let (f, g) = (l.face(face), whole.face(face));
                    if g == NO_VIEW {
                        assert_eq!(f, NO_VIEW);
                    } else {
                        assert_eq!(c.views[f as usize].layer, p.views[g as usize].layer);
                    }
                }
            }
            next_light += c.lights.len();
        }
        assert_eq!(
            chunks.iter().map(|c| c.views.len()).sum::<usize>(),
            p.views.len()
        );
        let none = chunk_lights(&[], &[], 64);
        assert_eq!(none.len(), 1);
        assert!(none[0].lights.is_empty());
    }

    /// `cube_face_coords` of `lighting.wgsl`: keep the two in step.
    fn cube_face_coords(face: usize, c: V3) -> V3 {
        match face {
            0 => [-c[2], c[1], -c[0]],
            1 => [c[2], c[1], c[0]],
            2 => [-c[2], -c[0], -c[1]],
            3 => [-c[2], c[0], c[1]],
            4 => [c[0], c[1], -c[2]],
            _ => [-c[0], c[1], c[2]],
        }
    }

    #[test]
    fn cube_faces_are_signed_permutations_of_the_cube_frame() {
        // The shader places points in a cube face by permuting their cube-frame coordinates
        // instead of reading the face's view matrix; every face of every axis must agree.
        let closed = [([-3.0, -3.0, -3.0], [3.0, 3.0, 3.0])];
        let axes = [
            [0.0, -1.0, 0.0],
            [0.3, -0.8, 0.5],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
        ];
        let dot = |a: V3, b: V3| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        for axis in axes {
            let s = LightSample {
                kind: SampleKind::Isotropic,
                direction: lightfold_scene::shading::normalize(axis),
                ..lobe([0.2, 0.1, -0.3])
            };
            let views = shadow_views(&s, &closed);
            assert_eq!(views.len(), 6, "a point inside a box sees all six faces");
            let frame = cube_frame(&s);
            for v in &views {
                let ShadowViewKind::CubeFace(face) = v.kind else {
                    panic!("{:?} is not a cube face", v.kind);
                };
                for d in [[0.3, -1.0, 0.2], [1.0, 0.5, -0.4], [-0.7, 0.2, 0.9]] {
                    let p: V3 = std::array::from_fn(|k| s.position[k] + d[k]);
                    let m = &v.view;
                    let q: V3 = std::array::from_fn(|r| {
                        m[0][r] * p[0] + m[1][r] * p[1] + m[2][r] * p[2] + m[3][r]
                    });
                    let c = [dot(d, frame[0]), dot(d, frame[1]), dot(d, frame[2])];
                    let want = cube_face_coords(face.index(), c);
                    for k in 0..3 {
                        assert!(
                            (q[k] - want[k]).abs() < 1e-5,
                            "axis {axis:?} face {face:?}: view {q:?}, permuted {want:?}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn boxes_outside_a_view_are_culled() {
        let s = lobe([0.0, 3.0, 0.0]);
        let v = shadow_views(&s, &[([-1.0, 0.0, -1.0], [1.0, 0.0, 1.0])])[0];
        assert!(box_in_view(&v, [-0.1, 0.5, -0.1], [0.1, 0.7, 0.1]));
        // Between the light and its near plane: kept (depth clamp).
        assert!(box_in_view(&v, [-0.1, 2.8, -0.1], [0.1, 2.9, 0.1]));
        assert!(!box_in_view(&v, [5.0, 0.0, 5.0], [6.0, 1.0, 6.0]));
        // Beyond the far plane (below the floor).
        assert!(!box_in_view(&v, [-0.1, -3.0, -0.1], [0.1, -2.0, 0.1]));
    }
}
