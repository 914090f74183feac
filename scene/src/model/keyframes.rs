//! The data of scene time ([`crate::animation`] poses a scene with it): the node hierarchy,
//! keyframed channels and the rigs that attach meshes and lights to nodes.

use serde::{Deserialize, Serialize};

/// A node of the animated hierarchy: its rest transform and its parent (which comes before it).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AnimNode {
    pub name: String,
    pub parent: Option<u32>,
    pub translation: [f32; 3],
    /// Unit quaternion `(x, y, z, w)`.
    pub rotation: [f32; 4],
    pub scale: [f32; 3],
    /// Rest morph weights of the mesh on this node (glTF `mesh.weights` / `node.weights`).
    pub weights: Vec<f32>,
}

impl AnimNode {
    /// A node at the identity transform.
    pub fn identity(name: &str, parent: Option<u32>) -> AnimNode {
        AnimNode {
            name: name.to_string(),
            parent,
            translation: [0.0; 3],
            rotation: [0.0, 0.0, 0.0, 1.0],
            scale: [1.0; 3],
            weights: Vec::new(),
        }
    }
}

/// What a channel animates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Target {
    Translation,
    Rotation,
    Scale,
    /// Morph-target weights (`width` values per key).
    Weights,
}

/// How a channel interpolates between keys (glTF 2.0 §3.11).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Interpolation {
    Step,
    /// Linear; rotations by spherical linear interpolation.
    Linear,
    /// Cubic Hermite spline: each key holds (in-tangent, value, out-tangent).
    CubicSpline,
}

/// One animated property of one node.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Channel {
    pub node: u32,
    pub target: Target,
    pub interpolation: Interpolation,
    /// Key times in seconds, non-decreasing.
    pub times: Vec<f32>,
    /// `times.len() × width` values (three times that for cubic splines: in, value, out).
    pub values: Vec<f32>,
    /// Components per key: 3 (translation, scale), 4 (rotation) or the morph-target count.
    pub width: u32,
    /// Repeats on its own period (its last key time) whatever the clip does: scene-file
    /// motions, whose spins and paths have periods of their own. glTF channels follow the clip.
    pub repeat: bool,
}

/// A skin: joints (nodes), their inverse bind matrices and each vertex's four influences.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SkinRig {
    pub joints: Vec<u32>,
    /// Column-major 4×4, one per joint.
    pub inverse_bind: Vec<[f32; 16]>,
    /// Per source vertex: indices into `joints`.
    pub vertex_joints: Vec<[u16; 4]>,
    pub vertex_weights: Vec<[f32; 4]>,
}

/// One morph target's per-vertex deltas (normals empty when the target has none).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MorphTarget {
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
}

/// How one of `Scene::meshes` is posed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MeshRig {
    /// Index into `Scene::meshes`.
    pub mesh: u32,
    /// The node that places it (ignored for skinned meshes, as glTF says).
    pub node: u32,
    /// Source vertices in the node's (mesh) space.
    pub positions: Vec<[f32; 3]>,
    /// Source normals in mesh space; empty: the mesh is flat-shaded and its normals are the posed
    /// triangles' own.
    pub normals: Vec<[f32; 3]>,
    /// For each vertex of the scene mesh, its source vertex (empty: the same index).
    pub vertex_map: Vec<u32>,
    pub skin: Option<SkinRig>,
    pub targets: Vec<MorphTarget>,
}

/// How one of `Scene::lights` moves.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LightRig {
    /// Index into `Scene::lights`.
    pub light: u32,
    pub node: u32,
    /// The node's world matrix the light's rest shape was built with (column-major).
    pub rest: [f32; 16],
}

/// What moves in a scene, and how.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Animation {
    /// Clip name (the glTF animation's, or "motion" for scene-file motions).
    pub name: String,
    /// Matrix applied above the root nodes (a glTF's placement scale and translation).
    pub root: [f32; 16],
    pub nodes: Vec<AnimNode>,
    pub channels: Vec<Channel>,
    pub meshes: Vec<MeshRig>,
    pub lights: Vec<LightRig>,
    /// Time wraps modulo [`Animation::duration`] (otherwise it clamps at the ends).
    pub looping: bool,
}
