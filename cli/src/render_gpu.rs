//! `lightfold render` on one local GPU: the scene's samples in batches of K (one shadow-map set and
//! one eye pass per batch), illumination summed over batches with `c_n` = white, material layers
//! from the first batch, then paper eq. 2 into linear radiance (EXR) and sRGB at the scene's
//! exposure (PNG). With `--aa N` the scene's camera is already N·W × N·H and the radiance is
//! box-resolved after that combine. `--timings` prints the per-phase cost of every frame.

use super::Args;
use anyhow::Context;
use lightfold_node::gpu::device::parse_backend;
use lightfold_node::gpu::{EyeVariant, Gpu, GpuOptions, RenderOptions, Renderer};
use lightfold_quality::single::{FrameTimes, Parts, Repeated, render_frame, render_repeated};
use lightfold_reference::output::png_next_to;
use lightfold_scene::{Image, LightSample, Scene};
use lightfold_telemetry::outln;

/// Renders `args.frames` frames of the scene's samples on one local GPU (as sort-last parts
/// with `--partitions`), printing each frame's costs with `--timings`, then writes the last
/// frame's radiance and the images asked for besides.
pub(super) fn render(args: &Args, scene: &Scene, samples: &[LightSample]) -> anyhow::Result<()> {
    // With partitions, meshes too large for a part in chunks, as the cluster splits them.
    let chunked = (args.partitions > 1)
        .then(|| lightfold_scene::partition::chunk_for_parts(scene, args.partitions as usize))
        .flatten();
    let scene = chunked.as_ref().unwrap_or(scene);
    let (gpu, mut renderer, k) = open_renderer(args, scene, samples)?;
    let frames = args.frames.max(1);
    let parts = (args.partitions > 1).then(|| Parts::new(scene, samples, args.partitions as usize));
    if let (Some(parts), true) = (&parts, args.timings) {
        for (i, p) in parts.parts.iter().enumerate() {
            let tris: usize = p
                .iter()
                .map(|&m| scene.meshes[m as usize].triangle_count())
                .sum();
            outln!("partition {i}: {} meshes, {tris} triangles", p.len());
        }
    }
    let each = |f: u32, times: &FrameTimes| {
        if args.timings {
            outln!(
                "{f:>5}  {:>13}  {:>9.1}  {:>6.1}  {:>11.1}  {:>8.1}",
                times.shadow_passes,
                times.shadow_us as f64 / 1e3,
                times.eye_us as f64 / 1e3,
                times.readback_us as f64 / 1e3,
                times.total_us as f64 / 1e3
            );
        }
    };
    let run = render_repeated(
        &gpu,
        &mut renderer,
        scene,
        samples,
        k,
        frames,
        parts.as_ref(),
        args.penumbra_filter,
        each,
    )?;
    if args.timings {
        print_steady(k, frames, &run);
    }
    let png = write_images(args, scene, run.image)?;
    if let Some(path) = &args.unoccluded_out {
        let none = vec![Vec::new(); samples.len()];
        let ((open, _), _) = render_frame(&gpu, &mut renderer, scene, samples, k, Some(&none), 0)?;
        open.box_resolve(args.aa)?.write_exr(path)?;
    }
    outln!(
        "wrote {} and {} on {} ({} samples, K = {k}{})",
        args.out.display(),
        png.display(),
        gpu.info.name,
        samples.len(),
        match &parts {
            Some(p) => format!(
                ", {} sort-last parts of {} mesh(es), depth-composed",
                p.parts.len(),
                p.parts.iter().map(Vec::len).sum::<usize>()
            ),
            None => String::new(),
        }
    );
    Ok(())
}

/// Opens the GPU the flags ask for and a renderer for the scene at the shadow map size the
/// cluster's planner would choose, returning them with K (the lights per batch, as many as
/// the device allows at most). With `--timings`, prints what will be rendered and the heading
/// of the per-frame table.
fn open_renderer(
    args: &Args,
    scene: &Scene,
    samples: &[LightSample],
) -> anyhow::Result<(Gpu, Renderer, usize)> {
    let backend = args
        .backend
        .as_deref()
        .map(parse_backend)
        .transpose()
        .context("bad --backend")?;
    let gpu = Gpu::new(&GpuOptions {
        backend,
        adapter_name: args.adapter.clone(),
    })
    .context(
        "no usable GPU (install a Vulkan driver: mesa-vulkan-drivers gives lavapipe on the CPU; \
         or render with --reference on the CPU)",
    )?;
    // `--shadow-map-size` is in the scene's quality already (checked against the limits); the
    // size comes from the rule the cluster's planner applies, so both render the same maps.
    let mut opts = RenderOptions::from_quality(&scene.quality);
    if let Some(n) = lightfold_coordinator::plan::MapSizing::Scene.uniform_size(&scene.quality) {
        opts.shadow_map_size = n;
    }
    opts.walkthrough = args.walkthrough;
    let k = args
        .k
        .unwrap_or(scene.quality.lights_per_node)
        .clamp(1, gpu.max_lights(opts.shadow_map_size).max(1)) as usize;
    let mut renderer = Renderer::new(&gpu, scene, opts)?;
    if args.forward {
        renderer.set_variant(EyeVariant::Forward);
    }
    if args.timings {
        outln!(
            "adapter {} ({:?}), {:?} eye pass, {}x{} (--aa {}), {} samples, K = {k}, {} maps, \
             {} batch(es)",
            gpu.info.name,
            gpu.info.backend,
            renderer.frame_variant(&gpu, scene.camera.width, scene.camera.height),
            scene.camera.width,
            scene.camera.height,
            args.aa,
            samples.len(),
            match opts.map_sizing {
                lightfold_scene::MapSizing::Fixed => format!("{}²", opts.shadow_map_size),
                lightfold_scene::MapSizing::Mismatch(m) =>
                    format!("mismatch-sized (m = {}, {}²–{}²)", m.target, m.min, m.max),
            },
            samples.len().div_ceil(k).max(1)
        );
        outln!("frame  shadow_passes  shadow_ms  eye_ms  readback_ms  total_ms");
    }
    Ok((gpu, renderer, k))
}

/// Prints the shadow views per light of the first frame and, when any batch counts, the
/// median cost of a node frame of K lights over the steady batches of `steady_frames` frames.
fn print_steady(k: usize, frames: u32, run: &Repeated) {
    let p = &run.views_per_light;
    let sum: u32 = p.iter().sum();
    outln!(
        "shadow views per light: min {}, mean {:.2}, max {} ({sum} in all)",
        p.iter().min().unwrap_or(&0),
        sum as f64 / p.len().max(1) as f64,
        p.iter().max().unwrap_or(&0)
    );
    if run.steady.is_empty() {
        return;
    }
    let [s, e, r] = run.steady_medians();
    let which = match frames {
        1 => "the only frame".to_string(),
        2 => "frame 1".to_string(),
        n => format!("each of frames 1–{}", n - 1),
    };
    let warm = if frames == 1 {
        ""
    } else {
        "frame 0 warms up; "
    };
    outln!(
        "node frame (K = {k}, illumination only): median of {} batches, {} in {which} \
         ({warm}each frame's first batch, which also renders the materials, is left out): \
         shadow {:.1} ms, eye {:.1} ms, readback {:.1} ms, total {:.1} ms",
        run.steady.len(),
        run.steady.len() / run.steady_frames.max(1),
        s as f64 / 1e3,
        e as f64 / 1e3,
        r as f64 / 1e3,
        (s + e + r) as f64 / 1e3
    );
}

/// Writes the frame's radiance, resolved to the requested size, as EXR at `--out` and as PNG
/// next to it (returning the PNG's path), and its eye depth with `--depth-out`.
fn write_images(
    args: &Args,
    scene: &Scene,
    (radiance, depth): (Image, Image),
) -> anyhow::Result<std::path::PathBuf> {
    // `--aa N`: the frame is N·W × N·H; resolve the final radiance (after the material
    // combine) and the depth to the requested size. N = 1 leaves both as rendered.
    let radiance = radiance.box_resolve(args.aa)?;
    let depth = depth.nearest_depth_resolve(args.aa)?;
    radiance.write_exr(&args.out)?;
    let png = png_next_to(&args.out);
    radiance.write_png(&png, scene.exposure)?;
    if let Some(path) = &args.depth_out {
        let mut rgb = Image::new(depth.width, depth.height, 3);
        for (o, &z) in rgb.data.chunks_exact_mut(3).zip(&depth.data) {
            o.fill(z);
        }
        rgb.write_exr(path)?;
    }
    Ok(png)
}
