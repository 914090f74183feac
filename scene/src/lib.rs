//! lightfold's scene: the model every part agrees on (meshes, materials, lights, camera), the
//! lighting maths defined once (`shading`), light sampling into point samples, primitives, images,
//! glTF 2.0, OBJ/MTL, PLY, USD and TOML scene-file loading, and the built-in scenes.
//!
//! Must not depend on tokio, wgpu or any networking: the GPU node, the CPU reference, the planner
//! and the tests all read scenes through this crate.

pub mod animation;
pub mod builtin;
pub mod bvh;
pub mod camera;
pub mod defaults;
mod encode;
mod error;
pub mod file;
pub mod framing;
pub mod gltf_load;
pub mod image;
mod input;
pub mod limits;
pub mod ltc;
pub mod model;
mod model_file;
pub mod moves;
pub mod obj_load;
pub mod partition;
pub mod ply_load;
pub mod primitives;
pub mod sampling;
mod sampling_shapes;
mod scene_ops;
pub mod shading;
pub mod shadow_views;
pub mod supersample;
pub mod trace;
pub mod usd_load;
pub mod validate;
pub mod vpl;
pub mod wire;

pub use builtin::{builtin, builtin_names, is_builtin};
pub use encode::{MAX_SCENE_BYTES, SCENE_BYTES_VERSION};
pub use error::SceneError;
pub use file::{SceneFile, is_loadable, load, load_scene_file, load_with_clip, parse_scene_file};
pub use gltf_load::{GltfOptions, ignored_features, load_gltf, load_gltf_slice, load_gltf_with};
pub use image::Image;
pub use input::read_bounded;
pub use model::*;
pub use model_file::ModelOptions;
pub use obj_load::{load_obj, load_obj_slice, load_obj_with};
pub use ply_load::{load_ply, load_ply_slice, load_ply_with};
pub use usd_load::{load_usd, load_usd_slice, load_usd_with};
pub use validate::{Issue, ValidationReport};
