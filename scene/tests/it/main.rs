//! The integration tests of `scene`, one binary (each file of this folder a module).

mod support;

mod animation;
mod builtin;
mod encode;
mod gltf;
mod hostile;
mod metallic_roughness;
mod partition;
mod scene_file;
mod shadow_views;
mod validate;
