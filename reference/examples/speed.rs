//! Measures the CPU reference's speed: the exact point sum over the scene's samples and (with
//! `--area SPP`) the area-light truth. Without `--scene` it uses a synthetic 50k-triangle scene
//! at 800×600 with 2 area lights × 16 samples.
//!
//! `cargo run --release -p lightfold-reference --example speed -- [--scene balls] [--area 64]`

use lightfold_scene::primitives::{plane, sphere};
use lightfold_scene::sampling::direct_samples;
use lightfold_scene::{Camera, Light, LightShape, Material, Quality, Scene};
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let value = |flag: &str| {
        args.iter()
            .position(|a| a == flag)
            .and_then(|i| args.get(i + 1))
    };
    let scene = match value("--scene") {
        Some(name) => match lightfold_scene::load(name) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("cannot load {name}: {e}");
                std::process::exit(2);
            }
        },
        None => synthetic_scene(),
    };
    let tris: usize = scene.meshes.iter().map(|m| m.triangle_count()).sum();
    let samples = direct_samples(&scene);
    let t = Instant::now();
    let tracer = lightfold_reference::Tracer::new(&scene);
    let build = t.elapsed();
    drop(tracer);
    let t = Instant::now();
    let img = lightfold_reference::radiance_point_sum(&scene, &samples);
    let secs = t.elapsed().as_secs_f64();
    let pixels = img.pixel_count() as f64;
    // Upper bound: one eye ray per pixel and one shadow ray per sample (back-facing samples skip
    // theirs).
    let rays = pixels * (1.0 + samples.len() as f64);
    println!(
        "{tris} triangles, BVH build {:.1} ms, {} lights, {}x{}: {secs:.2} s, {:.2} Mrays/s (≤ {:.1} M rays), {} threads",
        build.as_secs_f64() * 1e3,
        samples.len(),
        img.width,
        img.height,
        rays / secs / 1e6,
        rays / 1e6,
        rayon::current_num_threads()
    );
    if let Some(spp) = value("--area").and_then(|s| s.parse::<u32>().ok()) {
        let t = Instant::now();
        let opts = lightfold_reference::AreaOptions {
            samples_per_light: spp,
            ..Default::default()
        };
        let _ = lightfold_reference::render_area(&scene, &opts);
        let secs = t.elapsed().as_secs_f64();
        let area = scene.lights.iter().filter(|l| l.is_area()).count();
        let exact = scene.lights.len() - area;
        let rays = pixels * (1.0 + (spp as usize * area + exact) as f64);
        println!(
            "area truth at {spp} samples/light/pixel: {secs:.2} s, {:.2} Mrays/s (≤ {:.1} M rays)",
            rays / secs / 1e6,
            rays / 1e6
        );
    }
}

/// A ground plane, 12 spheres of 4k triangles and two 16-sample rectangle lights (~50k triangles).
fn synthetic_scene() -> Scene {
    let mut meshes = vec![plane(
        "ground",
        [0.0; 3],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [12.0, 12.0],
        16,
        0,
    )];
    for i in 0..12 {
        let a = i as f32 * std::f32::consts::TAU / 12.0;
        let r = 0.35 + 0.05 * (i % 3) as f32;
        meshes.push(sphere(
            "ball",
            [2.0 * a.cos(), r + 0.1 * (i % 2) as f32, 2.0 * a.sin()],
            r,
            64,
            32,
            1,
        ));
    }
    let rect = |name: &str, center: [f32; 3], normal: [f32; 3]| Light {
        name: name.into(),
        shape: LightShape::Rect {
            center,
            normal,
            u_axis: [1.0, 0.0, 0.0],
            size: [1.0, 1.0],
        },
        color: [1.0; 3],
        power: 8.0,
        range: None,
        samples: 16,
    };
    Scene {
        name: "speed".into(),
        meshes,
        materials: vec![
            Material::diffuse("ground", [0.8; 3]),
            Material::diffuse("balls", [0.7, 0.3, 0.2]),
        ],
        textures: Vec::new(),
        lights: vec![
            rect("key", [1.0, 4.0, 1.0], [0.0, -1.0, 0.0]),
            rect("fill", [-2.0, 3.0, -1.0], [0.4, -1.0, 0.2]),
        ],
        camera: Camera {
            position: [0.0, 4.0, 6.0],
            target: [0.0, 0.3, 0.0],
            up: [0.0, 1.0, 0.0],
            fov_y_deg: 45.0,
            width: 800,
            height: 600,
        },
        ambient: [0.0; 3],
        exposure: 1.0,
        quality: Quality::default(),
        animation: None,
    }
}
