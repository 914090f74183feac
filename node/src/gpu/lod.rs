//! Level of detail for shadow casters (issue 48, `docs/scaling.md` § Level of detail): each chunk
//! of an opaque mesh of at least [`MIN_TRIANGLES`] triangles (a smaller mesh is one chunk) gets
//! up to [`LEVELS`] simplified copies of its triangles
//! (meshoptimizer's edge-collapse simplifier, through the `meshopt` crate), each with the largest
//! distance it moved the surface (metres). A shadow view draws a chunk at the coarsest level whose
//! error is at most [`MAX_ERROR_TEXELS`] of a map texel where the chunk is nearest the light, so no
//! shadow edge moves by more than that.
//!
//! The eye pass draws full detail but for one more level per chunk where the chunk is
//! flat-shaded (every vertex normal its triangle's): welded by every attribute it reads and
//! simplified only by collapses that keep the picture (`eye_level`, `eye_locks`), which merges
//! coplanar runs of a finely divided flat surface, across the straight attribute seams where its
//! faces meet (a building's corners), and nothing else.
//!
//! Chunk borders are locked (the shadow levels' `LockBorder`, the eye levels' own locks): the
//! vertices a chunk shares with its neighbours never move, so chunks drawn at different levels
//! meet without cracks. Alpha-masked and translucent meshes keep their detail (their texels
//! decide the shadow, not their triangles), and so do meshes of fewer than [`MIN_TRIANGLES`]
//! (boxes, walls, panes: nothing to gain). Meshes a pose or a move changes are simplified again
//! from their new vertices ([`Lods::update`]).

use super::scene_data::{Chunk, MeshRange, Vertex};
use lightfold_scene::shadow_views::{ShadowView, ShadowViewKind};
use rayon::prelude::*;
use std::collections::{HashMap, HashSet};

/// Simplified levels per chunk (a quarter, a sixteenth and a sixty-fourth of its triangles, where
/// the simplifier gets there within the chunk's locked border).
pub const LEVELS: usize = 3;

/// A level's largest surface error, in map texels at the chunk's nearest point to the light, for
/// a shadow view to draw it.
pub const MAX_ERROR_TEXELS: f32 = 0.5;

/// Meshes of fewer triangles keep their detail.
pub const MIN_TRIANGLES: u32 = 256;

/// An eye level may move the surface by at most this share of its chunk's size (its collapses
/// are exact by construction: this bounds rounding and near-flat faces).
pub const EYE_TOLERANCE: f32 = 1e-4;

/// A chunk is flat-shaded where every vertex normal is its triangle's geometric normal within
/// this (cosine 1 − this).
const FLAT_SHADED: f32 = 1e-5;

/// An eye level keeps its chunk's area within this share.
const EYE_AREA_CHANGE: f64 = 1e-4;

/// An eye level is kept only if it has at most this share of the chunk's triangles.
const EYE_MIN_SAVING: f32 = 0.8;

/// A level is kept only if its area is within this share of the chunk's (1 %).
const MAX_AREA_CHANGE: f64 = 0.01;

/// A level is kept only if it has at most this share of the finer level's triangles.
const MIN_SAVING: f32 = 0.6;

/// One simplified level of a chunk: its triangles in the uploaded level buffer (`first_vertex`,
/// set by [`Lods::layout`]; `offset` within its mesh's block) and the largest distance the
/// simplifier moved the surface (metres).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Level {
    pub first_vertex: u32,
    pub offset: u32,
    pub vertex_count: u32,
    pub error: f32,
}

/// The simplified levels of every chunk, expanded like the scene's own vertices, in one block
/// per mesh (so a pose re-simplifies only the meshes it changed).
#[derive(Debug, Clone, Default)]
pub struct Lods {
    /// Per mesh, its levels' vertices: while they are needed on the CPU (a scene that may be
    /// posed again); empty once uploaded otherwise.
    pub mesh_vertices: Vec<Vec<Vertex>>,
    /// Per mesh, its block's vertex count in the uploaded buffer.
    pub mesh_count: Vec<u32>,
    /// Per chunk (as `SceneData::chunks`), its levels, finest first; empty for a chunk kept
    /// whole.
    pub levels: Vec<Vec<Level>>,
    /// Per chunk, its lossless level for the eye pass (module documentation), if it has one.
    pub eye: Vec<Option<Level>>,
    /// What was built: whether levels that lose area were refused (false only for
    /// `Fault::LodCoarsest`) and whether eye levels were made.
    pub build: Build,
}

/// What [`build`] makes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Build {
    /// Make the shadow passes' levels.
    pub shadow: bool,
    /// Refuse shadow levels that lose area (always, but in a negative control).
    pub guarded: bool,
    /// Make lossless levels for the eye pass too (not where the scene is normal-mapped: the
    /// level buffer carries no tangents).
    pub eye: bool,
}

impl Lods {
    /// The coarsest level of `chunk` whose error fits `texel` metres (`None`: the chunk itself).
    pub fn pick(&self, chunk: usize, texel: f32) -> Option<&Level> {
        self.levels
            .get(chunk)?
            .iter()
            .rev()
            .find(|l| l.error <= MAX_ERROR_TEXELS * texel)
    }

    /// The coarsest level of `chunk`, whatever its error (a negative control's mistake).
    pub fn coarsest(&self, chunk: usize) -> Option<&Level> {
        self.levels.get(chunk)?.last()
    }

    /// Whether some chunk has a level (for the shadow passes or the eye).
    pub fn any(&self) -> bool {
        self.levels.iter().any(|l| !l.is_empty()) || self.has_eye()
    }

    /// Whether some chunk has an eye level.
    pub fn has_eye(&self) -> bool {
        self.eye.iter().any(Option::is_some)
    }

    /// Triangles of every level of every chunk (shadow and eye).
    pub fn triangles(&self) -> u64 {
        self.levels
            .iter()
            .flatten()
            .chain(self.eye.iter().flatten())
            .map(|l| u64::from(l.vertex_count / 3))
            .sum()
    }

    /// The lossless eye level of `chunk`, if it has one.
    pub fn eye_level(&self, chunk: usize) -> Option<&Level> {
        self.eye.get(chunk)?.as_ref()
    }

    /// Lays the meshes' blocks out one after another (sets every level's `first_vertex`) and
    /// returns the buffer's vertices (from `mesh_vertices`).
    pub fn layout(&mut self, meshes: &[MeshRange]) -> Vec<Vertex> {
        let mut first = 0u32;
        for (m, r) in meshes.iter().enumerate() {
            for c in r.first_chunk..r.first_chunk + r.chunk_count {
                for l in self.levels.get_mut(c as usize).into_iter().flatten() {
                    l.first_vertex = first + l.offset;
                }
                if let Some(Some(l)) = self.eye.get_mut(c as usize) {
                    l.first_vertex = first + l.offset;
                }
            }
            first += self.mesh_count.get(m).copied().unwrap_or(0);
        }
        self.mesh_vertices.concat()
    }

    /// The levels of the meshes `changed` marks simplified again from `vertices` (the others
    /// kept), where the chunks are laid out as before; everything built again otherwise or
    /// where the levels' vertices were dropped. Call [`Lods::layout`] after.
    pub fn update(
        &mut self,
        vertices: &[Vertex],
        meshes: &[MeshRange],
        chunks: &[Chunk],
        changed: &[bool],
    ) {
        let kept = self.mesh_vertices.len() == meshes.len()
            && self.levels.len() == chunks.len()
            && self.eye.len() == chunks.len()
            && self
                .mesh_vertices
                .iter()
                .zip(&self.mesh_count)
                .all(|(v, &n)| v.len() as u32 == n);
        if !kept {
            *self = build(vertices, meshes, chunks, self.build);
            return;
        }
        let built = build_meshes(
            vertices,
            meshes,
            chunks,
            self.build,
            changed,
            &mut self.levels,
            &mut self.eye,
        );
        for (m, v) in built.into_iter().enumerate() {
            if let Some(v) = v {
                self.mesh_count[m] = v.len() as u32;
                self.mesh_vertices[m] = v;
            }
        }
    }
}

/// The levels of the chunks of `meshes` (ranges into `vertices`) that LOD applies to (module
/// documentation). Call [`Lods::layout`] after.
pub fn build(vertices: &[Vertex], meshes: &[MeshRange], chunks: &[Chunk], build: Build) -> Lods {
    let mut lods = Lods {
        levels: vec![Vec::new(); chunks.len()],
        eye: vec![None; chunks.len()],
        build,
        ..Lods::default()
    };
    let all = vec![true; meshes.len()];
    let built = build_meshes(
        vertices,
        meshes,
        chunks,
        build,
        &all,
        &mut lods.levels,
        &mut lods.eye,
    );
    for v in built.into_iter().flatten() {
        lods.mesh_count.push(v.len() as u32);
        lods.mesh_vertices.push(v);
    }
    lods
}

/// One mesh's block of level vertices, its chunks' shadow levels and eye levels.
type MeshLevels = (Vec<Vertex>, Vec<Vec<Level>>, Vec<Option<Level>>);

/// Mesh `m`'s block of level vertices and its chunks' levels (empty where LOD does not apply).
fn build_mesh(vertices: &[Vertex], m: &MeshRange, chunks: &[Chunk], build: Build) -> MeshLevels {
    let mut out = Vec::new();
    let applies = !m.masked && !m.translucent && m.vertex_count / 3 >= MIN_TRIANGLES;
    let (mut levels, mut eye) = (Vec::new(), Vec::new());
    let shared = if applies && build.eye {
        shared_positions(vertices, m, chunks)
    } else {
        HashSet::new()
    };
    for c in m.first_chunk..m.first_chunk + m.chunk_count {
        match chunks.get(c as usize) {
            Some(chunk) if applies => {
                let tris = &vertices[chunk.first_vertex as usize
                    ..(chunk.first_vertex + chunk.vertex_count) as usize];
                levels.push(if build.shadow {
                    simplify_chunk(tris, &mut out, build.guarded)
                } else {
                    Vec::new()
                });
                eye.push(if build.eye {
                    eye_level(tris, &shared, &mut out)
                } else {
                    None
                });
            }
            _ => {
                levels.push(Vec::new());
                eye.push(None);
            }
        }
    }
    (out, levels, eye)
}

/// [`build_mesh`] of the meshes `which` marks, in parallel (the simplifier is the slow part of
/// loading a large scene), their levels written into `levels`.
fn build_meshes(
    vertices: &[Vertex],
    meshes: &[MeshRange],
    chunks: &[Chunk],
    build: Build,
    which: &[bool],
    levels: &mut [Vec<Level>],
    eye: &mut [Option<Level>],
) -> Vec<Option<Vec<Vertex>>> {
    let built: Vec<Option<MeshLevels>> = meshes
        .par_iter()
        .enumerate()
        .map(|(i, m)| {
            which
                .get(i)
                .copied()
                .unwrap_or(true)
                .then(|| build_mesh(vertices, m, chunks, build))
        })
        .collect();
    built
        .into_iter()
        .zip(meshes)
        .map(|(b, m)| {
            b.map(|(v, l, e)| {
                for (k, (l, e)) in l.into_iter().zip(e).enumerate() {
                    let c = m.first_chunk as usize + k;
                    if let (Some(slot), Some(eslot)) = (levels.get_mut(c), eye.get_mut(c)) {
                        (*slot, *eslot) = (l, e);
                    }
                }
                v
            })
        })
        .collect()
}

/// The levels of one chunk's expanded triangles, appended to `out`.
fn simplify_chunk(tris: &[Vertex], out: &mut Vec<Vertex>, guarded: bool) -> Vec<Level> {
    // Weld by position: the shadow pass reads positions and object IDs only.
    let mut at: HashMap<[u32; 3], u32> = HashMap::with_capacity(tris.len());
    let mut positions: Vec<[f32; 3]> = Vec::new();
    let mut first: Vec<usize> = Vec::new();
    let indices: Vec<u32> = tris
        .iter()
        .enumerate()
        .map(|(i, v)| {
            *at.entry(v.position.map(f32::to_bits)).or_insert_with(|| {
                positions.push(v.position);
                first.push(i);
                positions.len() as u32 - 1
            })
        })
        .collect();
    let whole = area(&indices, &positions);
    let mut levels = Vec::new();
    // Each level is simplified from the one before (faster than from the chunk each time); its
    // error is bounded by the sum of the steps'.
    let mut finer = indices;
    let mut total_error = 0f32;
    for _ in 1..=LEVELS {
        let target = finer.len() / 4;
        if target < 3 {
            break;
        }
        let mut error = 0f32;
        let simplified = meshopt::simplify_decoder(
            &finer,
            &positions,
            target,
            f32::MAX,
            meshopt::SimplifyOptions::LockBorder | meshopt::SimplifyOptions::ErrorAbsolute,
            Some(&mut error),
        );
        if simplified.is_empty() || simplified.len() as f32 > MIN_SAVING * finer.len() as f32 {
            break;
        }
        // A thin part collapsed moves the surface by less than its thickness, under any texel
        // bound, and takes its shadow with it (hard case 8, the sub-texel fence): a level must
        // keep the chunk's area.
        if guarded && (area(&simplified, &positions) - whole).abs() > MAX_AREA_CHANGE * whole {
            break;
        }
        total_error += if error.is_finite() {
            error.max(0.0)
        } else {
            f32::MAX
        };
        levels.push(append(
            out,
            &simplified,
            &positions,
            &first,
            tris,
            total_error,
        ));
        finer = simplified;
    }
    levels
}

/// The positions (bits) of mesh `m`'s vertices that more than one of its chunks has: an eye
/// level keeps them, so chunks drawn at different levels meet without cracks or T-junctions.
fn shared_positions(vertices: &[Vertex], m: &MeshRange, chunks: &[Chunk]) -> HashSet<[u32; 3]> {
    let mut shared = HashSet::new();
    if m.chunk_count < 2 {
        return shared;
    }
    let mut owner: HashMap<[u32; 3], u32> = HashMap::new();
    for c in m.first_chunk..m.first_chunk + m.chunk_count {
        let Some(chunk) = chunks.get(c as usize) else {
            continue;
        };
        for v in &vertices
            [chunk.first_vertex as usize..(chunk.first_vertex + chunk.vertex_count) as usize]
        {
            let p = v.position.map(f32::to_bits);
            if *owner.entry(p).or_insert(c) != c {
                shared.insert(p);
            }
        }
    }
    shared
}

/// A flat-shaded chunk's level for the eye pass, appended to `out`: its triangles welded by every
/// attribute the eye pass reads (position, normal, UV, material, object), and simplified only by
/// collapses that keep the picture (`eye_locks`): every vertex whose collapse could move the
/// surface, its outline, an attribute seam or the UV mapping is locked, so what is left merges
/// coplanar runs of a finely divided flat surface (and slides seam vertices along straight
/// seams, both sides alike) and nothing else. The simplifier's error (which includes its own
/// regularisation, [`REGULARISATION`]) must stay within [`EYE_TOLERANCE`] of the chunk's size
/// plus that regularisation, and the area within [`EYE_AREA_CHANGE`]. Smooth-shaded chunks stay
/// whole.
fn eye_level(tris: &[Vertex], shared: &HashSet<[u32; 3]>, out: &mut Vec<Vertex>) -> Option<Level> {
    // Only flat-shaded chunks: where shading normals are interpolated across a curved surface, a
    // collapse under any position bound still bends them.
    let flat = tris.iter().all(|v| {
        let (n, g) = (v.normal, v.geometric_normal);
        n[0] * g[0] + n[1] * g[1] + n[2] * g[2] >= 1.0 - FLAT_SHADED
    });
    if !flat {
        return None;
    }
    let mut at: HashMap<[u32; 10], u32> = HashMap::with_capacity(tris.len());
    let mut positions: Vec<[f32; 3]> = Vec::new();
    let mut attributes: Vec<f32> = Vec::new();
    let mut first: Vec<usize> = Vec::new();
    let indices: Vec<u32> = tris
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let p = v.position.map(f32::to_bits);
            let n = v.normal.map(f32::to_bits);
            let t = v.uv.map(f32::to_bits);
            let key = [
                p[0], p[1], p[2], n[0], n[1], n[2], t[0], t[1], v.material, v.object,
            ];
            *at.entry(key).or_insert_with(|| {
                positions.push(v.position);
                attributes.extend(v.normal);
                attributes.extend(v.uv);
                first.push(i);
                positions.len() as u32 - 1
            })
        })
        .collect();
    let (lo, hi) = positions.iter().fold(
        ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]),
        |(lo, hi), p| {
            (
                [0, 1, 2].map(|k| lo[k].min(p[k])),
                [0, 1, 2].map(|k| hi[k].max(p[k])),
            )
        },
    );
    let size = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f32>().sqrt();
    let size = size.max(1e-6);
    let tolerance = EYE_TOLERANCE * size;
    let uvs: Vec<[f32; 2]> = first.iter().map(|&i| tris[i].uv).collect();
    let normals: Vec<[f32; 3]> = first.iter().map(|&i| tris[i].normal).collect();
    let (locks, moved) = eye_locks(&indices, &positions, &normals, &uvs, shared, size);
    // Every collapse left is exact, but the simplifier adds a small pull towards each vertex's
    // own place to its error (up to REGULARISATION of the distance a vertex travels, at most the
    // chunk's size): the bound allows that on top of the tolerance.
    let limit = tolerance.hypot(REGULARISATION * size);
    let mut error = 0f32;
    let simplified = meshopt::simplify_with_attributes_and_locks_decoder(
        &indices,
        &positions,
        &attributes,
        &[1.0; 5],
        5 * std::mem::size_of::<f32>(),
        &locks,
        0,
        limit,
        meshopt::SimplifyOptions::ErrorAbsolute,
        Some(&mut error),
    );
    let whole = area(&indices, &positions);
    if simplified.is_empty()
        || simplified.len() as f32 > EYE_MIN_SAVING * indices.len() as f32
        || error.is_nan()
        || error > limit
        || moved > tolerance
        || (area(&simplified, &positions) - whole).abs() > EYE_AREA_CHANGE * whole
    {
        return None;
    }
    Some(append(out, &simplified, &positions, &first, tris, moved))
}

/// The simplifier's regularisation (meshoptimizer 1.x adds a point quadric of 10⁻⁷ of each
/// vertex's weight at its own place): a collapse that moves a vertex by `d` within its plane
/// costs about √10⁻⁷ · `d` of error, surface moved or not.
const REGULARISATION: f32 = 3.2e-4;

/// A position edge's uses in an eye level's chunk: how many triangles use it, the welded edge
/// the first welds it from, and whether another welds it from different vertices (a seam).
type EdgeUses = (u32, (u32, u32), bool);

/// How far (in UV: a tenth of a texel of a 1024-texel texture) a welded component's vertices may
/// lie off its fitted affine UV mapping for them to collapse.
const UV_DRIFT: f64 = 1e-4;

/// How far a welded component's vertex normals may differ for its vertices to collapse.
const NORMAL_DRIFT: f64 = 1e-5;

/// Which of an eye level's welded vertices (`indices` into `positions`, with `uvs`) the
/// simplifier must not move, so that every collapse it makes keeps the picture (each locked
/// vertex locks every vertex at its place):
/// - the chunk's outline (a position edge one triangle uses) and non-manifold edges, and the
///   places in `shared` (other chunks have them): chunks and meshes meet as before, without
///   cracks or T-junctions;
/// - places where an attribute seam (a position edge whose two triangles weld it from different
///   vertices: a building's corner, a roof's edge, a UV or material seam) branches, ends or bends:
///   seam vertices may only slide along a straight seam, both sides alike;
/// - the vertices of a welded component that does not lie in one plane (within 10⁻⁵ of the
///   chunk's size), is not mapped by one affine UV mapping ([`UV_DRIFT`]) or whose normals differ
///   ([`NORMAL_DRIFT`]): a collapse there would bend the surface, the texture or the shading.
///
/// Also returns how far the collapses left may move the surface: twice the largest distance of a
/// component that may collapse from its plane (rounding).
fn eye_locks(
    indices: &[u32],
    positions: &[[f32; 3]],
    normals: &[[f32; 3]],
    uvs: &[[f32; 2]],
    shared: &HashSet<[u32; 3]>,
    size: f32,
) -> (Vec<bool>, f32) {
    let n = positions.len();
    let size = f64::from(size);
    let flatness = 1e-5 * size;
    let mut place_of: HashMap<[u32; 3], u32> = HashMap::with_capacity(n);
    let place: Vec<u32> = positions
        .iter()
        .map(|p| {
            let k = place_of.len() as u32;
            *place_of.entry(p.map(f32::to_bits)).or_insert(k)
        })
        .collect();
    let mut locked_place = vec![false; place_of.len()];
    for (p, &k) in &place_of {
        if shared.contains(p) {
            locked_place[k as usize] = true;
        }
    }
    let p64 = |i: u32| positions[i as usize].map(f64::from);
    let normal = |i: u32| normals[i as usize].map(f64::from);
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let cross = |a: [f64; 3], b: [f64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    // Welded components (triangles joined by the welded vertices they share: one attribute
    // region each); each must lie in one plane, with one affine UV mapping and one normal. The
    // plane and mapping are fitted to the whole component (area-weighted normal and UV
    // gradients, through its vertices' centroid), so rounding in one small triangle far from the
    // origin does not count as a bend.
    let mut parent: Vec<u32> = (0..n as u32).collect();
    fn root(parent: &mut [u32], mut v: u32) -> u32 {
        while parent[v as usize] != v {
            parent[v as usize] = parent[parent[v as usize] as usize];
            v = parent[v as usize];
        }
        v
    }
    for tri in indices.chunks_exact(3) {
        for &o in &tri[1..] {
            let (a, b) = (root(&mut parent, tri[0]), root(&mut parent, o));
            parent[a.max(b) as usize] = a.min(b);
        }
    }
    let roots: Vec<usize> = (0..n as u32)
        .map(|v| root(&mut parent, v) as usize)
        .collect();
    // Per component: Σ of twice each triangle's area vector, of its U and V gradients times
    // twice its area, and of twice its area.
    let mut fit = vec![[[0f64; 3]; 3]; n];
    let mut weight = vec![0f64; n];
    let mut normals_of = Vec::with_capacity(indices.len() / 3);
    for tri in indices.chunks_exact(3) {
        let (e1, e2) = (sub(p64(tri[1]), p64(tri[0])), sub(p64(tri[2]), p64(tri[0])));
        let nn = cross(e1, e2);
        normals_of.push(nn);
        let len2 = dot(nn, nn);
        if len2 <= 0.0 || !len2.is_finite() {
            continue;
        }
        let (a, b) = (cross(e2, nn), cross(nn, e1));
        let l = len2.sqrt();
        let r = roots[tri[0] as usize];
        for j in 0..3 {
            fit[r][0][j] += nn[j];
        }
        for k in 0..2 {
            let uv = |i: u32| f64::from(uvs[i as usize][k]);
            let (d1, d2) = (uv(tri[1]) - uv(tri[0]), uv(tri[2]) - uv(tri[0]));
            for j in 0..3 {
                // The gradient (d1·a + d2·b) / |n|², weighted by |n|.
                fit[r][1 + k][j] += (d1 * a[j] + d2 * b[j]) / l;
            }
        }
        weight[r] += l;
    }
    let mut bad = vec![false; n];
    for (tri, nn) in indices.chunks_exact(3).zip(&normals_of) {
        let r = roots[tri[0] as usize];
        bad[r] |= dot(*nn, fit[r][0]) < 0.0;
    }
    // Per component: its vertices' centroid and mean UV, and its first vertex.
    let mut centre = vec![[0f64; 5]; n];
    let mut count = vec![0f64; n];
    let mut first_of = vec![u32::MAX; n];
    for v in 0..n {
        let r = roots[v];
        let p = p64(v as u32);
        for j in 0..3 {
            centre[r][j] += p[j];
        }
        for k in 0..2 {
            centre[r][3 + k] += f64::from(uvs[v][k]);
        }
        count[r] += 1.0;
        if first_of[r] == u32::MAX {
            first_of[r] = v as u32;
        }
    }
    let mut off = vec![0f64; n];
    for v in 0..n {
        let r = roots[v];
        if weight[r] <= 0.0 {
            continue;
        }
        let plane = fit[r][0];
        let unit = plane.map(|c| c / dot(plane, plane).sqrt());
        let c = centre[r].map(|x| x / count[r]);
        let d = sub(p64(v as u32), [c[0], c[1], c[2]]);
        off[r] = off[r].max(dot(unit, d).abs());
        let drift = (0..2)
            .map(|k| {
                let g = fit[r][1 + k].map(|x| x / weight[r]);
                (f64::from(uvs[v][k]) - c[3 + k] - dot(g, d)).abs()
            })
            .fold(0f64, f64::max);
        let turned = {
            let t = sub(normal(v as u32), normal(first_of[r]));
            dot(t, t) > NORMAL_DRIFT * NORMAL_DRIFT
        };
        bad[r] |= drift > UV_DRIFT || turned;
    }
    let mut moved = 0f64;
    let bent: Vec<bool> = (0..n)
        .map(|v| {
            let r = roots[v];
            let bent = bad[r] || off[r] > flatness;
            if !bent {
                moved = moved.max(2.0 * off[r]);
            }
            bent
        })
        .collect();
    // Position edges: how many triangles use each, and whether its uses weld it differently.
    let mut edges: HashMap<(u32, u32), EdgeUses> = HashMap::new();
    for tri in indices.chunks_exact(3) {
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            let (pa, pb) = (place[a as usize], place[b as usize]);
            let key = if pa < pb { (pa, pb) } else { (pb, pa) };
            let welded = if a < b { (a, b) } else { (b, a) };
            let e = edges.entry(key).or_insert((0, welded, false));
            e.0 += 1;
            e.2 |= e.1 != welded;
        }
    }
    // Per place, the far ends of its seam edges (at most two kept; more locks it).
    let mut seams: Vec<Vec<u32>> = vec![Vec::new(); locked_place.len()];
    for (&(pa, pb), &(uses, _, seam)) in &edges {
        if uses != 2 {
            locked_place[pa as usize] = true;
            locked_place[pb as usize] = true;
        } else if seam {
            seams[pa as usize].push(pb);
            seams[pb as usize].push(pa);
        }
    }
    let mut any_vertex = vec![u32::MAX; locked_place.len()];
    let mut wedges = vec![0u32; locked_place.len()];
    for (v, &k) in place.iter().enumerate() {
        any_vertex[k as usize] = v as u32;
        wedges[k as usize] += 1;
    }
    for k in 0..locked_place.len() {
        let s = &seams[k];
        let straight = match s.as_slice() {
            [] => wedges[k] == 1,
            [a, b] => {
                let at = |q: u32| p64(any_vertex[q as usize]);
                let (o, a, b) = (at(k as u32), at(*a), at(*b));
                let (da, db) = (sub(a, o), sub(b, o));
                let line = sub(b, a);
                let len = dot(line, line).sqrt();
                dot(da, db) < 0.0 && len > 0.0 && {
                    let c = cross(da, line);
                    dot(c, c).sqrt() / len <= flatness
                }
            }
            _ => false,
        };
        locked_place[k] |= !straight;
    }
    let locks = (0..n)
        .map(|v| bent[v] || locked_place[place[v] as usize])
        .collect();
    (locks, moved as f32)
}

/// Appends the triangles `simplified` (indices into the welded `positions`; `first[i]` the first
/// of `tris` welded into `i`, whose other attributes the level takes) to `out`, each with its own
/// geometric normal, as a level of `error`. Triangles of no area (a collapse can leave three
/// vertices on a line, or within rounding of one: area below [`SLIVER`] of the longest edge
/// squared) are left out: they cover nothing, and their normal is no direction (a rasteriser
/// may still give such a sliver a fragment, which shaded to NaN).
fn append(
    out: &mut Vec<Vertex>,
    simplified: &[u32],
    positions: &[[f32; 3]],
    first: &[usize],
    tris: &[Vertex],
    error: f32,
) -> Level {
    let offset = out.len() as u32;
    for tri in simplified.chunks_exact(3) {
        let p = [0, 1, 2].map(|k| positions[tri[k] as usize]);
        let n = super::scene_data::geometric_normal(p[0], p[1], p[2]);
        if n == [0.0; 3] || sliver(p) {
            continue;
        }
        for (k, &i) in tri.iter().enumerate() {
            out.push(Vertex {
                position: p[k],
                geometric_normal: n,
                ..tris[first[i as usize]]
            });
        }
    }
    Level {
        first_vertex: offset,
        offset,
        vertex_count: out.len() as u32 - offset,
        error,
    }
}

/// A level's triangle whose area is below this share of its longest edge squared is a sliver of
/// rounding (its height a ten-millionth of its length: what f32 positions hold), not a surface.
const SLIVER: f64 = 1e-7;

/// Whether the triangle `p` is a sliver ([`SLIVER`]).
fn sliver(p: [[f32; 3]; 3]) -> bool {
    let edge = |a: [f32; 3], b: [f32; 3]| -> f64 {
        (0..3)
            .map(|k| (f64::from(a[k]) - f64::from(b[k])).powi(2))
            .sum()
    };
    let longest = edge(p[0], p[1]).max(edge(p[1], p[2])).max(edge(p[2], p[0]));
    area(&[0, 1, 2], &p) < SLIVER * longest
}

/// The area of the triangles `indices` makes of `positions` (m²).
fn area(indices: &[u32], positions: &[[f32; 3]]) -> f64 {
    indices
        .chunks_exact(3)
        .map(|t| {
            let p = [0, 1, 2].map(|k| positions[t[k] as usize].map(f64::from));
            let (a, b) = (
                [0, 1, 2].map(|k| p[1][k] - p[0][k]),
                [0, 1, 2].map(|k| p[2][k] - p[0][k]),
            );
            let c = [
                a[1] * b[2] - a[2] * b[1],
                a[2] * b[0] - a[0] * b[2],
                a[0] * b[1] - a[1] * b[0],
            ];
            0.5 * (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt()
        })
        .sum()
}

/// The size of one of `view`'s texels (metres) at the point of the box `lo`–`hi` nearest the
/// light (along its axis); `side` is the view's square in texels.
pub fn texel_at(view: &ShadowView, side: f32, lo: [f32; 3], hi: [f32; 3]) -> f32 {
    let per = (view.extent[1] - view.extent[0]).abs() / side.max(1.0);
    if view.kind == ShadowViewKind::Ortho {
        return per;
    }
    // The view looks down −Z: depth is −z of the corner in view space.
    let v = &view.view;
    let nearest = (0..8)
        .map(|i| {
            let p = [
                if i & 1 == 0 { lo[0] } else { hi[0] },
                if i & 2 == 0 { lo[1] } else { hi[1] },
                if i & 4 == 0 { lo[2] } else { hi[2] },
            ];
            -(v[0][2] * p[0] + v[1][2] * p[1] + v[2][2] * p[2] + v[3][2])
        })
        .fold(f32::INFINITY, f32::min);
    per * nearest.max(view.near).max(0.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A level keeps no triangle of zero area: three welded vertices on a line (what a collapse
    /// can leave) have no normal, and a rasteriser that still gives the sliver a fragment shaded
    /// it to NaN (one eye-depth pixel of the million-triangle city's street view did).
    #[test]
    fn levels_drop_triangles_of_no_area() {
        let positions = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [2.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
        ];
        let tris: Vec<Vertex> = positions
            .iter()
            .map(|&position| Vertex {
                position,
                normal: [0.0, 0.0, 1.0],
                geometric_normal: [0.0, 0.0, 1.0],
                uv: [0.0; 2],
                material: 0,
                object: 1,
            })
            .collect();
        let first = [0, 1, 2, 3];
        let mut out = Vec::new();
        // A proper triangle, then one on the x axis.
        let level = append(
            &mut out,
            &[0, 1, 3, 0, 1, 2],
            &positions,
            &first,
            &tris,
            0.0,
        );
        assert_eq!(level.vertex_count, 3);
        assert!(out.iter().all(|v| v.geometric_normal == [0.0, 0.0, 1.0]));
        // Within rounding of a line (a 4 M city's levels had 17 k such, one shaded to NaN): left
        // out; a thin but real triangle kept.
        let thin = |height: f32| {
            [
                [-130.96027, 10.809292, 0.9411278],
                [-130.96027, 21.618584, 3.0],
                [-130.96027, 14.41239, 1.6274186 + height],
            ]
        };
        assert!(sliver(thin(0.0)));
        assert!(!sliver(thin(0.01)));
    }
    use crate::gpu::scene_data::SceneData;
    use lightfold_scene::primitives::{cuboid, plane};
    use lightfold_scene::{Material, Scene};

    fn shadow_levels(guarded: bool) -> Build {
        Build {
            shadow: true,
            guarded,
            eye: false,
        }
    }

    /// A scene of one mesh: `parts` appended into one.
    fn one_mesh(parts: Vec<lightfold_scene::Mesh>) -> Scene {
        let mut s = Scene::new("lod");
        let m = s.add_material(Material::diffuse("grey", [0.5; 3]));
        let mut mesh = parts[0].clone();
        mesh.material = m;
        for p in &parts[1..] {
            let base = mesh.positions.len() as u32;
            mesh.positions.extend(&p.positions);
            mesh.normals.extend(&p.normals);
            mesh.uvs.extend(&p.uvs);
            mesh.indices.extend(p.indices.iter().map(|i| i + base));
        }
        s.add_mesh(mesh);
        s
    }

    /// Each level's area over the chunk's.
    fn area_ratios(data: &SceneData) -> Vec<f64> {
        let tri_area = |v: &[Vertex]| -> f64 {
            let idx: Vec<u32> = (0..v.len() as u32).collect();
            let pos: Vec<[f32; 3]> = v.iter().map(|v| v.position).collect();
            area(&idx, &pos)
        };
        let c = &data.chunks[0];
        let whole = tri_area(
            &data.vertices[c.first_vertex as usize..(c.first_vertex + c.vertex_count) as usize],
        );
        data.lods.levels[0]
            .iter()
            .map(|l| {
                let v = &data.lod_vertices
                    [l.first_vertex as usize..(l.first_vertex + l.vertex_count) as usize];
                tri_area(v) / whole
            })
            .collect()
    }

    /// The class of hard case 8 (the sub-texel fence): wires thinner than any texel collapse
    /// with an error under half a texel and take their shadow with them. Guarded, no level
    /// loses area; without the guard (the control) one does.
    #[test]
    fn thin_wires_keep_their_area() {
        let wires: Vec<_> = (0..64)
            .map(|i| {
                cuboid(
                    "wire",
                    [i as f32 * 0.06, 1.0, 0.0],
                    [0.0005, 1.0, 0.0005],
                    0,
                )
            })
            .collect();
        let scene = one_mesh(wires);
        let guarded = SceneData::with_lod(&scene, 4096, shadow_levels(true));
        let ratios = area_ratios(&guarded);
        assert!(
            ratios.iter().all(|r| (r - 1.0).abs() <= MAX_AREA_CHANGE),
            "{ratios:?}"
        );
        let unguarded = SceneData::with_lod(&scene, 4096, shadow_levels(false));
        let lost = area_ratios(&unguarded);
        assert!(
            lost.iter().any(|r| (r - 1.0).abs() > MAX_AREA_CHANGE),
            "the control must lose area: {lost:?}"
        );
    }

    /// A finely divided plane simplifies to a quarter and further, its error under a millimetre
    /// on 4 m (the simplifier's estimate is not exactly 0 on a plane) and no area lost; LOD off
    /// builds nothing.
    #[test]
    fn a_flat_grid_simplifies_without_error() {
        let scene = one_mesh(vec![plane(
            "floor",
            [0.0; 3],
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
            [4.0, 4.0],
            32,
            0,
        )]);
        let data = SceneData::with_lod(&scene, 4096, shadow_levels(true));
        let levels = &data.lods.levels[0];
        assert!(levels.len() >= 2, "{levels:?}");
        assert!(levels.iter().all(|l| l.error <= 1e-3), "{levels:?}");
        assert!(levels[0].vertex_count * 4 <= data.chunks[0].vertex_count + 3);
        assert!(area_ratios(&data).iter().all(|r| (r - 1.0).abs() < 1e-5));
        let off = SceneData::with_lod(&scene, 4096, Build::default());
        assert!(!off.lods.any() && off.lod_vertices.is_empty());
    }

    #[test]
    fn a_view_takes_the_coarsest_level_within_half_a_texel() {
        let level = |error| Level {
            error,
            ..Level::default()
        };
        let lods = Lods {
            levels: vec![vec![level(0.1), level(0.5), level(2.0)]],
            ..Lods::default()
        };
        let pick = |texel| lods.pick(0, texel).map(|l| l.error);
        assert_eq!(pick(0.1), None);
        assert_eq!(pick(0.3), Some(0.1));
        assert_eq!(pick(1.0), Some(0.5));
        assert_eq!(pick(10.0), Some(2.0));
        assert_eq!(lods.coarsest(0).map(|l| l.error), Some(2.0));
    }

    /// A texel's size at a box: an orthographic view's is the same everywhere; a perspective
    /// view's grows with the box's nearest depth (never nearer than the near plane).
    #[test]
    fn texels_grow_with_depth_in_perspective_views() {
        let identity = [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ];
        let mut view = ShadowView {
            kind: ShadowViewKind::Fitted,
            view: identity,
            proj: identity,
            near: 0.5,
            far: 100.0,
            extent: [-1.0, 1.0, -1.0, 1.0],
            half_space: None,
            eye_depth: None,
        };
        let t = |v: &ShadowView, lo, hi| texel_at(v, 100.0, lo, hi);
        assert!((t(&view, [0.0, 0.0, -10.0], [1.0, 1.0, -5.0]) - 0.1).abs() < 1e-6);
        // Straddling the light: its near plane.
        assert!((t(&view, [0.0, 0.0, -10.0], [1.0, 1.0, 5.0]) - 0.01).abs() < 1e-6);
        view.kind = ShadowViewKind::Ortho;
        view.extent = [-50.0, 50.0, -50.0, 50.0];
        assert!((t(&view, [0.0, 0.0, -10.0], [1.0, 1.0, -5.0]) - 1.0).abs() < 1e-6);
    }

    /// Eye levels: a finely divided flat plane gets one (fewer triangles, the same area); a
    /// smooth-shaded sphere of as many triangles gets none, however small its collapses.
    #[test]
    fn only_flat_shaded_chunks_get_an_eye_level() {
        let eye = Build {
            shadow: false,
            guarded: true,
            eye: true,
        };
        let flat = one_mesh(vec![plane(
            "floor",
            [0.0; 3],
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
            [4.0, 4.0],
            32,
            0,
        )]);
        let data = SceneData::with_lod(&flat, 4096, eye);
        let level = data
            .lods
            .eye_level(0)
            .expect("a flat grid has an eye level");
        assert!(
            level.vertex_count * 2 < data.chunks[0].vertex_count,
            "{level:?}"
        );
        assert!(
            level.error <= EYE_TOLERANCE * 4.0 * 2f32.sqrt(),
            "{level:?}"
        );
        assert!(data.lods.levels[0].is_empty(), "no shadow levels asked for");
        let round = one_mesh(vec![lightfold_scene::primitives::sphere(
            "ball", [0.0; 3], 1.0, 64, 32, 0,
        )]);
        let data = SceneData::with_lod(&round, 4096, eye);
        assert!(data.lods.eye.iter().all(Option::is_none));
    }

    /// A box of six faces like the city's buildings (each face a `div × div` plane of its own
    /// vertices, meeting its neighbours at attribute seams), at `center`.
    fn subdivided_box(center: [f32; 3], half: [f32; 3], div: u32) -> Vec<lightfold_scene::Mesh> {
        let [x, y, z] = center;
        let [hx, hy, hz] = half;
        [
            (
                [x, y, z + hz],
                [0.0, 0.0, 1.0],
                [1.0, 0.0, 0.0],
                [2.0 * hx, 2.0 * hy],
            ),
            (
                [x, y, z - hz],
                [0.0, 0.0, -1.0],
                [-1.0, 0.0, 0.0],
                [2.0 * hx, 2.0 * hy],
            ),
            (
                [x + hx, y, z],
                [1.0, 0.0, 0.0],
                [0.0, 0.0, -1.0],
                [2.0 * hz, 2.0 * hy],
            ),
            (
                [x - hx, y, z],
                [-1.0, 0.0, 0.0],
                [0.0, 0.0, 1.0],
                [2.0 * hz, 2.0 * hy],
            ),
            (
                [x, y + hy, z],
                [0.0, 1.0, 0.0],
                [1.0, 0.0, 0.0],
                [2.0 * hx, 2.0 * hz],
            ),
            (
                [x, y - hy, z],
                [0.0, -1.0, 0.0],
                [1.0, 0.0, 0.0],
                [2.0 * hx, 2.0 * hz],
            ),
        ]
        .into_iter()
        .map(|(c, n, u, size)| plane("face", c, n, u, size, div, 0))
        .collect()
    }

    /// The eye level of `chunk` as triangles of positions.
    fn eye_triangles(data: &SceneData, chunk: usize) -> Vec<[[f32; 3]; 3]> {
        let l = data.lods.eye_level(chunk).expect("an eye level");
        data.lod_vertices[l.first_vertex as usize..(l.first_vertex + l.vertex_count) as usize]
            .chunks_exact(3)
            .map(|t| [t[0].position, t[1].position, t[2].position])
            .collect()
    }

    /// The chunk's own triangles as positions.
    fn chunk_triangles(data: &SceneData, chunk: usize) -> Vec<[[f32; 3]; 3]> {
        let c = &data.chunks[chunk];
        data.vertices[c.first_vertex as usize..(c.first_vertex + c.vertex_count) as usize]
            .chunks_exact(3)
            .map(|t| [t[0].position, t[1].position, t[2].position])
            .collect()
    }

    /// The undirected edges of `tris` welded by exact position, with how many triangles use each.
    fn edge_uses(tris: &[[[f32; 3]; 3]]) -> HashMap<[[u32; 3]; 2], u32> {
        let mut uses = HashMap::new();
        for t in tris {
            for k in 0..3 {
                let (a, b) = (t[k].map(f32::to_bits), t[(k + 1) % 3].map(f32::to_bits));
                *uses.entry(if a < b { [a, b] } else { [b, a] }).or_insert(0) += 1;
            }
        }
        uses
    }

    fn triangles_area(tris: &[[[f32; 3]; 3]]) -> f64 {
        let positions: Vec<[f32; 3]> = tris.iter().flatten().copied().collect();
        let idx: Vec<u32> = (0..positions.len() as u32).collect();
        area(&idx, &positions)
    }

    const EYE_ONLY: Build = Build {
        shadow: false,
        guarded: true,
        eye: true,
    };

    /// A closed box of finely divided faces (the city's buildings' kind, its faces' own vertices
    /// meeting at attribute seams along its edges) collapses to a few triangles a face in the
    /// eye level, stays closed (every edge, welded by position, used by exactly two triangles)
    /// and keeps its area.
    #[test]
    fn a_divided_box_collapses_to_a_few_triangles_and_stays_closed() {
        // Near the origin, and as far out as the 10 M city's far corner (rounding in its
        // positions is no bend).
        for center in [[37.25, 4.5, -12.75], [283.7, 20.5, -291.3]] {
            let scene = one_mesh(subdivided_box(center, [2.5, 4.0, 3.0], 10));
            let data = SceneData::with_lod(&scene, 4096, EYE_ONLY);
            let whole = chunk_triangles(&data, 0);
            assert_eq!(whole.len(), 1200);
            assert!(
                edge_uses(&whole).values().all(|&n| n == 2),
                "the box is closed"
            );
            let level = eye_triangles(&data, 0);
            // Two a face: the fewest a closed box can have.
            assert!(level.len() <= 12, "{center:?}: {} triangles", level.len());
            let open: Vec<_> = edge_uses(&level)
                .into_iter()
                .filter(|(_, n)| *n != 2)
                .collect();
            assert!(open.is_empty(), "edges not used twice: {open:?}");
            let (a, b) = (triangles_area(&level), triangles_area(&whole));
            assert!((a - b).abs() <= 1e-5 * b, "area {a} against {b}");
        }
    }

    /// A plane of two chunks: their eye levels keep every vertex they share (an edge used once
    /// in the levels together lies on the plane's outline), so chunks drawn at different levels
    /// meet without cracks; the plane's outline stays whole.
    #[test]
    fn eye_levels_of_neighbouring_chunks_meet_without_cracks() {
        let scene = one_mesh(vec![plane(
            "floor",
            [0.5, 0.0, 0.25],
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
            [4.0, 4.0],
            64,
            0,
        )]);
        let data = SceneData::with_lod(&scene, 4096, EYE_ONLY);
        assert!(data.chunks.len() >= 2, "{} chunks", data.chunks.len());
        let mut level = Vec::new();
        let mut whole = Vec::new();
        for c in 0..data.chunks.len() {
            level.extend(eye_triangles(&data, c));
            whole.extend(chunk_triangles(&data, c));
        }
        assert!(
            level.len() * 4 < whole.len(),
            "{} of {}",
            level.len(),
            whole.len()
        );
        let outline = |p: [u32; 3]| {
            let p = p.map(f32::from_bits);
            (p[0] - 0.5).abs() == 2.0 || (p[2] - 0.25).abs() == 2.0
        };
        for (edge, n) in edge_uses(&level) {
            assert!(
                n == 2 || (n == 1 && outline(edge[0]) && outline(edge[1])),
                "edge {edge:?} used {n} times"
            );
        }
        let (a, b) = (triangles_area(&level), triangles_area(&whole));
        assert!((a - b).abs() <= 1e-5 * b, "area {a} against {b}");
    }
}
