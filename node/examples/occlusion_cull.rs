//! What eye-pass occlusion culling saves (issue 48, `gpu::occlusion`, `docs/scaling.md`
//! § Occlusion culling): a built-in (the city by default) seen from its own camera (most of it
//! in view, little hidden) and from street level (most of it behind the first buildings), the
//! camera moving a little every frame (orbiting 0.5° a frame, or walking `--walk` metres a frame
//! along the street), walkthrough mode (maps kept). Three renderers take turns on every frame:
//! frustum culling alone, occlusion culling every frame (`Always`) and the default (`Auto`); the
//! median eye pass of `--frames` each, the vertices drawn and hidden, and the pixels whose depth
//! or illumination differ from frustum culling's (`OCCLUSION_DIFF=1` lists them). Set
//! `LP_NUM_THREADS` as the bench does.
//!
//! `cargo run --release -p lightfold-node --example occlusion_cull -- [city:N] [--frames N] [--size WxH] [--walk M]`

use lightfold_node::gpu::{EyeOcclusion, Gpu, GpuOptions, LayerSet, RenderOptions, Renderer};
use lightfold_protocol::stats;
use lightfold_scene::{Camera, sampling};

mod common;

fn main() -> anyhow::Result<()> {
    let args = common::parse("city:1m", (800, 600), 5, &["--walk"])?;
    let (name, frames, (w, h)) = (args.scene.clone(), args.frames, args.size);
    let walk: f32 = args.get("--walk", 0.5)?;
    let scene = args.builtin_scene()?;
    let gpu = Gpu::new(&GpuOptions::default())?;
    let samples: Vec<_> = sampling::direct_samples(&scene)
        .into_iter()
        .take(4)
        .collect();
    let street = common::street_camera(&scene.camera);
    println!(
        "{name}: {} triangles, {} meshes, {w}×{h}, {} lights, walkthrough (maps kept)",
        scene.triangle_count(),
        scene.meshes.len(),
        samples.len()
    );
    let modes = [
        ("frustum", EyeOcclusion::Off),
        ("occlusion", EyeOcclusion::Always),
        ("auto", EyeOcclusion::Auto),
    ];
    let own = scene.camera;
    let orbit = move |i: u32| own.orbited(0.5 * i as f32);
    let stroll = move |i: u32| {
        let mut c = street;
        c.position[0] += walk * i as f32;
        c.target[0] += walk * i as f32;
        c
    };
    let views: [(&str, &dyn Fn(u32) -> Camera); 2] =
        [("own camera", &orbit), ("street level", &stroll)];
    for (what, camera_at) in views {
        let mut renderers = Vec::new();
        for (_, mode) in modes {
            let opts = RenderOptions {
                walkthrough: true,
                ..RenderOptions::from_quality(&scene.quality)
            };
            let mut r = Renderer::new(&gpu, &scene, opts)?;
            r.set_eye_occlusion(mode);
            r.set_camera(&camera_at(0));
            // Maps drawn once, pipelines warm, occluders found.
            r.render(&gpu, &samples, None, [1.0; 3], LayerSet::all())?;
            renderers.push(r);
        }
        let mut ms = vec![Vec::new(); modes.len()];
        let mut drawn = vec![Vec::new(); modes.len()];
        let mut hidden = vec![Vec::new(); modes.len()];
        // Pixels whose depth or illumination differs from the frustum-culled frame's.
        let mut differ = vec![0usize; modes.len()];
        for i in 1..=frames {
            let camera = camera_at(i);
            let mut out: Vec<Option<lightfold_node::gpu::NodeFrame>> = Vec::new();
            out.resize_with(modes.len(), || None);
            // A different renderer goes first each frame.
            for k in 0..modes.len() {
                let m = (k + i as usize) % modes.len();
                let r = &mut renderers[m];
                r.set_camera(&camera);
                let f = r.render(&gpu, &samples, None, [1.0; 3], LayerSet::all())?;
                ms[m].push(f.stats.eye_us as f64 / 1e3);
                drawn[m].push(f64::from(r.eye_vertices()));
                hidden[m].push(f64::from(r.occluded_vertices()));
                out[m] = Some(f);
            }
            let base = out[0].as_ref().expect("rendered");
            for (m, f) in out.iter().enumerate().skip(1) {
                let f = f.as_ref().expect("rendered");
                let (Some(a), Some(b), Some(ia), Some(ib)) = (
                    base.depth.as_ref(),
                    f.depth.as_ref(),
                    base.illumination.as_ref(),
                    f.illumination.as_ref(),
                ) else {
                    anyhow::bail!("a frame without its depth or illumination");
                };
                let per = ia.channels;
                for p in 0..a.data.len() {
                    // Bit for bit (a NaN is the same NaN).
                    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    if a.data[p].to_bits() != b.data[p].to_bits()
                        || bits(&ia.data[p * per..][..per]) != bits(&ib.data[p * per..][..per])
                    {
                        differ[m] += 1;
                        if std::env::var_os("OCCLUSION_DIFF").is_some() {
                            eprintln!(
                                "frame {i}, {}: pixel ({}, {}) depth {} against {}",
                                modes[m].0,
                                p as u32 % a.width,
                                p as u32 / a.width,
                                b.data[p],
                                a.data[p]
                            );
                        }
                    }
                }
            }
        }
        let median = |v: &[f64]| stats::median(v).unwrap_or(f64::NAN);
        let base = median(&ms[0]);
        println!("{what}:");
        for (m, (label, _)) in modes.iter().enumerate() {
            println!(
                "  {label:>9}: eye pass {:8.1} ms ({:.2}×), vertices drawn {:>10.0}, hidden {:>10.0}, pixels differing {}",
                median(&ms[m]),
                median(&ms[m]) / base,
                median(&drawn[m]),
                median(&hidden[m]),
                differ[m],
            );
        }
    }
    Ok(())
}
