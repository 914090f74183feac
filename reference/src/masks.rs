//! Pixel masks for the metrics: the penumbra (where a shadow is partial, the region soft shadows
//! are about) minus a dilated silhouette mask (where a raster and a ray tracer legitimately
//! disagree about which surface a pixel centre sees).

use lightfold_scene::Image;

/// Penumbra bounds on `shadowed / unoccluded` radiance.
pub const PENUMBRA_LOW: f32 = 0.02;
pub const PENUMBRA_HIGH: f32 = 0.98;
/// A neighbour's inverse depth differs from the line through its own neighbours by more than
/// this fraction: a depth discontinuity. Inverse depth is affine across a plane in screen space,
/// so flat surfaces at any slant give ~0; creases give small kinks, silhouettes large jumps.
pub const SILHOUETTE_THRESHOLD: f32 = 0.02;
/// Default dilation radius of the silhouette mask, in pixels (square neighbourhood).
pub const SILHOUETTE_DILATION: u32 = 2;

/// Pixels where `0.02 < shadowed/unoccluded < 0.98` (ratio of RGB sums), over covered pixels
/// whose unoccluded radiance is positive.
pub fn penumbra(shadowed: &Image, unoccluded: &Image) -> Vec<bool> {
    let n = shadowed.pixel_count().min(unoccluded.pixel_count());
    (0..n)
        .map(|i| {
            let sum = |img: &Image| -> f32 {
                let c = img.channels;
                img.data[i * c..i * c + c.min(3)].iter().sum()
            };
            let (s, u) = (sum(shadowed), sum(unoccluded));
            if u > 0.0 && u.is_finite() && s.is_finite() {
                let r = s / u;
                r > PENUMBRA_LOW && r < PENUMBRA_HIGH
            } else {
                false
            }
        })
        .collect()
}

/// Depth discontinuities and coverage edges, dilated by `dilation` pixels.
pub fn silhouettes(depth: &Image, coverage: &[bool], dilation: u32) -> Vec<bool> {
    let (w, h) = (depth.width as usize, depth.height as usize);
    let n = w * h;
    if coverage.len() != n || depth.data.len() < n * depth.channels {
        return vec![false; n];
    }
    let inv = |x: usize, y: usize| -> Option<f32> {
        let i = y * w + x;
        let z = depth.data[i * depth.channels];
        (coverage[i] && z > 0.0).then(|| 1.0 / z)
    };
    let mut edge = vec![false; n];
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let c = coverage[i];
            let right = x + 1 < w && coverage[i + 1] != c;
            let down = y + 1 < h && coverage[i + w] != c;
            if right {
                edge[i] = true;
                edge[i + 1] = true;
            }
            if down {
                edge[i] = true;
                edge[i + w] = true;
            }
            let Some(z) = inv(x, y) else { continue };
            // Second differences of inverse depth along x and y.
            let mut kink = |a: Option<f32>, b: Option<f32>| {
                if let (Some(a), Some(b)) = (a, b)
                    && (a - 2.0 * z + b).abs() > SILHOUETTE_THRESHOLD * z
                {
                    edge[i] = true;
                }
            };
            if x > 0 && x + 1 < w {
                kink(inv(x - 1, y), inv(x + 1, y));
            }
            if y > 0 && y + 1 < h {
                kink(inv(x, y - 1), inv(x, y + 1));
            }
        }
    }
    dilate(&edge, w, h, dilation)
}

/// The penumbra minus dilated silhouettes, restricted to covered pixels.
pub fn penumbra_mask(
    shadowed: &Image,
    unoccluded: &Image,
    depth: &Image,
    coverage: &[bool],
) -> Vec<bool> {
    let pen = penumbra(shadowed, unoccluded);
    let sil = silhouettes(depth, coverage, SILHOUETTE_DILATION);
    pen.iter()
        .zip(&sil)
        .zip(coverage)
        .map(|((&p, &s), &c)| p && !s && c)
        .collect()
}

/// Square dilation by `r` pixels (separable: rows, then columns).
pub fn dilate(mask: &[bool], w: usize, h: usize, r: u32) -> Vec<bool> {
    let r = r as usize;
    if r == 0 || mask.len() != w * h {
        return mask.to_vec();
    }
    let mut rows = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            let (lo, hi) = (x.saturating_sub(r), (x + r).min(w - 1));
            rows[y * w + x] = (lo..=hi).any(|k| mask[y * w + k]);
        }
    }
    let mut out = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            let (lo, hi) = (y.saturating_sub(r), (y + r).min(h - 1));
            out[y * w + x] = (lo..=hi).any(|k| rows[k * w + x]);
        }
    }
    out
}

/// Pixels fit for an exact GPU-against-reference comparison: neither the pixel nor any 3×3
/// neighbour is on a silhouette, and all nine share one shadow state (`states[i]` is a bit set of
/// the samples that light pixel `i`).
pub fn comparable(depth: &Image, coverage: &[bool], states: &[u64]) -> Vec<bool> {
    let (w, h) = (depth.width as i64, depth.height as i64);
    let sil = silhouettes(depth, coverage, 0);
    let mut out = vec![false; (w * h) as usize];
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            let mut ok = true;
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let (xx, yy) = (x + dx, y + dy);
                    if xx < 0 || yy < 0 || xx >= w || yy >= h {
                        continue;
                    }
                    let j = (yy * w + xx) as usize;
                    ok &= states[j] == states[i] && !sil[j];
                }
            }
            out[i] = ok;
        }
    }
    out
}
