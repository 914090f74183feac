//! Case 10, degenerate geometry, built in code because a scene file holds only whole primitives:
//! zero-area triangles, duplicate vertices, NaN and zero normals, and lights with zero area or zero
//! power beside a normal one. The raw scene goes to the GPU renderer and to the reference as is
//! (nothing sanitised first): neither may produce a NaN or Inf, and they must agree where shadow
//! maps and ray tracing can agree.

use super::support::{
    comparable, count_non_finite, disagreement, gpu, gpu_illumination, report, shadow_states,
};
use super::{CaseReport, HardCaseError};
use lightfold_node::gpu::RenderOptions;
use lightfold_reference::render_point_sum;
use lightfold_scene::primitives::{cuboid, plane};
use lightfold_scene::shading::length;
use lightfold_scene::{Camera, Light, LightShape, Material, Mesh, Scene, sampling};

const C_N: [f32; 3] = [1.0; 3];

/// A 1 m quad of four triangles at `x`, with the degenerate cases listed in the module docs.
fn junk_mesh(material: usize) -> Mesh {
    let nan = f32::NAN;
    Mesh {
        name: "junk".into(),
        positions: vec![
            [0.2, 0.0, -0.5],
            [1.2, 0.0, -0.5],
            [1.2, 1.0, -0.5],
            [0.2, 1.0, -0.5],
            // Collinear: a zero-area triangle.
            [0.2, 0.5, -0.5],
            [0.7, 0.5, -0.5],
            [1.2, 0.5, -0.5],
            // A duplicate of vertex 2.
            [1.2, 1.0, -0.5],
        ],
        normals: vec![
            [0.0, 0.0, 1.0],
            [nan, nan, nan],
            [0.0, 0.0, 0.0],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, 1.0],
            [nan, 0.0, 1.0],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, 0.0],
        ],
        uvs: Vec::new(),
        tangents: Vec::new(),
        indices: vec![0, 1, 2, 0, 2, 3, 4, 5, 6, 1, 7, 2, 3, 3, 3],
        material,
    }
}

pub(super) fn scene(width: u32, height: u32) -> Scene {
    let mut s = Scene::new("hard-degenerate");
    let grey = s.add_material(Material::diffuse("grey", [0.7, 0.7, 0.7]));
    let red = s.add_material(Material::diffuse("red", [0.8, 0.3, 0.2]));
    let (x, y) = ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
    s.add_mesh(plane("floor", [0.0; 3], y, x, [6.0, 6.0], 2, grey));
    s.add_mesh(junk_mesh(red));
    s.add_mesh(cuboid("box", [-0.8, 0.3, 0.0], [0.3, 0.3, 0.3], red));
    let rect = |name: &str, size: [f32; 2], power: f32| Light {
        name: name.into(),
        shape: LightShape::Rect {
            center: [0.0, 2.5, 1.0],
            normal: [0.0, -1.0, 0.0],
            u_axis: x,
            size,
        },
        color: [1.0; 3],
        power,
        range: None,
        samples: 4,
    };
    s.lights = vec![
        rect("panel", [0.6, 0.6], 40.0),
        rect("zero area", [0.0, 0.0], 40.0),
        rect("zero power", [0.6, 0.6], 0.0),
        Light {
            name: "zero sphere".into(),
            shape: LightShape::Sphere {
                center: [1.5, 1.5, 1.0],
                radius: 0.0,
            },
            color: [1.0; 3],
            power: 10.0,
            range: None,
            samples: 2,
        },
    ];
    s.camera = Camera {
        position: [0.0, 2.0, 4.0],
        target: [0.0, 0.4, 0.0],
        up: y,
        fov_y_deg: 50.0,
        width,
        height,
    };
    s
}

/// Metric: share of compared pixels outside 1e-3 of the reference; any non-finite value in a
/// sample, the GPU image or the reference fails. Control: how many of the scene's normals a naive
/// `n / |n|` turns non-finite — it must be > 0, or the scene does not exercise what it claims.
pub(super) fn degenerate(full: bool) -> Result<CaseReport, HardCaseError> {
    const CASE: &str = "degenerate";
    let (w, h) = if full { (512, 384) } else { (160, 120) };
    let scene = scene(w, h);
    let samples = sampling::direct_samples(&scene);
    let sample_bad = samples
        .iter()
        .filter(|s| {
            !(s.intensity.is_finite()
                && s.position.iter().chain(&s.direction).all(|v| v.is_finite()))
        })
        .count();
    let reference = render_point_sum(&scene, &samples, C_N);
    let st = shadow_states(&scene, &samples);
    let mask = comparable(&reference.depth, &reference.coverage, &st.visible);
    let gpu = gpu()?;
    let opts = RenderOptions::from_quality(&scene.quality);
    let img = gpu_illumination(CASE, &gpu, &scene, &samples, C_N, opts)?;
    let (dis, compared) = disagreement(&img, &reference.illumination, &mask);
    let naive = scene
        .meshes
        .iter()
        .flat_map(|m| &m.normals)
        .filter(|n| {
            let l = length(**n);
            !n.iter().all(|c| (c / l).is_finite())
        })
        .count();
    let mut r = report(
        CASE,
        "share of compared pixels outside 1e-3 of the reference (degenerate scene)",
        (dis, DEGENERATE_BOUND),
        "normals a naive n/|n| turns non-finite",
        naive as f64,
        sample_bad + count_non_finite(&img.data) + count_non_finite(&reference.illumination.data),
    );
    r.details = vec![
        format!(
            "{compared} pixels compared, {} samples ({sample_bad} non-finite)",
            samples.len()
        ),
        format!("validation: {}", scene.validate()),
    ];
    Ok(r)
}

/// docs/hard-cases.md, case 10.
const DEGENERATE_BOUND: f64 = 0.01;
