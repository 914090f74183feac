//! Pixel masks for the metrics: the penumbra (where a shadow is partial, the region soft shadows
//! are about) minus a dilated silhouette mask (where a raster and a ray tracer legitimately
//! disagree about which surface a pixel centre sees).

use lightfold_scene::shading::lobe_coefficients;
use lightfold_scene::trace::Tracer;
use lightfold_scene::{Image, LightSample, Scene};

/// Penumbra bounds on `shadowed / unoccluded` radiance.
pub const PENUMBRA_LOW: f32 = 0.02;
pub const PENUMBRA_HIGH: f32 = 0.98;
/// A neighbour's inverse depth differs from the line through its own neighbours by more than
/// this fraction: a depth discontinuity. Inverse depth is affine across a plane in screen space,
/// so flat surfaces at any slant give ~0; creases give small kinks, silhouettes large jumps.
pub const SILHOUETTE_THRESHOLD: f32 = 0.02;
/// Default dilation radius of the silhouette mask, in pixels (square neighbourhood).
pub const SILHOUETTE_DILATION: u32 = 2;
/// A pixel centre within this many pixels of a boundary between two surfaces is a tie
/// ([`ties`]): a rasteriser's fill rule and a ray tracer's intersection test may each give it
/// to either side. Rasterisers resolve 1/256 of a pixel (8 sub-pixel bits), so 1/64 holds every
/// disagreement of theirs and no pixel whose centre is clearly on one side.
pub const TIE_PIXELS: f32 = 1.0 / 64.0;
/// Shading normals closer than this cosine (2.6°) are one surface for [`ties`]: a smooth surface
/// turns far less over [`TIE_PIXELS`].
const TIE_COS: f32 = 0.999;

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

/// Pixels whose centre lies on a boundary between two surfaces, to within [`TIE_PIXELS`]: the
/// eye rays [`TIE_PIXELS`] to either side of the centre, across and down, do not all hit the same
/// surface as the centre's (the same coverage and material, shading normals within 2.6°). Which surface such
/// a pixel shows is a tie — the Cornell box's camera on the room's axis puts the floor–wall
/// junctions through a whole diagonal of pixel centres, where a rasteriser shows the floor and
/// the ray tracer the wall — so comparisons leave them out as they leave out silhouettes. The
/// depth-based silhouette mask cannot see these: the two surfaces meet at one depth. A crease
/// inside one mesh counts (a box's edge, a flat-shaded facet's), a seam between coplanar pieces of
/// one material or an edge between smoothly shaded triangles does not.
pub fn ties(scene: &Scene) -> Vec<bool> {
    use rayon::prelude::*;
    let tracer = Tracer::new(scene);
    let (w, h) = (scene.camera.width, scene.camera.height);
    let same = |a: &Option<lightfold_scene::trace::SurfaceHit>,
                b: &Option<lightfold_scene::trace::SurfaceHit>| match (a, b) {
        (None, None) => true,
        (Some(a), Some(b)) => {
            let (n, m) = (a.normal, b.normal);
            let cos = n[0] * m[0] + n[1] * m[1] + n[2] * m[2];
            a.material == b.material && cos > TIE_COS
        }
        _ => false,
    };
    (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            let tracer = &tracer;
            (0..w).map(move |x| {
                let (cx, cy) = (x as f32 + 0.5, y as f32 + 0.5);
                let centre = tracer.primary_at(cx, cy);
                let d = TIE_PIXELS;
                [(d, 0.0), (-d, 0.0), (0.0, d), (0.0, -d)]
                    .iter()
                    .any(|&(dx, dy)| !same(&centre, &tracer.primary_at(cx + dx, cy + dy)))
            })
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

/// Per pixel (ray traced): bit k of `lit` when sample k would light it, of `visible` when it also
/// reaches it unblocked; `covered` when the primary ray hit something. Only the first 64 samples
/// have bits: callers with more pass the 64 they judge.
#[derive(Debug, Clone)]
pub struct ShadowStates {
    pub lit: Vec<u64>,
    pub visible: Vec<u64>,
    pub covered: Vec<bool>,
}

impl ShadowStates {
    /// Fraction of all pixels where some sample that would light the pixel is blocked.
    pub fn shadowed_fraction(&self) -> f64 {
        let n = self
            .lit
            .iter()
            .zip(&self.visible)
            .filter(|(l, v)| l != v)
            .count();
        n as f64 / self.lit.len().max(1) as f64
    }
}

/// The [`ShadowStates`] of `scene`'s camera view for the first 64 of `samples`.
pub fn shadow_states(scene: &Scene, samples: &[LightSample]) -> ShadowStates {
    let tracer = Tracer::new(scene);
    let (w, h) = (scene.camera.width, scene.camera.height);
    let n = (w * h) as usize;
    let mut st = ShadowStates {
        lit: vec![0; n],
        visible: vec![0; n],
        covered: vec![false; n],
    };
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            let Some(hit) = tracer.primary(x, y) else {
                continue;
            };
            st.covered[i] = true;
            let lobe = tracer.surface(&hit).lobe;
            for (k, s) in samples.iter().enumerate().take(64) {
                let (id, is) =
                    lobe_coefficients(s, hit.position_f32(), hit.normal, hit.to_viewer, &lobe);
                if id > 0.0 || is.iter().any(|&c| c > 0.0) {
                    st.lit[i] |= 1 << k;
                    if tracer.visible(&hit, s) {
                        st.visible[i] |= 1 << k;
                    }
                }
            }
        }
    }
    st
}
