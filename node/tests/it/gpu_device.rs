//! Opens the device the renderer will use and checks what it reports. Fails (never skips) when no
//! adapter is found.

use crate::gpu_support::gpu;

#[test]
fn device_opens_and_reports_limits() {
    let gpu = gpu();
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
    let gpu = gpu();
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
    let gpu = gpu();
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
    let gpu = gpu();
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

/// Packing on the device (`gpu::pack`) against the CPU pack, the reference: the same band headers
/// and the same payload bytes for every link format, on hostile values and on rendered frames.
mod device_pack {
    use crate::gpu_support::gpu;
    use lightfold_node::daemon::bands::{
        BandLayout, LayerImages, PackedBand, assemble_frame, pack_frame,
    };
    use lightfold_node::gpu::pack::{DevicePacker, PackLayer, PackSource, PackedFrame};
    use lightfold_node::gpu::{EyeVariant, Gpu, LayerSet, RenderOptions, Renderer};
    use lightfold_protocol::{Layer, PixelFormat};
    use lightfold_scene::Image;
    use std::sync::Arc;
    use tokio::sync::mpsc;
    use wgpu::util::DeviceExt;

    /// A deterministic stream of f32 bit patterns that packing finds hard: every special value,
    /// subnormals, values at and around each format's range and rounding boundaries, random bit
    /// patterns, and ordinary light.
    struct Hostile(u64);

    impl Hostile {
        fn next_u32(&mut self) -> u32 {
            // xorshift64*
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 32) as u32
        }

        fn unit(&mut self) -> f32 {
            (self.next_u32() >> 8) as f32 / (1u32 << 24) as f32
        }

        fn value(&mut self, scale: f32) -> f32 {
            const SPECIAL: &[f32] = lightfold_node::gpu::pack::HOSTILE_SPECIALS;
            match self.next_u32() % 8 {
                0 => f32::from_bits(self.next_u32()),
                1 => SPECIAL[self.next_u32() as usize % SPECIAL.len()],
                // Around seed64's steps at this scale, ties included.
                2 => (self.next_u32() % 4096) as f32 * 0.5 * scale / 2047.0,
                3 => (self.next_u32() % 2048) as f32 * 0.5 * scale / 1023.0 * (1.0 + 1e-7),
                // Halfway between halves and between 8-bit codes.
                4 => {
                    let h = half::f16::from_bits((self.next_u32() % 0x7C00) as u16).to_f32();
                    h * (1.0 + 2f32.powi(-11))
                }
                5 => (self.next_u32() % 511) as f32 / 510.0,
                6 => self.unit() * 2f32.powi((self.next_u32() % 60) as i32 - 40),
                _ => self.unit() * 4.0,
            }
        }
    }

    const W: u32 = 67;
    const H: u32 = 37;
    const BAND: u32 = 5;

    /// `channels` f32 values a pixel, hostile except for rows that are all ±0 (two bands that
    /// must travel empty).
    fn hostile_values(seed: u64, channels: usize, scale: f32) -> Vec<f32> {
        let mut g = Hostile(seed);
        let mut v = Vec::with_capacity((W * H) as usize * channels);
        for y in 0..H {
            for _ in 0..W as usize * channels {
                v.push(match y / BAND {
                    1 => 0.0,
                    3 => -0.0,
                    _ => g.value(scale),
                });
            }
        }
        v
    }

    fn layout(scale: f32) -> BandLayout {
        BandLayout {
            epoch: 4,
            frame: 11,
            width: W,
            height: H,
            band_height: BAND,
            scale,
        }
    }

    fn cpu_bands(layout: &BandLayout, images: LayerImages) -> Vec<PackedBand> {
        let (tx, mut rx) = mpsc::channel(4096);
        pack_frame(layout, &images, None, &tx).expect("CPU pack");
        drop(tx);
        std::iter::from_fn(|| rx.try_recv().ok()).collect()
    }

    fn device_bands(
        layout: &BandLayout,
        layers: &[(Layer, PixelFormat)],
        packed: &PackedFrame,
    ) -> Vec<PackedBand> {
        let (tx, mut rx) = mpsc::channel(4096);
        assemble_frame(layout, layers, packed, &tx).expect("bands of the device pack");
        drop(tx);
        std::iter::from_fn(|| rx.try_recv().ok()).collect()
    }

    /// The first difference between two band streams, if any.
    fn difference(cpu: &[PackedBand], device: &[PackedBand]) -> Option<String> {
        if cpu.len() != device.len() {
            return Some(format!(
                "{} bands on the CPU, {} on the device",
                cpu.len(),
                device.len()
            ));
        }
        for (c, d) in cpu.iter().zip(device) {
            if c.header != d.header {
                return Some(format!("header {:?}\n  vs {:?}", c.header, d.header));
            }
            if c.payload != d.payload {
                let at = c.payload.iter().zip(&d.payload).position(|(a, b)| a != b);
                return Some(format!(
                    "{:?} band at row {}: payload differs at byte {at:?}",
                    c.header.format, c.header.y0
                ));
            }
        }
        None
    }

    fn texture(gpu: &Gpu, format: wgpu::TextureFormat, bytes: &[u8]) -> wgpu::Texture {
        lightfold_node::gpu::pack::source_texture(gpu, format, W, H, bytes)
    }

    fn image(channels: usize, data: Vec<f32>) -> Arc<Image> {
        Arc::new(Image {
            width: W,
            height: H,
            channels,
            data,
        })
    }

    /// Packs one layer from `source` on the device and from `values` on the CPU; returns the
    /// first difference.
    fn compare(
        gpu: &Gpu,
        packer: &mut DevicePacker,
        source: PackSource<'_>,
        layer: Layer,
        format: PixelFormat,
        values: &[f32],
        scale: f32,
    ) -> Option<String> {
        let layout = layout(scale);
        let channels = format.channels();
        let images: LayerImages = vec![(layer, format, image(channels, values.to_vec()))];
        let cpu = cpu_bands(&layout, images);
        let packed = packer
            .pack(gpu, &[PackLayer { source, format }], W, H, BAND, scale)
            .expect("device pack");
        let device = device_bands(&layout, &[(layer, format)], &packed);
        let peak = lightfold_node::daemon::bands::illumination_peak(
            &vec![(layer, format, image(channels, values.to_vec()))],
            None,
        );
        if layer == Layer::Illumination && packed.peak.to_bits() != peak.to_bits() {
            return Some(format!(
                "peak {} on the device, {peak} on the CPU",
                packed.peak
            ));
        }
        assert_eq!(
            packed.read_bytes,
            u64::from(W * H) * format.bytes_per_pixel() as u64
                + 4 * (1 + 2 * u64::from(H.div_ceil(BAND))),
            "only the packed bytes and the band counts are read back"
        );
        difference(&cpu, &device)
    }

    const ILLUMINATION: [PixelFormat; 4] = [
        PixelFormat::Seed64,
        PixelFormat::Rgb9e5x2,
        PixelFormat::F16x6,
        PixelFormat::F32x6,
    ];
    const MATERIAL: [PixelFormat; 4] = [
        PixelFormat::F16x4,
        PixelFormat::Rgba8Linear,
        PixelFormat::Rgba8Srgb,
        PixelFormat::F32x3,
    ];
    const SCALES: [f32; 4] = [1.0, 0.37, 3.5e-20, 3.0e38];

    #[test]
    fn hostile_values_pack_bit_for_bit_as_on_the_cpu() {
        let gpu = gpu();
        // The node's own start-up check (a smaller hostile set) passes on this device.
        DevicePacker::self_check(&gpu).expect("the device packs as the CPU does");
        let mut packer = DevicePacker::new(&gpu).expect("the pack pass builds");
        // Illumination from the deferred pass's lit buffer (two vec4<f32> a pixel).
        for (i, &scale) in SCALES.iter().enumerate() {
            let values = hostile_values(1 + i as u64, 6, scale);
            let mut words = Vec::with_capacity(values.len() / 6 * 8);
            for p in values.chunks_exact(6) {
                words.extend_from_slice(&[p[0], p[1], p[2], f32::NAN, p[3], p[4], p[5], -7.0]);
            }
            let lit = gpu
                .device
                .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("hostile lit buffer"),
                    contents: bytemuck::cast_slice(&words),
                    usage: wgpu::BufferUsages::STORAGE,
                });
            // The forward pass's two targets: f32 bits in Rgba32Uint.
            let target = |part: usize| {
                let mut texels = Vec::with_capacity(values.len() / 6 * 4);
                for p in values.chunks_exact(6) {
                    let c = &p[3 * part..3 * part + 3];
                    texels.extend_from_slice(&[c[0], c[1], c[2], f32::INFINITY]);
                }
                texture(
                    &gpu,
                    wgpu::TextureFormat::Rgba32Uint,
                    bytemuck::cast_slice(&texels),
                )
            };
            let (diffuse, specular) = (target(0), target(1));
            for format in ILLUMINATION {
                for (name, source) in [
                    ("the lit buffer", PackSource::Lit(&lit)),
                    ("two targets", PackSource::Split(&diffuse, &specular)),
                ] {
                    if let Some(d) = compare(
                        &gpu,
                        &mut packer,
                        source,
                        Layer::Illumination,
                        format,
                        &values,
                        scale,
                    ) {
                        panic!("{format:?} from {name} at scale {scale}: {d}");
                    }
                }
            }
        }
        // Material layers from f16 targets (the half bits themselves are hostile) and f32 ones.
        let mut g = Hostile(99);
        let halves: Vec<u16> = (0..W * H * 4)
            .map(|i| match (i / (W * 4)) / BAND {
                1 => 0,
                3 => 0x8000,
                _ if g.next_u32().is_multiple_of(3) => g.next_u32() as u16,
                _ => half::f16::from_f32(g.value(1.0)).to_bits(),
            })
            .collect();
        let f16_target = texture(
            &gpu,
            wgpu::TextureFormat::Rgba16Float,
            bytemuck::cast_slice(&halves),
        );
        let from_halves: Vec<f32> = halves
            .chunks_exact(4)
            .flat_map(|t| t[..3].iter().map(|&h| half::f16::from_bits(h).to_f32()))
            .collect();
        let values = hostile_values(7, 3, 1.0);
        let texels: Vec<f32> = values
            .chunks_exact(3)
            .flat_map(|c| [c[0], c[1], c[2], f32::NAN])
            .collect();
        let f32_target = texture(
            &gpu,
            wgpu::TextureFormat::Rgba32Float,
            bytemuck::cast_slice(&texels),
        );
        for format in MATERIAL {
            for (source, values) in [(&f16_target, &from_halves), (&f32_target, &values)] {
                if let Some(d) = compare(
                    &gpu,
                    &mut packer,
                    PackSource::Texture(source),
                    Layer::Diffuse,
                    format,
                    values,
                    1.0,
                ) {
                    panic!("{format:?} from {:?}: {d}", source.format());
                }
            }
        }
        // Depth from an R32Float target: negative, infinite and NaN depths included.
        let depth = hostile_values(8, 1, 1.0);
        let target = texture(
            &gpu,
            wgpu::TextureFormat::R32Float,
            bytemuck::cast_slice(&depth),
        );
        if let Some(d) = compare(
            &gpu,
            &mut packer,
            PackSource::Texture(&target),
            Layer::Depth,
            PixelFormat::DepthF32,
            &depth,
            1.0,
        ) {
            panic!("depth32: {d}");
        }

        // Negative control: the comparison sees a one-step difference. seed64 packed at a scale
        // one part in a million off is not the CPU's pack at the true scale.
        let values = hostile_values(1, 6, 1.0);
        let mut words = Vec::new();
        for p in values.chunks_exact(6) {
            words.extend_from_slice(&[p[0], p[1], p[2], 0.0, p[3], p[4], p[5], 0.0]);
        }
        let lit = gpu
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("control lit buffer"),
                contents: bytemuck::cast_slice(&words),
                usage: wgpu::BufferUsages::STORAGE,
            });
        let layout = layout(1.0);
        let cpu = cpu_bands(
            &layout,
            vec![(Layer::Illumination, PixelFormat::Seed64, image(6, values))],
        );
        let layers = [(Layer::Illumination, PixelFormat::Seed64)];
        let off = packer
            .pack(
                &gpu,
                &[PackLayer {
                    source: PackSource::Lit(&lit),
                    format: PixelFormat::Seed64,
                }],
                W,
                H,
                BAND,
                1.000_001,
            )
            .unwrap();
        let mut off_layout = layout;
        off_layout.scale = 1.000_001;
        let mut device = device_bands(&off_layout, &layers, &off);
        for b in &mut device {
            b.header.scale = 1.0;
            b.header.seal(&b.payload.clone());
        }
        assert!(
            difference(&cpu, &device).is_some(),
            "a pack at another scale went unnoticed"
        );
        // What the device cannot pack exactly it refuses: the node packs it on the CPU.
        assert!(!DevicePacker::supports(PixelFormat::Seed64, 1e-35));
        assert!(DevicePacker::supports(PixelFormat::Seed64, 1e-20));
        assert!(DevicePacker::supports(PixelFormat::Rgb9e5x2, 0.0));
        // A frame beyond the storage-binding limit is packed on the CPU, not failed.
        let limits = wgpu::Limits::default();
        let hd = [
            PixelFormat::F16x6,
            PixelFormat::F16x4,
            PixelFormat::DepthF32,
        ];
        assert!(DevicePacker::fits(&limits, &hd, 1920, 1080));
        assert!(!DevicePacker::fits(
            &limits,
            &[PixelFormat::Rgb9e5x2],
            8192,
            4096
        ));
    }

    /// A rendered frame packed on the device equals the same frame read back and packed on the
    /// CPU, for the deferred and the forward eye pass, every layer a node sends.
    #[test]
    fn rendered_frames_pack_bit_for_bit_as_on_the_cpu() {
        let gpu = gpu();
        let scene = lightfold_scene::builtin("balls").expect("built-in scene");
        let mut renderer =
            Renderer::new(&gpu, &scene, RenderOptions::from_quality(&scene.quality)).unwrap();
        let mut camera = scene.camera;
        camera.width = 83;
        camera.height = 61;
        renderer.set_camera(&camera);
        let all = lightfold_scene::sampling::direct_samples(&scene);
        let lights = &all[..all.len().min(4)];
        let configs: [&[(Layer, PixelFormat)]; 3] = [
            &[
                (Layer::Illumination, PixelFormat::Rgb9e5x2),
                (Layer::Depth, PixelFormat::DepthF32),
            ],
            &[(Layer::Illumination, PixelFormat::F16x6)],
            &[
                (Layer::Diffuse, PixelFormat::F16x4),
                (Layer::Specular, PixelFormat::Rgba8Srgb),
                (Layer::Ambient, PixelFormat::F16x4),
                (Layer::Emissive, PixelFormat::F16x4),
                (Layer::Depth, PixelFormat::DepthF32),
                (Layer::AmbientMask, PixelFormat::Rgba8Srgb),
            ],
        ];
        let layout = BandLayout {
            epoch: 1,
            frame: 2,
            width: camera.width,
            height: camera.height,
            band_height: 16,
            scale: 1.0,
        };
        for variant in [EyeVariant::Deferred, EyeVariant::Forward] {
            renderer.set_variant(variant);
            for layers in configs {
                let set = LayerSet::of(layers.iter().map(|(l, _)| *l));
                let mut frame = renderer
                    .render(&gpu, lights, None, [1.0; 3], set)
                    .expect("render");
                let images: LayerImages = layers
                    .iter()
                    .map(|&(l, f)| {
                        let img = lightfold_node::daemon::render_thread::take_layer(&mut frame, l)
                            .expect("layer rendered");
                        (l, f, Arc::new(img))
                    })
                    .collect();
                assert!(
                    images
                        .iter()
                        .any(|(_, _, i)| i.data.iter().any(|v| *v > 0.0)),
                    "the frame is lit"
                );
                let cpu = cpu_bands(&layout, images);
                let (packed, stats) = renderer
                    .render_packed(&gpu, lights, None, [1.0; 3], layers, 16, 1.0)
                    .expect("render and pack")
                    .expect("this device packs");
                let device = device_bands(&layout, layers, &packed);
                if let Some(d) = difference(&cpu, &device) {
                    panic!("{variant:?} {layers:?}: {d}");
                }
                let link: u64 = layers.iter().map(|(_, f)| f.bytes_per_pixel() as u64).sum();
                let pixels = u64::from(camera.width * camera.height);
                assert!(
                    stats.read_bytes < pixels * (link + 1),
                    "{} bytes read back for {link} link bytes a pixel",
                    stats.read_bytes
                );
            }
        }
    }
}
