//! glTF metallic-roughness on the GPU (issue 23): the specification's reference BRDF against a
//! closed form written here from the specification, and against the CPU reference's evaluation
//! (both eye variants) on a metal, a rough dielectric and a sphere and tile carrying every texture
//! (base colour, metallic-roughness, normal, occlusion, emissive). Negative controls: the former
//! Blinn-Phong mapping fails the closed form; the textured scene without its normal map fails the
//! reference comparison.

use crate::gpu_support;

use gpu_support::*;
use lightfold_node::gpu::{EyeVariant, Gpu, LayerSet, NodeFrame, RenderOptions, Renderer};
use lightfold_protocol::stats;
use lightfold_reference::render_point_sum;
use lightfold_scene::primitives::{plane, sphere};
use lightfold_scene::{
    Camera, Image, Light, LightSample, LightShape, Material, MetallicRoughness, Scene, Texture,
};

const W: u32 = 160;
const H: u32 = 120;

fn camera(position: [f32; 3], target: [f32; 3], fov: f32) -> Camera {
    Camera {
        position,
        target,
        up: [0.0, 1.0, 0.0],
        fov_y_deg: fov,
        width: W,
        height: H,
    }
}

fn render(gpu: &Gpu, scene: &Scene, samples: &[LightSample], variant: EyeVariant) -> NodeFrame {
    let opts = RenderOptions::from_quality(&scene.quality);
    let mut r = Renderer::new(gpu, scene, opts).expect("renderer");
    r.set_variant(variant);
    r.render(gpu, samples, None, [1.0; 3], LayerSet::all())
        .expect("render")
}

/// `m^d⊙I^d + m^s⊙I^s` of a frame (no ambient or emission in these scenes' checks).
fn reflected(frame: &NodeFrame) -> Image {
    let il = frame.illumination.as_ref().expect("illumination");
    let md = frame.diffuse.as_ref().expect("m^d");
    let ms = frame.specular.as_ref().expect("m^s");
    let mut out = Image::new(il.width, il.height, 3);
    for i in 0..il.pixel_count() {
        for k in 0..3 {
            out.data[i * 3 + k] = md.data[i * 3 + k] * il.data[i * 6 + k]
                + ms.data[i * 3 + k] * il.data[i * 6 + 3 + k];
        }
    }
    out
}

// ---- the closed form -------------------------------------------------------------------------

/// The glTF 2.0 specification's reference BRDF (Appendix B, "Implementation"), in f64, times
/// `n·l`: `(1 − F)·c_diff/π + F·D·V`, `F = F0 + (1 − F0)(1 − |v·h|)⁵`, `c_diff = base·(1 − m)`,
/// `F0 = mix(0.04, base, m)`, `α = roughness²`.
fn gltf_brdf_cos(
    base: [f64; 3],
    metallic: f64,
    roughness: f64,
    n: [f64; 3],
    l: [f64; 3],
    v: [f64; 3],
) -> [f64; 3] {
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let nl = dot(n, l);
    if nl <= 0.0 {
        return [0.0; 3];
    }
    let nv = dot(n, v).max(0.0);
    let h = {
        let s = [l[0] + v[0], l[1] + v[1], l[2] + v[2]];
        let len = dot(s, s).sqrt();
        s.map(|c| c / len)
    };
    let nh = dot(n, h).max(0.0);
    let vh = dot(v, h).abs();
    let a = roughness * roughness;
    let a2 = a * a;
    let d = a2 / (std::f64::consts::PI * (nh * nh * (a2 - 1.0) + 1.0).powi(2));
    let vis =
        0.5 / (nl * (nv * nv * (1.0 - a2) + a2).sqrt() + nv * (nl * nl * (1.0 - a2) + a2).sqrt());
    [0, 1, 2].map(|k| {
        let f0 = 0.04 + (base[k] - 0.04) * metallic;
        let f = f0 + (1.0 - f0) * (1.0 - vh).powi(5);
        let c_diff = base[k] * (1.0 - metallic);
        ((1.0 - f) * c_diff / std::f64::consts::PI + f * d * vis) * nl
    })
}

const E0: f32 = 3.0;

/// One sphere (radius 1 at the origin) under one directional light of irradiance `E0`.
fn lone_sphere(material: Material) -> (Scene, Vec<LightSample>) {
    let mut s = Scene::new("lone sphere");
    let m = s.add_material(material);
    s.add_mesh(sphere("ball", [0.0; 3], 1.0, 256, 128, m));
    s.camera = camera([0.0, 0.0, 4.0], [0.0; 3], 40.0);
    let travel = lightfold_scene::shading::normalize([-0.6, -0.5, -0.62]);
    let samples = vec![LightSample {
        position: [0.0; 3],
        direction: travel,
        kind: lightfold_scene::SampleKind::Directional,
        intensity: E0,
        color: [1.0; 3],
        range: None,
        light: 0,
        area: None,
        cell: 0.0,
    }];
    (s, samples)
}

/// Per pixel where the exact sphere is seen head-on enough (`n·v > 0.3`) and lit (`n·l > 0.1`):
/// the relative error of the frame's radiance against the closed form; its largest and median.
fn closed_form_errors(
    frame: &NodeFrame,
    scene: &Scene,
    base: [f64; 3],
    metallic: f64,
    roughness: f64,
) -> (f64, f64, usize) {
    let got = reflected(frame);
    let cam = &scene.camera;
    let o = cam.position.map(f64::from);
    let l = [0.6f64, 0.5, 0.62];
    let ll = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt();
    let l = l.map(|c| c / ll);
    let mut errors = Vec::new();
    for y in 0..cam.height {
        for x in 0..cam.width {
            let d = cam.ray_dir(x as f32 + 0.5, y as f32 + 0.5).map(f64::from);
            // |o + t·d|² = 1.
            let b = o[0] * d[0] + o[1] * d[1] + o[2] * d[2];
            let c = o[0] * o[0] + o[1] * o[1] + o[2] * o[2] - 1.0;
            let disc = b * b - c;
            if disc <= 0.0 {
                continue;
            }
            let t = -b - disc.sqrt();
            let n = [0, 1, 2].map(|k| o[k] + t * d[k]);
            let v = d.map(|c| -c);
            let nv = n[0] * v[0] + n[1] * v[1] + n[2] * v[2];
            let nl = n[0] * l[0] + n[1] * l[1] + n[2] * l[2];
            if nv < 0.3 || nl < 0.1 {
                continue;
            }
            let want = gltf_brdf_cos(base, metallic, roughness, n, l, v);
            let i = (y * cam.width + x) as usize;
            for (w, &g) in want.iter().zip(&got.data[i * 3..i * 3 + 3]) {
                let w = w * f64::from(E0);
                errors.push((f64::from(g) - w).abs() / w.max(1e-3));
            }
        }
    }
    let errors = stats::sorted(&errors);
    let median = stats::median(&errors).expect("lit pixels");
    (errors[errors.len() - 1], median, errors.len())
}

#[test]
fn a_white_sphere_has_the_closed_form_radiance_of_the_gltf_brdf() {
    let gpu = gpu();
    // Rough white dielectric (the "diffuse white" of glTF), a half-rough one and a rough gold.
    for (base, metallic, roughness) in [
        ([1.0f32, 1.0, 1.0], 0.0f32, 1.0f32),
        ([1.0, 1.0, 1.0], 0.0, 0.5),
        ([1.0, 0.78, 0.34], 1.0, 0.6),
    ] {
        let pbr = MetallicRoughness::new(base, metallic, roughness);
        let (scene, samples) = lone_sphere(Material::metallic_roughness("white", pbr));
        for variant in [EyeVariant::Forward, EyeVariant::Deferred] {
            let frame = render(&gpu, &scene, &samples, variant);
            let (max, median, n) = closed_form_errors(
                &frame,
                &scene,
                base.map(f64::from),
                f64::from(metallic),
                f64::from(roughness),
            );
            eprintln!(
                "{base:?} metallic {metallic} roughness {roughness} {variant:?}: {n} values, relative error max {max:.2e}, median {median:.2e}"
            );
            assert!(n > 10_000, "{n}");
            // The mesh's facets and interpolated normals are all that differ from the sphere.
            assert!(
                max < 0.02 && median < 2e-3,
                "max {max:.3e} median {median:.3e}"
            );
        }
    }
    // Negative control: the former mapping onto Blinn-Phong (full diffuse base·(1 − m), a
    // 0.04 lobe on top, the Beckmann-matched exponent) misses the closed form.
    let old = Material {
        specular: [0.04; 3],
        shininess: lightfold_scene::shading::shininess_from_roughness(0.5),
        ..Material::diffuse("former", [1.0; 3])
    };
    let (scene, samples) = lone_sphere(old);
    let frame = render(&gpu, &scene, &samples, EyeVariant::Deferred);
    let (max, median, _) = closed_form_errors(&frame, &scene, [1.0; 3], 0.0, 0.5);
    eprintln!("former mapping: max {max:.2e}, median {median:.2e}");
    assert!(
        max > 0.05 && median > 0.02,
        "the control passed: {max} {median}"
    );
}

#[test]
fn a_rough_gltf_sphere_reflects_no_more_than_a_lambertian_one() {
    // The energy the issue found added: the specular lobe on top of the full diffuse gave a grey
    // diffuse glTF scene +7.5 %. Under the specification's BRDF the rough sphere reflects less
    // than a Lambertian one of the same base colour (Fresnel-weighted diffuse, single-scatter
    // GGX), and not much less.
    let gpu = gpu();
    let grey = [0.5f32; 3];
    let total = |m: Material| {
        let (scene, samples) = lone_sphere(m);
        let img = reflected(&render(&gpu, &scene, &samples, EyeVariant::Deferred));
        img.data.iter().map(|&v| f64::from(v)).sum::<f64>()
    };
    let lambert = total(Material::diffuse("lambert", grey));
    let gltf = total(Material::metallic_roughness(
        "gltf",
        MetallicRoughness::new(grey, 0.0, 1.0),
    ));
    let ratio = gltf / lambert;
    eprintln!("rough grey glTF / Lambertian: {ratio:.4}");
    assert!(ratio < 1.0 && ratio > 0.9, "{ratio}");
}

// ---- against the CPU reference ---------------------------------------------------------------

fn texture(name: &str, n: u32, srgb: bool, texel: impl Fn(u32, u32) -> [u8; 4]) -> Texture {
    let mut rgba8 = Vec::with_capacity((n * n * 4) as usize);
    for y in 0..n {
        for x in 0..n {
            rgba8.extend_from_slice(&texel(x, y));
        }
    }
    Texture {
        name: name.into(),
        width: n,
        height: n,
        srgb,
        rgba8,
    }
}

/// Per-vertex tangents as a model would ship them: each vertex's adjacent triangles' tangents
/// summed and normalised, the handedness of the first (a sphere's UVs are not mirrored).
fn smooth_tangents(mesh: &lightfold_scene::Mesh) -> Vec<[f32; 4]> {
    let mut acc = vec![[0.0f32; 4]; mesh.positions.len()];
    for t in mesh.indices.chunks_exact(3) {
        let i = [t[0], t[1], t[2]].map(|i| i as usize);
        let tt = lightfold_scene::shading::triangle_tangent(
            i.map(|i| mesh.positions[i]),
            i.map(|i| mesh.uvs[i]),
        );
        for &v in &i {
            for k in 0..3 {
                acc[v][k] += tt[k];
            }
            if acc[v][3] == 0.0 {
                acc[v][3] = tt[3];
            }
        }
    }
    acc.iter()
        .map(|a| {
            let [x, y, z] = lightfold_scene::shading::normalize([a[0], a[1], a[2]]);
            [x, y, z, a[3]]
        })
        .collect()
}

/// A floor, a gold sphere, a rough red dielectric sphere, and a sphere and a tile with every
/// texture (the sphere with per-vertex tangents, the tile with its triangles' own); two lights
/// (a 4-sample panel and a point).
fn spheres(normal_map: bool) -> Scene {
    let mut s = Scene::new("metallic-roughness spheres");
    let floor = s.add_material(Material::diffuse("floor", [0.6, 0.6, 0.6]));
    let gold = s.add_material(Material::metallic_roughness(
        "gold",
        MetallicRoughness::new([1.0, 0.78, 0.34], 1.0, 0.35),
    ));
    let red = s.add_material(Material::metallic_roughness(
        "rough red",
        MetallicRoughness::new([0.8, 0.2, 0.15], 0.0, 0.7),
    ));
    let base = s.textures.len();
    s.textures.push(texture("base", 16, true, |x, y| {
        if (x / 4 + y / 4) % 2 == 0 {
            [230, 200, 160, 255]
        } else {
            [90, 140, 200, 255]
        }
    }));
    s.textures
        .push(texture("metallic-roughness", 16, false, |x, y| {
            [
                0,
                (40 + 12 * x) as u8,
                if y / 4 % 2 == 0 { 255 } else { 0 },
                255,
            ]
        }));
    s.textures.push(texture("normal", 32, false, |x, y| {
        let a = (x as f32 / 32.0 * std::f32::consts::TAU * 2.0).sin() * 0.45;
        let b = (y as f32 / 32.0 * std::f32::consts::TAU).cos() * 0.3;
        let z = (1.0 - a * a - b * b).sqrt();
        let q = |c: f32| ((c * 0.5 + 0.5) * 255.0).round() as u8;
        [q(a), q(b), q(z), 255]
    }));
    s.textures.push(texture("occlusion", 8, false, |x, y| {
        [(120 + 17 * ((x * 3 + y * 5) % 8)) as u8, 0, 0, 255]
    }));
    s.textures.push(texture("emissive", 8, true, |x, y| {
        if (x + y) % 5 == 0 {
            [255, 200, 90, 255]
        } else {
            [0, 0, 0, 255]
        }
    }));
    let mut every = MetallicRoughness::new([1.0; 3], 1.0, 1.0);
    every.metallic_roughness_texture = Some(base + 1);
    every.normal_texture = normal_map.then_some(base + 2);
    every.normal_scale = 0.8;
    every.occlusion_texture = Some(base + 3);
    every.occlusion_strength = 0.7;
    every.emissive_texture = Some(base + 4);
    let textured = s.add_material(Material {
        diffuse_texture: Some(base),
        emissive: [0.3, 0.2, 0.1],
        ..Material::metallic_roughness("every texture", every)
    });
    let (x, y) = ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
    s.add_mesh(plane("floor", [0.0; 3], y, x, [8.0, 8.0], 4, floor));
    s.add_mesh(sphere("gold", [-1.3, 0.6, 0.0], 0.6, 96, 48, gold));
    s.add_mesh(sphere("red", [0.0, 0.6, -0.4], 0.6, 96, 48, red));
    let mut ball = sphere("textured", [1.3, 0.6, 0.0], 0.6, 96, 48, textured);
    ball.tangents = smooth_tangents(&ball);
    s.add_mesh(ball);
    s.add_mesh(plane(
        "tile",
        [0.2, 0.01, 1.2],
        y,
        x,
        [1.6, 0.8],
        2,
        textured,
    ));
    s.lights = vec![
        Light {
            name: "panel".into(),
            shape: LightShape::Rect {
                center: [1.0, 3.0, 2.0],
                normal: lightfold_scene::shading::normalize([-0.3, -1.0, -0.6]),
                u_axis: x,
                size: [0.6, 0.6],
            },
            color: [1.0, 0.95, 0.9],
            power: 12.0,
            range: None,
            samples: 4,
        },
        Light {
            name: "point".into(),
            shape: LightShape::Point {
                position: [-2.0, 2.5, 1.5],
            },
            color: [0.8, 0.85, 1.0],
            power: 6.0,
            range: None,
            samples: 1,
        },
    ];
    s.camera = camera([0.0, 2.2, 4.6], [0.0, 0.5, 0.0], 45.0);
    s
}

#[test]
fn metallic_dielectric_and_textured_spheres_match_the_reference() {
    let gpu = gpu();
    let scene = spheres(true);
    let samples = samples(&scene);
    let reference = render_point_sum(&scene, &samples, [1.0; 3]);
    let states = shadow_states(&scene, &samples);
    let mask = comparable(&reference, &states.visible);
    for variant in [EyeVariant::Forward, EyeVariant::Deferred] {
        let frame = render(&gpu, &scene, &samples, variant);
        dump(
            &format!("metallic-roughness-{variant:?}"),
            &frame,
            &reference,
        );
        for (what, got, want) in [
            ("illumination", &frame.illumination, &reference.illumination),
            ("m^d", &frame.diffuse, &reference.diffuse),
            ("m^s", &frame.specular, &reference.specular),
            ("m^a", &frame.ambient, &reference.ambient),
            ("e", &frame.emissive, &reference.emissive),
        ] {
            let c = compare(got.as_ref().expect(what), want, &mask);
            eprintln!("{variant:?} {what}: {c:?}");
            assert!(c.passes(), "{variant:?} {what}: {c:?}");
        }
    }
    // Control: the same scene rendered without its normal map disagrees with the reference of
    // the scene with it, where the textured meshes are.
    let flat = render(&gpu, &spheres(false), &samples, EyeVariant::Deferred);
    let c = compare(
        flat.illumination.as_ref().expect("illumination"),
        &reference.illumination,
        &mask,
    );
    eprintln!("without the normal map: {c:?}");
    assert!(!c.passes(), "{c:?}");
    // Control: the sphere's own tangents are what bends its normals: turned a quarter about
    // the normal, the frame no longer matches.
    let mut turned = scene.clone();
    let ball = turned
        .meshes
        .iter_mut()
        .find(|m| m.name == "textured")
        .expect("the textured sphere");
    for (t, n) in ball.tangents.iter_mut().zip(&ball.normals) {
        let [x, y, z] = lightfold_scene::shading::cross(*n, [t[0], t[1], t[2]]);
        *t = [x, y, z, t[3]];
    }
    let frame = render(&gpu, &turned, &samples, EyeVariant::Deferred);
    let c = compare(
        frame.illumination.as_ref().expect("illumination"),
        &reference.illumination,
        &mask,
    );
    eprintln!("tangents turned: {c:?}");
    assert!(!c.passes(), "{c:?}");
}

/// Issue 46: closed-form glossy specular of area lights (`scene::ltc`) on the GPU equals the CPU
/// reference's, for every shape it integrates (rectangle, disk, sphere light), in both eye
/// variants. Control: the GPU's point highlights (`AreaSpecular::Sampled`) against the
/// reference's closed form disagree, so the comparison sees the specular model.
#[test]
fn closed_form_area_specular_matches_the_reference_for_every_shape() {
    let gpu = gpu();
    let mut scene = spheres(false);
    scene.lights = vec![
        Light {
            name: "panel".into(),
            shape: LightShape::Rect {
                center: [1.0, 3.0, 2.0],
                normal: lightfold_scene::shading::normalize([-0.3, -1.0, -0.6]),
                u_axis: [1.0, 0.0, 0.0],
                size: [0.8, 0.5],
            },
            color: [1.0, 0.95, 0.9],
            power: 10.0,
            range: None,
            samples: 4,
        },
        Light {
            name: "disk".into(),
            shape: LightShape::Disk {
                center: [-1.5, 2.5, 2.0],
                normal: lightfold_scene::shading::normalize([0.4, -1.0, -0.7]),
                radius: 0.4,
            },
            color: [0.9, 0.9, 1.0],
            power: 8.0,
            range: None,
            samples: 4,
        },
        Light {
            name: "bulb".into(),
            shape: LightShape::Sphere {
                center: [0.3, 2.0, 1.8],
                radius: 0.25,
            },
            color: [1.0, 0.9, 0.8],
            power: 6.0,
            range: None,
            samples: 4,
        },
    ];
    let samples = samples(&scene);
    assert!(samples.iter().all(|s| s.area.is_some()), "{samples:?}");
    let reference = render_point_sum(&scene, &samples, [1.0; 3]);
    let states = shadow_states(&scene, &samples);
    let mask = comparable(&reference, &states.visible);
    for variant in [EyeVariant::Forward, EyeVariant::Deferred] {
        let frame = render(&gpu, &scene, &samples, variant);
        dump(&format!("area-specular-{variant:?}"), &frame, &reference);
        let c = compare(
            frame.illumination.as_ref().expect("illumination"),
            &reference.illumination,
            &mask,
        );
        eprintln!("{variant:?}: {c:?}");
        assert!(c.passes(), "{variant:?}: {c:?}");
    }
    let points: Vec<LightSample> = samples
        .iter()
        .map(|s| LightSample { area: None, ..*s })
        .collect();
    let frame = render(&gpu, &scene, &points, EyeVariant::Deferred);
    let c = compare(
        frame.illumination.as_ref().expect("illumination"),
        &reference.illumination,
        &mask,
    );
    eprintln!("point highlights: {c:?}");
    assert!(!c.passes(), "{c:?}");
}
