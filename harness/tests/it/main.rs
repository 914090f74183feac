//! The integration tests of `tests`, one binary (each file of this folder a module).

mod ambient;
mod animation;
mod antialiasing;
mod cluster;
mod cluster_smoke;
mod failover;
mod frame_budget;
mod indirect;
mod local_cluster;
mod partitions;
mod peels;
mod penumbra_filter;
mod plan_culling;
mod plan_passes;
mod render_parity;
mod seed64_scale;
mod soft_lights;
mod tiles;
