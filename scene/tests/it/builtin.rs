//! Built-in scenes: they build, stay small, have the promised light samples, cast enough shadow,
//! and "box" has an occluder outside a 90° cone of a light sample. Preview PNGs (diffuse only, CPU
//! ray traced) are written to the cargo target tmp dir for a person to look at.

use crate::support;

use lightfold_scene::sampling::direct_samples;
use lightfold_scene::{builtin, builtin_names};
use std::path::PathBuf;

fn preview_dir() -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("scene-previews");
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn every_builtin_builds_small_with_its_samples() {
    for name in builtin_names() {
        let s = builtin(name).unwrap();
        assert_eq!(s.name, *name);
        let tris = s.triangle_count();
        assert!(tris <= 50_000, "{name}: {tris} triangles");
        let samples = direct_samples(&s);
        let expected = 32;
        assert_eq!(samples.len(), expected, "{name}");
        assert_eq!((s.camera.width, s.camera.height), (800, 600));
        println!(
            "{name}: {tris} triangles, {} lights, {} samples",
            s.lights.len(),
            samples.len()
        );
    }
    assert_eq!(builtin_names()[0], lightfold_scene::defaults::DEFAULT_SCENE);
    assert!(builtin("nope").is_err());
}

#[test]
fn balls_and_box_are_at_least_a_fifth_in_shadow() {
    let mut thin = Vec::new();
    for name in ["balls", "box", "plant", "animal", "cornell"] {
        let s = builtin(name).unwrap();
        let view = support::render(&s, &direct_samples(&s), 200, 150);
        let f = view.shadow_fraction();
        println!(
            "{name}: shadow/penumbra {:.1} %, mean luminance {:.3}",
            100.0 * f,
            view.mean_luminance()
        );
        view.image
            .write_png(&preview_dir().join(format!("{name}.png")), s.exposure)
            .unwrap();
        if (name == "balls" || name == "box") && f < 0.2 {
            thin.push(format!("{name}: only {:.1} % in shadow", 100.0 * f));
        }
    }
    assert!(thin.is_empty(), "{thin:?}");
}

#[test]
fn box_has_an_occluder_outside_a_90_degree_cone_of_a_light_sample() {
    use lightfold_scene::shading::{add, dot, irradiance, length, normalize, scale, sub};
    let s = builtin("box").unwrap();
    let tracer = support::Tracer::new(&s);
    let cos45 = std::f32::consts::FRAC_1_SQRT_2;
    let mut found = 0;
    for sample in direct_samples(&s).iter().filter(|x| x.light == 1) {
        for i in 0..48 {
            for k in 0..32 {
                let g = [-6.0 + 0.25 * i as f32, 0.0, -2.5 + 0.25 * k as f32];
                if irradiance(sample, g, [0.0, 1.0, 0.0]) <= 0.0 {
                    continue;
                }
                let to = sub(g, sample.position);
                let d = normalize(to);
                let Some(hit) = tracer.trace(sample.position, d, 1e-4, length(to) - 1e-3, false)
                else {
                    continue;
                };
                let p = add(sample.position, scale(d, hit.t));
                let off_axis = dot(normalize(sub(p, sample.position)), sample.direction) < cos45;
                if s.meshes[hit.mesh as usize].name == "pillar" && off_axis {
                    found += 1;
                }
            }
        }
    }
    println!("floor points shadowed by the pillar outside the lamp's 90° cone: {found}");
    assert!(found > 50, "only {found}");
}
