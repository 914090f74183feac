//! `lightfold render`: one image of a scene to EXR (linear) and PNG (sRGB at the scene's
//! exposure), on the local GPU (shadow maps, K samples per pass), or with `--reference` on the CPU:
//! the exact sum over the scene's point samples, or with `--area-truth SPP` the true area lights.
//! `-K` is lights per node, as in every other command.

use anyhow::{Context, bail};
use lightfold_reference::output::{
    Outputs, ReferenceMode, png_next_to, retain_lights, select_lights,
};
use lightfold_reference::{AreaOptions, render_to_files};
use lightfold_scene::limits;
use lightfold_telemetry::outln;
use std::path::PathBuf;

#[path = "render_gpu.rs"]
mod gpu;

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Built-in scene name, `.toml` scene file or `.gltf`/`.glb`, `.obj`, `.ply` or USD
    /// (`.usda`, `.usdc`, `.usdz`) model.
    #[arg(long, default_value = lightfold_scene::defaults::DEFAULT_SCENE)]
    pub scene: String,
    /// Output EXR (linear radiance); the PNG is written next to it.
    #[arg(long, default_value = "render.exr")]
    pub out: PathBuf,
    /// Render with the CPU reference (ray-traced visibility) instead of the GPU.
    #[arg(long)]
    pub reference: bool,
    /// GPU: lights per node (the paper's K, as in every other command): the samples are rendered
    /// in batches of K, each what one node renders in a frame (one shadow-map set and one eye
    /// pass), and summed (default: the scene's K).
    #[arg(short = 'K', long = "lights-per-node", alias = "lights-per-pass")]
    pub k: Option<u32>,
    /// GPU: shadow-map resolution per view (default: the scene's).
    #[arg(long)]
    pub shadow_map_size: Option<u32>,
    /// GPU: backend, `vulkan` (OpenGL adapters are refused; `metal` or `dx12` where wgpu is built
    /// with them). Default: `LIGHTFOLD_BACKEND`, else Vulkan.
    #[arg(long)]
    pub backend: Option<String>,
    /// GPU: adapter whose name contains this.
    #[arg(long)]
    pub adapter: Option<String>,
    /// GPU: render the image this many times (the last is written), e.g. for `--timings`.
    #[arg(long, default_value_t = 1)]
    pub frames: u32,
    /// GPU: keep shadow maps between frames (lights and geometry are static).
    #[arg(long)]
    pub walkthrough: bool,
    /// GPU: print shadow passes and shadow / eye / readback time per frame, then the median cost
    /// of one node frame (a batch of K) over the frames after the first.
    #[arg(long)]
    pub timings: bool,
    /// GPU: light pixels in the forward eye pass instead of the deferred G-buffer + compute pass.
    #[arg(long)]
    pub forward: bool,
    /// Only these source lights (names or indices, comma-separated).
    #[arg(long, value_delimiter = ',')]
    pub lights: Vec<String>,
    /// Render the true area lights with this many points per light per pixel instead of the
    /// point samples.
    #[arg(long, value_name = "SPP")]
    pub area_truth: Option<u32>,
    /// Seed of the area-truth jitter.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Point samples per area light (overrides the scene; at most
    /// `lightfold_scene::limits::MAX_SAMPLES_PER_AREA_LIGHT`, see `lightfold defaults`).
    #[arg(long)]
    pub samples: Option<u32>,
    /// Image size as WIDTHxHEIGHT (default: the scene's; at most 8192 per side and 4096x4096
    /// pixels, see `lightfold defaults`).
    #[arg(long)]
    pub size: Option<String>,
    /// Also write the radiance without shadows (EXR), for `compare --unoccluded`.
    #[arg(long)]
    pub unoccluded_out: Option<PathBuf>,
    /// Also write eye depth (EXR, 0 = background), for `compare --depth`.
    #[arg(long)]
    pub depth_out: Option<PathBuf>,
    /// Antialiasing: N×N samples per pixel (the image is rendered at N·width × N·height, within
    /// the image limits of `lightfold defaults`) box-filtered into each pixel after the material
    /// stage; with `--reference`, N×N primary rays per pixel (the area-averaged truth). Depth
    /// takes each pixel's nearest covered sample.
    #[arg(long, value_name = "N", default_value_t = 1)]
    pub aa: u32,
    /// Scene time in seconds: an animated scene (glTF clip, scene-file motions) is posed at it
    /// (default: its rest pose).
    #[arg(long, value_parser = crate::coordinator_cmd::finite_seconds)]
    pub time: Option<f32>,
    /// Screen-space penumbra filter of this radius on the summed illumination before the
    /// material multiply (0: none; the GPU render only): what a cluster planned with
    /// `--penumbra-filter R` does at its last stage.
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..=8))]
    pub penumbra_filter: u32,
    /// Sort-last partitions on this one device (issue 24; the GPU render only): the meshes are
    /// split into P spatially coherent parts balanced by triangles (`scene::partition`), each
    /// part's eye pass is drawn alone (shadows still from every caster) and each pixel takes the
    /// part with the nearest surface. The image equals the unpartitioned one; `--timings` shows
    /// what the P eye passes cost.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=64))]
    pub partitions: u32,
    #[command(flatten)]
    pub indirect: crate::indirect_args::IndirectArgs,
}

pub(crate) fn run(args: Args) -> anyhow::Result<()> {
    // The PNG goes beside the EXR with the extension changed: an `--out` ending in .png would
    // have the PNG written over the EXR.
    if args
        .out
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("png"))
    {
        bail!(
            "--out names the EXR (linear radiance) and the PNG is written beside it: give \
             --out {} instead of {}",
            args.out.with_extension("exr").display(),
            args.out.display()
        );
    }
    if !args.reference && args.area_truth.is_some() {
        bail!("--area-truth renders true area lights on the CPU: add --reference");
    }
    if args.reference && args.penumbra_filter > 0 {
        bail!("--penumbra-filter filters a GPU render's point-sampled penumbra: drop --reference");
    }
    if args.partitions > 1 && (args.reference || args.penumbra_filter > 0) {
        bail!(
            "--partitions splits a GPU render's eye pass: drop --reference and --penumbra-filter \
             (the filter reads neighbours across the parts' seams)"
        );
    }
    let mut scene = lightfold_scene::load(&args.scene)
        .with_context(|| format!("cannot load scene {:?}", args.scene))?;
    if let Some(size) = &args.size {
        let (w, h) = limits::parse_image_size(size)
            .map_err(|e| anyhow::anyhow!("bad --size: {e} (see `lightfold defaults`)"))?;
        scene.camera.width = w;
        scene.camera.height = h;
    }
    if let Some(n) = args.samples {
        limits::check_samples_per_area_light("--samples", n)
            .map_err(|e| anyhow::anyhow!("{e} (see `lightfold defaults`)"))?;
        scene.quality.samples_per_area_light = Some(n.max(1));
    }
    if let Some(n) = args.shadow_map_size {
        scene.quality.shadow_map_size = n;
        scene.quality.map_sizing = lightfold_scene::MapSizing::Fixed;
    }
    // Indirect light is traced for one pose: with --time, that pose.
    let mut time = args.time;
    let wants_indirect = args.indirect.indirect.unwrap_or(scene.quality.indirect) > 0;
    if let (Some(t), true) = (time, wants_indirect && scene.animation.is_some()) {
        scene = scene.still_at(t);
        time = None;
    }
    args.indirect.apply(&mut scene)?;
    // The same limits as scene files and the network: samples, image and maps with the
    // overrides applied, before anything is allocated.
    scene
        .check_limits()
        .map_err(|e| anyhow::anyhow!("{}: {e} (see `lightfold defaults`)", args.scene))?;
    // From here on the scene's camera is the internal (supersampled) image; the outputs are
    // resolved back to the requested size after the material stage.
    scene.camera = scene
        .camera
        .supersampled(args.aa)
        .map_err(|e| anyhow::anyhow!("{e} (see `lightfold defaults`)"))?;
    let (mode, samples) = match args.area_truth {
        Some(spp) => {
            if let Some(t) = time {
                scene = scene.still_at(t);
            }
            if !args.lights.is_empty() {
                scene = retain_lights(&scene, &args.lights)?;
            }
            let opts = AreaOptions {
                samples_per_light: spp.max(1),
                seed: args.seed,
                shadows: true,
            };
            (ReferenceMode::AreaTruth(opts), Vec::new())
        }
        None => {
            let all = match time {
                Some(t) => {
                    let all = scene.samples_at(t);
                    scene = scene.still_at(t);
                    all
                }
                None => lightfold_scene::vpl::frame_samples(&scene),
            };
            let samples = if args.lights.is_empty() {
                all
            } else {
                select_lights(&scene, &all, &args.lights)?
            };
            (ReferenceMode::PointSum, samples)
        }
    };
    if !args.reference {
        return gpu::render(&args, &scene, &samples);
    }
    let outputs = Outputs {
        exr: args.out.clone(),
        png: Some(png_next_to(&args.out)),
        unoccluded: args.unoccluded_out.clone(),
        depth: args.depth_out.clone(),
        supersample: args.aa,
    };
    let report = render_to_files(&scene, &samples, mode, &outputs)?;
    tracing::info!(
        scene = %scene.name,
        width = scene.camera.width / args.aa,
        height = scene.camera.height / args.aa,
        aa = args.aa,
        samples = samples.len(),
        seconds = format_args!("{:.2}", report.seconds),
        mrays_per_s = format_args!("{:.2}", report.rays_per_second() / 1e6),
        "rendered on the CPU"
    );
    outln!(
        "wrote {} and {} ({:.2} s, ≤ {:.1} M rays, {:.2} M rays/s)",
        outputs.exr.display(),
        png_next_to(&args.out).display(),
        report.seconds,
        report.max_rays / 1e6,
        report.rays_per_second() / 1e6
    );
    Ok(())
}
