//! Device setup in one place: pick a backend (flag, `LIGHTFOLD_BACKEND`, else Vulkan, with GL only
//! found to be refused with what to install),
//! pick an adapter (optionally by name), check the features and limits the renderer needs, and
//! open the device with typed errors. Everything else takes `&Device`/`&Queue` so tests can inject
//! their own.

use std::fmt;

/// Environment variable naming the backend (`vulkan`; `gl` is refused at device open) when no
/// flag is given.
pub const BACKEND_ENV: &str = "LIGHTFOLD_BACKEND";

/// Bytes of one shadow-map texel: Depth32Float and its R32Uint object ID.
pub const SHADOW_TEXEL_BYTES: u64 = 8;
/// Most shadow views one light can need: the six faces of a cube map.
pub const MAX_VIEWS_PER_LIGHT: u32 = 6;
/// Device memory we allow shadow maps to take (lavapipe allocates them in host memory).
pub const SHADOW_MEMORY_BUDGET: u64 = 1 << 30;

/// How to choose the device.
#[derive(Debug, Clone, Default)]
pub struct GpuOptions {
    /// Backends to consider; `None` reads [`BACKEND_ENV`], else Vulkan (then GL, whose adapter
    /// [`Gpu::new`] refuses with what to install).
    pub backend: Option<wgpu::Backends>,
    /// Case-insensitive substring of the adapter name (e.g. `llvmpipe`).
    pub adapter_name: Option<String>,
}

/// An open device and what it can do.
#[derive(Debug)]
pub struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub info: wgpu::AdapterInfo,
    pub limits: wgpu::Limits,
    pub features: wgpu::Features,
    /// Whether `Rgba32Float` is a render target here (GL cannot). The renderer does not need it:
    /// it writes f32 bits into integer targets.
    pub float32_targets: bool,
}

#[derive(Debug, thiserror::Error)]
pub enum DeviceError {
    #[error("no graphics adapter found for backends {backends}{}", name_hint(.adapter_name))]
    NoAdapter {
        backends: String,
        adapter_name: Option<String>,
    },
    #[error(
        "unknown backend {value:?} (expected vulkan; metal or dx12 where built; gl is refused at device open)"
    )]
    UnknownBackend { value: String },
    #[error("adapter {adapter} lacks required feature {feature}")]
    MissingFeature {
        adapter: String,
        feature: &'static str,
    },
    #[error("adapter limit {limit} is {maximum}, renderer needs {requested}")]
    LimitTooLow {
        limit: &'static str,
        requested: u64,
        maximum: u64,
    },
    #[error(
        "adapter {adapter} is OpenGL, which cannot run lightfold's shadow lookups (WGSL \
         `textureLoad` on depth textures has no GLSL form): use Vulkan — install the GPU's \
         Vulkan driver, or mesa-vulkan-drivers for lavapipe on the CPU"
    )]
    GlUnsupported { adapter: String },
    #[error("device request failed: {0}")]
    RequestDevice(String),
}

fn name_hint(name: &Option<String>) -> String {
    match name {
        Some(n) => format!(" matching adapter name {n:?}"),
        None => String::new(),
    }
}

/// Features the renderer cannot work without, with their names for error messages.
/// Depth clamping lets casters in front of a shadow frustum's near plane (which is fitted to the
/// receivers) still land in the map instead of being clipped away.
const REQUIRED_FEATURES: &[(wgpu::Features, &str)] =
    &[(wgpu::Features::DEPTH_CLIP_CONTROL, "DEPTH_CLIP_CONTROL")];

/// Limits below which the renderer cannot run at all: (name, needed, adapter value).
fn required_limits(l: &wgpu::Limits) -> [(&'static str, u64, u64); 6] {
    [
        // One chunk of the deferred light pass's views.
        (
            "max_uniform_buffer_binding_size",
            (lightfold_shaders::CHUNK_VIEWS * std::mem::size_of::<super::lights::GpuView>()) as u64,
            l.max_uniform_buffer_binding_size,
        ),
        // The scene group's six and the forward pass's lights and views.
        (
            "max_storage_buffers_per_shader_stage",
            8,
            l.max_storage_buffers_per_shader_stage as u64,
        ),
        ("max_color_attachments", 2, l.max_color_attachments as u64),
        (
            "max_texture_array_layers",
            2,
            l.max_texture_array_layers as u64,
        ),
        (
            "max_texture_dimension_2d",
            1024,
            l.max_texture_dimension_2d as u64,
        ),
        (
            "max_inter_stage_shader_variables",
            8,
            l.max_inter_stage_shader_variables as u64,
        ),
    ]
}

/// Parses a backend name as accepted by `--backend` and [`BACKEND_ENV`].
pub fn parse_backend(value: &str) -> Result<wgpu::Backends, DeviceError> {
    match value.trim().to_ascii_lowercase().as_str() {
        "vulkan" | "vk" => Ok(wgpu::Backends::VULKAN),
        "gl" | "gles" | "opengl" => Ok(wgpu::Backends::GL),
        "metal" => Ok(wgpu::Backends::METAL),
        "dx12" => Ok(wgpu::Backends::DX12),
        _ => Err(DeviceError::UnknownBackend {
            value: value.to_string(),
        }),
    }
}

fn backend_rank(b: wgpu::Backend) -> u32 {
    // GL misreads some texture arrays (docs/platform.md): every native API comes first.
    match b {
        wgpu::Backend::Vulkan | wgpu::Backend::Metal | wgpu::Backend::Dx12 => 0,
        wgpu::Backend::Gl => 1,
        _ => 2,
    }
}

fn device_rank(t: wgpu::DeviceType) -> u32 {
    match t {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Cpu => 3,
        wgpu::DeviceType::Other => 4,
    }
}

/// The adapter [`Gpu::new`] opens for `opts`: Vulkan before GL, then by device type.
fn choose_adapter(opts: &GpuOptions) -> Result<wgpu::Adapter, DeviceError> {
    let backends = match opts.backend {
        Some(b) => b,
        None => match std::env::var(BACKEND_ENV) {
            Ok(v) if !v.trim().is_empty() => parse_backend(&v)?,
            _ => wgpu::Backends::VULKAN | wgpu::Backends::GL,
        },
    };
    let named = |a: &wgpu::Adapter| {
        opts.adapter_name.as_ref().is_none_or(|name| {
            let needle = name.to_ascii_lowercase();
            a.get_info().name.to_ascii_lowercase().contains(&needle)
        })
    };
    let enumerate = |backends: wgpu::Backends| {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
        desc.backends = backends;
        // Debian's validation layers flag every SPIR-V module with a false "source language"
        // error when DEBUG is on (docs/platform.md); keep validation, drop the debug labels.
        desc.flags =
            (wgpu::InstanceFlags::from_build_config() - wgpu::InstanceFlags::DEBUG).with_env();
        let instance = wgpu::Instance::new(desc);
        let mut adapters = pollster::block_on(instance.enumerate_adapters(backends));
        adapters.retain(named);
        adapters
    };
    // Vulkan first, GL only where Vulkan has no (matching) adapter: probing GL on a machine
    // without a display driver logs EGL errors on every start although Vulkan serves.
    let mut adapters =
        if backends.contains(wgpu::Backends::VULKAN) && backends != wgpu::Backends::VULKAN {
            let vulkan = enumerate(wgpu::Backends::VULKAN);
            if vulkan.is_empty() {
                enumerate(backends - wgpu::Backends::VULKAN)
            } else {
                vulkan
            }
        } else {
            enumerate(backends)
        };
    adapters.sort_by_key(|a| {
        let i = a.get_info();
        (backend_rank(i.backend), device_rank(i.device_type))
    });
    adapters
        .into_iter()
        .next()
        .ok_or_else(|| DeviceError::NoAdapter {
            backends: format!("{backends:?}"),
            adapter_name: opts.adapter_name.clone(),
        })
}

/// Whether the adapter renders in software (lavapipe, llvmpipe, `DeviceType::Cpu`).
pub fn is_software(info: &wgpu::AdapterInfo) -> bool {
    lightfold_telemetry::is_software_rasteriser(
        &info.name,
        info.device_type == wgpu::DeviceType::Cpu,
    )
}

/// A hardware adapter's identity on this host, what its node reports as `Capabilities::device`:
/// the host, the PCI bus where the driver gives it (two identical cards differ there) or else
/// vendor and device ids, and the name. `None` for a software rasteriser, whose "device" is the
/// CPU cores.
pub fn device_identity(host: &str, info: &wgpu::AdapterInfo) -> Option<String> {
    if is_software(info) {
        return None;
    }
    let place = if info.device_pci_bus_id.is_empty() {
        format!("{:04x}:{:04x}", info.vendor, info.device)
    } else {
        info.device_pci_bus_id.clone()
    };
    Some(format!("{host}/{place}/{}", info.name))
}

/// The adapter [`Gpu::new`] would open for `opts`, without opening it: its name, backend and
/// whether it is a software rasteriser (what `--require-gpu` refuses before a node binds).
pub fn chosen_adapter(opts: &GpuOptions) -> Result<(String, String, bool), DeviceError> {
    let info = choose_adapter(opts)?.get_info();
    let software = is_software(&info);
    Ok((
        info.name,
        format!("{:?}", info.backend).to_lowercase(),
        software,
    ))
}

/// What a local node would render on, known without opening the device.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LocalDevice {
    /// A hardware GPU: its identity on this host (`Capabilities::device`) and the lights it
    /// takes at the reported map size.
    Gpu { identity: String, max_lights: u32 },
    /// A software rasteriser: this machine's CPU.
    Cpu,
}

/// What [`Gpu::new`] would open for `opts` on this host, without opening it (what a local
/// cluster's nodes will report); `None` when there is no adapter.
pub fn chosen_device(opts: &GpuOptions, host: &str) -> Option<LocalDevice> {
    let adapter = choose_adapter(opts).ok()?;
    Some(match device_identity(host, &adapter.get_info()) {
        Some(identity) => LocalDevice::Gpu {
            identity,
            max_lights: max_lights_for(
                &adapter.limits(),
                lightfold_scene::defaults::SHADOW_MAP_SIZE,
            ),
        },
        None => LocalDevice::Cpu,
    })
}

impl Gpu {
    /// Opens the best matching adapter with every limit it offers.
    pub fn new(opts: &GpuOptions) -> Result<Gpu, DeviceError> {
        let adapter = choose_adapter(opts)?;
        let info = adapter.get_info();
        // Refused here with what to install, rather than as a pipeline the GL driver cannot
        // compile (wgpu's handler for that panics).
        if info.backend == wgpu::Backend::Gl {
            return Err(DeviceError::GlUnsupported {
                adapter: info.name.clone(),
            });
        }
        let features = adapter.features();
        for (f, name) in REQUIRED_FEATURES {
            if !features.contains(*f) {
                return Err(DeviceError::MissingFeature {
                    adapter: info.name.clone(),
                    feature: name,
                });
            }
        }
        let limits = adapter.limits();
        for (limit, requested, maximum) in required_limits(&limits) {
            if maximum < requested {
                return Err(DeviceError::LimitTooLow {
                    limit,
                    requested,
                    maximum,
                });
            }
        }
        let required: wgpu::Features = REQUIRED_FEATURES
            .iter()
            .fold(wgpu::Features::empty(), |a, (f, _)| a | *f);
        let float32_targets = adapter
            .get_texture_format_features(wgpu::TextureFormat::Rgba32Float)
            .allowed_usages
            .contains(wgpu::TextureUsages::RENDER_ATTACHMENT);
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("lightfold node"),
            required_features: required,
            required_limits: limits.clone(),
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|e| DeviceError::RequestDevice(e.to_string()))?;
        tracing::info!(adapter = %info.name, backend = ?info.backend, float32_targets, "gpu device open");
        Ok(Gpu {
            device,
            queue,
            info,
            limits,
            features: required,
            float32_targets,
        })
    }

    /// Most lights one render can take with `shadow_map_size`² maps, assuming every light needs
    /// six views (the worst case): bounded by texture-array layers and the shadow memory budget.
    pub fn max_lights(&self, shadow_map_size: u32) -> u32 {
        max_lights_for(&self.limits, shadow_map_size)
    }

    /// Runs `make`, which creates device objects, and turns what the device refuses — memory it
    /// cannot allocate, a size beyond its limits — into an error naming `what` (wgpu's handler
    /// for errors nobody captures panics).
    pub fn allocate<T>(
        &self,
        what: &'static str,
        make: impl FnOnce(&wgpu::Device) -> T,
    ) -> Result<T, super::frame::RenderError> {
        let (made, error) = captured(&self.device, || make(&self.device));
        match error {
            Some(e) => Err(super::frame::RenderError::Allocation {
                what,
                message: e.to_string(),
            }),
            None => Ok(made),
        }
    }

    /// True on the GL backend, whose texture arrays need padding (docs/platform.md).
    pub fn is_gl(&self) -> bool {
        self.info.backend == wgpu::Backend::Gl
    }
}

/// Runs `make` with every kind of device error captured — validation, out of memory, and
/// internal ones (a shader the backend cannot translate is one): wgpu's handler for errors
/// nobody captures panics. Returns what `make` made and the first error, if any.
pub fn captured<T>(device: &wgpu::Device, make: impl FnOnce() -> T) -> (T, Option<wgpu::Error>) {
    let internal = device.push_error_scope(wgpu::ErrorFilter::Internal);
    let oom = device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
    let validation = device.push_error_scope(wgpu::ErrorFilter::Validation);
    let made = make();
    // Scopes pop in the reverse order of their pushes.
    let invalid = pollster::block_on(validation.pop());
    let out_of_memory = pollster::block_on(oom.pop());
    let broken = pollster::block_on(internal.pop());
    (made, invalid.or(out_of_memory).or(broken))
}

/// [`Gpu::max_lights`] for given limits (pure, so the planner can reason about other devices).
pub fn max_lights_for(limits: &wgpu::Limits, shadow_map_size: u32) -> u32 {
    if shadow_map_size == 0 || shadow_map_size > limits.max_texture_dimension_2d {
        return 0;
    }
    // One layer is kept spare for GL's layer-count padding.
    let by_layers = limits.max_texture_array_layers.saturating_sub(1) / MAX_VIEWS_PER_LIGHT;
    let layer_bytes = shadow_map_size as u64 * shadow_map_size as u64 * SHADOW_TEXEL_BYTES;
    let by_memory = SHADOW_MEMORY_BUDGET / (layer_bytes * MAX_VIEWS_PER_LIGHT as u64);
    by_layers.min(by_memory.min(u32::MAX as u64) as u32)
}

impl fmt::Display for GpuOptions {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "backend={:?} adapter={:?}",
            self.backend, self.adapter_name
        )
    }
}
