//! The penumbra filter (`ops::penumbra`): it averages a surface's own pixels and nothing across a
//! silhouette or a crease, a plain box filter (the same operator told to ignore depth) fails the
//! same checks, background is left alone, a band filtered with its halo gives the rows of the
//! whole frame's filter bit for bit, and the fast version gives the reference's bits on hostile
//! values.

use crate::common;

use common::{Owned, assert_same_bits, hostile, ordinary, rng, run};
use lightfold_compositor::ops::{self, BandMut, BandView, OpError, Operator};
use lightfold_protocol::Layer;
use rand::Rng;
use serde_json::json;

const ILL: Layer = Layer::Illumination;
const DEPTH: Layer = Layer::Depth;

fn filter(width: usize, extra: serde_json::Value) -> Box<dyn Operator> {
    let mut p = json!({ "width": width });
    if let serde_json::Value::Object(m) = extra {
        for (k, v) in m {
            p[k] = v;
        }
    }
    ops::create("penumbra", &p).unwrap()
}

/// A plain 7×7 box filter: the same operator with a depth tolerance no surface misses.
fn box_filter(width: usize) -> Box<dyn Operator> {
    filter(width, json!({ "depth_tolerance": 1e30, "kernel": "box" }))
}

fn inputs(il: Vec<f32>, depth: Vec<f32>) -> Vec<Owned> {
    let pixels = depth.len();
    vec![
        Owned {
            pixels,
            layers: vec![(ILL, il)],
        },
        Owned {
            pixels,
            layers: vec![(DEPTH, depth)],
        },
    ]
}

fn filtered(op: &dyn Operator, ins: &[Owned]) -> Vec<f32> {
    let pixels = ins[0].pixels;
    let fast = run(op, ins, pixels, false);
    let reference = run(op, ins, pixels, true);
    assert_same_bits(&fast, &reference, "penumbra fast vs reference");
    fast.layer(ILL).to_vec()
}

/// Illumination from a function of (x, y): diffuse = f, specular = 2f.
fn illumination(w: usize, h: usize, f: impl Fn(usize, usize) -> f32) -> Vec<f32> {
    let mut v = Vec::with_capacity(w * h * 6);
    for y in 0..h {
        for x in 0..w {
            let d = f(x, y);
            v.extend_from_slice(&[d, d, d, 2.0 * d, 2.0 * d, 2.0 * d]);
        }
    }
    v
}

/// A pinhole camera's eye depth over the plane n·p = 1 (n in camera space, the image plane at
/// distance `f` pixels): 1/z is affine in the pixel coordinates.
fn plane_depth(w: usize, h: usize, n: [f32; 3], f: f32) -> Vec<f32> {
    let mut v = Vec::with_capacity(w * h);
    for y in 0..h {
        for x in 0..w {
            let (u, t) = (x as f32 - w as f32 / 2.0, y as f32 - h as f32 / 2.0);
            // p = z·(u/f, t/f, 1): n·p = 1 gives 1/z = n·(u/f, t/f, 1).
            let inv = n[0] * u / f + n[1] * t / f + n[2];
            v.push(1.0 / inv);
        }
    }
    v
}

/// Equal but for the rounding of a mean of equal values.
fn close(a: f32, b: f32) -> bool {
    (a - b).abs() <= 1e-6 * b.abs().max(1.0)
}

/// The surface checks: where every pixel of a pixel's window lies on its surface the output is
/// the window's mean; a pixel next to another surface keeps only its own surface's values.
/// Returns the first failure.
fn check_edges(op: &dyn Operator) -> Result<(), String> {
    let (w, h) = (24, 20);
    // Silhouette: a near object (z = 2) on the left, a far wall (z = 3) on the right. Each side
    // is lit uniformly, differently: a filter that keeps to surfaces changes nothing.
    let il = illumination(w, h, |x, _| if x < 12 { 0.2 } else { 1.0 });
    let depth: Vec<f32> = (0..w * h)
        .map(|p| if p % w < 12 { 2.0 } else { 3.0 })
        .collect();
    let out = filtered(op, &inputs(il.clone(), depth));
    if let Some(k) = (0..il.len()).find(|&k| !close(out[k], il[k])) {
        return Err(format!(
            "silhouette: value {k} (pixel {}) became {} from {}",
            k / 6,
            out[k],
            il[k]
        ));
    }
    // Crease: two faces of one object meeting along x = 12 at the same depth there (a concave
    // corner, lit differently on each face): continuous depth, a kink in its slope.
    // 1/z = 0.4 ± 0.001·u, the faces meeting between pixels 11 and 12 (u = -0.5): the slope
    // changes by 0.5 % of 1/z a pixel there.
    let (left, right) = (
        plane_depth(w, h, [0.05, 0.0, 0.4], 50.0),
        plane_depth(w, h, [-0.05, 0.0, 0.399], 50.0),
    );
    let depth: Vec<f32> = (0..w * h)
        .map(|p| {
            let x = p % w;
            if x < 12 { left[p] } else { right[p] }
        })
        .collect();
    let il = illumination(w, h, |x, _| if x < 12 { 0.3 } else { 0.9 });
    let out = filtered(op, &inputs(il.clone(), depth));
    if let Some(k) = (0..il.len()).find(|&k| !close(out[k], il[k])) {
        return Err(format!(
            "crease: value {k} (pixel {}) became {} from {}",
            k / 6,
            out[k],
            il[k]
        ));
    }
    Ok(())
}

#[test]
fn no_blur_across_silhouettes_or_creases_and_a_box_filter_fails() {
    check_edges(&*filter(24, json!({}))).unwrap();
    // Negative control: a plain box filter blurs both edges.
    let e = check_edges(&*box_filter(24)).expect_err("a box filter blurs the silhouette");
    assert!(e.starts_with("silhouette"), "{e}");
}

/// A shallow crease as an 800×600 camera sees it (focal 724 px, 45° field of view): two faces of a
/// low-poly body 14° apart meeting at one depth, lit differently. The plane prediction misses a
/// tap across it by only its slope change times the distance (0.03 % of 1/z a pixel, under the
/// depth tolerance), so without the crease test the filter blurs the faces into each other; with
/// the tolerance the planner gives that camera it keeps each face's own value.
#[test]
fn a_shallow_crease_stops_the_filter_that_the_plane_test_alone_blurs() {
    let (w, h, f) = (40, 30, 724.0);
    let (left, right) = (
        plane_depth(w, h, [0.0, 0.0, 0.25], f),
        // Tilted by 14° about the vertical, through the same depth at the crease, between
        // pixels 19 and 20 (u = −0.5: a pixel centred exactly on a crease lies on both faces).
        plane_depth(
            w,
            h,
            [-0.25 * 0.2493, 0.0, 0.25 - 0.25 * 0.2493 * 0.5 / f],
            f,
        ),
    );
    let depth: Vec<f32> = (0..w * h)
        .map(|p| if p % w < 20 { left[p] } else { right[p] })
        .collect();
    let il = illumination(w, h, |x, _| if x < 20 { 0.3 } else { 0.9 });
    let crease = ops::penumbra::crease_tolerance(45.0, 600);
    let with = filter(w, json!({ "radius": 3, "crease_tolerance": crease }));
    let without = filter(w, json!({ "radius": 3 }));
    let (a, b) = (
        filtered(&*with, &inputs(il.clone(), depth.clone())),
        filtered(&*without, &inputs(il.clone(), depth)),
    );
    let changed = |out: &[f32]| (0..il.len()).filter(|&k| !close(out[k], il[k])).count();
    assert_eq!(changed(&a), 0, "the crease test keeps each face to itself");
    // Negative control: the plane test alone blurs the pixels next to the crease.
    assert!(changed(&b) > 0, "the plane test alone sees the 14° crease");
}

/// The crease test leaves a smooth curved surface to the filter: a cylinder of 0.3 m radius 3 m
/// away, seen by the same camera, is averaged like a plane (its normal turns 0.8° a pixel).
#[test]
fn a_smooth_curved_surface_is_still_averaged() {
    let (w, h, f) = (40, 30, 724.0f32);
    let (radius, distance) = (0.3f32, 3.0f32);
    // A vertical cylinder (axis along y) at x = 0, z = distance: the eye ray through column u
    // meets it at the nearer root of |t·(u/f, 1) − (0, distance)| = radius (in x and z).
    let depth: Vec<f32> = (0..w * h)
        .map(|p| {
            let u = (p % w) as f32 - w as f32 / 2.0;
            let d = [u / f, 1.0];
            let (a, b, c) = (
                d[0] * d[0] + d[1] * d[1],
                -2.0 * distance * d[1],
                distance * distance - radius * radius,
            );
            (-b - (b * b - 4.0 * a * c).sqrt()) / (2.0 * a)
        })
        .collect();
    // A step of illumination down the middle: a penumbra on the cylinder.
    let il = illumination(w, h, |x, _| if x < 20 { 0.2 } else { 0.8 });
    let crease = ops::penumbra::crease_tolerance(45.0, 600);
    let with = filter(w, json!({ "radius": 2, "crease_tolerance": crease }));
    let without = filter(w, json!({ "radius": 2 }));
    let a = filtered(&*with, &inputs(il.clone(), depth.clone()));
    let b = filtered(&*without, &inputs(il, depth));
    assert_same_bits_f32(
        &a,
        &b,
        "a smooth cylinder filters as without the crease test",
    );
}

fn assert_same_bits_f32(a: &[f32], b: &[f32], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: length");
    for (k, (x, y)) in a.iter().zip(b).enumerate() {
        assert_eq!(x.to_bits(), y.to_bits(), "{what}: value {k}: {x} vs {y}");
    }
}

#[test]
fn a_tilted_plane_is_averaged_over_the_whole_window() {
    // A receiver seen at a slant (1/z changes by 3 % a pixel across): every tap of a 7×7
    // window lies on it, so the output is the plain mean of the window's diffuse values, and
    // specular is left alone (`specular: false`).
    let (w, h) = (21, 15);
    let depth = plane_depth(w, h, [0.0, 0.05, 0.3], 40.0);
    // Penumbra banding: one step every 3 columns.
    let step = |x: usize, _y: usize| (x / 3) as f32 * 0.125;
    let il = illumination(w, h, step);
    let op = filter(w, json!({ "kernel": "box" }));
    let out = filtered(&*op, &inputs(il.clone(), depth.clone()));
    for y in 3..h - 3 {
        for x in 3..w - 3 {
            let mut sum = 0.0f32;
            for qy in y - 3..=y + 3 {
                for qx in x - 3..=x + 3 {
                    sum += step(qx, qy);
                }
            }
            let p = (y * w + x) * 6;
            let want = sum / 49.0;
            assert!(
                (out[p] - want).abs() <= 1e-6,
                "({x},{y}): {} vs {want}",
                out[p]
            );
            assert_eq!(out[p + 3], il[p + 3], "specular kept");
        }
    }
    // The tent weighs tap (dx, dy) by (4 − |dx|)(4 − |dy|).
    let op = filter(w, json!({}));
    let out = filtered(&*op, &inputs(il.clone(), depth.clone()));
    let (x, y) = (10, 7);
    let (mut sum, mut n) = (0.0f32, 0.0f32);
    for dy in -3i32..=3 {
        for dx in -3i32..=3 {
            let wt = ((4 - dx.abs()) * (4 - dy.abs())) as f32;
            sum += wt * step((x as i32 + dx) as usize, 0);
            n += wt;
        }
    }
    assert!((out[(y * w + x) * 6] - sum / n).abs() <= 1e-6);
    // With `specular: true` the specular channels are averaged too.
    let op = filter(w, json!({ "specular": true }));
    let out = filtered(&*op, &inputs(il, depth));
    let p = (7 * w + 10) * 6;
    assert!((out[p + 3] - 2.0 * out[p]).abs() <= 1e-6);
}

#[test]
fn background_is_left_alone_and_never_counted() {
    let (w, h) = (9, 9);
    let il = illumination(w, h, |x, y| (x + y) as f32 * 0.1);
    // Background (0, NaN, -1, +Inf) in a ring around a flat surface at z = 5.
    let mut depth = vec![5.0f32; w * h];
    for (p, d) in depth.iter_mut().enumerate() {
        let (x, y) = (p % w, p / w);
        if x == 0 || y == 0 || x == w - 1 || y == h - 1 {
            *d = [0.0, f32::NAN, -1.0, f32::INFINITY][p % 4];
        }
    }
    let op = filter(w, json!({ "radius": 1, "kernel": "box" }));
    let out = filtered(&*op, &inputs(il.clone(), depth.clone()));
    for p in 0..w * h {
        let (x, y) = (p % w, p / w);
        if depth[p] != 5.0 {
            assert_eq!(&out[p * 6..p * 6 + 6], &il[p * 6..p * 6 + 6], "background");
            continue;
        }
        // Mean of the 3×3 neighbours that are on the surface.
        let (mut sum, mut n) = (0.0f32, 0.0f32);
        for qy in y - 1..=y + 1 {
            for qx in x - 1..=x + 1 {
                if depth[qy * w + qx] == 5.0 {
                    sum += il[(qy * w + qx) * 6];
                    n += 1.0;
                }
            }
        }
        assert!((out[p * 6] - sum / n).abs() <= 1e-6, "({x},{y})");
    }
}

/// Rows `y0..y0 + rows` of a band of `il`/`depth` extended by up to `halo` rows each side.
fn banded(
    op: &dyn Operator,
    il: &[f32],
    depth: &[f32],
    w: usize,
    band: usize,
    halo: usize,
) -> Vec<f32> {
    let h = depth.len() / w;
    let mut out = Vec::with_capacity(il.len());
    let mut y0 = 0;
    while y0 < h {
        let rows = band.min(h - y0);
        let (a, b) = (y0.saturating_sub(halo), (y0 + rows + halo).min(h));
        let ins = inputs(
            il[a * w * 6..b * w * 6].to_vec(),
            depth[a * w..b * w].to_vec(),
        );
        let got = filtered(op, &ins);
        out.extend_from_slice(&got[(y0 - a) * w * 6..(y0 - a + rows) * w * 6]);
        y0 += rows;
    }
    out
}

#[test]
fn bands_with_their_halo_give_the_whole_frames_bits() {
    let (w, h) = (17, 23);
    let mut r = rng(7);
    let il: Vec<f32> = (0..w * h * 6).map(|_| ordinary(&mut r)).collect();
    // Two planes and a gap: silhouettes and slopes in every band.
    let a = plane_depth(w, h, [0.01, 0.03, 0.3], 30.0);
    let depth: Vec<f32> = (0..w * h)
        .map(|p| {
            if (p % w + p / w) % 11 < 4 {
                a[p] * 1.5
            } else if p % 13 == 0 {
                0.0
            } else {
                a[p]
            }
        })
        .collect();
    // With the crease test (a tolerance the tilted plane's slopes meet and the gaps' do not) a
    // tap's own slope is read too: two more rows of halo.
    for (radius, crease) in [
        (1, None),
        (3, None),
        (5, None),
        (1, Some(0.05)),
        (3, Some(0.05)),
    ] {
        let mut params = json!({ "radius": radius, "specular": true });
        if let Some(t) = crease {
            params["crease_tolerance"] = json!(t);
        }
        let op = filter(w, params);
        let whole = filtered(&*op, &inputs(il.clone(), depth.clone()));
        let halo = ops::penumbra::halo_rows(radius, crease.is_some()) as usize;
        let want = if crease.is_some() {
            radius + 2
        } else {
            radius.max(2)
        };
        assert_eq!(halo, want as usize);
        for band in [halo, 4, 7, 16] {
            if band < halo {
                continue;
            }
            let got = banded(&*op, &il, &depth, w, band, halo);
            assert_eq!(got.len(), whole.len());
            for (k, (g, x)) in got.iter().zip(&whole).enumerate() {
                assert_eq!(
                    g.to_bits(),
                    x.to_bits(),
                    "r={radius} crease={crease:?} band={band} value {k}"
                );
            }
            // Negative control: without the halo the band edges differ.
            let cut = banded(&*op, &il, &depth, w, band, 0);
            assert!(
                cut.iter().zip(&whole).any(|(a, b)| a != b),
                "r={radius} band={band}"
            );
        }
    }
}

#[test]
fn fast_matches_reference_on_hostile_values() {
    for (w, h) in [(1, 1), (1, 9), (7, 1), (13, 11), (64, 70), (33, 130)] {
        for seed in 0..3u64 {
            let mut r = rng(seed * 31 + w as u64);
            let il: Vec<f32> = (0..w * h * 6).map(|_| hostile(&mut r)).collect();
            // Depths: mostly a noisy plane, with hostile values mixed in.
            let depth: Vec<f32> = (0..w * h)
                .map(|_| {
                    if r.random_range(0..5) == 0 {
                        hostile(&mut r)
                    } else {
                        r.random_range(4.0..4.2f32)
                    }
                })
                .collect();
            for params in [
                json!({ "width": w }),
                json!({ "width": w, "kernel": "box", "radius": 2 }),
                json!({ "width": w, "radius": 8, "specular": true, "depth_tolerance": 0.5 }),
                json!({ "width": w, "radius": 3, "crease_tolerance": 1e-4 }),
                json!({ "width": w, "crease_tolerance": 3.0e38, "depth_tolerance": 1e30 }),
            ] {
                let op = ops::create("penumbra", &params).unwrap();
                let out = filtered(&*op, &inputs(il.clone(), depth.clone()));
                assert!(out.iter().all(|v| v.is_finite() && *v >= 0.0), "{params}");
            }
        }
    }
}

#[test]
fn parameters_and_band_shape_are_checked() {
    for bad in [
        json!({}),
        json!({ "width": 0 }),
        json!({ "width": 8, "radius": 0 }),
        json!({ "width": 8, "radius": 9 }),
        json!({ "width": 8, "depth_tolerance": 0.0 }),
        json!({ "width": 8, "depth_tolerance": -1.0 }),
        json!({ "width": 8, "crease_tolerance": 0.0 }),
        json!({ "width": 8, "crease_tolerance": -1e-4 }),
        json!({ "width": 8, "crease_tolerance": "flat" }),
        json!({ "width": 8, "blur": 1 }),
        json!({ "width": 8, "kernel": "gauss" }),
    ] {
        let e = ops::create("penumbra", &bad).expect_err(&bad.to_string());
        assert!(matches!(e, OpError::BadParam { .. }), "{bad}: {e}");
    }
    // A band that is not whole rows is refused, not misread.
    let op = filter(8, json!({}));
    let (il, depth) = (vec![0.5f32; 12 * 6], vec![1.0f32; 12]);
    let views = [
        BandView::new(12).with(ILL, &il),
        BandView::new(12).with(DEPTH, &depth),
    ];
    let mut o = vec![0.0f32; 12 * 6];
    let mut out = BandMut::new(12).with(ILL, &mut o);
    assert!(matches!(
        op.apply(&views, &mut out),
        Err(OpError::BadParam { .. })
    ));
    assert!(matches!(
        op.apply_scalar(&views, &mut out),
        Err(OpError::BadParam { .. })
    ));
}
