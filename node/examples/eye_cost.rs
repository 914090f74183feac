//! Eye-pass cost on one device: the fixed part F and the per-light part e of t(K) = F + K·e for
//! the default scene in walkthrough mode (maps kept, camera orbiting half a degree per frame), as
//! `lightfold bench node` drives a node but without the daemon, so shader changes can be timed in
//! a minute. Set `LP_NUM_THREADS` as the bench does (1) before running.
//!
//! `cargo run --release -p lightfold-node --example eye_cost -- [--forward] [--rounds N]
//! [--frames N] [--sums] [K…]`

use lightfold_node::gpu::{EyeVariant, Gpu, GpuOptions, LayerSet, RenderOptions, Renderer};
use lightfold_protocol::stats;
use lightfold_scene::Camera;

fn orbit(c: &Camera, f: u32) -> Camera {
    c.orbited(-0.5 * f as f32)
}

/// CPU time of this process so far (all live threads, from `/proc/self/task/*/schedstat`), ms.
fn cpu_ms() -> f64 {
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return f64::NAN;
    };
    let mut ns = 0u64;
    for t in tasks.flatten() {
        if let Ok(s) = std::fs::read_to_string(t.path().join("schedstat")) {
            ns += s
                .split_whitespace()
                .next()
                .and_then(|v| v.parse::<u64>().ok())
                .unwrap_or(0);
        }
    }
    ns as f64 / 1e6
}

fn median(v: &[f64]) -> f64 {
    stats::median(v).expect("timed frames")
}

fn main() -> anyhow::Result<()> {
    let mut forward = false;
    let mut sums = false;
    let mut rounds = 3u32;
    let mut frames = 4u32;
    let mut ks: Vec<usize> = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--forward" => forward = true,
            // The last frame's illumination sum and lit pixels per K: a quick check that a
            // faster variant still renders the same image.
            "--sums" => sums = true,
            "--rounds" => rounds = args.next().unwrap_or_default().parse()?,
            "--frames" => frames = args.next().unwrap_or_default().parse()?,
            k => ks.push(k.parse()?),
        }
    }
    if ks.is_empty() {
        ks = vec![0, 1, 4, 8];
    }
    let scene = lightfold_scene::builtin("balls")?;
    let samples = lightfold_scene::sampling::direct_samples(&scene);
    let gpu = Gpu::new(&GpuOptions::default())?;
    let mut opts = RenderOptions::from_quality(&scene.quality);
    opts.walkthrough = true;
    let mut r = Renderer::new(&gpu, &scene, opts)?;
    if forward {
        r.set_variant(EyeVariant::Forward);
    }
    let pick = |k: usize| -> Vec<_> {
        (0..k)
            .map(|i| samples[(i * samples.len() / k) % samples.len()])
            .collect()
    };
    let mut eye: Vec<Vec<f64>> = vec![Vec::new(); ks.len()];
    let mut cpu: Vec<Vec<f64>> = vec![Vec::new(); ks.len()];
    let mut frame = 0;
    for _ in 0..rounds {
        for (slot, &k) in ks.iter().enumerate() {
            let lights = pick(k);
            // Two warm-up frames (maps, shader compilation), then the timed ones.
            for f in 0..2 + frames {
                frame += 1;
                r.set_camera(&orbit(&scene.camera, frame));
                let c0 = cpu_ms();
                let out = r.render(&gpu, &lights, None, [1.0; 3], LayerSet::illumination())?;
                let c1 = cpu_ms();
                if f == 1 + frames && sums {
                    let il = out.illumination.as_ref().expect("illumination");
                    let sum: f64 = il.data.iter().map(|&v| f64::from(v)).sum();
                    let lit = il
                        .data
                        .chunks(6)
                        .filter(|p| p.iter().any(|&v| v > 0.0))
                        .count();
                    eprintln!("K={k} sum {sum:.3} lit px {lit}");
                }
                if f >= 2 {
                    eye[slot].push(out.stats.eye_us as f64 / 1000.0);
                    cpu[slot].push(c1 - c0);
                }
            }
        }
    }
    println!(
        "K\teye fastest\teye median\tframe CPU fastest\tframe CPU median (ms, {} frames)",
        frames * rounds
    );
    let mut fastest = Vec::new();
    let mut fastest_cpu = Vec::new();
    for (slot, &k) in ks.iter().enumerate() {
        let min = |v: &[f64]| v.iter().copied().fold(f64::INFINITY, f64::min);
        let (m, c) = (min(&eye[slot]), min(&cpu[slot]));
        println!(
            "{k}\t{m:.1}\t{:.1}\t{c:.1}\t{:.1}",
            median(&eye[slot]),
            median(&cpu[slot])
        );
        fastest.push((k as f64, m));
        fastest_cpu.push((k as f64, c));
    }
    let (f, e) = fit(&fastest);
    println!("eye wall fit: F = {f:.1} ms, e = {e:.1} ms per light");
    let (f, e) = fit(&fastest_cpu);
    println!("frame CPU fit: F = {f:.1} ms, e = {e:.1} ms per light");
    Ok(())
}

/// Least-squares line t(K) = F + K·e through (K, t) points.
fn fit(points: &[(f64, f64)]) -> (f64, f64) {
    let fastest = points;
    let n = fastest.len() as f64;
    let (sx, sy) = fastest
        .iter()
        .fold((0.0, 0.0), |(a, b), (x, y)| (a + x, b + y));
    let (mx, my) = (sx / n, sy / n);
    let sxx: f64 = fastest.iter().map(|(x, _)| (x - mx) * (x - mx)).sum();
    let sxy: f64 = fastest.iter().map(|(x, y)| (x - mx) * (y - my)).sum();
    let e = sxy / sxx;
    (my - e * mx, e)
}
