//! The integration tests of `node`, one binary (each file of this folder a module).

mod daemon_support;
mod gpu_support;

mod daemon_claims;
mod daemon_errors;
mod daemon_frame;
mod daemon_preempt;
mod daemon_tiles;
mod gpu_ambient_mask;
mod gpu_correctness;
mod gpu_device;
mod gpu_metallic_roughness;
mod gpu_modes;
mod gpu_partitions;
mod gpu_peel;
mod gpu_shadow_layers;
mod gpu_tiles;
mod gpu_translucent;
