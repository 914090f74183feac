//! The shadow-map cases, GPU renderer against the CPU reference on the same samples: grazing light
//! (acne, case 1), thin walls (leaking, case 6) and a light 1 cm from an occluder (1/r², full
//! sphere coverage, case 4). Each control is the same render with one of the renderer's own
//! deliberate faults.

use super::support::{
    ABS_TOL, comparable, count_non_finite, disagreement, gpu, gpu_illumination, load_case_scene,
    pixel_sum, report, shadow_states,
};
use super::{CaseReport, HardCaseError};
use lightfold_node::gpu::{Fault, Gpu, RenderOptions};
use lightfold_reference::{Layers, render_point_sum};
use lightfold_scene::{Image, LightSample, Scene, sampling};

/// The node colour of every case: white, so the illumination is the plain sum.
const C_N: [f32; 3] = [1.0; 3];

/// One case's scene with its samples, reference, shadow states and edge mask.
struct Setup {
    scene: Scene,
    samples: Vec<LightSample>,
    reference: Layers,
    lit: Vec<u64>,
    visible: Vec<u64>,
    mask: Vec<bool>,
}

fn setup(
    case: &'static str,
    file: &str,
    full: bool,
    small: (u32, u32),
) -> Result<Setup, HardCaseError> {
    let scene = load_case_scene(case, file, full, small)?;
    let samples = sampling::direct_samples(&scene);
    let reference = render_point_sum(&scene, &samples, C_N);
    let st = shadow_states(&scene, &samples);
    let mask = comparable(&reference.depth, &reference.coverage, &st.visible);
    Ok(Setup {
        scene,
        samples,
        reference,
        lit: st.lit,
        visible: st.visible,
        mask,
    })
}

fn render(
    case: &'static str,
    gpu: &Gpu,
    s: &Setup,
    fault: Option<Fault>,
) -> Result<Image, HardCaseError> {
    let opts = RenderOptions {
        fault,
        ..RenderOptions::from_quality(&s.scene.quality)
    };
    gpu_illumination(case, gpu, &s.scene, &s.samples, C_N, opts)
}

/// Share of the compared pixels that every sample should light fully (lit = visible ≠ ∅) where
/// the GPU is more than 10 % darker than the reference.
fn acne_share(s: &Setup, img: &Image) -> (f64, usize) {
    let (mut n, mut dark) = (0usize, 0usize);
    for i in 0..s.mask.len() {
        if !s.mask[i] || s.lit[i] == 0 || s.lit[i] != s.visible[i] {
            continue;
        }
        n += 1;
        let (g, r) = (pixel_sum(img, i), pixel_sum(&s.reference.illumination, i));
        // NaN counts as darkened.
        dark += usize::from(g.is_nan() || g < 0.9 * r);
    }
    (dark as f64 / n.max(1) as f64, n)
}

/// Case 1: `scenes/hard/grazing.toml` — a small light 5° above a floor with thin fins. Metric:
/// the acne share. Control: bias 0.
pub(super) fn grazing(full: bool) -> Result<CaseReport, HardCaseError> {
    acne_case("grazing", "grazing.toml", full, GRAZING_BOUND)
}

/// Case 11: `scenes/hard/terminator.toml` — low-poly (8×6) smooth-shaded spheres under a light
/// 10° above the horizon: the smooth normal says lit where the facets shadow themselves. Same
/// metric and control as case 1.
pub(super) fn terminator(full: bool) -> Result<CaseReport, HardCaseError> {
    acne_case("terminator", "terminator.toml", full, TERMINATOR_BOUND)
}

fn acne_case(
    case: &'static str,
    file: &str,
    full: bool,
    bound: f64,
) -> Result<CaseReport, HardCaseError> {
    let gpu = gpu()?;
    let s = setup(case, file, full, (192, 144))?;
    let img = render(case, &gpu, &s, None)?;
    let bad = render(case, &gpu, &s, Some(Fault::NoBias))?;
    let (share, n) = acne_share(&s, &img);
    let (control, _) = acne_share(&s, &bad);
    let (dis, compared) = disagreement(&img, &s.reference.illumination, &s.mask);
    let mut r = report(
        case,
        "share of fully lit pixels > 10 % too dark (acne)",
        (share, bound),
        "depth and slope bias 0",
        control,
        count_non_finite(&img.data) + count_non_finite(&s.reference.illumination.data),
    );
    r.details = vec![
        format!("{n} fully lit pixels compared, {} samples", s.samples.len()),
        format!(
            "pixels outside 1e-3 of the reference: {:.3} % of {compared}",
            dis * 100.0
        ),
    ];
    // A case without fully lit pixels to judge proves nothing.
    if n < 100 {
        r.measured = f64::INFINITY;
    }
    Ok(r)
}

/// docs/hard-cases.md, case 11.
const TERMINATOR_BOUND: f64 = 0.01;

/// Case 2: `scenes/hard/contact.toml` — boxes resting on the floor. Metric: share of compared
/// floor pixels within 10 cm of a box's footprint that are outside 1e-3 of the reference (where
/// peter-panning shows). Control: a 0.5 m constant bias.
pub(super) fn contact(full: bool) -> Result<CaseReport, HardCaseError> {
    const CASE: &str = "contact";
    let gpu = gpu()?;
    let s = setup(CASE, "contact.toml", full, (192, 144))?;
    let boxes: Vec<([f32; 3], [f32; 3])> = s
        .scene
        .meshes
        .iter()
        .filter(|m| m.name.starts_with("box"))
        .filter_map(|m| m.bounds())
        .collect();
    let tracer = lightfold_reference::Tracer::new(&s.scene);
    let (w, h) = (s.scene.camera.width, s.scene.camera.height);
    let mut contact = vec![false; (w * h) as usize];
    for y in 0..h {
        for x in 0..w {
            let Some(hit) = tracer.primary(x, y) else {
                continue;
            };
            let p = hit.position;
            let near = boxes.iter().any(|(lo, hi)| {
                let d = |k: usize| {
                    (f64::from(lo[k]) - p[k])
                        .max(p[k] - f64::from(hi[k]))
                        .max(0.0)
                };
                d(0).max(d(2)) <= 0.1
            });
            contact[(y * w + x) as usize] =
                near && p[1].abs() < 1e-3 && s.mask[(y * w + x) as usize];
        }
    }
    let img = render(CASE, &gpu, &s, None)?;
    let bad = render(CASE, &gpu, &s, Some(Fault::HugeBias))?;
    let (err, n) = disagreement(&img, &s.reference.illumination, &contact);
    let (control, _) = disagreement(&bad, &s.reference.illumination, &contact);
    let (dis, compared) = disagreement(&img, &s.reference.illumination, &s.mask);
    let mut r = report(
        CASE,
        "share of contact-line floor pixels outside 1e-3 of the reference",
        (err, CONTACT_BOUND),
        "constant bias 0.5 m",
        control,
        count_non_finite(&img.data) + count_non_finite(&s.reference.illumination.data),
    );
    r.details = vec![
        format!("{n} contact pixels compared, {} samples", s.samples.len()),
        format!(
            "whole image: {:.3} % of {compared} outside 1e-3",
            dis * 100.0
        ),
    ];
    if n < 100 {
        r.measured = f64::INFINITY;
    }
    Ok(r)
}

/// docs/hard-cases.md, case 2.
const CONTACT_BOUND: f64 = 0.01;

/// docs/hard-cases.md, case 1.
const GRAZING_BOUND: f64 = 0.01;

/// Case 6: `scenes/hard/thin_wall.toml` — a 1 cm wall with the light behind it. Metric: share of
/// compared pixels whose truth is 0 that the GPU lights. Control: a 0.5 m constant bias.
pub(super) fn thin_wall(full: bool) -> Result<CaseReport, HardCaseError> {
    const CASE: &str = "thin-wall";
    let gpu = gpu()?;
    let s = setup(CASE, "thin_wall.toml", full, (192, 144))?;
    let img = render(CASE, &gpu, &s, None)?;
    let bad = render(CASE, &gpu, &s, Some(Fault::HugeBias))?;
    let dark: Vec<usize> = (0..s.mask.len())
        .filter(|&i| {
            s.mask[i] && s.reference.coverage[i] && pixel_sum(&s.reference.illumination, i) == 0.0
        })
        .collect();
    let leak = |img: &Image| {
        let n = dark
            .iter()
            .filter(|&&i| {
                let v = pixel_sum(img, i);
                v.is_nan() || v > ABS_TOL
            })
            .count();
        n as f64 / dark.len().max(1) as f64
    };
    let (dis, compared) = disagreement(&img, &s.reference.illumination, &s.mask);
    let mut r = report(
        CASE,
        "share of truly dark pixels the GPU lights (leaking)",
        (leak(&img), THIN_WALL_BOUND),
        "constant bias 0.5 m",
        leak(&bad),
        count_non_finite(&img.data) + count_non_finite(&s.reference.illumination.data),
    );
    r.details = vec![
        format!(
            "{} truly dark pixels compared, {} samples",
            dark.len(),
            s.samples.len()
        ),
        format!(
            "pixels outside 1e-3 of the reference: {:.3} % of {compared}",
            dis * 100.0
        ),
    ];
    // A case that shows no dark region proves nothing.
    if dark.len() < 100 {
        r.measured = f64::INFINITY;
    }
    Ok(r)
}

/// docs/hard-cases.md, case 6.
const THIN_WALL_BOUND: f64 = 0.001;

/// Case 4: `scenes/hard/near_light.toml` — a point light 1 cm above a block under a shelf, with
/// walls around, and a panel 1 cm in front of another block. Metric: share of compared pixels
/// outside 1e-3 of the reference; the 1/r² peak must be finite. Control: cube maps keep one face.
pub(super) fn near_light(full: bool) -> Result<CaseReport, HardCaseError> {
    const CASE: &str = "near-light";
    let gpu = gpu()?;
    let s = setup(CASE, "near_light.toml", full, (192, 144))?;
    let img = render(CASE, &gpu, &s, None)?;
    let bad = render(CASE, &gpu, &s, Some(Fault::MissingFace))?;
    let (dis, compared) = disagreement(&img, &s.reference.illumination, &s.mask);
    let (control, _) = disagreement(&bad, &s.reference.illumination, &s.mask);
    let peak = |img: &Image| img.data.iter().copied().fold(0f32, f32::max);
    let mut r = report(
        CASE,
        "share of compared pixels outside 1e-3 of the reference",
        (dis, NEAR_LIGHT_BOUND),
        "cube maps keep only the face along the axis",
        control,
        count_non_finite(&img.data)
            + count_non_finite(&bad.data)
            + count_non_finite(&s.reference.illumination.data),
    );
    r.details = vec![
        format!("{compared} pixels compared, {} samples", s.samples.len()),
        format!(
            "peak illumination: GPU {:.4e}, reference {:.4e}",
            peak(&img),
            peak(&s.reference.illumination)
        ),
    ];
    Ok(r)
}

/// docs/hard-cases.md, case 4.
const NEAR_LIGHT_BOUND: f64 = 0.01;
