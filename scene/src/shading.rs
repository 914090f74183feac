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

use crate::model::{LightSample, SampleKind, Texture};
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

/// The final pixel of paper eq. 2: `e + m^a⊙(c^a + I^a) + m^d⊙I^d + m^s⊙I^s`.
/// The eight arguments are the eight named terms of eq. 2; a struct would hide the mapping.
#[allow(clippy::too_many_arguments)]
#[inline]
pub fn compose(e: V3, ma: V3, ca: V3, ia: V3, md: V3, id: V3, ms: V3, is: V3) -> V3 {
    add(add(e, mul(ma, add(ca, ia))), add(mul(md, id), mul(ms, is)))
}

/// sRGB transfer of a linear value in [0, 1].
#[inline]
pub fn linear_to_srgb(x: f32) -> f32 {
    let x = if x.is_finite() {
        x.clamp(0.0, 1.0)
    } else {
        0.0
    };
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// Inverse sRGB transfer.
#[inline]
pub fn srgb_to_linear(x: f32) -> f32 {
    if x <= 0.040_45 {
        x / 12.92
    } else {
        ((x + 0.055) / 1.055).powf(2.4)
    }
}

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
    let unit = |x: f32| {
        if x.is_finite() {
            x.clamp(0.0, 1.0)
        } else {
            0.0
        }
    };
    let covered = [0, 1, 2].map(|k| unit(tr.color[k]) * unit(texture_rgb[k]));
    if tr.coverage {
        let a = unit(alpha);
        covered.map(|c| (1.0 - a) + a * c)
    } else {
        covered
    }
}
