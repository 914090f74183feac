//! lightfold's CPU ground truth: the exact sum over a set of point-light samples with ray-traced
//! visibility, the true area-light illumination, and the image metrics every accuracy claim uses.
//!
//! Shares the scene model and `scene::shading` with the GPU path but no visibility code. Must not
//! depend on tokio or wgpu.

pub mod bvh;
pub mod point_sum;
pub mod trace;

pub use point_sum::{
    Layers, PointSumOptions, radiance_point_sum, render_point_sum, render_point_sum_with,
};
pub use trace::{SurfaceHit, Tracer};
