//! Hard case 19 (issue 46): glossy highlights of an area light. A row of silver metallic-roughness
//! spheres, roughness 0.1 to 0.5, under one rectangular light at the default 16 samples. Point
//! samples cannot integrate a lobe narrower than their spacing: each sample leaves its own
//! highlight, a grid of dots at several times the true peak. Judged on the spheres' light-facing
//! pixels (away from silhouettes and the terminator) against a truth computed here, independently
//! of both the renderer and `scene::ltc`: per pixel, the GGX lobe importance-sampled (1 024
//! stratified half-vectors, 4 096 at full size), each reflected ray intersected with the
//! rectangle, `∫ f·cos·L dω` estimated with the weight `4·V·(n·l)·|v·h|/(n·h)·F` (unoccluded: no
//! sphere hides the light from another's lit side). The metric is the worst sphere's RMS error
//! over its truth's peak; the control renders the same samples' own point highlights
//! (`AreaSpecular::Sampled`).

use super::support::{count_non_finite, gpu, report};
use super::{CaseReport, HardCaseError};
use lightfold_scene::primitives::{plane, sphere};
use lightfold_scene::sampling::{direct_samples, grid_shape};
use lightfold_scene::shading::{
    V3, add, cross, dot, ggx_alpha, normalize, scale, schlick_weight, smith_visibility, sub,
    surface_point,
};
use lightfold_scene::trace::Tracer;
use lightfold_scene::{
    AreaSpecular, Camera, Image, Light, LightShape, Material, MetallicRoughness, Scene,
};
use std::f32::consts::TAU;

const CASE: &str = "glossy-area";
/// Worst sphere's RMS error over its truth's peak (bound from measurement, docs/hard-cases.md).
const BOUND: f64 = 0.03;
const ROUGHNESS: [f32; 5] = [0.1, 0.15, 0.2, 0.3, 0.5];
const RADIUS: f32 = 0.4;
const SILVER: [f32; 3] = [0.97, 0.96, 0.91];
/// The light: a 1.6 × 0.8 m panel 2.6 m above and 2 m in front of the row, facing it.
const LIGHT_CENTER: V3 = [0.0, 2.6, 2.0];
const LIGHT_SIZE: [f32; 2] = [1.6, 0.8];
const RADIANCE: f32 = 4.0;

/// A row of glossy spheres under one panel: the case's own ([`Setup::case`]) or another, for
/// sweeps of roughness, light size and samples (`examples/glossy_sweep.rs`).
#[derive(Debug, Clone)]
pub struct Setup {
    /// One sphere per roughness, left to right (at most five fit the frame).
    pub roughness: Vec<f32>,
    /// The panel's centre (it faces the row's middle sphere) and size (metres).
    pub light_center: V3,
    pub light_size: [f32; 2],
    /// Samples of the panel.
    pub samples: u32,
    /// Metallic-roughness highlights in closed form (the default) or each sample's own.
    pub area_specular: AreaSpecular,
}

impl Setup {
    /// Hard case 19's scene.
    pub fn case() -> Setup {
        Setup {
            roughness: ROUGHNESS.to_vec(),
            light_center: LIGHT_CENTER,
            light_size: LIGHT_SIZE,
            samples: lightfold_scene::defaults::SAMPLES_PER_AREA_LIGHT,
            area_specular: AreaSpecular::default(),
        }
    }

    /// The panel's frame: centre, unit normal, unit u and v axes.
    fn panel(&self) -> (V3, V3, V3, V3) {
        let n = normalize(sub([0.0, RADIUS, 0.0], self.light_center));
        let u = [1.0, 0.0, 0.0];
        (self.light_center, n, u, cross(n, u))
    }

    /// The centre of sphere `i`.
    pub fn sphere_center(&self, i: usize) -> V3 {
        [sphere_x(i), RADIUS, 0.0]
    }
}

fn sphere_x(i: usize) -> f32 {
    (i as f32 - 2.0) * 1.1
}

/// The case's scene: ground, five spheres (materials 1..=5), the panel, 16 samples.
pub fn scene(full_size: bool) -> Scene {
    setup_scene(&Setup::case(), full_size)
}

/// A setup's scene: ground, one sphere per roughness (materials 1..), the panel.
pub fn setup_scene(setup: &Setup, full_size: bool) -> Scene {
    let mut s = Scene::new("hard-glossy-area");
    let ground = s.add_material(Material::diffuse("ground", [0.5, 0.5, 0.5]));
    s.add_mesh(plane(
        "ground",
        [0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [20.0, 20.0],
        1,
        ground,
    ));
    for (i, r) in setup.roughness.iter().enumerate() {
        let m = s.add_material(Material::metallic_roughness(
            &format!("silver r{r}"),
            MetallicRoughness::new(SILVER, 1.0, *r),
        ));
        s.add_mesh(sphere(
            &format!("sphere r{r}"),
            setup.sphere_center(i),
            RADIUS,
            128,
            64,
            m,
        ));
    }
    let (center, normal, u_axis, _) = setup.panel();
    s.lights.push(Light {
        name: "panel".into(),
        shape: LightShape::Rect {
            center,
            normal,
            u_axis,
            size: setup.light_size,
        },
        color: [1.0; 3],
        power: RADIANCE,
        range: None,
        samples: setup.samples,
    });
    s.quality.area_specular = setup.area_specular;
    let (width, height) = if full_size { (800, 300) } else { (320, 120) };
    s.camera = Camera {
        position: [0.0, 1.3, 4.2],
        target: [0.0, RADIUS, 0.0],
        up: [0.0, 1.0, 0.0],
        fov_y_deg: 36.0,
        width,
        height,
    };
    s
}

/// Reflected radiance of the panel at a surface point: the GGX lobe sampled by half-vectors
/// (`D(h)·(n·h)`), each reflected ray meeting the panel's emitting side adding
/// `4·V·(n·l)·|v·h|/(n·h)·F·L`.
fn truth_at(setup: &Setup, p: V3, n: V3, v: V3, alpha: f32, f0: V3, samples: u32) -> V3 {
    let (c, ln, lu, lv) = setup.panel();
    let (t1, t2) = lightfold_scene::sampling::basis(n);
    let (nx, ny) = grid_shape(samples);
    let nv = dot(n, v).max(0.0);
    let mut sum = [0.0f64; 3];
    for j in 0..ny {
        for i in 0..nx {
            let a = (i as f32 + 0.5) / nx as f32;
            let b = (j as f32 + 0.5) / ny as f32;
            let tan2 = alpha * alpha * a / (1.0 - a);
            let cos_h = 1.0 / (1.0 + tan2).sqrt();
            let sin_h = (1.0 - cos_h * cos_h).max(0.0).sqrt();
            let phi = TAU * b;
            let h = add(
                scale(n, cos_h),
                add(scale(t1, sin_h * phi.cos()), scale(t2, sin_h * phi.sin())),
            );
            let vh = dot(v, h);
            let l = sub(scale(h, 2.0 * vh), v);
            let nl = dot(n, l);
            let facing = -dot(l, ln);
            if nl <= 0.0 || vh <= 0.0 || facing <= 0.0 {
                continue;
            }
            let t = dot(sub(c, p), ln) / dot(l, ln);
            let q = sub(add(p, scale(l, t)), c);
            if t <= 0.0
                || dot(q, lu).abs() > 0.5 * setup.light_size[0]
                || dot(q, lv).abs() > 0.5 * setup.light_size[1]
            {
                continue;
            }
            let weight = 4.0 * smith_visibility(nl, nv, alpha) * nl * vh / cos_h;
            let w = schlick_weight(vh);
            for k in 0..3 {
                sum[k] += f64::from(weight * (f0[k] + (1.0 - f0[k]) * w) * RADIANCE);
            }
        }
    }
    sum.map(|s| (s / f64::from(nx * ny)) as f32)
}

/// Per sphere: the judged pixels' truth (RGB) and indices.
#[derive(Debug)]
pub struct Truth {
    per_sphere: Vec<Vec<(usize, V3)>>,
}

impl Truth {
    /// Judged pixels per sphere.
    pub fn pixels(&self) -> Vec<usize> {
        self.per_sphere.iter().map(Vec::len).collect()
    }
}

/// The truth of `setup`'s scene (`scene`), `samples` half-vectors a pixel.
pub fn truth(setup: &Setup, scene: &Scene, samples: u32) -> Truth {
    let tracer = Tracer::new(scene);
    let cam = &scene.camera;
    let (w, h) = (cam.width, cam.height);
    let mut material = vec![usize::MAX; (w * h) as usize];
    let mut hits = Vec::with_capacity(material.len());
    for y in 0..h {
        for x in 0..w {
            let hit = tracer.primary(x, y);
            if let Some(hit) = &hit {
                material[(y * w + x) as usize] = hit.material;
            }
            hits.push(hit);
        }
    }
    let (c, ..) = setup.panel();
    let spheres = setup.roughness.len();
    let mut per_sphere = vec![Vec::new(); spheres];
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let i = (y * w + x) as usize;
            let m = material[i];
            if m == 0 || m > spheres {
                continue;
            }
            // Away from silhouettes: the 3×3 neighbourhood is the same sphere.
            let whole = (-1i32..=1).all(|dy| {
                (-1i32..=1).all(|dx| {
                    let j = ((y as i32 + dy) as u32 * w + (x as i32 + dx) as u32) as usize;
                    material[j] == m
                })
            });
            let Some(hit) = hits[i].as_ref().filter(|_| whole) else {
                continue;
            };
            let p = hit.position_f32();
            // Away from the terminator, where shadow maps and the cosine's edge disagree.
            if dot(hit.geometric_normal, normalize(sub(c, p))) < 0.3 {
                continue;
            }
            let mat = &scene.materials[m];
            let pbr = mat.pbr.as_ref().expect("metallic-roughness sphere");
            let point = lightfold_scene::shading::metallic_roughness_point(pbr, [1.0; 4], [1.0; 4]);
            let ms = surface_point(mat, &scene.textures, hit.uv).specular;
            let rgb = truth_at(
                setup,
                p,
                hit.normal,
                hit.to_viewer,
                ggx_alpha(pbr.roughness),
                point.f0,
                samples,
            );
            per_sphere[m - 1].push((i, [0, 1, 2].map(|k| rgb[k] * ms[k])));
        }
    }
    Truth { per_sphere }
}

/// Per sphere: RMS error over the truth's peak, and the image's peak over the truth's.
pub fn errors(t: &Truth, img: &Image) -> Vec<(f64, f64)> {
    t.per_sphere
        .iter()
        .map(|px| {
            let (mut se, mut n, mut peak, mut top) = (0.0f64, 0usize, 0f32, 0f32);
            for (i, rgb) in px {
                for (&want, &got) in rgb.iter().zip(&img.data[i * 3..i * 3 + 3]) {
                    let d = f64::from(got - want);
                    se += d * d;
                    n += 1;
                    peak = peak.max(want);
                    top = top.max(got);
                }
            }
            let rms = (se / n.max(1) as f64).sqrt();
            let rel = if n == 0 || peak <= 0.0 {
                f64::INFINITY
            } else {
                rms / f64::from(peak)
            };
            (rel, f64::from(top) / f64::from(peak).max(1e-30))
        })
        .collect()
}

/// The render and its GPU seconds (after a warm-up frame).
pub fn render(
    gpu: &lightfold_node::gpu::Gpu,
    scene: &Scene,
) -> Result<(Image, f64), HardCaseError> {
    let samples = direct_samples(scene);
    crate::gpu_radiance(gpu, scene, &samples).map_err(|e| HardCaseError::Render {
        case: CASE,
        message: format!("{e:#}"),
    })
}

pub fn glossy_area(full_size: bool) -> Result<CaseReport, HardCaseError> {
    let gpu = gpu()?;
    let setup = Setup::case();
    let scene = setup_scene(&setup, full_size);
    let t = truth(&setup, &scene, if full_size { 4096 } else { 1024 });
    let (img, seconds) = render(&gpu, &scene)?;
    let mut sampled = scene.clone();
    sampled.quality.area_specular = AreaSpecular::Sampled;
    let (control, control_seconds) = render(&gpu, &sampled)?;
    let worst = |e: &[(f64, f64)]| e.iter().map(|x| x.0).fold(0f64, f64::max);
    let (e, c) = (errors(&t, &img), errors(&t, &control));
    let mut r = report(
        CASE,
        "worst sphere's RMS error over its truth's peak",
        (worst(&e), BOUND),
        "each sample's own point highlight (AreaSpecular::Sampled)",
        worst(&c),
        count_non_finite(&img.data),
    );
    r.details = ROUGHNESS
        .iter()
        .zip(e.iter().zip(&c))
        .zip(&t.per_sphere)
        .map(|((rough, (e, c)), px)| {
            format!(
                "roughness {rough:.2}: {} px, closed form {:.4} (peak {:.2}× the truth's), \
                 sampled {:.4} (peak {:.2}×)",
                px.len(),
                e.0,
                e.1,
                c.0,
                c.1
            )
        })
        .collect();
    r.details.push(format!(
        "GPU time of the frame: closed form {:.1} ms, sampled {:.1} ms (one run each; a \
         figure, not a bound)",
        seconds * 1e3,
        control_seconds * 1e3
    ));
    if t.per_sphere.iter().any(|p| p.len() < 50) {
        r.measured = f64::INFINITY;
    }
    // For looking at the case: LIGHTFOLD_HARD_DUMP=DIR writes both renders and the truth.
    if let Some(dir) = std::env::var_os("LIGHTFOLD_HARD_DUMP") {
        let dir = std::path::PathBuf::from(dir);
        let mut truth_img = Image::new(img.width, img.height, 3);
        for (i, rgb) in t.per_sphere.iter().flatten() {
            truth_img.data[i * 3..i * 3 + 3].copy_from_slice(rgb);
        }
        for (im, what) in [(&img, "gpu"), (&control, "sampled"), (&truth_img, "truth")] {
            let path = dir.join(format!("{CASE}-{what}.png"));
            if let Err(e) = im.write_png(&path, 1.0) {
                tracing::warn!(path = %path.display(), "{e}");
            }
        }
    }
    Ok(r)
}
