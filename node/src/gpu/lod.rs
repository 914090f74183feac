//! Level of detail for shadow casters (issue 48, `docs/scaling.md` § Level of detail): each chunk
//! of an opaque mesh of at least [`MIN_TRIANGLES`] triangles (a smaller mesh is one chunk) gets
//! up to [`LEVELS`] simplified copies of its triangles
//! (meshoptimizer's edge-collapse simplifier, through the `meshopt` crate), each with the largest
//! distance it moved the surface (metres). A shadow view draws a chunk at the coarsest level whose
//! error is at most [`MAX_ERROR_TEXELS`] of a map texel where the chunk is nearest the light, so no
//! shadow edge moves by more than that; the eye pass always draws the full mesh.
//!
//! Chunk borders are locked (`LockBorder`): the vertices a chunk shares with its neighbours never
//! move, so chunks drawn at different levels meet without cracks. Alpha-masked and translucent
//! meshes keep their detail (their texels decide the shadow, not their triangles), and so do
//! meshes of fewer than [`MIN_TRIANGLES`] (boxes, walls, panes: nothing to gain). Posed meshes
//! (animation, moves) are drawn at full detail (their levels would be stale).

use super::scene_data::{Chunk, MeshRange, Vertex};
use lightfold_scene::shadow_views::{ShadowView, ShadowViewKind};
use std::collections::HashMap;

/// Simplified levels per chunk (a quarter, a sixteenth and a sixty-fourth of its triangles, where
/// the simplifier gets there within the chunk's locked border).
pub const LEVELS: usize = 3;

/// A level's largest surface error, in map texels at the chunk's nearest point to the light, for
/// a shadow view to draw it.
pub const MAX_ERROR_TEXELS: f32 = 0.5;

/// Meshes of fewer triangles keep their detail.
pub const MIN_TRIANGLES: u32 = 256;

/// A level is kept only if it has at most this share of the finer level's triangles.
const MIN_SAVING: f32 = 0.6;

/// One simplified level of a chunk: its triangles in [`Lods::vertices`] and the largest distance
/// the simplifier moved the surface (metres).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Level {
    pub first_vertex: u32,
    pub vertex_count: u32,
    pub error: f32,
}

/// The simplified levels of every chunk, expanded like the scene's own vertices.
#[derive(Debug, Clone, Default)]
pub struct Lods {
    pub vertices: Vec<Vertex>,
    /// Per chunk (as `SceneData::chunks`), its levels, finest first; empty for a chunk kept
    /// whole.
    pub levels: Vec<Vec<Level>>,
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

    /// Whether some chunk has a level.
    pub fn any(&self) -> bool {
        self.levels.iter().any(|l| !l.is_empty())
    }

    /// Triangles of every level of every chunk.
    pub fn triangles(&self) -> u64 {
        self.levels
            .iter()
            .flatten()
            .map(|l| u64::from(l.vertex_count / 3))
            .sum()
    }
}

/// The levels of the chunks of `meshes` (ranges into `vertices`) that LOD applies to (module
/// documentation).
pub fn build(vertices: &[Vertex], meshes: &[MeshRange], chunks: &[Chunk]) -> Lods {
    let mut lods = Lods {
        vertices: Vec::new(),
        levels: vec![Vec::new(); chunks.len()],
    };
    for m in meshes {
        if m.masked || m.translucent || m.vertex_count / 3 < MIN_TRIANGLES {
            continue;
        }
        for c in m.first_chunk..m.first_chunk + m.chunk_count {
            let chunk = &chunks[c as usize];
            let tris = &vertices
                [chunk.first_vertex as usize..(chunk.first_vertex + chunk.vertex_count) as usize];
            lods.levels[c as usize] = simplify_chunk(tris, &mut lods.vertices);
        }
    }
    lods
}

/// The levels of one chunk's expanded triangles, appended to `out`.
fn simplify_chunk(tris: &[Vertex], out: &mut Vec<Vertex>) -> Vec<Level> {
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
    let mut levels = Vec::new();
    let mut finer = indices.len();
    for k in 1..=LEVELS {
        let target = indices.len() / 4usize.pow(k as u32);
        if target < 3 {
            break;
        }
        let mut error = 0f32;
        let simplified = meshopt::simplify_decoder(
            &indices,
            &positions,
            target,
            f32::MAX,
            meshopt::SimplifyOptions::LockBorder | meshopt::SimplifyOptions::ErrorAbsolute,
            Some(&mut error),
        );
        if simplified.is_empty() || simplified.len() as f32 > MIN_SAVING * finer as f32 {
            break;
        }
        let first_vertex = out.len() as u32;
        for tri in simplified.chunks_exact(3) {
            let p = [0, 1, 2].map(|k| positions[tri[k] as usize]);
            let n = super::scene_data::geometric_normal(p[0], p[1], p[2]);
            for (k, &i) in tri.iter().enumerate() {
                out.push(Vertex {
                    position: p[k],
                    geometric_normal: n,
                    ..tris[first[i as usize]]
                });
            }
        }
        finer = simplified.len();
        levels.push(Level {
            first_vertex,
            vertex_count: out.len() as u32 - first_vertex,
            error: if error.is_finite() {
                error.max(0.0)
            } else {
                f32::MAX
            },
        });
    }
    levels
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
