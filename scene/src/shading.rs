//! The lighting maths of lightfold, defined once (ARCHITECTURE §2, documented in
//! `docs/shading.md`). The WGSL shaders mirror these functions; the CPU reference and the tests
//! call them directly.
//!
//! Per light sample `λ` at a surface point with unit normal `n`, unit direction to the viewer `v`:
//! - irradiance `E_λ = I_λ(ω)·max(0, n·l)/r²` (times the range window), `l` the unit direction to
//!   the light, `r` its distance;
//! - diffuse coefficient `i^d_λ = E_λ/π` (so outgoing radiance is `m^d ⊙ I^d` with `m^d` the albedo);
//! - specular coefficient `i^s_λ = E_λ·(s+8)/(8π)·max(0, n·h)^s`, `h = normalize(l + v)`,
//!   `s` the material's Blinn-Phong exponent;
//! - pixel `p = e + m^a ⊙ (c^a + I^a) + m^d ⊙ I^d + m^s ⊙ I^s` (paper eq. 2),
//!   `I^d = Σ c_λ·i^d_λ·s_λ`, `I^s = Σ c_λ·i^s_λ·s_λ`, `s_λ ∈ [0, 1]` the shadow coefficient.

use crate::Image;
use crate::model::{AlphaMode, LightSample, Material, MetallicRoughness, SampleKind, Texture};
use std::f32::consts::PI;

pub type V3 = [f32; 3];

#[inline]
pub fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline]
pub fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
#[inline]
pub fn scale(a: V3, s: f32) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
#[inline]
pub fn mul(a: V3, b: V3) -> V3 {
    [a[0] * b[0], a[1] * b[1], a[2] * b[2]]
}
#[inline]
pub fn dot(a: V3, b: V3) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline]
pub fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
#[inline]
pub fn length(a: V3) -> f32 {
    dot(a, a).sqrt()
}
/// Unit vector, or zero for a zero / non-finite input (never NaN).
#[inline]
pub fn normalize(a: V3) -> V3 {
    let l = length(a);
    if l > 0.0 && l.is_finite() {
        scale(a, 1.0 / l)
    } else {
        [0.0; 3]
    }
}

/// The smooth range window of KHR_lights_punctual: `clamp(1 − (r/range)⁴, 0, 1)²`.
#[inline]
pub fn range_window(r: f32, range: Option<f32>) -> f32 {
    match range {
        Some(range) if range > 0.0 => {
            let q = r / range;
            let w = (1.0 - q * q * q * q).clamp(0.0, 1.0);
            w * w
        }
        _ => 1.0,
    }
}

/// Radiant intensity (W/sr) of the sample towards unit direction `to_point` (light → point).
#[inline]
pub fn sample_intensity(s: &LightSample, to_point: V3) -> f32 {
    let c = dot(s.direction, to_point);
    match s.kind {
        SampleKind::Isotropic => s.intensity,
        SampleKind::CosineLobe | SampleKind::Bounce { .. } => s.intensity * c.max(0.0),
        SampleKind::TwoSidedLobe => s.intensity * c.abs(),
        SampleKind::Spot {
            cos_outer,
            cos_inner,
        } => {
            let t = ((c - cos_outer) / (cos_inner - cos_outer).max(1e-4)).clamp(0.0, 1.0);
            s.intensity * t * t
        }
        SampleKind::Directional => s.intensity,
    }
}

/// Direction from `p` towards the light (unit) and the distance (`f32::INFINITY` for directional).
#[inline]
pub fn to_light(s: &LightSample, p: V3) -> (V3, f32) {
    match s.kind {
        SampleKind::Directional => (scale(normalize(s.direction), -1.0), f32::INFINITY),
        _ => {
            let d = sub(s.position, p);
            let r = length(d);
            (normalize(d), r)
        }
    }
}

/// The `r²` of the inverse-square law, clamped for a virtual point light to `max(r², clamp²)`.
#[inline]
pub fn falloff(s: &LightSample, r: f32) -> f32 {
    match s.kind {
        SampleKind::Bounce { clamp } => (r * r).max(clamp * clamp),
        _ => r * r,
    }
}

/// Unshadowed irradiance `E_λ` (W/m², scalar; colour applied separately) at `p` with normal `n`.
/// Finite for every input: a point on the light gives 0.
#[inline]
pub fn irradiance(s: &LightSample, p: V3, n: V3) -> f32 {
    let (l, r) = to_light(s, p);
    let cos_n = dot(n, l);
    if cos_n <= 0.0 {
        return 0.0;
    }
    let e = match s.kind {
        SampleKind::Directional => s.intensity * cos_n,
        _ => {
            if r.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
                return 0.0;
            }
            sample_intensity(s, scale(l, -1.0)) * cos_n / falloff(s, r) * range_window(r, s.range)
        }
    };
    if e.is_finite() { e } else { 0.0 }
}

/// Energy-normalised Blinn-Phong lobe `(s+8)/(8π)·max(0, n·h)^s`.
#[inline]
pub fn blinn_phong(n: V3, l: V3, v: V3, shininess: f32) -> f32 {
    let h = normalize(add(l, v));
    let nh = dot(n, h).max(0.0);
    (shininess + 8.0) / (8.0 * PI) * nh.powf(shininess)
}

/// Unshadowed diffuse and specular coefficients `(i^d, i^s)` of one sample at a surface point.
#[inline]
pub fn coefficients(
    s: &LightSample,
    p: V3,
    n: V3,
    v: V3,
    shininess: f32,
    specular: bool,
) -> (f32, f32) {
    let e = irradiance(s, p, n);
    if e == 0.0 {
        return (0.0, 0.0);
    }
    let id = e / PI;
    let is = if specular {
        let (l, _) = to_light(s, p);
        e * blinn_phong(n, l, v, shininess)
    } else {
        0.0
    };
    (id, is)
}

/// How a surface reflects one light sample: the paper's Blinn-Phong lobe, or the glTF 2.0
/// metallic-roughness reference BRDF at one surface point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Lobe {
    /// `i^s` from [`blinn_phong`] at `shininess` where `specular` (the material has `m^s ≠ 0`).
    BlinnPhong { shininess: f32, specular: bool },
    /// GGX with `alpha` = roughness² and normal-incidence reflectance `f0` (RGB).
    Ggx { alpha: f32, f0: V3 },
}

/// Unshadowed `(i^d, i^s)` of one sample under `lobe`; `i^s` is RGB (the glTF BRDF's Fresnel
/// term carries the surface's colour), `i^d` is scalar.
///
/// Under [`Lobe::Ggx`], with `w = (1 − |v·h|)⁵` (Schlick), `D` GGX and `V` the height-correlated
/// Smith visibility of the glTF specification's Appendix B:
/// `i^d = E·(1 − w)/π` and `i^s = E·D·V·(F0 + (1 − F0)·w)`. The material layer
/// `m^d = c_diff ⊙ (1 − F0)` and `m^s = 1` ([`metallic_roughness_point`]) then make
/// `m^d⊙i^d + m^s⊙i^s = E·((1 − F)⊙c_diff/π + F·D·V)`, `F = F0 + (1 − F0)·w`: the
/// specification's `f_diffuse + f_specular` times `E`.
#[inline]
pub fn lobe_coefficients(s: &LightSample, p: V3, n: V3, v: V3, lobe: &Lobe) -> (f32, V3) {
    match *lobe {
        Lobe::BlinnPhong {
            shininess,
            specular,
        } => {
            let (id, is) = coefficients(s, p, n, v, shininess, specular);
            (id, [is; 3])
        }
        Lobe::Ggx { alpha, f0 } => ggx_coefficients(s, p, n, v, alpha, f0),
    }
}

/// Smallest GGX `α`: a perfect mirror's `D` is a delta no point sample can meet.
pub const MIN_ALPHA: f32 = 1e-3;

/// GGX `α = roughness²` (roughness clamped to [0, 1], NaN as 1), at least [`MIN_ALPHA`].
#[inline]
pub fn ggx_alpha(roughness: f32) -> f32 {
    let r = if roughness.is_nan() {
        1.0
    } else {
        roughness.clamp(0.0, 1.0)
    };
    (r * r).max(MIN_ALPHA)
}

/// GGX (Trowbridge-Reitz) normal distribution `D = α²/(π((n·h)²(α² − 1) + 1)²)` of unit normal
/// `n` and half vector `h`, evaluated as `α²/(π(|n × h|² + α²(n·h)²)²)`: the same for unit
/// vectors, without `1 − (n·h)²`'s cancellation, which in f32 costs a near-mirror lobe (α = 10⁻³)
/// several per cent of its peak in steps. `n·h` is clamped at 0.
#[inline]
pub fn ggx_d(n: V3, h: V3, alpha: f32) -> f32 {
    let a2 = alpha * alpha;
    let nh = dot(n, h);
    let (nh, t2) = if nh > 0.0 {
        let c = cross(n, h);
        (nh, dot(c, c))
    } else {
        (0.0, 1.0)
    };
    let d = t2 + a2 * nh * nh;
    a2 / (PI * d * d)
}

/// Height-correlated Smith visibility `V = G/(4|n·l||n·v|)`
/// `= 0.5/(n·l·√((n·v)²(1 − α²) + α²) + n·v·√((n·l)²(1 − α²) + α²))`, cosines clamped at 0.
#[inline]
pub fn smith_visibility(nl: f32, nv: f32, alpha: f32) -> f32 {
    let a2 = alpha * alpha;
    let gv = nl * (nv * nv * (1.0 - a2) + a2).sqrt();
    let gl = nv * (nl * nl * (1.0 - a2) + a2).sqrt();
    let sum = gv + gl;
    if sum > 0.0 { 0.5 / sum } else { 0.0 }
}

/// Schlick's weight `w = (1 − |v·h|)⁵`: `F = F0 + (1 − F0)·w`.
#[inline]
pub fn schlick_weight(vh: f32) -> f32 {
    let x = 1.0 - vh.abs().min(1.0);
    let x2 = x * x;
    x2 * x2 * x
}

/// The glTF reference BRDF's coefficients (see [`lobe_coefficients`]).
#[inline]
pub fn ggx_coefficients(s: &LightSample, p: V3, n: V3, v: V3, alpha: f32, f0: V3) -> (f32, V3) {
    let e = irradiance(s, p, n);
    if e == 0.0 {
        return (0.0, [0.0; 3]);
    }
    let (l, _) = to_light(s, p);
    let (id, dv, w) = ggx_terms(n, l, v, alpha);
    // A sample of an area light of known shape takes its irradiance's share of the lobe
    // integrated over that shape (`crate::ltc`), not its own point highlight.
    let share = crate::ltc::closed_form_share(alpha);
    let area = s
        .area
        .filter(|_| share > 0.0)
        .and_then(|a| crate::ltc::ggx_area_terms(&a, p, n, v, alpha));
    let is = f0.map(|f| {
        let point = e * dv * (f + (1.0 - f) * w);
        let x = match area {
            Some((s1, sw)) => point + (e * (f * s1 + (1.0 - f) * sw) - point) * share,
            None => point,
        };
        if x.is_finite() { x } else { 0.0 }
    });
    (e * id, is)
}

/// Per unit irradiance: the diffuse weight `(1 − w)/π`, the specular `D·V` and Schlick's `w`
/// for light from unit direction `l`.
#[inline]
pub fn ggx_terms(n: V3, l: V3, v: V3, alpha: f32) -> (f32, f32, f32) {
    let h = normalize(add(l, v));
    let w = schlick_weight(dot(v, h));
    let nl = dot(n, l).max(0.0);
    let nv = dot(n, v).max(0.0);
    let dv = ggx_d(n, h, alpha) * smith_visibility(nl, nv, alpha);
    ((1.0 - w) / PI, if dv.is_finite() { dv } else { 0.0 }, w)
}

/// A metallic-roughness surface at one point: the material layers and the lobe.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MetallicRoughnessPoint {
    /// `m^d = c_diff ⊙ (1 − F0)`, `c_diff = base·(1 − metallic)·(1 − τ)`.
    pub diffuse: V3,
    pub f0: V3,
    pub alpha: f32,
}

/// The glTF metallic-roughness parameters at a point from its base-colour texel (linear RGBA,
/// white without a texture) and metallic-roughness texel (linear; G roughness, B metallic):
/// `base = factor ⊙ texel`, `F0 = mix(0.04, base, metallic)`.
#[inline]
pub fn metallic_roughness_point(
    m: &MetallicRoughness,
    base_texel: [f32; 4],
    mr_texel: [f32; 4],
) -> MetallicRoughnessPoint {
    let unit = |x: f32| if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) };
    let metallic = unit(m.metallic * mr_texel[2]);
    let roughness = m.roughness * mr_texel[1];
    let keep = (1.0 - metallic) * (1.0 - unit(m.transmission));
    let mut diffuse = [0.0; 3];
    let mut f0 = [0.0; 3];
    for k in 0..3 {
        let base = m.base_color[k] * base_texel[k];
        let base = if base.is_finite() { base.max(0.0) } else { 0.0 };
        f0[k] = 0.04 + (base - 0.04) * metallic;
        diffuse[k] = base * keep * (1.0 - f0[k]);
    }
    MetallicRoughnessPoint {
        diffuse,
        f0,
        alpha: ggx_alpha(roughness),
    }
}

/// What a material is at one surface point: its four material layers and its lobe.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfacePoint {
    /// `m^d`, `m^s`, `m^a`, `e`.
    pub diffuse: V3,
    pub specular: V3,
    pub ambient: V3,
    pub emissive: V3,
    pub lobe: Lobe,
}

/// A material at texture coordinates `uv`, its textures from `textures` (a missing one reads
/// white). Blinn-Phong: `m^d` = diffuse × base texture, the rest as authored. Metallic-roughness
/// (every texture read at [`shading_uv`]): `m^d = c_diff ⊙ (1 − F0)`, `m^s` = the material's
/// `specular` (1, or 0 where a scene file's `specular = false` turned the lobe off),
/// `m^a = m^d · occlusion`, `e` = emissive × emissive texture.
pub fn surface_point(m: &Material, textures: &[Texture], uv: [f32; 2]) -> SurfacePoint {
    let read = |t: Option<usize>, uv: [f32; 2]| {
        t.and_then(|t| textures.get(t))
            .map_or([1.0; 4], |t| sample_texture(t, uv))
    };
    let Some(p) = &m.pbr else {
        let c = read(m.diffuse_texture, uv);
        return SurfacePoint {
            diffuse: [0, 1, 2].map(|k| m.diffuse[k] * c[k]),
            specular: m.specular,
            ambient: m.ambient,
            emissive: m.emissive,
            lobe: Lobe::BlinnPhong {
                shininess: m.shininess,
                specular: m.has_specular(),
            },
        };
    };
    let suv = shading_uv(uv);
    let at = metallic_roughness_point(
        p,
        read(m.diffuse_texture, suv),
        read(p.metallic_roughness_texture, suv),
    );
    let occ = match p.occlusion_texture {
        Some(_) => occlusion(p.occlusion_strength, read(p.occlusion_texture, suv)[0]),
        None => 1.0,
    };
    let e = read(p.emissive_texture, suv);
    SurfacePoint {
        diffuse: at.diffuse,
        specular: m.specular,
        ambient: scale(at.diffuse, occ),
        emissive: [0, 1, 2].map(|k| m.emissive[k] * e[k]),
        lobe: Lobe::Ggx {
            alpha: at.alpha,
            f0: at.f0,
        },
    }
}

/// The shading normal at a point (front face, unit `n` interpolated) with texture coordinates
/// `uv`: the normal map's where the material has one, else `n`. `tangent` gives the point's
/// tangent (the mesh's, interpolated, or its triangle's), asked for only when a map is applied.
pub fn mapped_normal(
    m: &Material,
    textures: &[Texture],
    n: V3,
    tangent: impl FnOnce() -> [f32; 4],
    uv: [f32; 2],
) -> V3 {
    let Some(pbr) = &m.pbr else { return n };
    let Some(t) = pbr.normal_texture.and_then(|t| textures.get(t)) else {
        return n;
    };
    let texel = sample_texture(t, shading_uv(uv));
    perturb_normal(
        n,
        tangent(),
        [texel[0], texel[1], texel[2]],
        pbr.normal_scale,
    )
}

/// A mesh's tangents at barycentric weights `b` of a triangle with corner tangents `corners`:
/// xyz interpolated, `w` the interpolated handedness (±1 at every corner of a glTF mesh), as the
/// GPU interpolates its vertex attribute.
#[inline]
pub fn interpolated_tangent(corners: [[f32; 4]; 3], b: [f32; 3]) -> [f32; 4] {
    std::array::from_fn(|k| b[0] * corners[0][k] + b[1] * corners[1][k] + b[2] * corners[2][k])
}

/// The occlusion a texel's red channel gives at `strength`: `1 + strength·(r − 1)`.
#[inline]
pub fn occlusion(strength: f32, r: f32) -> f32 {
    let unit = |x: f32| if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) };
    1.0 + unit(strength) * (unit(r) - 1.0)
}

/// The Blinn-Phong exponent matched to a GGX roughness (`s = 2/α² − 2`, the Beckmann match,
/// clamped to [1, 2048]): a metallic-roughness material's `shininess` summary, which the
/// planner's light culling and the indirect light's bounce read.
pub fn shininess_from_roughness(roughness: f32) -> f32 {
    let r = if roughness.is_finite() {
        roughness.clamp(0.0, 1.0)
    } else {
        1.0
    };
    let alpha = r * r;
    let s = 2.0 / (alpha * alpha).max(1e-12) - 2.0;
    s.clamp(1.0, 2048.0)
}

/// The texture coordinates metallic-roughness shading reads its textures at: each coordinate's
/// fraction (repeat wrapping makes it the same texel) to 16 bits, as a G-buffer word holds them
/// (`pack2x16unorm`): `⌊0.5 + 65535·fract(u)⌋/65535`. A 4096-texel texture is read within 1/16
/// texel of the exact coordinate.
#[inline]
pub fn shading_uv(uv: [f32; 2]) -> [f32; 2] {
    uv.map(|x| {
        let x = if x.is_finite() { x } else { 0.0 };
        let f = (x - x.floor()).clamp(0.0, 1.0);
        (0.5 + 65535.0 * f).floor() / 65535.0
    })
}

/// A triangle's tangent for normal mapping: the unit `∂p/∂u` (xyz) and the handedness `w` = ±1
/// with which the bitangent is `w·(n × t)` along `−∂p/∂v` (glTF's V runs down the image, a
/// normal map's +Y up), from its corners and their UVs, in f64; zero where the UVs are
/// degenerate (no normal mapping there).
pub fn triangle_tangent(p: [V3; 3], uv: [[f32; 2]; 3]) -> [f32; 4] {
    let f = |a: V3| a.map(f64::from);
    let (p0, p1, p2) = (f(p[0]), f(p[1]), f(p[2]));
    let e1 = [0, 1, 2].map(|k| p1[k] - p0[k]);
    let e2 = [0, 1, 2].map(|k| p2[k] - p0[k]);
    let (du1, dv1) = (
        f64::from(uv[1][0]) - f64::from(uv[0][0]),
        f64::from(uv[1][1]) - f64::from(uv[0][1]),
    );
    let (du2, dv2) = (
        f64::from(uv[2][0]) - f64::from(uv[0][0]),
        f64::from(uv[2][1]) - f64::from(uv[0][1]),
    );
    let det = du1 * dv2 - du2 * dv1;
    if !det.is_finite() || det.abs() <= 1e-20 {
        return [0.0; 4];
    }
    let t = [0, 1, 2].map(|k| (e1[k] * dv2 - e2[k] * dv1) / det);
    let b = [0, 1, 2].map(|k| (e2[k] * du1 - e1[k] * du2) / det);
    let ng = [
        e1[1] * e2[2] - e1[2] * e2[1],
        e1[2] * e2[0] - e1[0] * e2[2],
        e1[0] * e2[1] - e1[1] * e2[0],
    ];
    let len = (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt();
    if !(len > 0.0 && len.is_finite()) {
        return [0.0; 4];
    }
    let nt = [
        ng[1] * t[2] - ng[2] * t[1],
        ng[2] * t[0] - ng[0] * t[2],
        ng[0] * t[1] - ng[1] * t[0],
    ];
    let w = if nt[0] * b[0] + nt[1] * b[1] + nt[2] * b[2] > 0.0 {
        -1.0
    } else {
        1.0
    };
    [
        (t[0] / len) as f32,
        (t[1] / len) as f32,
        (t[2] / len) as f32,
        w,
    ]
}

/// The shading normal a normal-map texel (linear RGB) gives on the front face with unit shading
/// normal `n` and [`triangle_tangent`] `tangent`: `normalize(T·x + B·y + n·z)` with
/// `(x, y, z) = (2·texel − 1) ⊙ (scale, scale, 1)`, `T` the tangent made orthogonal to `n`,
/// `B = sign(w)·(n × T)`. Unchanged where the tangent is zero or the result degenerate.
#[inline]
pub fn perturb_normal(n: V3, tangent: [f32; 4], texel: V3, scale_xy: f32) -> V3 {
    if tangent[3] == 0.0 || tangent[3].is_nan() {
        return n;
    }
    let w = if tangent[3] < 0.0 { -1.0 } else { 1.0 };
    let t3 = [tangent[0], tangent[1], tangent[2]];
    let t = normalize(sub(t3, scale(n, dot(n, t3))));
    if t == [0.0; 3] {
        return n;
    }
    let b = scale(cross(n, t), w);
    let x = (2.0 * texel[0] - 1.0) * scale_xy;
    let y = (2.0 * texel[1] - 1.0) * scale_xy;
    let z = 2.0 * texel[2] - 1.0;
    let m = normalize(add(add(scale(t, x), scale(b, y)), scale(n, z)));
    if m == [0.0; 3] { n } else { m }
}

/// The final pixel of paper eq. 2: `e + m^a⊙(c^a + I^a) + m^d⊙I^d + m^s⊙I^s`.
/// The eight arguments are the eight named terms of eq. 2; a struct would hide the mapping.
#[allow(clippy::too_many_arguments)]
#[inline]
pub fn compose(e: V3, ma: V3, ca: V3, ia: V3, md: V3, id: V3, ms: V3, is: V3) -> V3 {
    add(add(e, mul(ma, add(ca, ia))), add(mul(md, id), mul(ms, is)))
}

/// A frame's material layers, 3 channels a pixel each, as [`compose_frame`] reads them.
#[derive(Debug, Clone, Copy)]
pub struct MaterialLayers<'a> {
    /// `m^d`.
    pub diffuse: &'a Image,
    /// `m^s`.
    pub specular: &'a Image,
    /// `m^a`.
    pub ambient: &'a Image,
    /// `e`.
    pub emissive: &'a Image,
}

/// Paper eq. 2 over a frame, the one copy every single-device renderer and reference uses: per
/// pixel [`compose`] of the material layers with `I^d = c_n ⊙ illumination[0..3]`,
/// `I^s = c_n ⊙ illumination[3..6]` (`illumination` has 6 channels), `I^a = 0` and the global
/// ambient `c^a = ambient` only where `covered(pixel)`: the background takes no ambient light
/// whatever its material layers hold. 3 channels out, the illumination's size.
pub fn compose_frame(
    illumination: &Image,
    c_n: V3,
    m: MaterialLayers<'_>,
    ambient: V3,
    covered: impl Fn(usize) -> bool,
) -> Image {
    let mut out = Image::new(illumination.width, illumination.height, 3);
    for (i, px) in out.data.chunks_exact_mut(3).enumerate() {
        let rgb = |img: &Image| -> V3 { [0, 1, 2].map(|c| img.data[i * 3 + c]) };
        let l = &illumination.data[i * 6..i * 6 + 6];
        let ca = if covered(i) { ambient } else { [0.0; 3] };
        px.copy_from_slice(&compose(
            rgb(m.emissive),
            rgb(m.ambient),
            ca,
            [0.0; 3],
            rgb(m.diffuse),
            [0, 1, 2].map(|c| c_n[c] * l[c]),
            rgb(m.specular),
            [0, 1, 2].map(|c| c_n[c] * l[3 + c]),
        ));
    }
    out
}

pub use lightfold_protocol::srgb::{linear_to_srgb, srgb_to_linear};

/// Bilinear texture lookup with repeat wrapping, texel centres at +0.5; returns linear RGBA.
pub fn sample_texture(t: &Texture, uv: [f32; 2]) -> [f32; 4] {
    if t.width == 0 || t.height == 0 || t.rgba8.len() < (t.width * t.height * 4) as usize {
        return [1.0; 4];
    }
    let (w, h) = (t.width as i64, t.height as i64);
    let fu = if uv[0].is_finite() { uv[0] } else { 0.0 } * w as f32 - 0.5;
    let fv = if uv[1].is_finite() { uv[1] } else { 0.0 } * h as f32 - 0.5;
    let (x0, y0) = (fu.floor(), fv.floor());
    let (tx, ty) = (fu - x0, fv - y0);
    let texel = |x: i64, y: i64| -> [f32; 4] {
        let x = x.rem_euclid(w);
        let y = y.rem_euclid(h);
        let i = ((y * w + x) * 4) as usize;
        let c = &t.rgba8[i..i + 4];
        let f = |b: u8| b as f32 / 255.0;
        if t.srgb {
            [
                srgb_to_linear(f(c[0])),
                srgb_to_linear(f(c[1])),
                srgb_to_linear(f(c[2])),
                f(c[3]),
            ]
        } else {
            [f(c[0]), f(c[1]), f(c[2]), f(c[3])]
        }
    };
    let (x0, y0) = (x0 as i64, y0 as i64);
    let a = texel(x0, y0);
    let b = texel(x0 + 1, y0);
    let c = texel(x0, y0 + 1);
    let d = texel(x0 + 1, y0 + 1);
    let mut out = [0.0; 4];
    for k in 0..4 {
        let top = a[k] + (b[k] - a[k]) * tx;
        let bot = c[k] + (d[k] - c[k]) * tx;
        out[k] = top + (bot - top) * ty;
    }
    out
}

/// Transmittance `t` (RGB in [0, 1]) of one texel of a translucent caster: `(1 − a) + a·c⊙x`
/// under coverage (`a` = material alpha × texture alpha, clamped to [0, 1]), else `c⊙x`; `c` is
/// the transmission colour and `x` the diffuse texture's colour (white without one). A shadow
/// ray keeps the product of the `t` of the translucent texels it passes (`docs/translucency.md`).
/// Non-finite inputs count as 0: opaque.
#[inline]
pub fn transmittance(tr: &crate::model::Transmission, alpha: f32, texture_rgb: V3) -> V3 {
    let covered = [0, 1, 2].map(|k| unit(tr.color[k]) * unit(texture_rgb[k]));
    if tr.coverage {
        let a = unit(alpha);
        covered.map(|c| (1.0 - a) + a * c)
    } else {
        covered
    }
}

/// A value clamped to [0, 1], non-finite counted as 0.
#[inline]
fn unit(x: f32) -> f32 {
    if x.is_finite() {
        x.clamp(0.0, 1.0)
    } else {
        0.0
    }
}

/// What the eye sees of one texel of a translucent surface when translucency is peeled
/// ([`eye_cover`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EyeCover {
    /// `a`: the share of the pixel the surface's own colour covers; its four material layers
    /// (`m^d`, `m^s`, `m^a`, `e`) are multiplied by it.
    pub coverage: f32,
    /// `T` (RGB): what it lets through of what lies behind it.
    pub transmittance: V3,
}

/// The eye's view of one texel of translucent `tr` when translucency is peeled into layers
/// (`docs/translucency.md`), `alpha` the material's alpha and `texel` the diffuse texture's
/// linear RGBA there (white without one):
/// - coverage (glTF BLEND): `a = α · texel alpha` clamped to [0, 1], `T = 1 − a` in all three
///   channels (the covered share is the surface's own colour, not a filter);
/// - a filter (glass): `a = 1`, `T = c ⊙ texel rgb` ([`transmittance`], clamped).
///
/// Non-finite inputs count as 0 (a NaN coverage covers nothing).
#[inline]
pub fn eye_cover(tr: &crate::model::Transmission, alpha: f32, texel: [f32; 4]) -> EyeCover {
    if tr.coverage {
        let a = unit(alpha * texel[3]);
        EyeCover {
            coverage: a,
            transmittance: [1.0 - a; 3],
        }
    } else {
        EyeCover {
            coverage: 1.0,
            transmittance: transmittance(tr, alpha * texel[3], [texel[0], texel[1], texel[2]]),
        }
    }
}

impl MetallicRoughness {
    /// The layer values at the factors, untextured (`metallic_roughness_point`
    /// with white textures): `(m^d, m^s, m^a)` = `(c_diff ⊙ (1 − F0), 1, m^d)`.
    pub fn summary(&self) -> ([f32; 3], [f32; 3], [f32; 3]) {
        let at = metallic_roughness_point(self, [1.0; 4], [1.0; 4]);
        (at.diffuse, [1.0; 3], at.diffuse)
    }
}

impl Material {
    /// A glTF metallic-roughness material with no textures, opaque and double-sided.
    pub fn metallic_roughness(name: &str, pbr: MetallicRoughness) -> Self {
        let (diffuse, specular, ambient) = pbr.summary();
        Material {
            name: name.to_string(),
            diffuse,
            diffuse_texture: None,
            specular,
            shininess: shininess_from_roughness(pbr.roughness),
            ambient,
            emissive: [0.0; 3],
            alpha: 1.0,
            alpha_mode: AlphaMode::Opaque,
            double_sided: true,
            transmission: None,
            pbr: Some(pbr),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn compose_frame_is_eq_2_with_ambient_only_where_covered() {
        // Two pixels with the same layers; the second is background.
        let layer = |v: V3| {
            let mut img = Image::new(2, 1, 3);
            img.data = [v, v].concat();
            img
        };
        let (md, ms, ma, e) = (
            layer([0.5, 0.25, 1.0]),
            layer([0.1, 0.2, 0.3]),
            layer([0.4, 0.4, 0.4]),
            layer([0.01, 0.02, 0.03]),
        );
        let mut il = Image::new(2, 1, 6);
        il.data = [[2.0, 4.0, 8.0, 1.0, 1.0, 1.0]; 2].concat();
        let m = MaterialLayers {
            diffuse: &md,
            specular: &ms,
            ambient: &ma,
            emissive: &e,
        };
        let out = compose_frame(&il, [1.0, 0.5, 1.0], m, [0.5; 3], |i| i == 0);
        // By hand: e + m^a·c^a + m^d·c_n·I^d + m^s·c_n·I^s, c^a only on the covered pixel.
        let covered = [
            0.01 + 0.4 * 0.5 + 0.5 * 2.0 + 0.1,
            0.02 + 0.4 * 0.5 + 0.25 * 2.0 + 0.2 * 0.5,
            0.03 + 0.4 * 0.5 + 1.0 * 8.0 + 0.3,
        ];
        let background = [0.01 + 1.0 + 0.1, 0.02 + 0.5 + 0.1, 0.03 + 8.0 + 0.3];
        for (k, want) in covered.iter().chain(&background).enumerate() {
            assert!(
                (out.data[k] - want).abs() < 1e-6,
                "{k}: {} vs {want}",
                out.data[k]
            );
        }
        // The same bits as `compose`, pixel by pixel.
        let p = compose(
            [0.01, 0.02, 0.03],
            [0.4; 3],
            [0.5; 3],
            [0.0; 3],
            [0.5, 0.25, 1.0],
            [2.0, 2.0, 8.0],
            [0.1, 0.2, 0.3],
            [1.0, 0.5, 1.0],
        );
        assert_eq!(out.data[..3], p);
    }
}
