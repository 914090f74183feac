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

/// An allocation the device refuses is a `RenderError` naming it, and the device stays usable.
#[test]
fn a_refused_allocation_is_an_error() {
    use lightfold_node::gpu::RenderError;
    let gpu = Gpu::new(&GpuOptions::default())
        .unwrap_or_else(|e| panic!("no usable GPU adapter (install mesa-vulkan-drivers): {e}"));
    let side = gpu.limits.max_texture_dimension_2d + 1;
    let refused = gpu.allocate("a texture wider than the device allows", |d| {
        d.create_texture(&wgpu::TextureDescriptor {
            label: Some("too wide"),
            size: wgpu::Extent3d {
                width: side,
                height: 1,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba8Unorm,
            usage: wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        })
    });
    match refused {
        Err(RenderError::Allocation { what, message }) => {
            assert!(what.contains("wider than"), "{what}");
            assert!(!message.is_empty());
        }
        other => panic!("expected an allocation error, got {other:?}"),
    }
    let scene = lightfold_scene::builtin("box").unwrap();
    let opts = lightfold_node::gpu::RenderOptions::from_quality(&scene.quality);
    lightfold_node::gpu::Renderer::new(&gpu, &scene, opts).expect("the device still works");
}

/// An image whose targets the device cannot hold is an error before anything is allocated
/// (16384 × 16384, inside the old documented range, used to panic in wgpu); one whose deferred
/// lit buffer exceeds the storage-binding limit (lavapipe: above 2048 × 2048) renders with the
/// forward pass instead of panicking.
#[test]
fn images_beyond_the_device_buffers_are_errors_or_fall_back() {
    use lightfold_node::gpu::{EyeVariant, LayerSet, RenderError, RenderOptions, Renderer};
    use lightfold_scene::limits::{MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE};
    let gpu = Gpu::new(&GpuOptions::default())
        .unwrap_or_else(|e| panic!("no usable GPU adapter (install mesa-vulkan-drivers): {e}"));
    let mut scene = lightfold_scene::builtin("box").unwrap();
    let opts = RenderOptions::from_quality(&scene.quality);
    let samples = lightfold_scene::sampling::direct_samples(&scene);
    let lights = &samples[..1];
    let max_side = gpu.limits.max_texture_dimension_2d;
    // The readback of a 16-byte target: rows padded to 256 bytes.
    let row = (u64::from(max_side) * 16).div_ceil(256) * 256;
    let rows = gpu.limits.max_buffer_size / row + 1;
    if rows <= u64::from(max_side) {
        (scene.camera.width, scene.camera.height) = (max_side, rows as u32);
        let mut r = Renderer::new(&gpu, &scene, opts).unwrap();
        match r.render(&gpu, lights, None, [1.0; 3], LayerSet::illumination()) {
            Err(RenderError::BindingTooLarge { what, .. }) => {
                assert!(what.contains("readback"), "{what}")
            }
            other => panic!("{max_side}x{rows}: expected a size error, got {other:?}"),
        }
    }
    // Just past the deferred pass's lit buffer (32 bytes per pixel, one storage binding).
    let pixels = gpu.limits.max_storage_buffer_binding_size / 32 + 1;
    let w = 2112u32;
    let h = pixels.div_ceil(u64::from(w)) as u32;
    let r = Renderer::new(&gpu, &scene, opts).unwrap();
    if u64::from(w) * u64::from(h) <= MAX_IMAGE_PIXELS && h <= MAX_IMAGE_SIDE.min(max_side) {
        (scene.camera.width, scene.camera.height) = (w, h);
        let mut r = Renderer::new(&gpu, &scene, opts).unwrap();
        assert_eq!(r.frame_variant(&gpu, w, h), EyeVariant::Forward);
        let frame = r
            .render(&gpu, lights, None, [1.0; 3], LayerSet::illumination())
            .unwrap_or_else(|e| panic!("{w}x{h}: {e}"));
        let il = frame.illumination.expect("illumination");
        assert_eq!((il.width, il.height), (w, h));
        assert!(il.data.iter().any(|v| *v > 0.0), "a lit image");
    } else {
        // This device's storage bindings hold the deferred buffer of any image the limits allow.
        assert_eq!(r.frame_variant(&gpu, 4096, 4096), EyeVariant::Deferred);
    }
}

#[test]
fn an_opengl_adapter_is_refused_with_what_to_install() {
    // lightfold's shadow lookups need Vulkan (or Metal, DX12): a GL adapter, where the machine
    // has one, is refused with an error naming the driver to install, never opened to panic
    // later on a pipeline GL cannot compile.
    let opts = lightfold_node::gpu::GpuOptions {
        backend: Some(wgpu::Backends::GL),
        adapter_name: None,
    };
    match lightfold_node::gpu::Gpu::new(&opts) {
        Ok(g) => panic!("a GL device opened: {}", g.info.name),
        Err(e) => {
            let text = e.to_string();
            eprintln!("{text}");
            assert!(
                matches!(
                    e,
                    lightfold_node::gpu::DeviceError::GlUnsupported { .. }
                        | lightfold_node::gpu::DeviceError::NoAdapter { .. }
                ),
                "{text}"
            );
        }
    }
}
