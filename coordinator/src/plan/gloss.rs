//! Glossy highlights of point-sampled area lights: the samples an area light needs so that the
//! glossy lobes it lights integrate its samples into one highlight, not a grid of dots
//! (`docs/planner.md` § Glossy highlights).
//!
//! N point samples of an area light reflect in a glossy surface as N highlights; they merge into
//! the area light's one highlight when the lobe is wide against the samples' spacing as seen
//! from the surface. The rule's variable is that ratio, `ρ = θ_cell / (2α)`: `θ_cell` the angle
//! one sample's cell of the light (its largest side) subtends at the nearest point of a receiver,
//! `2α` the reflected lobe's width (GGX `α`; a Blinn-Phong exponent `s` as `α = √(2/(s + 2))`,
//! the Beckmann match the scene already uses). The highlight's RMS error over the surface's
//! brightest radiance, measured against the lobe integrated over the light
//! (`quality/examples/glossy_sweep.rs`, silver spheres), grows with `ρ²`; it stays within the
//! default target's 45 dB up to [`SPACING_OVER_LOBE_AT_45_DB`], and a material whose specular
//! is a share `σ` of its reflectance ([`sampled_lobe`]) allows `ρ` up to that over `√σ`.
//!
//! Lobes the closed form integrates (metallic-roughness at roughness ≤ 0.4 with the default
//! `area_specular = "analytic"`, `scene::ltc`) need no samples for their highlight; between 0.4
//! and 0.6 the samples carry a growing share, judged here at roughness 0.5, where they carry
//! half. An error target ([`super::targeted`]) raises each area light to the count its visible
//! glossy receivers need, and the plan says which light, for which material, and why.

use super::cull::Receiver;
use lightfold_scene::shading::{ggx_alpha, length, sub};
use lightfold_scene::{AreaSpecular, Light, LightShape, Scene};
use serde::{Deserialize, Serialize};

/// The largest sample spacing over lobe width at which point-sampled highlights stayed within
/// 0.56 % RMS of their peak (45 dB, the default error target) beyond the truth's own noise in
/// every setting `quality/examples/glossy_sweep.rs` measured (roughness 0.3–0.8, panels 1–3×
/// hard case 19's, 4–256 samples; `docs/planner.md` § Glossy highlights).
pub const SPACING_OVER_LOBE_AT_45_DB: f32 = 0.4;

/// The most samples the rule raises a light to: the most the sweep measured.
pub const MAX_GLOSS_SAMPLES: u32 = 256;

/// The largest spacing over lobe width for an error target (dB, as the penumbra's): the
/// highlight's RMS error grew with about the square of `ρ` in the sweep (2 to 2.7 between
/// halvings), so `ρ` scales with the square root of the allowed error.
pub fn max_spacing_over_lobe(target_db: f32) -> f32 {
    let t = if target_db.is_finite() {
        target_db
    } else {
        45.0
    };
    SPACING_OVER_LOBE_AT_45_DB * 10f32.powf((45.0 - t.clamp(20.0, 80.0)) / 40.0)
}

/// The roughness a metallic-roughness lobe is judged at where the closed form takes part of it
/// (between `ltc::CLOSED_FORM_ROUGHNESS`): the blend's middle, where the samples carry half.
const BLENDED_ROUGHNESS: f32 = 0.5;

/// The least specular share the rule divides by (a share near 0 would allow any spacing).
const MIN_SHARE: f32 = 0.01;

/// One area light raised for a glossy receiver.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GlossRaise {
    /// The light (index into `Scene::lights`) and its name.
    pub light: usize,
    pub name: String,
    /// Its samples before and after.
    pub from: u32,
    pub to: u32,
    /// The receiver that asks most: its material's name, the lobe's GGX `α`, and its nearest
    /// distance to the light (metres).
    pub material: String,
    pub alpha: f32,
    /// The specular's share of the material's reflectance ([`sampled_lobe`]).
    pub share: f32,
    pub distance: f32,
    /// Whether `to` reaches the rule's spacing (false: capped at [`MAX_GLOSS_SAMPLES`]).
    pub reached: bool,
}

/// The lobe a material's highlight takes from point samples: its GGX `α` and the specular's
/// share of the material's reflectance (`max m^s / (max m^s + max m^d)`; for metallic-roughness
/// `F0` against `c_diff`), or `None` where its highlight takes nothing from them (no specular,
/// or the closed form carries all of it). The share scales the highlight's error against the
/// surface's brightest radiance: the sweep's silver (share 1) sets the rule.
pub fn sampled_lobe(scene: &Scene, material: usize) -> Option<(f32, f32)> {
    let m = scene.materials.get(material)?;
    let cmax = |c: [f32; 3]| c.iter().fold(0.0f32, |a, &v| a.max(v));
    let share = |spec: f32, diff: f32| {
        let t = spec + diff;
        (spec > 0.0 && t.is_finite()).then(|| (spec / t).clamp(0.0, 1.0))
    };
    if let Some(p) = &m.pbr {
        let analytic = scene.quality.area_specular == AreaSpecular::Analytic;
        // A texture scales the factors by [0, 1]: the narrowest lobe and most metal it allows.
        let textured = p.metallic_roughness_texture.is_some();
        let (r, metallic) = if textured {
            (0.0, p.metallic.clamp(0.0, 1.0))
        } else {
            (p.roughness, p.metallic.clamp(0.0, 1.0))
        };
        let (lo, _) = lightfold_scene::ltc::CLOSED_FORM_ROUGHNESS;
        let r = if !analytic {
            r
        } else if r <= lo && !textured {
            return None;
        } else {
            r.max(BLENDED_ROUGHNESS)
        };
        let base = cmax(p.base_color);
        let f0 = 0.04 * (1.0 - metallic) + base * metallic;
        let c_diff = base * (1.0 - metallic);
        return Some((ggx_alpha(r), share(f0, c_diff)?));
    }
    let s = m.shininess;
    if !(m.has_specular() && s.is_finite() && s > 0.0) {
        return None;
    }
    Some((
        (2.0 / (s + 2.0)).sqrt(),
        share(cmax(m.specular), cmax(m.diffuse))?,
    ))
}

/// The width of one sample's cell (`scene::sampling::cell_width`).
fn cell(light: &Light, samples: u32) -> Option<f32> {
    lightfold_scene::sampling::cell_width(light, samples)
}

/// The light's centre, for distances (`None` for a sun, which is at infinity).
fn center(light: &Light) -> Option<[f32; 3]> {
    match &light.shape {
        LightShape::Rect { center, .. }
        | LightShape::Disk { center, .. }
        | LightShape::Sphere { center, .. }
        | LightShape::Cylinder { center, .. } => Some(*center),
        _ => None,
    }
}

/// The angle a cell subtends at distance `d` (the sun's cell is an angle already).
fn cell_angle(light: &Light, samples: u32, d: f32) -> Option<f32> {
    let c = cell(light, samples)?;
    if center(light).is_none() {
        return Some(c);
    }
    Some(2.0 * (0.5 * c / d.max(1e-6)).atan())
}

/// `ρ` (module documentation) of `light` at its own sample count for a lobe of GGX `alpha` at
/// `point`; 0 for lights the rule does not size.
pub fn spacing_over_lobe(light: &Light, point: [f32; 3], alpha: f32) -> f32 {
    let d = center(light).map_or(f32::INFINITY, |c| length(sub(c, point)));
    cell_angle(light, light.samples, d).map_or(0.0, |a| a / (2.0 * alpha.max(1e-4)))
}

/// The fewest samples from `from` up to `max` at which `light`'s cells subtend at most
/// `rho · 2α` at distance `d`; `(max, false)` where none does.
fn samples_for(light: &Light, from: u32, max: u32, d: f32, alpha: f32, rho: f32) -> (u32, bool) {
    if cell(light, from).is_none() {
        return (from, true);
    }
    let bound = rho * 2.0 * alpha;
    for n in from.max(1)..=max {
        if cell_angle(light, n, d).is_some_and(|a| a <= bound) {
            return (n, true);
        }
    }
    (max, false)
}

/// Raises each area light of `scene` whose visible glossy receivers need more samples than it
/// has (its count as the scene gives it: `Quality::samples_per_area_light`, or its own) to the
/// fewest at which their lobes are at least `1/rho` times the samples' spacing
/// ([`max_spacing_over_lobe`]), at most [`MAX_GLOSS_SAMPLES`] (never lowered). Returns the
/// scene (every light's count its own) and what was raised, with each light at the cap whose
/// highlight still needs more (`reached` false, its count kept); `None` where neither.
pub(crate) fn raise(
    scene: &Scene,
    receivers: &[Receiver],
    rho: f32,
) -> Option<(Scene, Vec<GlossRaise>)> {
    let glossy: Vec<(&Receiver, f32, f32)> = receivers
        .iter()
        .filter_map(|r| {
            let (alpha, share) = sampled_lobe(scene, scene.meshes[r.mesh].material)?;
            Some((r, alpha, share))
        })
        .collect();
    if glossy.is_empty() {
        return None;
    }
    let mut raises = Vec::new();
    for (i, light) in scene.lights.iter().enumerate() {
        if !light.is_area() {
            continue;
        }
        let from = scene.quality.samples_of(light);
        let mut best: Option<GlossRaise> = None;
        for (r, alpha, share) in &glossy {
            let d = center(light).map_or(f32::INFINITY, |c| r.bounds.distance(c));
            // The error goes with ρ² × share: a dimmer highlight allows wider spacing.
            let rho = rho / share.max(MIN_SHARE).sqrt();
            let (n, reached) = samples_for(light, from, MAX_GLOSS_SAMPLES, d, *alpha, rho);
            // A raise, or a light already at the cap whose highlight still needs more (said,
            // though its count stays).
            let capped_here = !reached && best.is_none();
            if n > best.as_ref().map_or(from, |b| b.to) || capped_here {
                best = Some(GlossRaise {
                    light: i,
                    name: light.name.clone(),
                    from,
                    to: n.max(from),
                    material: scene.materials[scene.meshes[r.mesh].material].name.clone(),
                    alpha: *alpha,
                    share: *share,
                    distance: d,
                    reached,
                });
            }
        }
        raises.extend(best);
    }
    if raises.is_empty() {
        return None;
    }
    let mut s = scene.clone();
    for l in s.lights.iter_mut().filter(|l| l.is_area()) {
        l.samples = scene.quality.samples_of(l);
    }
    s.quality.samples_per_area_light = None;
    for r in &raises {
        s.lights[r.light].samples = r.to;
    }
    Some((s, raises))
}
