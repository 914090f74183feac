//! The scene as the GPU sees it: triangles expanded to one vertex each (so every vertex carries its
//! triangle's geometric normal, computed in f64 like the CPU reference), the material table with
//! the reference's grey fallback, and textures as packed RGBA8 words sampled by the shaders
//! themselves (bit-for-bit the `scene::shading::sample_texture` rules).

use bytemuck::{Pod, Zeroable};
use lightfold_scene::shading::{V3, triangle_tangent};
use lightfold_scene::{AlphaMode, Material, Mesh, MetallicRoughness, Scene};

/// Marks a vertex whose mesh has no UVs (the shaders then ignore texture alpha, as the reference).
pub const NO_UV_BIT: u32 = 0x8000_0000;
/// `Material::diffuse_texture` when there is none.
pub const NO_TEXTURE: u32 = u32::MAX;

/// One vertex of the expanded triangle list; layout matches `VsIn` in `eye.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct Vertex {
    pub position: [f32; 3],
    pub normal: [f32; 3],
    pub geometric_normal: [f32; 3],
    pub uv: [f32; 2],
    /// Material index, with [`NO_UV_BIT`] when the mesh has no UVs.
    pub material: u32,
    /// The mesh's index + 1: the object ID shadow maps store beside depth, so a receiver tells
    /// its own surface from other casters (0 is "no caster").
    pub object: u32,
}

/// A vertex's normal-map tangent, in its own buffer (`@location(6)` of `VsIn`, read by the eye
/// pipelines only, so shadow passes and scenes without normal maps fetch no more than before):
/// the mesh's (glTF `TANGENT`), else the triangle's own (`scene::shading::triangle_tangent`);
/// zero unless its material has a normal texture and the mesh UVs.
pub type Tangent = [f32; 4];

/// `Material` in `materials.wgsl` (std430).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct GpuMaterial {
    pub diffuse: [f32; 3],
    pub diffuse_texture: u32,
    pub specular: [f32; 3],
    pub shininess: f32,
    pub ambient: [f32; 3],
    pub alpha: f32,
    pub emissive: [f32; 3],
    pub alpha_mode: u32,
    pub cutoff: f32,
    pub double_sided: u32,
    pub has_specular: u32,
    /// [`MODEL_BLINN_PHONG`] or [`MODEL_METALLIC_ROUGHNESS`] (whose parameters are the same
    /// index of [`SceneData::pbr`]).
    pub model: u32,
    /// Transmittance where a translucent caster covers (`scene::Transmission::color`).
    pub transmission: [f32; 3],
    /// [`TRANSMITS_NONE`], [`TRANSMITS_FILTER`] or [`TRANSMITS_COVERAGE`].
    pub transmits: u32,
}

/// `Pbr` in `materials.wgsl` (std430): a material's glTF metallic-roughness parameters
/// (`scene::MetallicRoughness`), in their own array index for index with the materials (which
/// stay 96 bytes); textures [`NO_TEXTURE`] where none.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct GpuPbr {
    pub base_color: [f32; 3],
    pub metallic: f32,
    pub roughness: f32,
    pub metallic_roughness_texture: u32,
    pub normal_texture: u32,
    pub normal_scale: f32,
    pub occlusion_texture: u32,
    pub occlusion_strength: f32,
    pub emissive_texture: u32,
    /// KHR_materials_transmission's factor τ.
    pub transmission: f32,
}

/// `Material::model` in `materials.wgsl`: the paper's Blinn-Phong.
pub const MODEL_BLINN_PHONG: u32 = 0;
/// The glTF metallic-roughness reference BRDF.
pub const MODEL_METALLIC_ROUGHNESS: u32 = 1;

/// `Material::transmits` in `materials.wgsl`: an opaque caster.
pub const TRANSMITS_NONE: u32 = 0;
/// A translucent caster filtering by its transmission colour (× texture).
pub const TRANSMITS_FILTER: u32 = 1;
/// A translucent caster whose alpha is coverage (glTF BLEND).
pub const TRANSMITS_COVERAGE: u32 = 2;

/// `TextureInfo` in `materials.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct GpuTexture {
    pub offset: u32,
    pub width: u32,
    pub height: u32,
    pub srgb: u32,
}

/// Triangles in a chunk of a large mesh. A mesh of more is drawn in chunks: its triangles ordered
/// along a Morton curve of their centroids and cut into runs of this many, each with its own box,
/// so the eye and shadow passes leave out the parts of it their frustum misses. A smaller mesh
/// is one chunk, its triangles in their own order.
pub const CHUNK_TRIANGLES: u32 = 4096;

/// A run of a mesh's triangles in the vertex list, with its box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Chunk {
    pub first_vertex: u32,
    pub vertex_count: u32,
    pub bounds: (V3, V3),
}

/// Where one mesh's triangles sit in the vertex list.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshRange {
    pub first_vertex: u32,
    pub vertex_count: u32,
    /// Its chunks: `SceneData::chunks[first_chunk..first_chunk + chunk_count]` (none when it
    /// has no valid triangle).
    pub first_chunk: u32,
    pub chunk_count: u32,
    /// Whether its material discards masked texels (needs the masked shadow pipeline).
    pub masked: bool,
    /// Whether its material lets light through: it casts into the transmittance maps, not the
    /// depth maps (`docs/translucency.md`).
    pub translucent: bool,
    /// Bounds of the mesh's referenced positions, `None` when it has no valid triangle.
    pub bounds: Option<(V3, V3)>,
    /// The mesh's own box where it is one (every triangle on a face of a box of any
    /// orientation: a wall, a tile, a turned crate), so a point in that box is in the solid.
    pub solid: Option<SolidBox>,
}

/// An oriented box a mesh fills: centre, three orthonormal axes and the half extent along each.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolidBox {
    pub center: V3,
    pub axes: [V3; 3],
    pub half: V3,
}

/// One object's bounds as the lighting shader reads them (`object_bounds`, indexed by
/// object − 1): where a receiver's plane, carried to another object's texel, leaves the
/// receiver's own object's axis-aligned box, or enters the solid box the caster fills, that
/// texel tells nothing about the receiver, and the filter does not count it (`texel_lit`;
/// docs/hard-cases.md, case 18).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct GpuBounds {
    pub lo: [f32; 4],
    pub hi: [f32; 4],
    /// The solid box (`MeshRange::solid`): its centre, w 1 where there is one (else all 0).
    pub center: [f32; 4],
    /// Its axes, each with its half extent in w.
    pub axes: [[f32; 4]; 3],
}

impl GpuBounds {
    /// Bounds no point leaves (finite: WGSL may assume no infinities).
    pub const UNBOUNDED: GpuBounds = GpuBounds {
        lo: [-3.0e38, -3.0e38, -3.0e38, 0.0],
        hi: [3.0e38, 3.0e38, 3.0e38, 0.0],
        center: [0.0; 4],
        axes: [[0.0; 4]; 3],
    };
}

/// Each mesh's bounds as the shader reads them, object − 1 for object, with the solid box it
/// fills where it fills one; a mesh without a valid triangle holds every point (never a
/// receiver). Never empty (storage bindings cannot be).
pub fn object_bounds(meshes: &[MeshRange]) -> Vec<GpuBounds> {
    let mut out: Vec<GpuBounds> = meshes
        .iter()
        .map(|m| match m.bounds {
            Some((a, b)) => {
                let (center, axes) = match m.solid {
                    Some(s) => (
                        [s.center[0], s.center[1], s.center[2], 1.0],
                        std::array::from_fn(|k| {
                            let a = s.axes[k];
                            [a[0], a[1], a[2], s.half[k]]
                        }),
                    ),
                    None => ([0.0; 4], [[0.0; 4]; 3]),
                };
                GpuBounds {
                    lo: [a[0], a[1], a[2], 0.0],
                    hi: [b[0], b[1], b[2], 0.0],
                    center,
                    axes,
                }
            }
            None => GpuBounds::UNBOUNDED,
        })
        .collect();
    if out.is_empty() {
        out.push(GpuBounds::UNBOUNDED);
    }
    out
}

/// The CPU-side arrays uploaded once per scene.
#[derive(Debug, Clone)]
pub struct SceneData {
    /// The expanded vertices, while they are needed on the CPU: an animated scene's, which
    /// `Renderer::set_meshes` compares against the posed ones. A still scene's are dropped once
    /// uploaded (`vertex_count` still says how many there are).
    pub vertices: Vec<Vertex>,
    pub vertex_count: u32,
    /// One per vertex where some mesh is normal-mapped (`normal_mapped`), else empty; dropped
    /// once uploaded.
    pub tangents: Vec<Tangent>,
    /// Whether some mesh with UVs has a material with a normal texture: the eye pipelines then
    /// read a tangent per vertex (else one zero tangent for every vertex).
    pub normal_mapped: bool,
    pub meshes: Vec<MeshRange>,
    /// Simplified levels of the meshes' chunks for the shadow passes (`gpu::lod`; empty
    /// without LOD), laid out (`Lods::layout`).
    pub lods: super::lod::Lods,
    /// The level buffer's vertices until uploaded.
    pub lod_vertices: Vec<Vertex>,
    /// Every mesh's chunks, mesh after mesh (`MeshRange::first_chunk`).
    pub chunks: Vec<Chunk>,
    /// Triangles per chunk of a large mesh (0: every mesh whole).
    pub chunk_triangles: u32,
    pub materials: Vec<GpuMaterial>,
    /// Each material's metallic-roughness parameters (zero for Blinn-Phong ones), index for
    /// index with `materials`.
    pub pbr: Vec<GpuPbr>,
    pub textures: Vec<GpuTexture>,
    pub texels: Vec<u32>,
    /// Length of the scene's bounding-box diagonal (1 for an empty scene).
    pub diagonal: f32,
    /// Each object's bounds, object − 1 for object (never empty); posed again with the meshes
    /// (`Renderer::set_meshes`).
    pub object_bounds: Vec<GpuBounds>,
}

impl SceneData {
    /// The scene's arrays, large meshes in chunks of [`CHUNK_TRIANGLES`].
    pub fn new(scene: &Scene) -> SceneData {
        SceneData::chunked(scene, CHUNK_TRIANGLES)
    }

    /// The scene's arrays, meshes of more than `chunk_triangles` triangles in chunks of that
    /// many (0: every mesh whole, its triangles in their own order), without LOD.
    pub fn chunked(scene: &Scene, chunk_triangles: u32) -> SceneData {
        SceneData::with_lod(scene, chunk_triangles, super::lod::Build::default())
    }

    /// [`SceneData::chunked`], with the simplified levels of the chunks of opaque meshes that
    /// `lod` asks for (`gpu::lod`; eye levels never where the scene is normal-mapped).
    pub fn with_lod(scene: &Scene, chunk_triangles: u32, lod: super::lod::Build) -> SceneData {
        // Out-of-range material indices get the reference's mid-grey diffuse fallback, last.
        let fallback_material = Material::diffuse("fallback", [0.5; 3]);
        let (materials, pbr): (Vec<GpuMaterial>, Vec<GpuPbr>) = scene
            .materials
            .iter()
            .chain(std::iter::once(&fallback_material))
            .map(|m| gpu_material(m, scene.textures.len()))
            .unzip();
        let fallback = materials.len() as u32 - 1;

        let normal_mapped = scene
            .meshes
            .iter()
            .any(|m| is_normal_mapped(m, material_of(m, fallback), &materials, &pbr));
        let (vertices, tangents, meshes, chunks) = triangles(
            &scene.meshes,
            &materials,
            &pbr,
            fallback,
            normal_mapped,
            chunk_triangles,
        );
        let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for (a, b) in meshes.iter().filter_map(|m| m.bounds) {
            for k in 0..3 {
                lo[k] = lo[k].min(a[k]);
                hi[k] = hi[k].max(b[k]);
            }
        }
        let diagonal = if lo[0] <= hi[0] {
            let d = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
            (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-3)
        } else {
            1.0
        };

        let mut textures = Vec::with_capacity(scene.textures.len());
        let mut texels: Vec<u32> = Vec::new();
        for t in &scene.textures {
            let n = t.width as usize * t.height as usize;
            // A texture with too few bytes samples as white, like `sample_texture`.
            let valid = n > 0 && t.rgba8.len() >= n * 4;
            textures.push(GpuTexture {
                offset: texels.len() as u32,
                width: if valid { t.width } else { 0 },
                height: if valid { t.height } else { 0 },
                srgb: t.srgb as u32,
            });
            if valid {
                texels.extend(
                    t.rgba8[..n * 4]
                        .chunks_exact(4)
                        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])),
                );
            }
        }
        // Storage bindings cannot be empty.
        if textures.is_empty() {
            textures.push(GpuTexture::zeroed());
        }
        if texels.is_empty() {
            texels.push(0);
        }
        let object_bounds = object_bounds(&meshes);
        let lod = super::lod::Build {
            eye: lod.eye && !normal_mapped,
            ..lod
        };
        let mut lods = if lod.shadow || lod.eye {
            super::lod::build(&vertices, &meshes, &chunks, lod)
        } else {
            super::lod::Lods::default()
        };
        let lod_vertices = lods.layout(&meshes);
        SceneData {
            lods,
            lod_vertices,
            object_bounds,
            vertex_count: vertices.len() as u32,
            tangents,
            normal_mapped,
            vertices,
            meshes,
            chunks,
            chunk_triangles,
            materials,
            pbr,
            textures,
            texels,
            diagonal,
        }
    }

    /// The expanded vertices, their tangents (where the scene is normal-mapped), mesh ranges and
    /// chunks of `meshes` (this scene's meshes, posed), with this scene's materials.
    pub fn geometry(&self, meshes: &[Mesh]) -> Geometry {
        let fallback = self.materials.len() as u32 - 1;
        triangles(
            meshes,
            &self.materials,
            &self.pbr,
            fallback,
            self.normal_mapped,
            self.chunk_triangles,
        )
    }

    /// The chunks of mesh range `r` (one of `meshes`).
    pub fn mesh_chunks(&self, r: &MeshRange) -> &[Chunk] {
        let at = r.first_chunk as usize;
        self.chunks
            .get(at..at + r.chunk_count as usize)
            .unwrap_or(&[])
    }

    /// Receivers for `shadow_views`: the bounds of every mesh with triangles.
    pub fn receivers(&self) -> Vec<(V3, V3)> {
        self.meshes.iter().filter_map(|m| m.bounds).collect()
    }
}

/// Expanded vertices, their tangents, where each mesh lies and its chunks.
pub type Geometry = (Vec<Vertex>, Vec<Tangent>, Vec<MeshRange>, Vec<Chunk>);

/// Triangles expanded to one vertex each, their tangents (`with_tangents`: one per vertex, else
/// none), where each mesh's lie and its chunks of `chunk` triangles (0: one chunk a mesh);
/// `materials` ends with the `fallback` for out-of-range indices.
fn triangles(
    scene_meshes: &[Mesh],
    materials: &[GpuMaterial],
    pbr: &[GpuPbr],
    fallback: u32,
    with_tangents: bool,
    chunk: u32,
) -> Geometry {
    let mut vertices = Vec::new();
    let mut tangents = Vec::new();
    let mut meshes = Vec::with_capacity(scene_meshes.len());
    let mut chunks = Vec::new();
    for (index, mesh) in scene_meshes.iter().enumerate() {
        let first_vertex = vertices.len() as u32;
        let object = u32::try_from(index + 1).unwrap_or(u32::MAX);
        let material = material_of(mesh, fallback);
        let masked = materials[material as usize].alpha_mode == 1;
        let translucent = materials[material as usize].transmits != TRANSMITS_NONE;
        let has_normals = mesh.normals.len() == mesh.positions.len();
        let has_uvs = mesh.uvs.len() == mesh.positions.len();
        let word = material | if has_uvs { 0 } else { NO_UV_BIT };
        let normal_mapped = is_normal_mapped(mesh, material, materials, pbr);
        let has_tangents = mesh.tangents.len() == mesh.positions.len();
        let (mut mlo, mut mhi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        let count = mesh.indices.len() / 3;
        let order: Vec<usize> = if chunk > 0 && count > chunk as usize {
            spatial_order(mesh)
        } else {
            (0..count).collect()
        };
        for t in order {
            let tri = &mesh.indices[3 * t..3 * t + 3];
            let idx = [tri[0] as usize, tri[1] as usize, tri[2] as usize];
            let Some(p) = idx
                .iter()
                .map(|&i| mesh.positions.get(i).copied())
                .collect::<Option<Vec<V3>>>()
            else {
                continue; // out-of-range index: the reference skips the triangle too
            };
            if p.iter().flatten().any(|c| !c.is_finite()) {
                continue;
            }
            let ng = geometric_normal(p[0], p[1], p[2]);
            // A mesh without tangents gets its triangle's own, once for the three vertices.
            let own = (normal_mapped && !has_tangents).then(|| {
                let uv = |k: usize| mesh.uvs[idx[k]];
                triangle_tangent([p[0], p[1], p[2]], [uv(0), uv(1), uv(2)])
            });
            let tangent = |k: usize| match (normal_mapped, own) {
                (false, _) => [0.0; 4],
                (true, Some(t)) => t,
                (true, None) => mesh.tangents[idx[k]],
            };
            for (k, &i) in idx.iter().enumerate() {
                for a in 0..3 {
                    mlo[a] = mlo[a].min(p[k][a]);
                    mhi[a] = mhi[a].max(p[k][a]);
                }
                vertices.push(Vertex {
                    position: p[k],
                    normal: if has_normals { mesh.normals[i] } else { ng },
                    geometric_normal: ng,
                    uv: if has_uvs { mesh.uvs[i] } else { [0.0; 2] },
                    material: word,
                    object,
                });
                if with_tangents {
                    tangents.push(tangent(k));
                }
            }
        }
        let vertex_count = vertices.len() as u32 - first_vertex;
        let bounds = (vertex_count > 0).then_some((mlo, mhi));
        let solid = solid_box(&vertices[first_vertex as usize..]);
        let first_chunk = chunks.len() as u32;
        let per = if chunk == 0 {
            vertex_count.max(1)
        } else {
            3 * chunk
        };
        let mut at = first_vertex;
        for part in vertices[first_vertex as usize..].chunks(per as usize) {
            chunks.push(Chunk {
                first_vertex: at,
                vertex_count: part.len() as u32,
                bounds: vertex_bounds(part),
            });
            at += part.len() as u32;
        }
        meshes.push(MeshRange {
            first_vertex,
            vertex_count,
            first_chunk,
            chunk_count: chunks.len() as u32 - first_chunk,
            masked,
            translucent,
            bounds,
            solid,
        });
    }
    (vertices, tangents, meshes, chunks)
}

/// `ranges` sorted, overlapping and touching ones merged: fewer draws for the same vertices.
pub fn merged(mut ranges: Vec<std::ops::Range<u32>>) -> Vec<std::ops::Range<u32>> {
    ranges.sort_by_key(|r| r.start);
    let mut out: Vec<std::ops::Range<u32>> = Vec::with_capacity(ranges.len());
    for r in ranges {
        match out.last_mut() {
            Some(last) if r.start <= last.end => last.end = last.end.max(r.end),
            _ => out.push(r),
        }
    }
    out
}

/// The box of `vertices`' positions.
fn vertex_bounds(vertices: &[Vertex]) -> (V3, V3) {
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for v in vertices {
        for a in 0..3 {
            lo[a] = lo[a].min(v.position[a]);
            hi[a] = hi[a].max(v.position[a]);
        }
    }
    (lo, hi)
}

/// `mesh`'s triangle indices ordered along a Morton (Z-order) curve of their centroids over the
/// mesh's box, 10 bits an axis (ties keep their order): neighbours in the list are neighbours in
/// space, so consecutive runs make compact chunks. A triangle with an index out of range or a
/// non-finite corner sorts anywhere (it is skipped).
fn spatial_order(mesh: &Mesh) -> Vec<usize> {
    let finite = mesh
        .positions
        .iter()
        .filter(|p| p.iter().all(|c| c.is_finite()));
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for p in finite {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    let cell = |c: f32, a: usize| -> u64 {
        let span = hi[a] - lo[a];
        let f = if span > 0.0 { (c - lo[a]) / span } else { 0.0 };
        if f.is_finite() {
            (f.clamp(0.0, 1.0) * 1023.0) as u64
        } else {
            0
        }
    };
    // Spreads 10 bits to every third bit.
    let spread = |mut x: u64| -> u64 {
        x &= 0x3ff;
        x = (x | (x << 16)) & 0x0300_00ff;
        x = (x | (x << 8)) & 0x0300_f00f;
        x = (x | (x << 4)) & 0x030c_30c3;
        (x | (x << 2)) & 0x0924_9249
    };
    let mut keyed: Vec<(u64, usize)> = mesh
        .indices
        .chunks_exact(3)
        .enumerate()
        .map(|(t, tri)| {
            let mut c = [0.0f32; 3];
            for &i in tri {
                let p = mesh.positions.get(i as usize).copied().unwrap_or([0.0; 3]);
                for a in 0..3 {
                    c[a] += p[a] / 3.0;
                }
            }
            let key =
                spread(cell(c[0], 0)) | spread(cell(c[1], 1)) << 1 | spread(cell(c[2], 2)) << 2;
            (key, t)
        })
        .collect();
    keyed.sort_by_key(|&(k, _)| k);
    keyed.into_iter().map(|(_, t)| t).collect()
}

/// The box `vertices` (three at a time, each with its triangle's geometric normal) fill, if they
/// fill one: their triangles face exactly three orthogonal directions (either way), and each
/// triangle lies in the box's face plane on its own axis (to a millionth of the box's size).
fn solid_box(vertices: &[Vertex]) -> Option<SolidBox> {
    let dot = |a: V3, b: V3| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let mut axes: Vec<V3> = Vec::with_capacity(3);
    let mut axis_of = Vec::with_capacity(vertices.len() / 3);
    for t in vertices.chunks_exact(3) {
        let n = t[0].geometric_normal;
        let k = match axes.iter().position(|a| dot(*a, n).abs() > 0.9999) {
            Some(k) => k,
            None if axes.len() < 3 => {
                axes.push(n);
                axes.len() - 1
            }
            None => return None,
        };
        axis_of.push(k);
    }
    if axes.len() != 3 || (0..3).any(|i| dot(axes[i], axes[(i + 1) % 3]).abs() > 1e-4) {
        return None;
    }
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for v in vertices {
        for k in 0..3 {
            let d = dot(axes[k], v.position);
            lo[k] = lo[k].min(d);
            hi[k] = hi[k].max(d);
        }
    }
    let size = (0..3).map(|k| hi[k] - lo[k]).fold(0.0f32, f32::max);
    let eps =
        1e-6 * size.max(1e-3) + 1e-6 * lo.iter().chain(&hi).fold(0.0f32, |m, x| m.max(x.abs()));
    let on_face = vertices.chunks_exact(3).zip(&axis_of).all(|(t, &k)| {
        [lo[k], hi[k]].iter().any(|&face| {
            t.iter()
                .all(|v| (dot(axes[k], v.position) - face).abs() <= eps)
        })
    });
    if !on_face {
        return None;
    }
    let mid: V3 = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
    Some(SolidBox {
        center: std::array::from_fn(|c| (0..3).map(|k| axes[k][c] * mid[k]).sum()),
        axes: [axes[0], axes[1], axes[2]],
        half: std::array::from_fn(|k| 0.5 * (hi[k] - lo[k])),
    })
}

fn gpu_material(m: &Material, texture_count: usize) -> (GpuMaterial, GpuPbr) {
    let (alpha_mode, cutoff) = match m.alpha_mode {
        AlphaMode::Opaque => (0, 0.0),
        AlphaMode::Mask { cutoff } => (1, cutoff),
    };
    let texture = |t: Option<usize>| match t {
        Some(t) if t < texture_count => t as u32,
        _ => NO_TEXTURE,
    };
    let pbr = m.pbr.unwrap_or(MetallicRoughness::new([0.0; 3], 0.0, 1.0));
    let material = GpuMaterial {
        diffuse: m.diffuse,
        diffuse_texture: texture(m.diffuse_texture),
        specular: m.specular,
        shininess: m.shininess,
        ambient: m.ambient,
        alpha: m.alpha,
        emissive: m.emissive,
        alpha_mode,
        cutoff,
        double_sided: m.double_sided as u32,
        has_specular: m.has_specular() as u32,
        model: if m.pbr.is_some() {
            MODEL_METALLIC_ROUGHNESS
        } else {
            MODEL_BLINN_PHONG
        },
        transmission: m.transmission.map_or([0.0; 3], |t| t.color),
        transmits: match m.transmission {
            None => TRANSMITS_NONE,
            Some(t) if t.coverage => TRANSMITS_COVERAGE,
            Some(_) => TRANSMITS_FILTER,
        },
    };
    let pbr = GpuPbr {
        base_color: pbr.base_color,
        metallic: pbr.metallic,
        roughness: pbr.roughness,
        metallic_roughness_texture: texture(pbr.metallic_roughness_texture),
        normal_texture: texture(pbr.normal_texture),
        normal_scale: pbr.normal_scale,
        occlusion_texture: texture(pbr.occlusion_texture),
        occlusion_strength: pbr.occlusion_strength,
        emissive_texture: texture(pbr.emissive_texture),
        transmission: pbr.transmission,
    };
    (material, pbr)
}

/// The material index a mesh draws with: its own, or `fallback` where that is out of range.
fn material_of(mesh: &Mesh, fallback: u32) -> u32 {
    if mesh.material < fallback as usize {
        mesh.material as u32
    } else {
        fallback
    }
}

/// Whether a mesh's normal map applies: it has UVs and its material (`material`, in range) is
/// metallic-roughness with a normal texture.
fn is_normal_mapped(mesh: &Mesh, material: u32, materials: &[GpuMaterial], pbr: &[GpuPbr]) -> bool {
    mesh.uvs.len() == mesh.positions.len()
        && materials[material as usize].model == MODEL_METALLIC_ROUGHNESS
        && pbr[material as usize].normal_texture != NO_TEXTURE
}

/// Unit counter-clockwise normal computed in f64 (zero for a degenerate triangle).
pub(crate) fn geometric_normal(a: V3, b: V3, c: V3) -> V3 {
    let f = |v: V3| v.map(f64::from);
    let (a, b, c) = (f(a), f(b), f(c));
    let e1 = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
    let e2 = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
    let n = [
        e1[1] * e2[2] - e1[2] * e2[1],
        e1[2] * e2[0] - e1[0] * e2[2],
        e1[0] * e2[1] - e1[1] * e2[0],
    ];
    let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if l > 0.0 {
        n.map(|c| (c / l) as f32)
    } else {
        [0.0; 3]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightfold_scene::primitives::plane;

    #[test]
    fn layouts_match_the_wgsl_structs() {
        assert_eq!(std::mem::size_of::<Vertex>(), 52);
        assert_eq!(std::mem::size_of::<GpuMaterial>(), 96);
        assert_eq!(std::mem::size_of::<GpuPbr>(), 48);
        assert_eq!(std::mem::size_of::<GpuTexture>(), 16);
        assert_eq!(std::mem::size_of::<GpuBounds>(), 96);
    }

    #[test]
    fn triangles_expand_with_geometric_normals_and_fallback_material() {
        let mut mesh = plane(
            "p",
            [0.0; 3],
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
            [2.0; 2],
            1,
            7,
        );
        mesh.normals.clear();
        mesh.indices.extend_from_slice(&[0, 1, 99]); // out of range: skipped
        let scene = Scene {
            name: "t".into(),
            meshes: vec![mesh],
            materials: vec![Material::diffuse("m", [1.0; 3])],
            textures: vec![],
            lights: vec![],
            camera: lightfold_scene::Camera {
                position: [0.0, 1.0, 3.0],
                target: [0.0; 3],
                up: [0.0, 1.0, 0.0],
                fov_y_deg: 45.0,
                width: 8,
                height: 8,
            },
            ambient: [0.0; 3],
            exposure: 1.0,
            quality: Default::default(),
            animation: None,
        };
        let d = SceneData::new(&scene);
        assert_eq!(d.vertices.len(), 6);
        assert_eq!(d.materials.len(), 2);
        for v in &d.vertices {
            assert_eq!(v.material & !NO_UV_BIT, 1, "fallback material");
            assert_eq!(v.geometric_normal, [0.0, 1.0, 0.0]);
            assert_eq!(v.normal, v.geometric_normal);
        }
        assert_eq!(d.meshes[0].vertex_count, 6);
        assert_eq!(d.receivers().len(), 1);
    }

    /// The solid box of a mesh: a box of any orientation fills one, with its own half extents;
    /// a plane, a sphere, and a box with one face pushed off it do not.
    #[test]
    fn boxes_fill_their_oriented_box_and_nothing_else_does() {
        let (material, pbr) = gpu_material(&Material::diffuse("m", [1.0; 3]), 0);
        let expand =
            |mesh: &Mesh| triangles(std::slice::from_ref(mesh), &[material], &[pbr], 0, false, 0).2;
        let solid = |mesh: &Mesh| expand(mesh)[0].solid;
        let mut turned =
            lightfold_scene::primitives::cuboid("b", [1.0, 2.0, 3.0], [0.5, 0.25, 2.0], 0);
        // A quarter turn about y, then 30° more: the box is no longer axis-aligned.
        let (c, s) = (30f32.to_radians().cos(), 30f32.to_radians().sin());
        for p in &mut turned.positions {
            let (x, z) = (p[0] - 1.0, p[2] - 3.0);
            (p[0], p[2]) = (1.0 + c * x + s * z, 3.0 - s * x + c * z);
        }
        let b = solid(&turned).expect("a turned box fills its box");
        for k in 0..3 {
            assert!((b.center[k] - [1.0, 2.0, 3.0][k]).abs() < 1e-5, "{b:?}");
        }
        let mut half = b.half;
        half.sort_by(f32::total_cmp);
        for (h, want) in half.iter().zip([0.25, 0.5, 2.0]) {
            assert!((h - want).abs() < 1e-5, "{b:?}");
        }
        assert_eq!(
            solid(&plane(
                "p",
                [0.0; 3],
                [0.0, 1.0, 0.0],
                [1.0, 0.0, 0.0],
                [2.0; 2],
                1,
                0
            )),
            None
        );
        let ball = lightfold_scene::primitives::sphere("s", [0.0; 3], 1.0, 16, 8, 0);
        assert_eq!(solid(&ball), None);
        // Negative control: one corner pushed out of its faces' planes.
        let mut bent = lightfold_scene::primitives::cuboid("b", [0.0; 3], [1.0; 3], 0);
        bent.positions[0][0] += 0.1;
        assert_eq!(solid(&bent), None);
    }
}
