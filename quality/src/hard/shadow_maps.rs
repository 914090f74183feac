//! Issue 22's shadow-map cases: scenes where the default maps leak light through closed corners
//! (14), detach a shadow from its caster under grazing light (15), lose the shadows of small
//! near occluders in a deep scene (16) and of thin poles (17). Truth is the exact point sum of the
//! same samples (`render_point_sum`, ray-traced visibility), so every error is the maps'.
//!
//! Each case is judged twice, and fails on either: the whole image's PSNR (final radiance, after
//! the exposure, as `lightfold compare` computes it) must be at least [`MIN_PSNR_DB`], and no
//! pixel the point sum holds fully shadowed may come out lit — above [`LIT_SHARE`] of its
//! unshadowed illumination. Judged dark pixels are compared pixels (one shadow state over their
//! 3×3 neighbourhood, no silhouette) whose whole [`ERODE`]-pixel neighbourhood is fully shadowed
//! too, so the filter's legitimate blur of a shadow edge is not counted.

use super::support::{ABS_TOL, comparable, count_non_finite, gpu, pixel_sum, report};
use super::{CaseReport, HardCaseError};
use lightfold_node::gpu::{Fault, Gpu, LayerSet, RenderOptions, Renderer};
use lightfold_reference::masks::shadow_states;
use lightfold_reference::metrics::error_stats;
use lightfold_reference::{PointSumOptions, render_point_sum, render_point_sum_with};
use lightfold_scene::{Image, LightSample, Scene, sampling};

/// The bar on whole-image PSNR against the same-sample point sum.
pub const MIN_PSNR_DB: f64 = 40.0;
/// A truly dark pixel counts as lit above this share of its unshadowed illumination.
pub const LIT_SHARE: f32 = 0.05;
/// Judged dark pixels have a fully shadowed neighbourhood of this radius (pixels).
pub const ERODE: i64 = 1;
/// A case with fewer judged dark pixels proves nothing.
const MIN_JUDGED: usize = 100;

/// The node colour of every case: white, so the illumination is the plain sum.
const C_N: [f32; 3] = [1.0; 3];

/// The deliberate mistake of a case's negative control.
#[derive(Debug, Clone, Copy)]
enum Control {
    Fault(Fault),
    MapSize(u32),
}

impl Control {
    fn describe(self) -> &'static str {
        match self {
            Control::Fault(Fault::HugeBias) => "constant bias 0.5 m",
            Control::Fault(_) => "a renderer fault",
            Control::MapSize(_) => "64² shadow maps",
        }
    }

    fn apply(self, opts: RenderOptions) -> RenderOptions {
        match self {
            Control::Fault(f) => RenderOptions {
                fault: Some(f),
                ..opts
            },
            Control::MapSize(size) => opts.fixed_maps(size),
        }
    }
}

/// One whole-image case of this file: its name, scene file, small (test) size and negative
/// control.
#[derive(Clone, Copy)]
struct MapCase {
    name: &'static str,
    file: &'static str,
    small: (u32, u32),
    control: Control,
}

/// Cases 14–18 and 20 (docs/hard-cases.md).
const MAP_CASES: [MapCase; 6] = [
    MapCase {
        name: "corner-leak",
        file: "corner_leak.toml",
        small: (256, 192),
        control: Control::Fault(Fault::HugeBias),
    },
    MapCase {
        name: "grazing-fin",
        file: "grazing_fin.toml",
        small: (256, 192),
        control: Control::Fault(Fault::HugeBias),
    },
    MapCase {
        name: "deep-near",
        file: "deep_near.toml",
        small: (256, 192),
        control: Control::MapSize(64),
    },
    MapCase {
        name: "thin-poles",
        file: "thin_poles.toml",
        small: (320, 240),
        control: Control::MapSize(64),
    },
    MapCase {
        name: "thin-house",
        file: "thin_house.toml",
        small: (320, 240),
        control: Control::Fault(Fault::HugeBias),
    },
    MapCase {
        name: "cornell-junction",
        file: "cornell_junction.toml",
        small: (320, 240),
        control: Control::Fault(Fault::HugeBias),
    },
];

/// Case `name` of [`MAP_CASES`] with every fix.
fn all_fixes(name: &str, full: bool) -> Result<CaseReport, HardCaseError> {
    run_with(name, full, Fixes::ALL).expect("a case of MAP_CASES")
}

/// Case 14: `scenes/hard/corner_leak.toml` — a closed room of 2 cm walls and roof (a skylight
/// in it), the light outside.
pub fn corner_leak(full: bool) -> Result<CaseReport, HardCaseError> {
    all_fixes("corner-leak", full)
}

/// Case 15: `scenes/hard/grazing_fin.toml` — a fin on a 60 m floor, light 5° above the horizon.
pub fn grazing_fin(full: bool) -> Result<CaseReport, HardCaseError> {
    all_fixes("grazing-fin", full)
}

/// Case 16: `scenes/hard/deep_near.toml` — 25 cm boxes near the camera on an 800 m ground.
pub fn deep_near(full: bool) -> Result<CaseReport, HardCaseError> {
    all_fixes("deep-near", full)
}

/// Case 17: `scenes/hard/thin_poles.toml` — 6 cm poles on a 40 m yard.
pub fn thin_poles(full: bool) -> Result<CaseReport, HardCaseError> {
    all_fixes("thin-poles", full)
}

/// Case 18 (issue 46): `scenes/hard/thin_house.toml` — a closed house of 1 cm walls and roof,
/// lit from outside at 30° through one window.
pub fn thin_house(full: bool) -> Result<CaseReport, HardCaseError> {
    all_fixes("thin-house", full)
}

/// Case 20 (issue 46): `scenes/hard/cornell_junction.toml` — the Cornell box, a room of separate
/// planes meeting edge to edge, lit from inside by its ceiling panel.
pub fn cornell_junction(full: bool) -> Result<CaseReport, HardCaseError> {
    all_fixes("cornell-junction", full)
}

/// Which of issue 22's fixes a render uses (all by default), so each can be measured alone.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Fixes {
    /// Maps fitted to what the camera sees split into cascades by eye depth.
    pub cascades: bool,
    /// The object-ID test: other objects' casters compared without the receiver's slope bias.
    pub object_ids: bool,
    /// Shadow maps of this size instead of the scene's (to measure what resolution buys).
    pub map_size: Option<u32>,
    /// Other objects' texels compared with the receiver's plane at their centre (issue 46).
    pub receiver_plane: bool,
}

impl Fixes {
    /// The renderer as it is.
    pub const ALL: Fixes = Fixes {
        cascades: true,
        object_ids: true,
        map_size: None,
        receiver_plane: true,
    };
    /// The renderer before issue 22.
    pub const NONE: Fixes = Fixes {
        cascades: false,
        object_ids: false,
        map_size: None,
        receiver_plane: false,
    };
}

/// The truth of one case: the point sum's radiance and illumination, and the judged dark pixels.
struct Truth {
    radiance: Image,
    unshadowed: Image,
    dark: Vec<usize>,
}

fn truth(scene: &Scene, samples: &[LightSample]) -> Truth {
    let layers = render_point_sum(scene, samples, C_N);
    let unshadowed =
        render_point_sum_with(scene, samples, C_N, PointSumOptions { shadows: false }).illumination;
    let st = shadow_states(scene, samples);
    let mask = comparable(&layers.depth, &layers.coverage, &st.visible);
    let (w, h) = (
        i64::from(scene.camera.width),
        i64::from(scene.camera.height),
    );
    let shadowed = |i: usize| st.lit[i] != 0 && st.visible[i] == 0 && layers.coverage[i];
    let mut dark = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            if !mask[i] || !shadowed(i) {
                continue;
            }
            let around = (-ERODE..=ERODE).all(|dy| {
                (-ERODE..=ERODE).all(|dx| {
                    let (u, v) = (x + dx, y + dy);
                    (0..w).contains(&u) && (0..h).contains(&v) && shadowed((v * w + u) as usize)
                })
            });
            if around {
                dark.push(i);
            }
        }
    }
    Truth {
        radiance: layers.radiance(C_N, scene.ambient),
        unshadowed,
        dark,
    }
}

/// What one GPU render scored.
struct Score {
    psnr: f64,
    energy_bias: f64,
    /// Judged dark pixels the GPU lights, and the brightest of them against the brightest
    /// correctly lit radiance of the truth.
    lit: usize,
    /// Those pixels' indices (for `LIGHTFOLD_HARD_DUMP`).
    leaks: Vec<usize>,
    brightest: f64,
    non_finite: usize,
}

impl Score {
    /// The case's figure: lit dark pixels, infinite when the PSNR misses its bar.
    fn metric(&self) -> f64 {
        if self.psnr.is_nan() || self.psnr < MIN_PSNR_DB {
            f64::INFINITY
        } else {
            self.lit as f64
        }
    }
}

fn render_radiance(
    case: &'static str,
    gpu: &Gpu,
    scene: &Scene,
    samples: &[LightSample],
    opts: RenderOptions,
    fixes: Fixes,
) -> Result<(Image, Image, u32, Vec<u32>), HardCaseError> {
    let err = |e: String| HardCaseError::Render { case, message: e };
    let mut r = Renderer::new(gpu, scene, opts).map_err(|e| err(e.to_string()))?;
    r.set_cascades(fixes.cascades);
    r.set_object_ids(fixes.object_ids);
    r.set_receiver_plane(fixes.receiver_plane);
    let frame = r
        .render(gpu, samples, None, C_N, LayerSet::all())
        .map_err(|e| err(e.to_string()))?;
    let illum = frame
        .illumination
        .clone()
        .ok_or_else(|| err("no illumination layer".into()))?;
    let radiance = frame
        .radiance(&illum, scene.ambient)
        .map_err(|e| err(e.to_string()))?;
    Ok((
        illum,
        radiance,
        frame.stats.passes_per_light.iter().sum(),
        frame.stats.map_sides,
    ))
}

fn score(
    case: &'static str,
    scene: &Scene,
    t: &Truth,
    illum: &Image,
    radiance: &Image,
) -> Result<Score, HardCaseError> {
    let stats = error_stats(radiance, &t.radiance, scene.exposure, None).map_err(|e| {
        HardCaseError::Render {
            case,
            message: e.to_string(),
        }
    })?;
    let peak = t
        .radiance
        .data
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .fold(0f32, f32::max);
    let (mut lit, mut brightest, mut leaks) = (0usize, 0f64, Vec::new());
    for &i in &t.dark {
        let v = pixel_sum(illum, i);
        if v.is_nan() || v > LIT_SHARE * pixel_sum(&t.unshadowed, i) + ABS_TOL {
            lit += 1;
            leaks.push(i);
        }
        let rgb = &radiance.data[i * 3..i * 3 + 3];
        brightest = brightest.max(f64::from(rgb.iter().copied().fold(0f32, f32::max)));
    }
    Ok(Score {
        psnr: stats.psnr,
        energy_bias: stats.energy_bias,
        lit,
        leaks,
        brightest: brightest / f64::from(peak).max(1e-30),
        non_finite: count_non_finite(&illum.data) + count_non_finite(&radiance.data),
    })
}

/// Runs case `name` of this file with only `fixes` (the hard-case test runs [`Fixes::ALL`]).
pub fn run_with(name: &str, full: bool, fixes: Fixes) -> Option<Result<CaseReport, HardCaseError>> {
    let c = MAP_CASES.iter().find(|c| c.name == name)?;
    Some(whole_image_case(c, full, fixes))
}

/// The distinct map sides of a frame with their counts, largest first: "1024² ×4, 512² ×12".
fn map_sides(sides: &[u32]) -> String {
    let mut counts = std::collections::BTreeMap::<std::cmp::Reverse<u32>, usize>::new();
    for &s in sides {
        *counts.entry(std::cmp::Reverse(s)).or_default() += 1;
    }
    counts
        .iter()
        .map(|(s, n)| format!("{}² ×{n}", s.0))
        .collect::<Vec<_>>()
        .join(", ")
}

fn whole_image_case(c: &MapCase, full: bool, fixes: Fixes) -> Result<CaseReport, HardCaseError> {
    let MapCase {
        name: case,
        file,
        small,
        control,
    } = *c;
    let gpu = gpu()?;
    let scene = super::support::load_case_scene(case, file, full, small)?;
    let samples = sampling::direct_samples(&scene);
    let t = truth(&scene, &samples);
    let mut opts = RenderOptions::from_quality(&scene.quality);
    if let Some(size) = fixes.map_size {
        opts = opts.fixed_maps(size);
    }
    let (illum, radiance, passes, sides) =
        render_radiance(case, &gpu, &scene, &samples, opts, fixes)?;
    let s = score(case, &scene, &t, &illum, &radiance)?;
    // For looking at a case: LIGHTFOLD_HARD_DUMP=DIR writes both images as PNG.
    if let Some(dir) = std::env::var_os("LIGHTFOLD_HARD_DUMP") {
        let dir = std::path::PathBuf::from(dir);
        // The judged dark pixels the renderer lights, in red over its image.
        let mut leaks = radiance.clone();
        for &i in &s.leaks {
            leaks.data[i * 3..i * 3 + 3].copy_from_slice(&[1e3, 0.0, 0.0]);
        }
        for (img, what) in [
            (&radiance, "gpu"),
            (&t.radiance, "truth"),
            (&leaks, "leaks"),
        ] {
            let path = dir.join(format!("{case}-{what}.png"));
            if let Err(e) = img.write_png(&path, scene.exposure) {
                tracing::warn!(path = %path.display(), "{e}");
            }
        }
    }
    let (c_illum, c_radiance, _, _) =
        render_radiance(case, &gpu, &scene, &samples, control.apply(opts), fixes)?;
    let c = score(case, &scene, &t, &c_illum, &c_radiance)?;
    let mut r = report(
        case,
        "truly dark pixels lit (∞ when whole-image PSNR < 40 dB)",
        (s.metric(), 0.0),
        control.describe(),
        c.metric(),
        s.non_finite + count_non_finite(&t.radiance.data),
    );
    let line = |what: &str, s: &Score| {
        format!(
            "{what}: PSNR {:.2} dB, energy bias {:+.3e}, {} of {} dark pixels lit, brightest of \
             them {:.3}× the truth's peak",
            s.psnr,
            s.energy_bias,
            s.lit,
            t.dark.len(),
            s.brightest
        )
    };
    r.details = vec![
        format!(
            "{} samples, {passes} shadow passes, map sides {}, {} judged dark pixels",
            samples.len(),
            map_sides(&sides),
            t.dark.len()
        ),
        line("renderer", &s),
        line("control", &c),
    ];
    if t.dark.len() < MIN_JUDGED {
        r.measured = f64::INFINITY;
    }
    Ok(r)
}
