//! lightfold's CPU ground truth: the exact sum over a set of point-light samples with ray-traced
//! visibility, the true area-light illumination, and the image metrics every accuracy claim uses.
//!
//! Shares the scene model and `scene::shading` with the GPU path but no visibility code. Must not
//! depend on tokio or wgpu.

pub mod area;
pub mod indirect;
pub mod masks;
pub mod metrics;
pub mod output;
pub mod peel;
pub mod point_sum;
pub mod truth;

pub use area::{AreaOptions, direct_at, radiance_area, render_area};
pub use indirect::{OneBounceOptions, render_one_bounce};
/// The ray tracer every reference render uses (it lives beside the scene model, which the
/// planner's VPL placement shares).
pub use lightfold_scene::trace::{SurfaceHit, Tracer};
pub use metrics::{ErrorStats, Metrics, MetricsError, compare};
pub use output::{ReferenceError, ReferenceMode, render_to_files};
pub use peel::{PeeledLayers, radiance_peeled, render_peeled};
pub use point_sum::{
    Layers, PointSumOptions, radiance_point_sum, render_point_sum, render_point_sum_with,
};
pub use truth::{ErrorSplit, GroundTruth, noise_floor, split_error};
