//! Glossy highlights in the planner's sample sizing (`plan/gloss.rs`, `docs/planner.md` § Glossy
//! highlights): an error target raises an area light whose visible glossy receivers need more
//! samples than the penumbra does, and only those. (That the raised count is right is checked
//! against an independent truth in `quality/tests/it/gloss_rule.rs`.)

use lightfold_coordinator::plan::{PlanOptions, TargetChoice, gloss, targeted};
use lightfold_scene::primitives::{plane, sphere};
use lightfold_scene::{
    AreaSpecular, Camera, Light, LightShape, Material, MetallicRoughness, Scene,
};

/// A sphere of `material` under a rect panel `size` metres across, 1.6 m above it.
fn scene(material: Material, size: f32) -> Scene {
    let mut s = Scene::new("gloss");
    let ground = s.add_material(Material::diffuse("ground", [0.5; 3]));
    s.add_mesh(plane(
        "ground",
        [0.0; 3],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [10.0, 10.0],
        1,
        ground,
    ));
    let m = s.add_material(material);
    s.add_mesh(sphere("ball", [0.0, 0.5, 0.0], 0.5, 32, 16, m));
    s.lights.push(Light {
        name: "panel".into(),
        shape: LightShape::Rect {
            center: [0.0, 2.6, 0.0],
            normal: [0.0, -1.0, 0.0],
            u_axis: [1.0, 0.0, 0.0],
            size: [size, size],
        },
        color: [1.0; 3],
        power: 5.0,
        range: None,
        samples: 16,
    });
    s.camera = Camera {
        position: [0.0, 1.5, 4.0],
        target: [0.0, 0.5, 0.0],
        up: [0.0, 1.0, 0.0],
        fov_y_deg: 40.0,
        width: 200,
        height: 150,
    };
    s
}

fn silver(roughness: f32) -> Material {
    Material::metallic_roughness("silver", MetallicRoughness::new([0.95; 3], 1.0, roughness))
}

fn choice(s: &Scene, target: f32) -> TargetChoice {
    targeted(s, target, &PlanOptions::default())
        .expect("an area light")
        .2
}

#[test]
fn a_large_panel_over_a_glossy_sphere_is_raised_and_says_why() {
    let s = scene(silver(0.7), 3.0);
    let (raised, _, t) = targeted(&s, 45.0, &PlanOptions::default()).unwrap();
    let g = &t.gloss[0];
    assert_eq!(
        (g.light, g.from, g.name.as_str(), g.material.as_str()),
        (0, 16, "panel", "silver")
    );
    assert!(
        g.reached && g.to > 16 && g.to <= gloss::MAX_GLOSS_SAMPLES,
        "{g:?}"
    );
    assert_eq!(raised.lights[0].samples, g.to);
    assert!(
        (g.distance - 1.6).abs() < 1e-3,
        "nearest point of the sphere's box: {g:?}"
    );
    // The fewest: one sample fewer than the rule's count would not do (the grid of the count
    // below it has a wider cell, or one that is not square).
    let rho = gloss::max_spacing_over_lobe(45.0);
    let center = [0.0, 1.0, 0.0];
    let mut l = raised.lights[0].clone();
    assert!(gloss::spacing_over_lobe(&l, center, g.alpha) <= rho * 1.0001);
    l.samples = g.to - 1;
    assert!(gloss::spacing_over_lobe(&l, center, g.alpha) > rho);
    // The plan prints it.
    let p = lightfold_coordinator::plan::plan(
        &s,
        &lightfold_coordinator::plan::ClusterSpec::local(8, 2),
        &PlanOptions {
            target_penumbra_db: Some(45.0),
            ..PlanOptions::default()
        },
    )
    .unwrap();
    let line = p.target_line().unwrap();
    assert!(
        line.contains("highlights: \"panel\" 16 → ") && line.contains("\"silver\""),
        "{line}"
    );
}

#[test]
fn only_sampled_glossy_lobes_raise_and_tighter_targets_raise_more() {
    let big = |m: Material| choice(&scene(m, 3.0), 45.0).gloss;
    // Controls: a diffuse sphere, and a narrow lobe the closed form carries whole.
    assert!(big(Material::diffuse("chalk", [0.8; 3])).is_empty());
    assert!(big(silver(0.3)).is_empty());
    // The same narrow lobe with every sample its own highlight is raised, further than the
    // rough one (capped at the most the sweep measured: it says so).
    let mut sampled = scene(silver(0.3), 3.0);
    sampled.quality.area_specular = AreaSpecular::Sampled;
    let narrow = choice(&sampled, 45.0).gloss;
    let rough = big(silver(0.7));
    assert!(narrow[0].to > rough[0].to, "{narrow:?} {rough:?}");
    assert!(!narrow[0].reached, "{narrow:?}");
    // A small panel needs nothing; a dim highlight (Blinn-Phong, little specular over a bright
    // diffuse) asks for fewer than a metal of the same lobe.
    assert!(choice(&scene(silver(0.7), 0.3), 45.0).gloss.is_empty());
    let plastic = Material {
        specular: [0.1; 3],
        shininess: 2.0 / (0.49f32 * 0.49) - 2.0,
        ..Material::diffuse("plastic", [0.8; 3])
    };
    let dim = big(plastic);
    assert!(
        dim.first().is_none_or(|d| d.to < rough[0].to),
        "{dim:?} {rough:?}"
    );
    // Targets: tighter asks more, looser less, never below the scene's own count.
    let s = scene(silver(0.7), 3.0);
    let (t40, t45, t50) = (choice(&s, 40.0), choice(&s, 45.0), choice(&s, 50.0));
    // The light's count after the choice and the raise (a choice may take enough samples
    // itself where a raise would cost as much).
    let to = |t: &TargetChoice| t.gloss.first().map_or(t.to, |g| g.to);
    assert!(
        to(&t40) <= to(&t45) && to(&t45) < to(&t50),
        "{} {} {}",
        to(&t40),
        to(&t45),
        to(&t50)
    );
    assert!(t50.gloss.iter().all(|g| g.to >= g.from));
}

#[test]
fn a_panel_touching_its_receiver_is_capped_and_says_so() {
    let mut s = scene(silver(0.7), 3.0);
    if let LightShape::Rect { center, .. } = &mut s.lights[0].shape {
        center[1] = 1.0; // on the sphere's top
    }
    let g = &choice(&s, 45.0).gloss[0];
    assert!(!g.reached && g.to == gloss::MAX_GLOSS_SAMPLES, "{g:?}");
}
