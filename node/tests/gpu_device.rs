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
