//! `penumbra`: the screen-space penumbra filter (seed 003's 7×7 average of the shadow image, seed
//! 001's selective filtering), run on the illumination sum before the material multiply, so a
//! few point samples per area light give a smooth penumbra instead of one visible step per
//! sample.
//!
//! Each pixel becomes the weighted average (`kernel`: a tent by default, or a plain box) of the
//! pixels of its (2r+1)² window that lie on its own surface, and only those: a neighbour counts when its inverse eye depth 1/z lies within
//! `depth_tolerance · (1/z_p)` of the plane through the pixel. For a perspective camera 1/z is
//! affine in screen space over a plane, so a plane's own pixels fit its prediction exactly,
//! whatever its slope; a silhouette (another object behind or in front) misses it by the depth
//! gap, and a crease (another face of the same object) by its change of slope times the
//! distance. The plane's slope at a pixel is, per axis, the one-sided difference of 1/z on the side
//! where the surface goes on as a plane (two pixels each way, the smaller second difference), so
//! a pixel on a silhouette or a crease takes its slope from its own side.
//! This is the normal-aware part: the plane is the surface's tangent plane as the depth layer
//! gives it, so no normal layer travels. A crease whose faces meet at one depth and differ by
//! a few degrees (the facets of a low-poly body) misses the prediction only by its slope change
//! times the distance, under `depth_tolerance` for the nearest taps; so with `crease_tolerance`
//! (the planner always gives it: [`crease_tolerance`] of the camera, [`CREASE_DEG`]) a tap also
//! needs its own slope, relative to its 1/z, within that of the pixel's. Background pixels (depth 0, or not finite and positive)
//! are left as they are and never counted.
//!
//! Input 0 carries the illumination (diffuse RGB, specular RGB), input 1 the depth layer (eye
//! depth along the camera's forward axis, ARCHITECTURE §3). The band is read as an image `width`
//! pixels wide; taps beyond its first or last row are not counted, so a stage that runs it band
//! by band gives it `halo()` rows (the radius, at least 2) of each neighbouring band above and
//! below and keeps
//! only the rows in between (`compositor/src/daemon/engine.rs`): those come out exactly as if the
//! whole frame had been filtered at once.
//!
//! Diffuse channels are always filtered; specular ones only with `specular: true` (highlights are
//! sharp by design, and most of the penumbra's energy is diffuse). Colour values follow the value
//! policy (`sanitize` on read, saturating at `MAX_VALUE`); both versions sum a window's taps in
//! row-major order and give the same bits.

use super::params;
use super::{
    BandMut, BandView, InputSpec, MAX_VALUE, OpError, Operator, Signature, check_band, clamp_fast,
    sanitize, saturate,
};
use lightfold_protocol::Layer;
use rayon::prelude::*;
use serde_json::Value;

pub const NAME: &str = PenumbraParams::NAME;

pub use lightfold_protocol::pipeline::{
    CREASE_DEG, Kernel, PENUMBRA_DEFAULT_DEPTH_TOLERANCE as DEFAULT_DEPTH_TOLERANCE,
    PENUMBRA_DEFAULT_RADIUS as DEFAULT_RADIUS, PENUMBRA_MAX_RADIUS as MAX_RADIUS, PenumbraParams,
    crease_tolerance, halo_rows,
};

/// Rows below which a band is filtered on the calling thread. A stage's bands are a few tens of
/// rows, each row thousands of taps: rows go to the stage's compute pool from a handful on (one
/// 1080p band on one thread made the filter the slowest stage on a 16-core GPU machine).
const PAR_ROWS: usize = 4;

/// The penumbra filter (see the module documentation).
#[derive(Debug, Clone)]
pub struct Penumbra {
    params: PenumbraParams,
}

fn bad(reason: String) -> OpError {
    OpError::BadParam { op: NAME, reason }
}

impl Penumbra {
    /// From JSON parameters (`PenumbraParams`).
    pub fn new(params: &Value) -> Result<Self, OpError> {
        Self::from_params(params::parse(NAME, params)?)
    }

    /// From typed parameters, validated (`PenumbraParams::validate`).
    pub fn from_params(p: PenumbraParams) -> Result<Self, OpError> {
        p.validate()?;
        Ok(Penumbra { params: p })
    }

    /// The window's radius.
    pub fn radius(&self) -> u32 {
        self.params.radius
    }

    /// Rows of each neighbouring band a band needs to be filtered as the whole frame would be
    /// ([`halo_rows`]).
    pub fn halo(&self) -> u32 {
        self.params.halo()
    }

    /// The row length this operator reads bands with.
    pub fn width(&self) -> u32 {
        self.params.width
    }

    /// The weight of a tap `(dx, dy)` from the centre.
    fn weight(&self, dx: i64, dy: i64) -> f32 {
        match self.params.kernel {
            Kernel::Box => 1.0,
            Kernel::Tent => {
                let r = i64::from(self.params.radius) + 1;
                ((r - dx.abs()) * (r - dy.abs())) as f32
            }
        }
    }

    /// Channels filtered per pixel (3: diffuse only; 6: diffuse and specular).
    fn filtered(&self) -> usize {
        if self.params.specular { 6 } else { 3 }
    }

    /// Checks the band and that it is whole rows; returns the rows.
    fn rows(&self, inputs: &[BandView<'_>], out: &BandMut<'_>) -> Result<usize, OpError> {
        check_band(NAME, &self.signature(), inputs, out)?;
        let w = self.params.width as usize;
        if !out.pixels.is_multiple_of(w) {
            return Err(bad(format!(
                "a band of {} pixels is not whole rows of {w}",
                out.pixels
            )));
        }
        Ok(out.pixels / w)
    }
}

/// The filter over one whole frame `width` pixels wide: `illumination` (6 channels a pixel) and
/// `depth` (1) in, the filtered illumination out, as a last stage planned for a camera of
/// vertical field of view `fov_y_deg` gives it band by band (`PenumbraParams::planned`). What
/// `lightfold render` and the accuracy sweep apply after a single-device render.
pub fn filter_frame(
    width: u32,
    radius: u32,
    fov_y_deg: f32,
    illumination: &[f32],
    depth: &[f32],
) -> Result<Vec<f32>, OpError> {
    let height = (depth.len() / width.max(1) as usize) as u32;
    let op = Penumbra::from_params(PenumbraParams::planned(width, height, radius, fov_y_deg))?;
    let pixels = depth.len();
    let mut out = vec![0.0; pixels * 6];
    let views = [
        BandView::new(pixels).with(Layer::Illumination, illumination),
        BandView::new(pixels).with(Layer::Depth, depth),
    ];
    let mut o = BandMut::new(pixels).with(Layer::Illumination, &mut out);
    op.apply(&views, &mut o)?;
    Ok(out)
}

/// Inverse eye depth: 0 for background and for a value that is not finite and positive.
#[inline]
fn inverse(z: f32) -> f32 {
    if z.is_finite() && z > 0.0 {
        1.0 / z
    } else {
        0.0
    }
}

/// The plane's slope along one axis at a pixel of inverse depth `c`, from its neighbours one and
/// two pixels before (`a`, `aa`) and after (`b`, `bb`) on that axis (0: absent or background).
/// Each side offers its one-sided difference; the side whose surface goes on along it (the
/// smaller second difference, `|2a − aa − c|`) is taken, so a pixel next to a silhouette or on
/// one face of a crease takes its own surface's slope. A side with one neighbour only is judged
/// by its difference; with no neighbour the slope is 0.
#[inline]
fn slope(c: f32, a: f32, aa: f32, b: f32, bb: f32) -> f32 {
    let side = |n: f32, nn: f32, d: f32| -> Option<(f32, f32)> {
        (n > 0.0).then(|| {
            let bend = if nn > 0.0 {
                (2.0 * n - nn - c).abs()
            } else {
                d.abs()
            };
            (d, bend)
        })
    };
    match (side(a, aa, c - a), side(b, bb, b - c)) {
        (Some(l), Some(r)) => {
            if r.1 < l.1 {
                r.0
            } else {
                l.0
            }
        }
        (Some(l), None) => l.0,
        (None, Some(r)) => r.0,
        (None, None) => 0.0,
    }
}

/// How much a tap of inverse depth `q` (`z_q` = 1/q) and slopes (`qx`, `qy`) counts as the
/// pixel's own face (`c`; `gx`, `gy`; `per` = 1/(crease·c)), from the larger difference of
/// their relative slopes g/(1/z) per axis over the crease tolerance,
/// ratio = max|qx·c − gx·q| · per · z_q: 1 up to a ratio of ½, 0 from 1 on, linear between — so
/// a tap near the limit does not flip the pixel's value on a rounding of its depth (a
/// cluster's depth and a single device's may differ in the last bit). Branch-free (the fast
/// version runs it across a row); not finite (an extreme depth) weighs 1, as the plane test
/// keeps it.
#[inline]
fn face_weight(
    (gx, gy, c): (f32, f32, f32),
    (qx, qy, q): (f32, f32, f32),
    per: f32,
    z_q: f32,
) -> f32 {
    let e = (qx * c - gx * q).abs().max((qy * c - gy * q).abs());
    // min then max, not clamp: a NaN ratio must weigh 1, not stay NaN.
    #[allow(clippy::manual_clamp)]
    let w = (2.0 - 2.0 * (e * per * z_q)).min(1.0).max(0.0);
    w
}

impl Operator for Penumbra {
    fn name(&self) -> &'static str {
        NAME
    }

    fn signature(&self) -> Signature {
        Signature {
            inputs: vec![
                InputSpec {
                    required: vec![Layer::Illumination],
                    optional: vec![],
                },
                InputSpec {
                    required: vec![Layer::Depth],
                    optional: vec![],
                },
            ],
            outputs: vec![Layer::Illumination],
        }
    }

    fn apply_scalar(&self, inputs: &[BandView<'_>], out: &mut BandMut<'_>) -> Result<(), OpError> {
        let rows = self.rows(inputs, out)?;
        let il = inputs[0].layer(Layer::Illumination).expect("checked");
        let depth = inputs[1].layer(Layer::Depth).expect("checked");
        let dst = out.layer_mut(Layer::Illumination).expect("checked");
        let (w, r) = (self.params.width as usize, self.params.radius as i64);
        let tol = self.params.depth_tolerance;
        let crease = self.params.crease_tolerance;
        let nf = self.filtered();
        let at = |x: i64, y: i64| -> f32 {
            if x < 0 || y < 0 || x >= w as i64 || y >= rows as i64 {
                0.0
            } else {
                inverse(depth[y as usize * w + x as usize])
            }
        };
        for y in 0..rows as i64 {
            for x in 0..w as i64 {
                let p = y as usize * w + x as usize;
                for c in 0..6 {
                    dst[p * 6 + c] = sanitize(il[p * 6 + c]);
                }
                let c = at(x, y);
                if c <= 0.0 {
                    continue;
                }
                let slopes = |x: i64, y: i64, c: f32| {
                    (
                        slope(c, at(x - 1, y), at(x - 2, y), at(x + 1, y), at(x + 2, y)),
                        slope(c, at(x, y - 1), at(x, y - 2), at(x, y + 1), at(x, y + 2)),
                    )
                };
                let (gx, gy) = slopes(x, y, c);
                let limit = tol * c;
                let mut sum = [0.0f32; 6];
                let mut n = 0.0f32;
                for dy in -r..=r {
                    for dx in -r..=r {
                        let q = at(x + dx, y + dy);
                        if q <= 0.0 {
                            continue;
                        }
                        let predicted = c + gx * dx as f32 + gy * dy as f32;
                        if (q - predicted).abs() > limit {
                            continue;
                        }
                        let face = match crease {
                            Some(t) => {
                                let (qx, qy) = slopes(x + dx, y + dy, q);
                                face_weight((gx, gy, c), (qx, qy, q), 1.0 / (t * c), 1.0 / q)
                            }
                            None => 1.0,
                        };
                        let k = ((y + dy) as usize * w + (x + dx) as usize) * 6;
                        let wt = self.weight(dx, dy) * face;
                        for (s, v) in sum.iter_mut().zip(&il[k..k + nf]) {
                            *s += wt * sanitize(*v);
                        }
                        n += wt;
                    }
                }
                for (ch, s) in sum.iter().enumerate().take(nf) {
                    dst[p * 6 + ch] = (s / n).min(MAX_VALUE);
                }
            }
        }
        Ok(())
    }

    fn apply(&self, inputs: &[BandView<'_>], out: &mut BandMut<'_>) -> Result<(), OpError> {
        let rows = self.rows(inputs, out)?;
        let il = inputs[0].layer(Layer::Illumination).expect("checked");
        let depth = inputs[1].layer(Layer::Depth).expect("checked");
        let w = self.params.width as usize;
        let r = self.params.radius as usize;
        let tol = self.params.depth_tolerance;
        let crease = self.params.crease_tolerance;
        let nf = self.filtered();
        // Inverse depth with a border of `pad` zeros (background: never counted), so neighbours
        // and taps read without bounds tests; and the plane's slopes, once per pixel.
        let pad = r.max(2);
        let pw = w + 2 * pad;
        let mut inv = vec![0.0f32; pw * (rows + 2 * pad)];
        for (y, zs) in depth.chunks_exact(w).enumerate() {
            let start = (y + pad) * pw + pad;
            for (o, z) in inv[start..start + w].iter_mut().zip(zs) {
                *o = inverse(*z);
            }
        }
        // Depth (1/(1/z), as the reference computes it) in the same padded layout, for the
        // crease test's weights.
        let zs: Vec<f32> = if crease.is_some() {
            inv.iter().map(|q| 1.0 / q).collect()
        } else {
            Vec::new()
        };
        // Slopes in the same padded layout, so a tap's own slopes read like its depth.
        let mut gxs = vec![0.0f32; inv.len()];
        let mut gys = vec![0.0f32; inv.len()];
        for y in 0..rows {
            for x in 0..w {
                let i = (y + pad) * pw + x + pad;
                let c = inv[i];
                gxs[i] = slope(c, inv[i - 1], inv[i - 2], inv[i + 1], inv[i + 2]);
                gys[i] = slope(
                    c,
                    inv[i - pw],
                    inv[i - 2 * pw],
                    inv[i + pw],
                    inv[i + 2 * pw],
                );
            }
        }
        // The filtered channels, read by the value policy, one plane each (contiguous taps).
        let planes: Vec<Vec<f32>> = (0..nf)
            .map(|ch| {
                il.iter()
                    .skip(ch)
                    .step_by(6)
                    .map(|v| clamp_fast(*v))
                    .collect()
            })
            .collect();
        let dst = out.layer_mut(Layer::Illumination).expect("checked");
        let side = 2 * r + 1;
        let weights: Vec<f32> = (0..side * side)
            .map(|k| self.weight((k % side) as i64 - r as i64, (k / side) as i64 - r as i64))
            .collect();
        // One output row, tap by tap across the whole row: first which pixels keep the tap (its
        // weight or 0; contiguous, vectorised), then its values added. Each pixel still adds its
        // taps in the reference's row-major order, and a tap not kept adds 0 (x + 0 is x for
        // the non-negative sums), so the bits are the reference's.
        let row = |y: usize, line: &mut [f32]| {
            let at = y * w;
            let own = (y + pad) * pw + pad..(y + pad) * pw + pad + w;
            let (gx, gy) = (&gxs[own.clone()], &gys[own.clone()]);
            let c = &inv[own];
            let per: Vec<f32> = match crease {
                Some(t) => c.iter().map(|c| 1.0 / (t * c)).collect(),
                None => Vec::new(),
            };
            let mut n = vec![0.0f32; w];
            let mut m = vec![0.0f32; w];
            let mut sums = vec![vec![0.0f32; w]; nf];
            for qy in y.saturating_sub(r)..=(y + r).min(rows - 1) {
                let dy = qy as f32 - y as f32;
                for dxi in -(r as isize)..=r as isize {
                    let wt = weights[(qy + r - y) * side + (dxi + r as isize) as usize];
                    let dx = dxi as f32;
                    let start = ((qy + pad) * pw) as isize + pad as isize + dxi;
                    let taps = start as usize..start as usize + w;
                    let qinv = &inv[taps.clone()];
                    for x in 0..w {
                        let q = qinv[x];
                        // The reference's `c + gx·dx + gy·dy` and its test, as written there
                        // (negated: a NaN prediction, from extreme depths, is kept in both).
                        let predicted = c[x] + gx[x] * dx + gy[x] * dy;
                        #[allow(clippy::neg_cmp_op_on_partial_ord)]
                        let keep = q > 0.0 && !((q - predicted).abs() > tol * c[x]);
                        m[x] = if keep { wt } else { 0.0 };
                    }
                    if crease.is_some() {
                        // The reference's weight of each kept tap, across the row.
                        let (qgx, qgy, zq) = (&gxs[taps.clone()], &gys[taps.clone()], &zs[taps]);
                        for x in 0..w {
                            m[x] *= face_weight(
                                (gx[x], gy[x], c[x]),
                                (qgx[x], qgy[x], qinv[x]),
                                per[x],
                                zq[x],
                            );
                        }
                    }
                    for x in 0..w {
                        n[x] += m[x];
                    }
                    // The pixels whose tap dxi lies in the row (off it, m is 0: the padding).
                    let xa = (-dxi).max(0) as usize;
                    let xb = (w as isize - dxi).clamp(0, w as isize) as usize;
                    if xa >= xb {
                        continue;
                    }
                    let first = (qy * w) as isize + xa as isize + dxi;
                    for (sum, plane) in sums.iter_mut().zip(&planes) {
                        let v = &plane[first as usize..first as usize + (xb - xa)];
                        for ((s, m), v) in sum[xa..xb].iter_mut().zip(&m[xa..xb]).zip(v) {
                            *s += m * v;
                        }
                    }
                }
            }
            for x in 0..w {
                let o = &mut line[x * 6..x * 6 + 6];
                for (o, v) in o.iter_mut().zip(&il[(at + x) * 6..(at + x) * 6 + 6]) {
                    *o = clamp_fast(*v);
                }
                if c[x] > 0.0 {
                    for (o, sum) in o.iter_mut().zip(&sums) {
                        *o = saturate(sum[x] / n[x]);
                    }
                }
            }
        };
        if rows < PAR_ROWS || rayon::current_num_threads() < 2 {
            for (y, line) in dst.chunks_mut(w * 6).enumerate() {
                row(y, line);
            }
        } else {
            dst.par_chunks_mut(w * 6)
                .enumerate()
                .for_each(|(y, line)| row(y, line));
        }
        Ok(())
    }

    fn set_params(&mut self, params: &Value) -> Result<(), OpError> {
        let current = serde_json::to_value(&self.params).map_err(|e| bad(e.to_string()))?;
        let next = Penumbra::new(&params::merge(NAME, &current, params)?)?;
        *self = next;
        Ok(())
    }
}
