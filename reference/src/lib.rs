//! lightfold's CPU ground truth: the exact sum over a set of point-light samples with ray-traced
//! visibility, the true area-light illumination, and the image metrics every accuracy claim uses.
//!
//! Shares the scene model and `scene::shading` with the GPU path but no visibility code. Must not
//! depend on tokio or wgpu.
