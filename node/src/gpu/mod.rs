//! The GPU renderer of a render node: device setup, shadow maps for K point-light samples, the
//! illumination eye pass with optional material layers, and readback into `scene::Image`s.

mod ambient_mask;
pub mod atlas;
mod deferred;
pub mod device;
mod eye_pass;
pub mod frame;
pub mod lights;
pub mod lod;
mod occlusion;
pub mod pack;
mod peel;
mod pipelines;
mod readback;
pub mod renderer;
pub mod scene_data;
mod shadow_depth;
mod shadow_pass;

pub use device::{DeviceError, Gpu, GpuOptions};
pub use frame::{
    EyeVariant, LayerSet, MissingLayer, NodeFrame, RenderError, RenderOptions, RenderStats,
    check_rows,
};
pub use lights::Fault;
pub use occlusion::{AUTO_MIN_HIDDEN, AUTO_MIN_VERTICES, AUTO_PAUSE, EyeOcclusion};
pub use peel::MAX_PEEL;
pub use renderer::Renderer;
