//! Opens the device the renderer will use and checks what it reports. Fails (never skips) when no
//! adapter is found.

use lightfold_node::gpu::{Gpu, GpuOptions};

#[test]
fn device_opens_and_reports_limits() {
    let gpu = Gpu::new(&GpuOptions::default())
        .unwrap_or_else(|e| panic!("no usable GPU adapter (install mesa-vulkan-drivers): {e}"));
    eprintln!("adapter {:?} backend {:?}", gpu.info.name, gpu.info.backend);
    eprintln!("limits {:#?}", gpu.limits);
    eprintln!("float32 targets {}", gpu.float32_targets);
    let k = gpu.max_lights(512);
    assert!(k >= 16, "max lights at 512² is {k}");
}

/// A pipeline the device rejects is a `RenderError`, not a panic from wgpu's default error
/// handler, and the device stays usable for the next renderer.
#[test]
fn a_rejected_pipeline_is_an_error() {
    use lightfold_node::gpu::{Fault, RenderError, RenderOptions, Renderer};
    let gpu = Gpu::new(&GpuOptions::default())
        .unwrap_or_else(|e| panic!("no usable GPU adapter (install mesa-vulkan-drivers): {e}"));
    let scene = lightfold_scene::builtin("box").unwrap();
    let mut opts = RenderOptions::from_quality(&scene.quality);
    opts.fault = Some(Fault::InvalidPipeline);
    match Renderer::new(&gpu, &scene, opts) {
        Err(RenderError::Gpu(msg)) => assert!(msg.contains("pipelines"), "{msg}"),
        Err(other) => panic!("expected a gpu error, got {other}"),
        Ok(_) => panic!("an invalid pipeline was accepted"),
    }
    opts.fault = None;
    Renderer::new(&gpu, &scene, opts).expect("the device still works");
}
