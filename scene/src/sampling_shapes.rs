//! Sampling of disk, sphere, cylinder and emissive-mesh area lights and of soft suns (rectangles
//! live in `sampling`).
//!
//! Every shape maps the same stratified unit-square points (`sampling::unit_square_points`, so the
//! quality pattern and seed apply) onto its surface with an area-preserving map, and gives each of
//! the N samples the intensity `L·A/N`: the samples together emit exactly the light's power. A
//! soft sun maps them onto the cap of directions its disk covers, equal solid angle to each.

use crate::model::{AreaShape, Light, LightSample, LightShape, Quality, SampleKind, Scene};
use crate::sampling::{analytic, lobe, unit_square_points};
use crate::shading::{V3, add, cross, length, normalize, scale, sub};
use std::f32::consts::{FRAC_PI_2, FRAC_PI_4, PI, TAU};

pub(crate) fn samples(
    scene: &Scene,
    light: &Light,
    shape: &LightShape,
    n: u32,
    q: &Quality,
    base: LightSample,
) -> Vec<LightSample> {
    let seed = q.seed ^ base.light as u64;
    let points = || unit_square_points(n, q.pattern, seed);
    match shape {
        LightShape::Disk {
            center,
            normal,
            radius,
        } => {
            let nrm = normalize(*normal);
            let (u, v) = basis(nrm);
            let intensity = light.power * PI * radius * radius / n as f32;
            let base = LightSample {
                area: analytic(q, || AreaShape::Disk {
                    center: *center,
                    u: scale(u, *radius),
                    v: scale(v, *radius),
                }),
                ..base
            };
            points()
                .into_iter()
                .map(|(a, b)| {
                    let (x, y) = concentric(a, b);
                    let p = add(*center, add(scale(u, x * radius), scale(v, y * radius)));
                    lobe(base, p, nrm, intensity)
                })
                .collect()
        }
        LightShape::Sphere { center, radius } => {
            let intensity = light.power * 4.0 * PI * radius * radius / n as f32;
            let base = LightSample {
                area: analytic(q, || AreaShape::Sphere {
                    center: *center,
                    radius: *radius,
                }),
                ..base
            };
            points()
                .into_iter()
                .map(|(a, b)| {
                    let d = sphere_direction(a, b);
                    lobe(base, add(*center, scale(d, *radius)), d, intensity)
                })
                .collect()
        }
        LightShape::EmissiveMesh { mesh } => {
            let Some(m) = scene.meshes.get(*mesh) else {
                tracing::warn!(light = %light.name, mesh, "emissive mesh index out of range");
                return Vec::new();
            };
            let two_sided = scene
                .materials
                .get(m.material)
                .is_some_and(|mat| mat.double_sided);
            mesh_samples(
                &m.positions,
                &m.indices,
                two_sided,
                light.power,
                &points(),
                base,
            )
        }
        LightShape::Cylinder {
            center,
            axis,
            length,
            radius,
        } => {
            let ax = normalize(*axis);
            let (u, v) = basis(ax);
            let intensity = light.power * TAU * radius * length / n as f32;
            points()
                .into_iter()
                .map(|(a, b)| {
                    let (s, c) = (TAU * b).sin_cos();
                    let nrm = add(scale(u, c), scale(v, s));
                    let p = add(
                        *center,
                        add(scale(ax, (a - 0.5) * length), scale(nrm, *radius)),
                    );
                    lobe(base, p, nrm, intensity)
                })
                .collect()
        }
        LightShape::Directional { direction, angle } => {
            let d = normalize(*direction);
            let (u, v) = basis(d);
            // 1 − cos α of the cap's half-angle α, without cancellation at the sun's 0.27°.
            let k = 2.0 * (0.25 * angle.min(PI)).sin().powi(2);
            // The mean cosine over the cap is 1 − k/2: a surface facing the sun receives `power`.
            let intensity = light.power / n as f32 / (1.0 - 0.5 * k);
            points()
                .into_iter()
                .map(|(a, b)| {
                    let (x, y) = concentric(a, b);
                    let r2 = x * x + y * y;
                    let w = if r2 > 0.0 {
                        let t = r2 * k;
                        (t * (2.0 - t)).max(0.0).sqrt() / r2.sqrt()
                    } else {
                        0.0
                    };
                    let dir = add(
                        scale(d, 1.0 - r2 * k),
                        add(scale(u, x * w), scale(v, y * w)),
                    );
                    LightSample {
                        direction: normalize(dir),
                        kind: SampleKind::Directional,
                        intensity,
                        ..base
                    }
                })
                .collect()
        }
        // Point, spot, parallel directional and rectangle lights are handled in `sampling`.
        _ => Vec::new(),
    }
}

/// An orthonormal pair spanning the plane perpendicular to unit `n` (deterministic).
pub fn basis(n: V3) -> (V3, V3) {
    let helper = if n[0].abs() < 0.9 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let u = normalize(cross(helper, n));
    (u, cross(n, u))
}

/// Shirley–Chiu concentric map of the unit square onto the unit disk (area-preserving, keeps
/// strata compact).
pub(crate) fn concentric(a: f32, b: f32) -> (f32, f32) {
    let x = 2.0 * a - 1.0;
    let y = 2.0 * b - 1.0;
    if x == 0.0 && y == 0.0 {
        return (0.0, 0.0);
    }
    let (r, theta) = if x.abs() > y.abs() {
        (x, FRAC_PI_4 * (y / x))
    } else {
        (y, FRAC_PI_2 - FRAC_PI_4 * (x / y))
    };
    (r * theta.cos(), r * theta.sin())
}

/// Equal-area map of the unit square onto the unit sphere (Archimedes' cylinder projection).
pub(crate) fn sphere_direction(a: f32, b: f32) -> V3 {
    let y = 1.0 - 2.0 * b;
    let s = (1.0 - y * y).max(0.0).sqrt();
    let phi = TAU * a;
    [s * phi.cos(), y, s * phi.sin()]
}

/// Area-weighted stratified samples over a triangle list: the first coordinate picks the triangle
/// through the cumulative-area table and is then reused inside it, so strata stay intact.
fn mesh_samples(
    positions: &[V3],
    indices: &[u32],
    two_sided: bool,
    radiance: f32,
    points: &[(f32, f32)],
    base: LightSample,
) -> Vec<LightSample> {
    let mut tris: Vec<(V3, V3, V3, V3)> = Vec::new();
    let mut cdf: Vec<f64> = Vec::new();
    let mut total = 0.0f64;
    for t in indices.chunks_exact(3) {
        let get = |i: u32| positions.get(i as usize).copied();
        let (Some(p0), Some(p1), Some(p2)) = (get(t[0]), get(t[1]), get(t[2])) else {
            continue;
        };
        let c = cross(sub(p1, p0), sub(p2, p0));
        let area = 0.5 * length(c);
        if !(area > 0.0 && area.is_finite()) {
            continue;
        }
        total += area as f64;
        cdf.push(total);
        tris.push((p0, p1, p2, normalize(c)));
    }
    if tris.is_empty() || points.is_empty() {
        return Vec::new();
    }
    let intensity = (radiance as f64 * total / points.len() as f64) as f32;
    let kind = if two_sided {
        SampleKind::TwoSidedLobe
    } else {
        SampleKind::CosineLobe
    };
    points
        .iter()
        .map(|&(a, b)| {
            let target = a as f64 * total;
            let k = cdf.partition_point(|&c| c <= target).min(tris.len() - 1);
            let lo = if k == 0 { 0.0 } else { cdf[k - 1] };
            let a2 = (((target - lo) / (cdf[k] - lo)) as f32).clamp(0.0, 1.0);
            let (p0, p1, p2, nrm) = tris[k];
            let su = a2.sqrt();
            let (b0, b1) = (1.0 - su, b * su);
            let p = add(add(scale(p0, b0), scale(p1, b1)), scale(p2, 1.0 - b0 - b1));
            LightSample {
                kind,
                ..lobe(base, p, nrm, intensity)
            }
        })
        .collect()
}

/// Radiant power (W, scalar) of one sample: `π·I` for a cosine lobe, `2π·I` two-sided.
pub fn sample_power(s: &LightSample) -> Option<f64> {
    match s.kind {
        SampleKind::CosineLobe | SampleKind::Bounce { .. } => Some(PI as f64 * s.intensity as f64),
        SampleKind::TwoSidedLobe => Some(2.0 * PI as f64 * s.intensity as f64),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Material, SamplePattern};
    use crate::primitives;
    use crate::sampling::{direct_samples, light_samples};

    fn area_light(name: &str, shape: LightShape, power: f32, samples: u32) -> Light {
        Light {
            name: name.into(),
            shape,
            color: [1.0, 0.5, 0.25],
            power,
            range: None,
            samples,
        }
    }

    fn test_scene() -> Scene {
        let mut s = Scene::new("sampling");
        let one = s.add_material(Material {
            double_sided: false,
            transmission: None,
            ..Material::diffuse("one-sided", [0.5; 3])
        });
        let two = s.add_material(Material::diffuse("two-sided", [0.5; 3]));
        let ball = s.add_mesh(primitives::sphere("lamp", [1.0, 2.0, 0.0], 0.3, 12, 6, one));
        let panel = s.add_mesh(primitives::cuboid(
            "panel",
            [0.0, 3.0, 0.0],
            [0.4, 0.1, 0.2],
            two,
        ));
        s.lights = vec![
            area_light(
                "rect",
                LightShape::Rect {
                    center: [0.0, 4.0, 0.0],
                    normal: [0.0, -1.0, 0.0],
                    u_axis: [1.0, 0.0, 0.0],
                    size: [1.5, 0.5],
                },
                7.0,
                16,
            ),
            area_light(
                "disk",
                LightShape::Disk {
                    center: [2.0, 3.0, 1.0],
                    normal: [0.3, -1.0, 0.2],
                    radius: 0.4,
                },
                11.0,
                16,
            ),
            area_light(
                "sphere",
                LightShape::Sphere {
                    center: [-2.0, 2.0, 0.0],
                    radius: 0.25,
                },
                3.0,
                32,
            ),
            area_light("mesh", LightShape::EmissiveMesh { mesh: ball }, 5.0, 16),
            area_light(
                "two-sided mesh",
                LightShape::EmissiveMesh { mesh: panel },
                2.0,
                9,
            ),
            area_light(
                "tube",
                LightShape::Cylinder {
                    center: [0.5, 3.5, -1.0],
                    axis: [1.0, 0.2, 0.0],
                    length: 1.2,
                    radius: 0.05,
                },
                9.0,
                16,
            ),
        ];
        s
    }

    #[test]
    fn samples_emit_the_area_lights_power() {
        let mut s = test_scene();
        for pattern in [
            SamplePattern::Grid,
            SamplePattern::Jittered,
            SamplePattern::Halton,
        ] {
            for n in [1, 5, 16, 32, 33] {
                s.quality.pattern = pattern;
                s.quality.samples_per_area_light = Some(n);
                for (i, light) in s.lights.iter().enumerate() {
                    let samples = light_samples(&s, i, &s.quality);
                    assert_eq!(samples.len(), n as usize, "{} {pattern:?}", light.name);
                    let total: f64 = samples.iter().map(|x| sample_power(x).unwrap()).sum();
                    let exact = s.area_light_power(light).unwrap();
                    let rel = (total - exact).abs() / exact;
                    assert!(
                        rel < 1e-6,
                        "{} {pattern:?} n={n}: {total} vs {exact}",
                        light.name
                    );
                }
            }
        }
    }

    /// A soft sun's parallel lights lie within its disk on the sky, are spread about its axis,
    /// and together give a surface facing it exactly its irradiance.
    #[test]
    fn a_soft_sun_spreads_its_irradiance_over_its_disk() {
        let mut s = Scene::new("sun");
        let axis = normalize([0.3, -1.0, 0.2]);
        for angle_deg in [0.53f32, 10.0, 90.0] {
            let angle = angle_deg.to_radians();
            s.lights = vec![area_light(
                "sun",
                LightShape::Directional {
                    direction: [0.3, -1.0, 0.2],
                    angle,
                },
                2.0,
                16,
            )];
            for pattern in [
                SamplePattern::Grid,
                SamplePattern::Jittered,
                SamplePattern::Halton,
            ] {
                for n in [1, 16, 33, 256] {
                    s.quality.pattern = pattern;
                    s.quality.samples_per_area_light = Some(n);
                    let samples = light_samples(&s, 0, &s.quality);
                    assert_eq!(samples.len(), n as usize);
                    let mut irradiance = 0.0f64;
                    let mut mean = [0.0f64; 3];
                    for x in &samples {
                        assert_eq!(x.kind, SampleKind::Directional);
                        let c = crate::shading::dot(x.direction, axis);
                        assert!(
                            c >= (angle / 2.0).cos() - 1e-5,
                            "{angle_deg}° {pattern:?}: cos {c} outside the disk"
                        );
                        irradiance += f64::from(x.intensity) * f64::from(c);
                        for (m, d) in mean.iter_mut().zip(x.direction) {
                            *m += f64::from(d) / f64::from(n);
                        }
                    }
                    // The mean cosine of N stratified points is the cap's within its spread.
                    let spread = 1.0 - f64::from((angle / 2.0).cos());
                    let tol = 1e-5 + if n == 1 { spread } else { spread / 4.0 };
                    assert!(
                        (irradiance - 2.0).abs() / 2.0 < tol,
                        "{angle_deg}° {pattern:?} n={n}: {irradiance}"
                    );
                    // Centred: the mean direction is near the axis (one jittered point
                    // may lie anywhere in the disk).
                    if n > 1 {
                        let m = normalize(mean.map(|c| c as f32));
                        let off = crate::shading::dot(m, axis).clamp(-1.0, 1.0).acos();
                        assert!(
                            off < 0.2 * angle / 2.0 + 1e-3,
                            "{angle_deg}° {pattern:?} n={n}: mean direction {m:?}, {off} rad off"
                        );
                    }
                }
            }
        }
        // Parallel (angle 0): one exact sample of the whole irradiance.
        s.lights[0].shape = LightShape::Directional {
            direction: axis,
            angle: 0.0,
        };
        let one = light_samples(&s, 0, &s.quality);
        assert_eq!(one.len(), 1);
        assert_eq!(one[0].intensity, 2.0);
    }

    #[test]
    fn two_sided_meshes_give_two_sided_lobes() {
        let s = test_scene();
        let one = light_samples(&s, 3, &s.quality);
        let two = light_samples(&s, 4, &s.quality);
        assert!(one.iter().all(|x| x.kind == SampleKind::CosineLobe));
        assert!(two.iter().all(|x| x.kind == SampleKind::TwoSidedLobe));
        let exact = s.area_light_power(&s.lights[4]).unwrap();
        let area = crate::scene_ops::mesh_area(&s.meshes[1]);
        assert!((exact - 2.0 * std::f64::consts::PI * 2.0 * area).abs() < 1e-9 * exact);
    }

    #[test]
    fn samples_lie_on_their_shapes_and_face_outwards() {
        let s = test_scene();
        for x in light_samples(&s, 1, &s.quality) {
            let d = sub(x.position, [2.0, 3.0, 1.0]);
            assert!(length(d) <= 0.4 + 1e-5);
            assert!(crate::shading::dot(d, x.direction).abs() < 1e-5);
        }
        for x in light_samples(&s, 2, &s.quality) {
            let d = sub(x.position, [-2.0, 2.0, 0.0]);
            assert!((length(d) - 0.25).abs() < 1e-5);
            assert!(crate::shading::dot(normalize(d), x.direction) > 0.9999);
        }
        for x in light_samples(&s, 3, &s.quality) {
            let d = sub(x.position, [1.0, 2.0, 0.0]);
            assert!(length(d) <= 0.3 + 1e-5);
            assert!(crate::shading::dot(d, x.direction) > 0.0);
        }
        // The tube: on its side (distance 0.05 from the axis, within its length), facing out.
        let axis = normalize([1.0, 0.2, 0.0]);
        for x in light_samples(&s, 5, &s.quality) {
            let d = sub(x.position, [0.5, 3.5, -1.0]);
            let along = crate::shading::dot(d, axis);
            let radial = sub(d, scale(axis, along));
            assert!(along.abs() <= 0.6 + 1e-5, "{along}");
            assert!((length(radial) - 0.05).abs() < 1e-5, "{radial:?}");
            assert!(crate::shading::dot(normalize(radial), x.direction) > 0.9999);
        }
    }

    #[test]
    fn grid_is_the_default_and_deterministic() {
        let s = test_scene();
        assert_eq!(s.quality.pattern, SamplePattern::Grid);
        assert_eq!(
            crate::model::Quality::default().pattern,
            SamplePattern::Grid
        );
        let a = direct_samples(&s);
        let b = direct_samples(&test_scene());
        assert_eq!(a, b);
        assert_eq!(a.len(), 16 + 16 + 32 + 16 + 9 + 16);
        // The grid ignores the seed; jittered sets depend on it.
        let mut t = test_scene();
        t.quality.seed = 99;
        assert_eq!(direct_samples(&t), a);
        t.quality.pattern = SamplePattern::Jittered;
        let j99 = direct_samples(&t);
        assert_eq!(j99, direct_samples(&t));
        t.quality.seed = 100;
        assert_ne!(direct_samples(&t), j99);
    }

    #[test]
    fn disk_grid_is_symmetric_about_the_centre() {
        let s = test_scene();
        let pts = light_samples(&s, 1, &s.quality);
        let mean = pts.iter().fold([0.0; 3], |acc, x| {
            add(acc, scale(x.position, 1.0 / pts.len() as f32))
        });
        assert!(length(sub(mean, [2.0, 3.0, 1.0])) < 1e-5, "{mean:?}");
    }

    #[test]
    fn concentric_map_stays_in_the_disk() {
        for (a, b) in unit_square_points(64, SamplePattern::Halton, 0) {
            let (x, y) = concentric(a, b);
            assert!(x * x + y * y <= 1.0 + 1e-6);
        }
        assert_eq!(concentric(0.5, 0.5), (0.0, 0.0));
    }
}
