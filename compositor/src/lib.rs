//! lightfold's compositors: the per-pixel operators of the paper (accumulate, material, depth,
//! join, output) as pure, fast CPU code, and the stage daemon that streams bands through them.
//!
//! Must not depend on wgpu, the node crate or the coordinator crate.

pub mod daemon;
pub mod ops;
pub mod pipeline;
