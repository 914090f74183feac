//! The integration tests of `scene`, one binary (each file of this folder a module).

mod support;

mod animation;
mod builtin;
mod bvh;
mod defaults;
mod encode;
mod eye_cover;
mod gltf;
mod hostile;
mod layering;
mod metallic_roughness;
mod obj;
mod partition;
mod ply;
mod scene_file;
mod shadow_views;
mod usd;
mod validate;
