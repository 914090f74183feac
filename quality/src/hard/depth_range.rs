//! Case 3, a huge depth range: one shadow frustum from ~1 cm to ~1330 m (far/near at the
//! renderer's limit of 1e5) over five self-similar bands 5, 20, 80, 300 and 1300 m from the lamp.
//! Each band is seen by its own camera through the same maps, so a band's figures differ from
//! another's only by what distance does to the map (depth precision, texel size, constant bias).
//! Per band: false shadows (truly fully lit pixels the GPU darkens by more than 10 %) and lost
//! contact shadows (truly fully shadowed tile pixels next to a box's base that the GPU lights to
//! more than 10 % of their unshadowed value).

use super::support::{
    ReferenceView, count_non_finite, gpu, gpu_illumination_views, load_case_scene, pixel_sum,
    report,
};
use super::{CaseReport, HardCaseError};
use lightfold_node::gpu::{Fault, RenderOptions};
use lightfold_reference::Tracer;
use lightfold_scene::shadow_views::{mesh_receivers, shadow_views};
use lightfold_scene::{Camera, Image, LightSample, Mesh, Scene, sampling};

const CASE: &str = "depth-range";

/// A band of the scene: its tile's centre and the boxes resting on it, found by name.
struct Band {
    distance: f32,
    center: [f32; 3],
    /// Unit horizontal direction away from the lamp, and the one across it.
    along: [f32; 3],
    across: [f32; 3],
    boxes: Vec<Footprint>,
}

/// A box's footprint in the band's frame: centre offsets and half extents along `across`/`along`.
struct Footprint {
    center: [f32; 2],
    half: [f32; 2],
}

fn bands(scene: &Scene) -> Vec<Band> {
    let mut out = Vec::new();
    for tile in scene.meshes.iter().filter(|m| m.name.starts_with("tile ")) {
        let Some(distance) = tile
            .name
            .trim_start_matches("tile ")
            .trim_end_matches(" m")
            .parse::<f32>()
            .ok()
        else {
            continue;
        };
        let Some((lo, hi)) = tile.bounds() else {
            continue;
        };
        let center = [0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k]));
        let h = (center[0] * center[0] + center[2] * center[2]).sqrt();
        let along = [center[0] / h, 0.0, center[2] / h];
        let across = [along[2], 0.0, -along[0]];
        let suffix = format!(" {}", &tile.name["tile ".len()..]);
        let boxes = scene
            .meshes
            .iter()
            .filter(|m| !m.name.starts_with("tile ") && m.name.ends_with(&suffix))
            .map(|m| footprint(m, center, across, along))
            .collect();
        out.push(Band {
            distance,
            center,
            along,
            across,
            boxes,
        });
    }
    out
}

fn footprint(m: &Mesh, c: [f32; 3], across: [f32; 3], along: [f32; 3]) -> Footprint {
    let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
    for p in &m.positions {
        let d = [p[0] - c[0], p[2] - c[2]];
        let q = [
            d[0] * across[0] + d[1] * across[2],
            d[0] * along[0] + d[1] * along[2],
        ];
        for k in 0..2 {
            lo[k] = lo[k].min(q[k]);
            hi[k] = hi[k].max(q[k]);
        }
    }
    Footprint {
        center: [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])],
        half: [0.5 * (hi[0] - lo[0]), 0.5 * (hi[1] - lo[1])],
    }
}

/// The band's camera: behind the boxes (seen from the side away from the lamp, where their
/// shadows fall), 0.1·d up, scaled with the band so every band fills the image alike.
fn band_camera(b: &Band, width: u32, height: u32) -> Camera {
    let d = b.distance;
    let at = |s_along: f32, up: f32| {
        [
            b.center[0] + d * s_along * b.along[0],
            b.center[1] + d * up,
            b.center[2] + d * s_along * b.along[2],
        ]
    };
    Camera {
        position: at(0.17, 0.10),
        target: at(0.03, 0.0),
        up: [0.0, 1.0, 0.0],
        fov_y_deg: 50.0,
        width,
        height,
    }
}

/// Per-band judged pixels: fully lit ones, and fully shadowed tile pixels within `CONTACT` of a
/// box's footprint; both only where every sample keeps the pixel's state when the point moves
/// `MARGIN` texels along the tile either way (shadow-map texels here are ~10 full-size pixels,
/// so the texel staircase of every shadow outline would otherwise dominate both figures, the
/// same at every distance; what is left is what depth precision and bias do).
struct Judged {
    lit: Vec<usize>,
    contact: Vec<usize>,
}

/// Contact zone, as a fraction of the band's distance (a quarter of the cube's side).
const CONTACT: f32 = 0.01;
/// Robustness margin in shadow-map texels.
const MARGIN: f32 = 2.0;

fn judged(band: &Band, view: &ReferenceView, samples: &[LightSample], texel: f32) -> Judged {
    let tracer = Tracer::new(&view.scene);
    let (w, h) = (view.scene.camera.width, view.scene.camera.height);
    let d = band.distance;
    let mut j = Judged {
        lit: Vec::new(),
        contact: Vec::new(),
    };
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            if !view.mask[i] {
                continue;
            }
            let Some(hit) = tracer.primary(x, y) else {
                continue;
            };
            let p = hit.position_f32();
            let rel = [p[0] - band.center[0], p[2] - band.center[2]];
            let q = [
                rel[0] * band.across[0] + rel[1] * band.across[2],
                rel[0] * band.along[0] + rel[1] * band.along[2],
            ];
            // Only this band's tile and boxes.
            if q[0].abs() > 0.1 * d || q[1].abs() > 0.1 * d {
                continue;
            }
            let on_tile = (p[1] - band.center[1]).abs() < 1e-4 * d;
            let lit = view.fully_lit(i);
            let near_box = band.boxes.iter().any(|f| {
                let e = [0, 1].map(|k| ((q[k] - f.center[k]).abs() - f.half[k]).max(0.0));
                (e[0] * e[0] + e[1] * e[1]).sqrt() <= CONTACT * d
            });
            let contact = on_tile && near_box && view.fully_shadowed(i);
            if !(lit || contact) || !robust(&tracer, &hit, band, samples, texel) {
                continue;
            }
            if lit {
                j.lit.push(i);
            } else {
                j.contact.push(i);
            }
        }
    }
    j
}

/// Whether every sample's visibility at `hit` is the same `MARGIN` texels away along the band's
/// two horizontal axes, either way. A texel at distance r spans `texel·r` across the light's
/// view, and twice that along a tile lit at 30°; box faces are judged with the same offsets.
fn robust(
    tracer: &Tracer<'_>,
    hit: &lightfold_reference::SurfaceHit,
    band: &Band,
    samples: &[LightSample],
    texel: f32,
) -> bool {
    let p = hit.position_f32();
    let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    let delta = f64::from(MARGIN * texel * r * 2.0);
    let state = |h: &lightfold_reference::SurfaceHit| -> u64 {
        samples
            .iter()
            .enumerate()
            .filter(|(_, s)| tracer.visible(h, s))
            .fold(0, |m, (k, _)| m | 1 << k)
    };
    let here = state(hit);
    [band.along, band.across].iter().all(|axis| {
        [-1.0, 1.0].iter().all(|sign| {
            let mut moved = *hit;
            for (c, a) in moved.position.iter_mut().zip(axis) {
                *c += sign * delta * f64::from(*a);
            }
            state(&moved) == here
        })
    })
}

/// `(false-shadow share, lost-contact share)` of one band's GPU image.
fn shares(view: &ReferenceView, j: &Judged, img: &Image) -> (f64, f64) {
    let darkened = j
        .lit
        .iter()
        .filter(|&&i| {
            let g = pixel_sum(img, i);
            g.is_nan() || g < 0.9 * pixel_sum(&view.shadowed.illumination, i)
        })
        .count();
    let lost = j
        .contact
        .iter()
        .filter(|&&i| {
            let g = pixel_sum(img, i);
            g.is_nan() || g > 0.1 * pixel_sum(&view.unshadowed, i)
        })
        .count();
    (
        darkened as f64 / j.lit.len().max(1) as f64,
        lost as f64 / j.contact.len().max(1) as f64,
    )
}

/// Case 3: `scenes/hard/depth_range.toml`. Metric: the worst band's worse share (false shadows
/// or lost contact shadows). Controls: bias 0 must break the bound with false shadows and a
/// 0.5 m constant bias with lost contact shadows; 16-bit and conventional-Z maps (the depth
/// precision the case is about) must each make the farthest band worse than the nearest by more
/// than the bound. The control value is the smallest of those four.
pub(super) fn depth_range(full: bool) -> Result<CaseReport, HardCaseError> {
    let gpu = gpu()?;
    let scene = load_case_scene(CASE, "depth_range.toml", full, (160, 120))?;
    let samples = sampling::direct_samples(&scene);
    let bands = bands(&scene);
    let (w, h) = (scene.camera.width, scene.camera.height);
    let cameras: Vec<Camera> = bands.iter().map(|b| band_camera(b, w, h)).collect();
    let views: Vec<ReferenceView> = cameras
        .iter()
        .map(|c| ReferenceView::new(&scene, *c, &samples))
        .collect();
    let texel = texel_tangent(&scene);
    let judged: Vec<Judged> = bands
        .iter()
        .zip(&views)
        .map(|(b, v)| judged(b, v, &samples, texel))
        .collect();
    let base = RenderOptions::from_quality(&scene.quality);
    let render = |fault| {
        gpu_illumination_views(
            CASE,
            &gpu,
            &scene,
            &samples,
            RenderOptions { fault, ..base },
            &cameras,
        )
    };
    let imgs = render(None)?;
    let per_band = |imgs: &[Image]| -> Vec<(f64, f64)> {
        views
            .iter()
            .zip(&judged)
            .zip(imgs)
            .map(|((v, j), img)| shares(v, j, img))
            .collect()
    };
    // (worst band's false shadows, worst band's lost contact); NaN stays NaN.
    let worst = |per: &[(f64, f64)]| {
        per.iter()
            .fold((0.0, 0.0), |(a, b), &(f, l)| (nan_max(a, f), nan_max(b, l)))
    };
    let no_bias = worst(&per_band(&render(Some(Fault::NoBias))?));
    let huge_bias = worst(&per_band(&render(Some(Fault::HugeBias))?));
    let (nearest, farthest) = extreme_bands(&bands);
    let mut depth_controls = Vec::new();
    for (fault, label) in DEPTH_CONTROLS {
        let per = per_band(&render(Some(fault))?);
        depth_controls.push((label, growth(&per, nearest, farthest), per));
    }
    let non_finite = imgs
        .iter()
        .map(|i| count_non_finite(&i.data))
        .sum::<usize>()
        + views
            .iter()
            .map(|v| count_non_finite(&v.shadowed.illumination.data))
            .sum::<usize>();
    let (f, l) = worst(&per_band(&imgs));
    let mut measured = nan_max(f, l);
    let mut details = vec![format!(
        "{} samples; texel {:.2} mrad; shadow frustum far/near {}",
        samples.len(),
        texel * 1e3,
        depth_ratios(&scene)
    )];
    for ((b, j), (v, img)) in bands.iter().zip(&judged).zip(views.iter().zip(&imgs)) {
        let (f, l) = shares(v, j, img);
        details.push(format!(
            "{:>6} m: false shadows {:.3} % of {} lit px, lost contact {:.3} % of {} contact px",
            b.distance,
            f * 100.0,
            j.lit.len(),
            l * 100.0,
            j.contact.len()
        ));
        // A band with too little to judge proves nothing.
        if j.lit.len() < 200 || j.contact.len() < 20 {
            measured = f64::INFINITY;
        }
    }
    details.push(format!(
        "controls, worst band: bias 0 false shadows {:.3} % (lost contact {:.3} %); 0.5 m bias lost contact {:.3} % (false shadows {:.3} %)",
        no_bias.0 * 100.0,
        no_bias.1 * 100.0,
        huge_bias.1 * 100.0,
        huge_bias.0 * 100.0
    ));
    for (label, growth, per) in &depth_controls {
        let list = |k: usize| {
            per.iter()
                .map(|p| format!("{:.3}", 100.0 * if k == 0 { p.0 } else { p.1 }))
                .collect::<Vec<_>>()
                .join(" / ")
        };
        details.push(format!(
            "control {label}, per band: false shadows {} %, lost contact {} %; farthest band minus nearest {:.3} %",
            list(0),
            list(1),
            growth * 100.0
        ));
    }
    if bands.len() != 5 {
        measured = f64::INFINITY;
    }
    let control_value = depth_controls
        .iter()
        .fold(no_bias.0.min(huge_bias.1), |m, (_, g, _)| m.min(*g));
    let mut r = report(
        CASE,
        "worst band's share of false shadows or lost contact shadows",
        (measured, DEPTH_RANGE_BOUND),
        "bias 0 (false shadows), a 0.5 m constant bias (lost contact), and 16-bit or conventional-Z maps (farthest band's share minus nearest's); the smallest counts",
        control_value,
        non_finite,
    );
    r.details = details;
    Ok(r)
}

/// The depth-precision controls: the textbook ways a shadow map loses depth precision at range.
/// (A fixed 1 m near plane is not one: reversed-Z floats keep the same relative precision
/// whatever the near plane, and the figures came out identical to the renderer's.)
const DEPTH_CONTROLS: [(Fault, &str); 2] = [
    (Fault::Depth16, "16-bit maps"),
    (Fault::ConventionalZ, "conventional Z"),
];

/// Indices of the nearest and the farthest band.
fn extreme_bands(bands: &[Band]) -> (usize, usize) {
    let by_distance =
        |a: &(usize, &Band), b: &(usize, &Band)| a.1.distance.total_cmp(&b.1.distance);
    let nearest = bands.iter().enumerate().min_by(by_distance);
    let farthest = bands.iter().enumerate().max_by(by_distance);
    (nearest.map_or(0, |b| b.0), farthest.map_or(0, |b| b.0))
}

/// How much worse the farthest band is than the nearest (each band's worse share): a depth
/// control must break the bound by failing at range, not everywhere alike. NaN stays NaN.
fn growth(per: &[(f64, f64)], nearest: usize, farthest: usize) -> f64 {
    let worse = |i: usize| per.get(i).map_or(f64::NAN, |&(f, l)| nan_max(f, l));
    worse(farthest) - worse(nearest)
}

/// `max` that keeps a NaN (a NaN share must fail, not vanish).
fn nan_max(a: f64, b: f64) -> f64 {
    if a.is_nan() || b.is_nan() {
        f64::NAN
    } else {
        a.max(b)
    }
}

/// The largest texel of any sample's shadow views, in tangent units (radians near the axis).
fn texel_tangent(scene: &Scene) -> f32 {
    let receivers = mesh_receivers(scene);
    let size = scene.quality.shadow_map_size.max(1) as f32;
    sampling::direct_samples(scene)
        .iter()
        .flat_map(|s| shadow_views(s, &receivers))
        .map(|v| (v.extent[1] - v.extent[0]).max(v.extent[3] - v.extent[2]) / size)
        .fold(0.0, f32::max)
}

/// far/near of each sample's shadow views over every receiver (what the renderer fits here).
fn depth_ratios(scene: &Scene) -> String {
    let receivers = mesh_receivers(scene);
    let ratios: Vec<String> = sampling::direct_samples(scene)
        .iter()
        .flat_map(|s| shadow_views(s, &receivers))
        .map(|v| format!("{:.3e} ({:.4} m..{:.0} m)", v.far / v.near, v.near, v.far))
        .collect();
    ratios.join(", ")
}

/// docs/hard-cases.md, case 3.
const DEPTH_RANGE_BOUND: f64 = 0.01;
