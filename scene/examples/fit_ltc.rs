//! Fits the Linearly Transformed Cosines (LTC) table of lightfold's GGX specular lobe, after
//! Heitz, Dupuy, Hill & Neubelt, "Real-Time Polygonal-Light Shading with Linearly Transformed
//! Cosines" (SIGGRAPH 2016). Run as
//!
//! ```text
//! cargo run --release -p lightfold-scene --example fit_ltc -- scene/data/ltc_ggx.bin
//! ```
//!
//! **Target.** In the local frame `n = +z`, `v = (sin θ, 0, cos θ)`, the cosine-weighted BRDF
//! `f_cos(l) = D(n·h)·V(n·l, n·v)·(n·l)` (Fresnel 1; `D` = [`ggx_d`], `V` = [`smith_visibility`],
//! zero for `n·l ≤ 0`), normalised to a pdf by `norm = ∫ f_cos dω`.
//!
//! **Method.** An LTC is `D(ω) = D_o(ω_o)·|M⁻¹|/|M⁻¹ω|³`, `ω_o = M⁻¹ω/|M⁻¹ω|`, `D_o = max(z, 0)/π`.
//! Per cell `M = [X Y Z]·[[m11, 0, m13], [0, m22, 0], [0, 0, 1]]`, with `Z` the lobe's average
//! direction `∫ f_cos·l dω` (in the xz plane), `Y = +y`, `X = Y × Z`; the optimiser works on
//! `(ln m11, ln m22, m13/m11)` (the same family of `M`: the logs keep the scales positive, which
//! loses nothing as `D` is unchanged by negating a column of the scale-shear matrix, and the
//! scaled shear keeps the simplex well conditioned for narrow lobes, where `m11 ~ α`). At normal
//! incidence the lobe is isotropic, so there the fit has the single parameter `m11 = m22`,
//! `m13 = 0`. Nelder–Mead minimises Heitz's error: with `p_b = f_cos/norm` and `p_l` the LTC,
//! both importance-sampled on a fixed 32×32 stratified set (the LTC by transforming a
//! cosine-weighted sample; the BRDF through GGX visible normals, pdf `q_b`),
//! `E = mean |p_b − p_l|³/(p_l + q_b)`. Cells are visited as in Heitz's fitter: roughness from
//! rough to smooth, θ from normal to grazing, each fit starting from the previous θ of its
//! roughness (normal incidence: from the next rougher row), the roughest normal-incidence cell
//! from the identity.
//!
//! **Integrals.** `norm`, `fresnel = ∫ f_cos·schlick_weight(v·h) dω` and the average direction are
//! computed by deterministic quadrature over the half vector (see [`Brdf::integrals`]): the GGX
//! CDF angle `w` (`tan θ_h = α·tan w`) absorbs `D`, the horizon is an exact bound
//! `θ_h < β/2 + π/4`, adaptive Simpson in `w`, trapezoid in `φ`; refinement changes the results by
//! under 1e-5. (Stratified visible-normal sampling with 256² samples was off by up to 7e-4: its
//! strata cannot resolve the horizon cut in the lobe's tail.) `D` is evaluated in f64 in the
//! cancellation-free form `α²|l+v|⁴/(π((l+v)ₓ² + (l+v)ᵧ² + α²(l+v)_z²)²)` (the crate's f32
//! [`ggx_d`] now takes the same form, `α²/(π(|n × h|² + α²(n·h)²)²)`; the table was fitted when it
//! still computed `1 − (n·h)²`, which cannot resolve the `α = 10⁻³` lobe in f32), checked at
//! start-up against [`ggx_d`]; `V` and Schlick's weight are the crate's functions.
//!
//! **Table convention** (`scene/data/ltc_ggx.bin`, 64·64·8 little-endian f32 = 131072 bytes, no
//! header). Row `i` in 0..64: roughness `r = i/63`, `α = ggx_alpha(r)`. Column `j` in 0..64:
//! `t = j/63`, `cos θ = 1 − t²` (`t = √(1 − cos θ)`), θ clamped to at most 89.5° for the fit.
//! Cell `(i, j)` at `i·64 + j` holds `[a, b, c, d, norm, fresnel, 0, 0]` where the inverse matrix
//! `M⁻¹ = [[a, 0, b], [0, 1, 0], [c, 0, d]]` (row-major, scaled so its middle entry is 1) maps a
//! direction `(x, y, z)` of the lobe to `(a·x + b·z, y, c·x + d·z)` in the clamped cosine's space.
//! A polygonal light's `∫ f_cos dω ≈ norm · E(M⁻¹·P)` with `E` the clamped (z ≥ 0) edge integral.
//!
//! After writing the table the fitter reads it back and prints a check: for a grid of roughness
//! and view angles and a few rectangles, the brute-force area integral of `f_cos` against the LTC
//! estimate from the bilinearly interpolated table and from a fresh fit at the exact parameters.

use lightfold_scene::ltc;
use lightfold_scene::shading::{MIN_ALPHA, ggx_alpha, ggx_d, schlick_weight, smith_visibility};
use std::f64::consts::PI;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

type V3 = [f64; 3];
type M3 = [[f64; 3]; 3];

const N: usize = 64;
const FIT_SAMPLES: usize = 32;
const PHI_STEPS: usize = 128;
const QUAD_TOL: f64 = 1e-7;
const MAX_THETA_DEG: f64 = 89.5;

fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
fn len(a: V3) -> f64 {
    dot(a, a).sqrt()
}
fn norm3(a: V3) -> V3 {
    let l = len(a);
    [a[0] / l, a[1] / l, a[2] / l]
}
fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn scale(a: V3, s: f64) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}
fn mat_vec(m: &M3, v: V3) -> V3 {
    [dot(m[0], v), dot(m[1], v), dot(m[2], v)]
}
fn mat_mul(a: &M3, b: &M3) -> M3 {
    let mut r = [[0.0; 3]; 3];
    for (i, row) in r.iter_mut().enumerate() {
        for (j, x) in row.iter_mut().enumerate() {
            *x = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    r
}
fn det(m: &M3) -> f64 {
    dot(m[0], cross(m[1], m[2]))
}
fn inverse(m: &M3) -> M3 {
    // Column k of the inverse is (row k+1 × row k+2)/det: row i · that column = det·δᵢₖ.
    let d = det(m);
    let c0 = cross(m[1], m[2]);
    let c1 = cross(m[2], m[0]);
    let c2 = cross(m[0], m[1]);
    [
        [c0[0] / d, c1[0] / d, c2[0] / d],
        [c0[1] / d, c1[1] / d, c2[1] / d],
        [c0[2] / d, c1[2] / d, c2[2] / d],
    ]
}

/// `cos θ` of table column `j` before the grazing clamp.
fn column_cos(j: usize) -> f64 {
    let t = j as f64 / (N - 1) as f64;
    1.0 - t * t
}
fn clamp_cos(c: f64) -> f64 {
    c.max(MAX_THETA_DEG.to_radians().cos())
}
fn row_alpha(i: usize) -> f64 {
    f64::from(ggx_alpha(i as f32 / (N - 1) as f32))
}

/// The GGX lobe for one view.
#[derive(Debug, Clone, Copy)]
struct Brdf {
    alpha: f64,
    a2: f64,
    v: V3,
    nv: f64,
    /// Smith `G1(v)`, the visible-normal distribution's normalisation.
    g1v: f64,
}

impl Brdf {
    fn new(alpha: f64, cos_theta: f64) -> Self {
        let nv = cos_theta;
        let v = [(1.0 - nv * nv).max(0.0).sqrt(), 0.0, nv];
        let a2 = alpha * alpha;
        let g1v = 2.0 * nv / (nv + (a2 + (1.0 - a2) * nv * nv).sqrt());
        Self {
            alpha,
            a2,
            v,
            nv,
            g1v,
        }
    }

    /// GGX `D` of the half vector `h = normalize(hh)` (upper hemisphere), in f64 without the
    /// `1 − (n·h)²` cancellation.
    fn d_of(&self, hh: V3) -> f64 {
        if hh[2] <= 0.0 {
            return 0.0;
        }
        let hl2 = dot(hh, hh);
        let q = hh[0] * hh[0] + hh[1] * hh[1] + self.a2 * hh[2] * hh[2];
        self.a2 * hl2 * hl2 / (PI * q * q)
    }

    /// `(f_cos, q, w)` at unit `l`: the cosine-weighted BRDF, the visible-normal sampling pdf of
    /// `l` and Schlick's weight.
    fn eval(&self, l: V3) -> (f64, f64, f64) {
        let hh = add(l, self.v);
        let d = self.d_of(hh);
        let q = self.g1v * d / (4.0 * self.nv);
        let nl = l[2];
        if nl <= 0.0 {
            return (0.0, q, 0.0);
        }
        let vis = f64::from(smith_visibility(
            nl as f32,
            self.nv as f32,
            self.alpha as f32,
        ));
        let vh = dot(self.v, hh) / len(hh);
        let w = f64::from(schlick_weight(vh as f32));
        (d * vis * nl, q, w)
    }

    /// Reflects `v` about a GGX visible normal (Heitz 2018's sampling of the visible normals).
    fn sample(&self, u1: f64, u2: f64) -> V3 {
        let a = self.alpha;
        let vh = norm3([a * self.v[0], a * self.v[1], self.v[2]]);
        let lensq = vh[0] * vh[0] + vh[1] * vh[1];
        let t1v = if lensq > 0.0 {
            scale([-vh[1], vh[0], 0.0], 1.0 / lensq.sqrt())
        } else {
            [1.0, 0.0, 0.0]
        };
        let t2v = cross(vh, t1v);
        let r = u1.sqrt();
        let phi = 2.0 * PI * u2;
        let t1 = r * phi.cos();
        let mut t2 = r * phi.sin();
        let s = 0.5 * (1.0 + vh[2]);
        t2 = (1.0 - s) * (1.0 - t1 * t1).max(0.0).sqrt() + s * t2;
        let tz = (1.0 - t1 * t1 - t2 * t2).max(0.0).sqrt();
        let nh = add(add(scale(t1v, t1), scale(t2v, t2)), scale(vh, tz));
        let h = norm3([a * nh[0], a * nh[1], nh[2].max(0.0)]);
        sub(scale(h, 2.0 * dot(self.v, h)), self.v)
    }

    /// `(norm, fresnel, average direction)` by quadrature over the half vector
    /// `h = (sin θ cos φ, sin θ sin φ, cos θ)`. With `tan θ = α·tan w` (the GGX CDF's angle),
    /// `D(h)·sin θ·dθ = sin w·√(cos²w + α²sin²w)/π·dw`, so the inner integrand
    /// `f_cos(l)·4(v·h)` (the Jacobian of `l = 2(v·h)h − v`) without `D` is smooth in `w`, and
    /// `l` lies above the horizon exactly for `θ < θ*(φ) = β/2 + π/4`, `β = atan2(sin θ_v cos φ,
    /// cos θ_v)` (then `v·h > 0` too): adaptive Simpson in `w` up to that cut, the trapezoid rule
    /// (spectral for this smooth periodic integrand) over `φ`, halved by the lobe's y symmetry.
    fn integrals(&self, k_phi: usize, tol: f64) -> (f64, f64, V3) {
        let (sv, cv, a) = (self.v[0], self.v[2], self.alpha);
        let mut acc = [0.0f64; 4];
        for k in 0..=k_phi {
            let phi = PI * k as f64 / k_phi as f64;
            let wk = if k == 0 || k == k_phi { 0.5 } else { 1.0 } * PI / k_phi as f64;
            let (sp, cp) = phi.sin_cos();
            let beta = (sv * cp).atan2(cv);
            let theta_max = 0.5 * beta + 0.25 * PI;
            let w_max = (theta_max.tan() / a).atan();
            let inner = |w: f64| -> [f64; 4] {
                let (sw, cw) = w.sin_cos();
                let theta = (a * sw).atan2(cw);
                let (st, ct) = theta.sin_cos();
                let h = [st * cp, st * sp, ct];
                let vh = sv * h[0] + cv * h[2];
                let l = sub(scale(h, 2.0 * vh), self.v);
                let nl = l[2];
                if nl <= 0.0 || vh <= 0.0 {
                    return [0.0; 4];
                }
                let vis = f64::from(smith_visibility(nl as f32, self.nv as f32, a as f32));
                let jac = sw * (cw * cw + a * a * sw * sw).sqrt() / PI;
                let f = jac * vis * nl * 4.0 * vh;
                let fw = f * f64::from(schlick_weight(vh as f32));
                [f, fw, f * l[0], f * l[2]]
            };
            let line = adaptive_simpson(&inner, 0.0, w_max, tol);
            for (x, y) in acc.iter_mut().zip(line) {
                *x += 2.0 * wk * y;
            }
        }
        (acc[0], acc[1], [acc[2], 0.0, acc[3]])
    }
}

/// A linearly transformed cosine.
#[derive(Debug, Clone, Copy)]
struct Ltc {
    m: M3,
    minv: M3,
    det_minv: f64,
}

impl Ltc {
    /// `M = [X Y Z]·[[m11, 0, m13], [0, m22, 0], [0, 0, 1]]`, `Z` the unit lobe direction in the
    /// xz plane.
    fn new(z: V3, m11: f64, m22: f64, m13: f64) -> Self {
        let y = [0.0, 1.0, 0.0];
        let x = cross(y, z);
        let frame = [[x[0], y[0], z[0]], [x[1], y[1], z[1]], [x[2], y[2], z[2]]];
        let s = [[m11, 0.0, m13], [0.0, m22, 0.0], [0.0, 0.0, 1.0]];
        let m = mat_mul(&frame, &s);
        Self::from_minv(inverse(&m))
    }
    fn from_minv(minv: M3) -> Self {
        Self {
            m: inverse(&minv),
            minv,
            det_minv: det(&minv).abs(),
        }
    }
    fn eval(&self, l: V3) -> f64 {
        let w = mat_vec(&self.minv, l);
        let lw = len(w);
        let z = w[2] / lw;
        if z <= 0.0 {
            return 0.0;
        }
        z / PI * self.det_minv / (lw * lw * lw)
    }
    fn sample(&self, u1: f64, u2: f64) -> V3 {
        let r = u1.sqrt();
        let phi = 2.0 * PI * u2;
        let wo = [r * phi.cos(), r * phi.sin(), (1.0 - u1).max(0.0).sqrt()];
        norm3(mat_vec(&self.m, wo))
    }
    /// `M⁻¹` scaled so its middle entry is 1, as `[a, b, c, d]`.
    fn table_entry(&self) -> [f64; 4] {
        let s = 1.0 / self.minv[1][1];
        [
            self.minv[0][0] * s,
            self.minv[0][2] * s,
            self.minv[2][0] * s,
            self.minv[2][2] * s,
        ]
    }
}

/// The fit's parameters: `(ln m11, ln m22, m13/m11)`.
type Params = [f64; 3];

fn ltc_of(z: V3, p: &Params) -> Ltc {
    let m11 = p[0].exp();
    Ltc::new(z, m11, p[1].exp(), p[2] * m11)
}

/// `∫ₐᵇ f` (vector-valued) by adaptive Simpson, to absolute error about `tol` in the first two
/// components.
fn adaptive_simpson(f: &dyn Fn(f64) -> [f64; 4], a: f64, b: f64, tol: f64) -> [f64; 4] {
    fn simpson(fa: &[f64; 4], fm: &[f64; 4], fb: &[f64; 4], h: f64) -> [f64; 4] {
        std::array::from_fn(|k| h / 6.0 * (fa[k] + 4.0 * fm[k] + fb[k]))
    }
    #[allow(clippy::too_many_arguments)]
    fn rec(
        f: &dyn Fn(f64) -> [f64; 4],
        a: f64,
        b: f64,
        fa: [f64; 4],
        fm: [f64; 4],
        fb: [f64; 4],
        whole: [f64; 4],
        tol: f64,
        depth: u32,
    ) -> [f64; 4] {
        let m = 0.5 * (a + b);
        let (lm, rm) = (0.5 * (a + m), 0.5 * (m + b));
        let (flm, frm) = (f(lm), f(rm));
        let left = simpson(&fa, &flm, &fm, m - a);
        let right = simpson(&fm, &frm, &fb, b - m);
        let err = (0..2)
            .map(|k| (left[k] + right[k] - whole[k]).abs())
            .fold(0.0, f64::max);
        if depth == 0 || err <= 15.0 * tol {
            return std::array::from_fn(|k| {
                left[k] + right[k] + (left[k] + right[k] - whole[k]) / 15.0
            });
        }
        let l = rec(f, a, m, fa, flm, fm, left, 0.5 * tol, depth - 1);
        let r = rec(f, m, b, fm, frm, fb, right, 0.5 * tol, depth - 1);
        std::array::from_fn(|k| l[k] + r[k])
    }
    let panels = 16;
    let mut out = [0.0; 4];
    for p in 0..panels {
        let x0 = a + (b - a) * p as f64 / panels as f64;
        let x1 = a + (b - a) * (p + 1) as f64 / panels as f64;
        let (f0, fm, f1) = (f(x0), f(0.5 * (x0 + x1)), f(x1));
        let whole = simpson(&f0, &fm, &f1, x1 - x0);
        let r = rec(f, x0, x1, f0, fm, f1, whole, tol / panels as f64, 18);
        for (o, x) in out.iter_mut().zip(r) {
            *o += x;
        }
    }
    out
}

/// Heitz's error of `ltc` against the normalised lobe.
fn fit_error(ltc: &Ltc, brdf: &Brdf, norm: f64) -> f64 {
    let n = FIT_SAMPLES;
    let mut err = 0.0;
    let mut term = |l: V3| {
        let (f, q, _) = brdf.eval(l);
        let pb = f / norm;
        let pl = ltc.eval(l);
        let den = pl + q;
        if den > 0.0 {
            let e = (pb - pl).abs();
            err += e * e * e / den;
        }
    };
    for j in 0..n {
        for i in 0..n {
            let u1 = (i as f64 + 0.5) / n as f64;
            let u2 = (j as f64 + 0.5) / n as f64;
            term(ltc.sample(u1, u2));
            term(brdf.sample(u1, u2));
        }
    }
    err / (n * n) as f64
}

/// Nelder–Mead on `f` from `x0` with initial step `step`; returns the best point and value.
fn nelder_mead(
    f: &dyn Fn(&[f64]) -> f64,
    x0: &[f64],
    step: f64,
    max_iter: usize,
) -> (Vec<f64>, f64) {
    let n = x0.len();
    let mut pts: Vec<Vec<f64>> = vec![x0.to_vec()];
    for i in 0..n {
        let mut p = x0.to_vec();
        p[i] += step;
        pts.push(p);
    }
    let mut vals: Vec<f64> = pts.iter().map(|p| f(p)).collect();
    for _ in 0..max_iter {
        let mut order: Vec<usize> = (0..=n).collect();
        order.sort_by(|&a, &b| vals[a].total_cmp(&vals[b]));
        pts = order.iter().map(|&i| pts[i].clone()).collect();
        vals = order.iter().map(|&i| vals[i]).collect();
        let (best, worst) = (vals[0], vals[n]);
        let size = pts[1..]
            .iter()
            .map(|p| {
                p.iter()
                    .zip(&pts[0])
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max)
            })
            .fold(0.0, f64::max);
        if size < 1e-7 || (worst - best).abs() <= 1e-10 * best.abs() {
            break;
        }
        let centroid: Vec<f64> = (0..n)
            .map(|k| pts[..n].iter().map(|p| p[k]).sum::<f64>() / n as f64)
            .collect();
        let along = |t: f64| -> Vec<f64> {
            (0..n)
                .map(|k| centroid[k] + t * (pts[n][k] - centroid[k]))
                .collect()
        };
        let xr = along(-1.0);
        let fr = f(&xr);
        if fr < vals[0] {
            let xe = along(-2.0);
            let fe = f(&xe);
            if fe < fr {
                pts[n] = xe;
                vals[n] = fe;
            } else {
                pts[n] = xr;
                vals[n] = fr;
            }
        } else if fr < vals[n - 1] {
            pts[n] = xr;
            vals[n] = fr;
        } else {
            let (xc, fc) = if fr < vals[n] {
                let xc = along(-0.5);
                let fc = f(&xc);
                (xc, fc)
            } else {
                let xc = along(0.5);
                let fc = f(&xc);
                (xc, fc)
            };
            if fc < vals[n].min(fr) {
                pts[n] = xc;
                vals[n] = fc;
            } else {
                for i in 1..=n {
                    let p: Vec<f64> = (0..n)
                        .map(|k| pts[0][k] + 0.5 * (pts[i][k] - pts[0][k]))
                        .collect();
                    vals[i] = f(&p);
                    pts[i] = p;
                }
            }
        }
    }
    let b = (0..=n)
        .min_by(|&a, &b| vals[a].total_cmp(&vals[b]))
        .unwrap_or(0);
    (pts[b].clone(), vals[b])
}

/// The lobe's integrals and the fit's frame for one cell.
#[derive(Debug, Clone, Copy)]
struct CellSetup {
    brdf: Brdf,
    norm: f64,
    fresnel: f64,
    z: V3,
    isotropic: bool,
}

fn setup(alpha: f64, cos_theta: f64) -> CellSetup {
    let isotropic = cos_theta >= 1.0;
    let brdf = Brdf::new(alpha, cos_theta);
    let (norm, fresnel, avg) = brdf.integrals(PHI_STEPS, QUAD_TOL);
    let z = if isotropic {
        [0.0, 0.0, 1.0]
    } else {
        norm3([avg[0], 0.0, avg[2]])
    };
    CellSetup {
        brdf,
        norm,
        fresnel,
        z,
        isotropic,
    }
}

/// Fits one cell from `start`, restarting Nelder–Mead from its result until it stops improving.
fn fit(cs: &CellSetup, start: &Params) -> (Params, f64) {
    let err = |p: &Params| fit_error(&ltc_of(cs.z, p), &cs.brdf, cs.norm);
    let mut best = *start;
    if cs.isotropic {
        best[1] = best[0];
        best[2] = 0.0;
    }
    let mut best_e = err(&best);
    for round in 0..4 {
        let step = if round == 0 { 0.1 } else { 0.02 };
        let (x, e) = if cs.isotropic {
            let (x, e) = nelder_mead(&|x: &[f64]| err(&[x[0], x[0], 0.0]), &best[..1], step, 400);
            ([x[0], x[0], 0.0], e)
        } else {
            let (x, e) = nelder_mead(&|x: &[f64]| err(&[x[0], x[1], x[2]]), &best, step, 600);
            ([x[0], x[1], x[2]], e)
        };
        let improved = e < best_e * (1.0 - 1e-6);
        if e < best_e {
            best = x;
            best_e = e;
        }
        if !improved && round > 0 {
            break;
        }
    }
    (best, best_e)
}

#[derive(Debug, Clone, Copy, Default)]
struct Cell {
    entry: [f64; 4],
    norm: f64,
    fresnel: f64,
    params: Params,
    err: f64,
}

fn fit_cell(i: usize, j: usize, start: &Params) -> Cell {
    let cs = setup(row_alpha(i), clamp_cos(column_cos(j)));
    let (params, err) = fit(&cs, start);
    Cell {
        entry: ltc_of(cs.z, &params).table_entry(),
        norm: cs.norm,
        fresnel: cs.fresnel,
        params,
        err,
    }
}

/// Runs `work(k)` for k in 0..count on two threads; results in order.
fn parallel<T: Send>(count: usize, work: impl Fn(usize) -> T + Sync) -> Vec<T> {
    let threads = std::thread::available_parallelism()
        .map_or(2, |n| n.get())
        .clamp(1, 8);
    let next = AtomicUsize::new(0);
    let mut out: Vec<Option<T>> = (0..count).map(|_| None).collect();
    let results: Vec<Vec<(usize, T)>> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads)
            .map(|_| {
                s.spawn(|| {
                    let mut mine = Vec::new();
                    loop {
                        let k = next.fetch_add(1, Ordering::Relaxed);
                        if k >= count {
                            break;
                        }
                        mine.push((k, work(k)));
                    }
                    mine
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("worker panicked"))
            .collect()
    });
    for (k, t) in results.into_iter().flatten() {
        out[k] = Some(t);
    }
    out.into_iter()
        .map(|t| t.expect("every item computed"))
        .collect()
}

/// The normal-incidence column, rough to smooth (each cell starting from the rougher one): each
/// row's start.
fn normal_incidence_column() -> Vec<Cell> {
    let mut column0 = vec![Cell::default(); N];
    let mut start: Params = [0.0, 0.0, 0.0];
    for i in (0..N).rev() {
        column0[i] = fit_cell(i, 0, &start);
        start = column0[i].params;
    }
    column0
}

/// Row `i` from its normal-incidence cell towards grazing.
fn fit_row(i: usize, first: Cell) -> Vec<Cell> {
    let mut row = vec![first; N];
    for j in 1..N {
        row[j] = fit_cell(i, j, &row[j - 1].params);
    }
    row
}

fn fit_table() -> Vec<Cell> {
    let column0 = normal_incidence_column();
    eprintln!("normal-incidence column fitted");
    let t0 = Instant::now();
    let rows = parallel(N, |i| {
        let row = fit_row(i, column0[i]);
        eprintln!("row {i} fitted ({:.1} s)", t0.elapsed().as_secs_f64());
        row
    });
    rows.into_iter().flatten().collect()
}

/// A cell as the table file stores it.
fn stored(c: &Cell) -> [f32; 8] {
    let e = c.entry;
    [e[0], e[1], e[2], e[3], c.norm, c.fresnel, 0.0, 0.0].map(|x| x as f32)
}

fn write_table(path: &str, cells: &[Cell]) -> std::io::Result<()> {
    let mut bytes = Vec::with_capacity(N * N * 32);
    for c in cells {
        for x in stored(c) {
            bytes.extend_from_slice(&x.to_le_bytes());
        }
    }
    if let Some(dir) = std::path::Path::new(path).parent()
        && !dir.as_os_str().is_empty()
    {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(path, bytes)
}

fn read_table(path: &str) -> std::io::Result<Vec<[f32; 8]>> {
    let bytes = std::fs::read(path)?;
    assert_eq!(bytes.len(), N * N * 32, "table size");
    Ok(ltc::parse_table(&bytes))
}

/// A parallelogram light `corner + s·e1 + t·e2`, s, t ∈ [0, 1].
#[derive(Debug, Clone, Copy)]
struct Rect {
    name: &'static str,
    corner: V3,
    e1: V3,
    e2: V3,
}

impl Rect {
    /// A w×w square centred at `c`, facing the origin, `up` roughly along its second edge.
    fn facing(name: &'static str, c: V3, w: f64, up: V3) -> Self {
        let nrm = norm3(scale(c, -1.0));
        let e1 = scale(norm3(cross(up, nrm)), w);
        let e2 = scale(norm3(cross(nrm, e1)), w);
        Self {
            name,
            corner: sub(c, scale(add(e1, e2), 0.5)),
            e1,
            e2,
        }
    }
    fn verts(&self) -> [V3; 4] {
        [
            self.corner,
            add(self.corner, self.e1),
            add(add(self.corner, self.e1), self.e2),
            add(self.corner, self.e2),
        ]
    }
    /// `∫ f_cos dω` by the midpoint rule on an `n×n` grid of the rectangle's area.
    fn brute_force(&self, brdf: &Brdf, n: usize) -> f64 {
        let c = cross(self.e1, self.e2);
        let area = len(c);
        let nrm = scale(c, 1.0 / area);
        let da = area / (n * n) as f64;
        let mut sum = 0.0;
        for j in 0..n {
            let t = (j as f64 + 0.5) / n as f64;
            let row = add(self.corner, scale(self.e2, t));
            for i in 0..n {
                let s = (i as f64 + 0.5) / n as f64;
                let p = add(row, scale(self.e1, s));
                let r2 = dot(p, p);
                let r = r2.sqrt();
                let l = scale(p, 1.0 / r);
                let (f, _, _) = brdf.eval(l);
                if f > 0.0 {
                    sum += f * dot(nrm, l).abs() / r2;
                }
            }
        }
        sum * da
    }
    /// The shipped polygon integral (`scene::ltc`, f32) of the rectangle through `minv`.
    fn ltc(&self, minv: &M3) -> f64 {
        let v = self.verts().map(|p| mat_vec(minv, p).map(|c| c as f32));
        f64::from(ltc::clipped_cosine_integral(&v))
    }
}

fn rects(theta_deg: f64) -> Vec<Rect> {
    // The mirror direction, raised so the whole square (half-angle ≈ 14°) stays above the horizon.
    let elev = (90.0 - theta_deg).max(16.0).to_radians();
    let peak = scale([-elev.cos(), 0.0, elev.sin()], 2.0);
    vec![
        Rect {
            name: "above",
            corner: [-0.5, -0.5, 2.0],
            e1: [1.0, 0.0, 0.0],
            e2: [0.0, 1.0, 0.0],
        },
        // 1×1, centred at (-0.6, 0.4, 1.5), tilted 40° about y and 25° about x.
        {
            let (a, b) = (40f64.to_radians(), 25f64.to_radians());
            let e1 = [a.cos(), 0.0, a.sin()];
            let e2 = [0.0, b.cos(), b.sin()];
            Rect {
                name: "tilted",
                corner: sub([-0.6, 0.4, 1.5], scale(add(e1, e2), 0.5)),
                e1,
                e2,
            }
        },
        Rect::facing("peak", peak, 1.0, [0.0, 1.0, 0.0]),
        Rect::facing("side", [0.0, 2.0, 0.8], 1.0, [0.0, 0.0, 1.0]),
        Rect::facing("big", [-1.0, 0.5, 1.0], 3.0, [0.0, 0.0, 1.0]),
    ]
}

/// Cross-checks the f64 `D` against the crate's f32 [`ggx_d`] where f32 is well conditioned.
fn check_d() {
    let mut worst: f64 = 0.0;
    for &alpha in &[0.05f64, 0.1, 0.3, 0.7, 1.0] {
        let brdf = Brdf::new(alpha, 0.7);
        for k in 0..200 {
            let th = (k as f64 / 200.0) * 1.5;
            let ph = k as f64 * 2.4;
            let h = [th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()];
            let ours = brdf.d_of(scale(h, 1.7));
            let theirs = f64::from(ggx_d([0.0, 0.0, 1.0], h.map(|c| c as f32), alpha as f32));
            worst = worst.max((ours - theirs).abs() / theirs);
        }
    }
    assert!(
        worst < 1e-4,
        "f64 GGX D disagrees with shading::ggx_d: {worst:e}"
    );
    println!("f64 D vs shading::ggx_d (alpha >= 0.05): max rel diff {worst:.1e}");
}

/// The quadrature of `norm` and `fresnel` against the closed form `1 − ln 2` (α = 1, normal
/// incidence) and against itself with 4× the φ steps and a tenth of the tolerance.
fn check_integrals() {
    let (n, _, _) = Brdf::new(1.0, 1.0).integrals(PHI_STEPS, QUAD_TOL);
    let exact = 1.0 - 2f64.ln();
    let mut worst: f64 = 0.0;
    for i in [0usize, 3, 10, 20, 32, 45, 63] {
        for j in [0usize, 20, 40, 55, 60, 62, 63] {
            let b = Brdf::new(row_alpha(i), clamp_cos(column_cos(j)));
            let (n1, f1, _) = b.integrals(PHI_STEPS, QUAD_TOL);
            let (n2, f2, _) = b.integrals(4 * PHI_STEPS, QUAD_TOL / 10.0);
            worst = worst.max((n1 - n2).abs()).max((f1 - f2).abs());
        }
    }
    println!(
        "norm quadrature: alpha=1, theta=0: {n:.7} vs 1 - ln 2 = {exact:.7}; \
         max |change| of norm/fresnel under refinement: {worst:.1e}"
    );
}

fn main() {
    let path = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "scene/data/ltc_ggx.bin".to_string());
    let check_only = std::env::args().any(|a| a == "--check-only");
    check_d();
    check_integrals();
    println!("MIN_ALPHA = {MIN_ALPHA}");

    let t0 = Instant::now();
    if !check_only {
        let cells = fit_table();
        println!(
            "fit {}x{} cells in {:.1} s",
            N,
            N,
            t0.elapsed().as_secs_f64()
        );
        write_table(&path, &cells).expect("write table");
        println!("wrote {path}");
        print_summary(&cells);
    }
    let table = read_table(&path).expect("read table back");
    let t1 = Instant::now();
    check(&table);
    println!(
        "check in {:.1} s; total {:.1} s",
        t1.elapsed().as_secs_f64(),
        t0.elapsed().as_secs_f64()
    );
}

fn print_summary(cells: &[Cell]) {
    println!("\nsample cells [a, b, c, d, norm, fresnel] (fit error):");
    for &i in &[0usize, 3, 8, 16, 32, 48, 63] {
        for &j in &[0usize, 16, 32, 48, 56, 63] {
            let c = &cells[i * N + j];
            println!(
                "  r={:.3} j={:2} cos={:.4}: [{:9.4} {:9.4} {:9.4} {:9.4} {:.5} {:.5}] ({:.2e})",
                i as f64 / 63.0,
                j,
                column_cos(j),
                c.entry[0],
                c.entry[1],
                c.entry[2],
                c.entry[3],
                c.norm,
                c.fresnel,
                c.err
            );
        }
    }
    // Continuity: the largest jump of each entry between neighbours, relative to the entry scale.
    let mut worst = [(0.0f64, 0usize, 0usize); 4];
    for i in 0..N {
        for j in 0..N {
            for (di, dj) in [(1, 0), (0, 1)] {
                if i + di >= N || j + dj >= N {
                    continue;
                }
                let a = &cells[i * N + j].entry;
                let b = &cells[(i + di) * N + j + dj].entry;
                for k in 0..4 {
                    let s = a[k].abs().max(b[k].abs()).max(1e-3);
                    let rel = (a[k] - b[k]).abs() / s;
                    if rel > worst[k].0 {
                        worst[k] = (rel, i, j);
                    }
                }
            }
        }
    }
    let sign_flips = (0..N * N)
        .filter(|&k| {
            let (i, j) = (k / N, k % N);
            j + 1 < N && {
                let (a, b) = (&cells[k].entry, &cells[k + 1].entry);
                (0..4).any(|q| a[q] * b[q] < 0.0 && a[q].abs().min(b[q].abs()) > 1e-3)
            } || i + 1 < N && {
                let (a, b) = (&cells[k].entry, &cells[k + N].entry);
                (0..4).any(|q| a[q] * b[q] < 0.0 && a[q].abs().min(b[q].abs()) > 1e-3)
            }
        })
        .count();
    println!("largest relative neighbour jump per entry (a, b, c, d): {worst:?}");
    println!("neighbour sign flips (|x| > 1e-3): {sign_flips}");
}

fn check(table: &[[f32; 8]]) {
    let roughs = [0.05, 0.1, 0.2, 0.3, 0.5, 0.8];
    let thetas = [0.0, 30.0, 60.0, 80.0];
    let combos: Vec<(f64, f64)> = roughs
        .iter()
        .flat_map(|&r| thetas.iter().map(move |&t| (r, t)))
        .collect();
    let lines = parallel(combos.len(), |k| {
        let (r, th) = combos[k];
        let alpha = f64::from(ggx_alpha(r as f32));
        let cos_theta = th.to_radians().cos();
        let brdf = Brdf::new(alpha, cos_theta);
        let e = ltc::lookup_in(table, (r * r) as f32, cos_theta as f32).map(f64::from);
        let tab = Ltc::from_minv([[e[0], 0.0, e[1]], [0.0, 1.0, 0.0], [e[2], 0.0, e[3]]]);
        // A fresh fit at the exact parameters, started from the table.
        let cs = setup(alpha, clamp_cos(cos_theta));
        let start = {
            // Recover (ln m11, ln m22, m13/m11) of the interpolated M in the cell's frame.
            let y = [0.0, 1.0, 0.0];
            let x = cross(y, cs.z);
            let frame_t = [x, y, cs.z];
            let s = mat_mul(&frame_t, &tab.m);
            let k = 1.0 / s[2][2];
            let (m11, m22, m13) = (s[0][0] * k, s[1][1] * k, s[0][2] * k);
            [m11.abs().ln(), m22.abs().ln(), m13 / m11.abs()]
        };
        let (p, _) = fit(&cs, &start);
        let exact = ltc_of(cs.z, &p);
        let mut out = String::new();
        let mut stats = Vec::new();
        for rect in rects(th) {
            let bf = rect.brute_force(&brdf, 4096);
            let bf2 = rect.brute_force(&brdf, 2048);
            let lt = e[4] * rect.ltc(&tab.minv);
            let lx = cs.norm * rect.ltc(&exact.minv);
            let share = bf / cs.norm;
            out.push_str(&format!(
                "{:5.2} {:4.0} {:7} {:11.4e} {:9.1e} {:7.4} {:+8.2}% {:+8.2}% {:+8.3}%\n",
                r,
                th,
                rect.name,
                bf,
                (bf - bf2).abs() / bf.max(1e-300),
                share,
                100.0 * (lt - bf) / bf,
                100.0 * (lx - bf) / bf,
                100.0 * (lt - bf) / cs.norm,
            ));
            stats.push((share, ((lt - bf) / bf).abs(), ((lt - bf) / cs.norm).abs()));
        }
        (out, stats)
    });
    println!("\nfit check: brute-force ∫ f_cos dω over a rectangle vs norm·E(M⁻¹P)");
    println!(
        "(bf conv.: |4096² − 2048²| relative; share: brute-force / norm; last column: table \
         error relative to norm)"
    );
    println!("    r  θ°  rect     brute-force  bf conv.   share   table     fresh fit  tab/norm");
    let mut all = Vec::new();
    for (l, st) in lines {
        print!("{l}");
        all.extend(st);
    }
    for min_share in [0.0, 0.01, 0.1, 0.3] {
        let sel: Vec<_> = all.iter().filter(|s| s.0 >= min_share).collect();
        let max_rel = sel.iter().map(|s| s.1).fold(0.0, f64::max);
        let mean_rel = sel.iter().map(|s| s.1).sum::<f64>() / sel.len().max(1) as f64;
        println!(
            "rects with share >= {min_share:4}: {:3}, relative error (table) max {:.2}% mean {:.2}%",
            sel.len(),
            100.0 * max_rel,
            100.0 * mean_rel
        );
    }
    let max_abs = all.iter().map(|s| s.2).fold(0.0, f64::max);
    println!(
        "max |error| relative to norm over all rects: {:.2}%",
        100.0 * max_abs
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The shipped table (`scene/data/ltc_ggx.bin`, compiled into `scene::ltc`) is this fitter's
    /// output: the normal-incidence column and one whole row, fitted again here, give the same
    /// cells (to 1e-4 of the cell's largest entry: another libm may round a sine differently).
    /// A cell of the neighbouring row (the control) differs by far more.
    #[test]
    fn the_shipped_table_is_what_the_fitter_writes() {
        let shipped = ltc::table();
        let column0 = normal_incidence_column();
        let i = 20;
        let row = fit_row(i, column0[i]);
        let differs = |a: &[f32; 8], b: &[f32; 8]| {
            let scale = a.iter().fold(1e-6f32, |m, x| m.max(x.abs()));
            a.iter().zip(b).fold(0f32, |m, (x, y)| m.max((x - y).abs())) / scale
        };
        let worst = row
            .iter()
            .enumerate()
            .map(|(j, c)| differs(&stored(c), &shipped[i * N + j]))
            .fold(0f32, f32::max);
        assert!(
            worst < 1e-4,
            "row {i} differs from the shipped table by {worst}"
        );
        let control = differs(&stored(&row[40]), &shipped[(i + 1) * N + 40]);
        assert!(control > 1e-3, "neighbouring rows should differ: {control}");
        for (k, c) in column0.iter().enumerate() {
            let d = differs(&stored(c), &shipped[k * N]);
            assert!(d < 1e-4, "normal-incidence cell {k} differs by {d}");
        }
    }
}
