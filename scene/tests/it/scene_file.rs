//! Scene files: the simple case is expressed exactly, files round-trip through TOML, unknown
//! fields and versions are rejected, every example in `scenes/` (and `assets/fox.toml`) loads
//! clean, and `load` dispatches on built-in names and extensions.

use crate::support;

use lightfold_scene::file::{parse, to_toml};
use lightfold_scene::sampling::{direct_samples, sample_power};
use lightfold_scene::{LightShape, SceneError, load, parse_scene_file};
use std::path::{Path, PathBuf};

fn scenes_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes")
}

fn example(name: &str) -> String {
    scenes_dir().join(name).display().to_string()
}

/// `assets/fox.toml`: beside its model, since a scene file reads only inside its own folder.
fn fox() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/fox.toml")
}

#[test]
fn the_simple_case_is_expressed_exactly() {
    let s = load(&example("simple.toml")).unwrap();
    assert_eq!(s.name, "simple");
    let c = s.camera;
    assert_eq!(
        (c.position, c.target, c.up, c.fov_y_deg, c.width, c.height),
        (
            [0.0, 2.5, 6.0],
            [0.0, 0.5, 0.0],
            [0.0, 1.0, 0.0],
            45.0,
            800,
            600
        )
    );
    let names: Vec<&str> = s.meshes.iter().map(|m| m.name.as_str()).collect();
    assert_eq!(
        names,
        ["ground", "box", "sphere"],
        "no ground or light added"
    );
    let colours: Vec<[f32; 3]> = s
        .meshes
        .iter()
        .map(|m| s.materials[m.material].diffuse)
        .collect();
    assert_eq!(colours, [[0.8, 0.8, 0.8], [0.8, 0.3, 0.2], [0.2, 0.4, 0.8]]);
    assert!(s.materials.iter().all(|m| !m.has_specular()));
    assert_eq!(s.lights.len(), 1);
    let l = &s.lights[0];
    assert_eq!(
        l.shape,
        LightShape::Rect {
            center: [-2.5, 2.5, 1.5],
            normal: [0.0, -1.0, 0.0],
            u_axis: [1.0, 0.0, 0.0],
            size: [1.0, 0.5],
        }
    );
    assert_eq!(
        (l.power, l.color, l.samples, l.range),
        (40.0, [1.0; 3], 16, None)
    );
    // One-sided: every sample is a cosine lobe pointing down, together emitting π·L·A.
    let samples = direct_samples(&s);
    assert_eq!(samples.len(), 16);
    let total: f64 = samples.iter().map(|x| sample_power(x).unwrap()).sum();
    let exact = std::f64::consts::PI * 40.0 * 0.5;
    assert!((total - exact).abs() < 1e-6 * exact);
    assert!(s.validate().is_clean(), "{}", s.validate());
    let view = support::render(&s, &samples, 160, 120);
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("scene-previews");
    std::fs::create_dir_all(&dir).unwrap();
    view.image
        .write_png(&dir.join("simple.png"), s.exposure)
        .unwrap();
    assert!(view.shadow_fraction() > 0.05, "{}", view.shadow_fraction());
    // The box is the cube [-1.4, -0.4] × [0, 1] × [-0.5, 0.5].
    let (lo, hi) = s.meshes[1].bounds().unwrap();
    let expect = [-1.4, 0.0, -0.5, -0.4, 1.0, 0.5];
    for (got, want) in lo.iter().chain(&hi).zip(expect) {
        assert!((got - want).abs() < 1e-6, "{lo:?} {hi:?}");
    }
}

#[test]
fn scene_files_round_trip_through_toml() {
    for path in [
        PathBuf::from(example("simple.toml")),
        PathBuf::from(example("lights.toml")),
        fox(),
    ] {
        let name = path.file_name().unwrap().to_str().unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let file = parse(&text, name).unwrap();
        let again = parse(&to_toml(&file).unwrap(), name).unwrap();
        assert_eq!(file, again, "{name}");
        let base = path.parent().unwrap();
        let a = parse_scene_file(&text, name, Some(base)).unwrap();
        let b = parse_scene_file(&to_toml(&file).unwrap(), name, Some(base)).unwrap();
        assert_eq!(a, b, "{name}");
    }
}

#[test]
fn every_example_loads_clean() {
    let mut n = 0;
    let examples = std::fs::read_dir(scenes_dir()).unwrap();
    for path in examples.map(|e| e.unwrap().path()).chain([fox()]) {
        if path.extension().is_some_and(|e| e == "toml") {
            let s = load(&path.display().to_string()).unwrap_or_else(|e| panic!("{e}"));
            assert!(
                s.validate().is_clean(),
                "{}: {}",
                path.display(),
                s.validate()
            );
            assert!(!direct_samples(&s).is_empty());
            n += 1;
        }
    }
    assert!(n >= 3);
}

#[test]
fn every_light_kind_is_read() {
    let s = load(&example("lights.toml")).unwrap();
    let kinds: Vec<&str> = s
        .lights
        .iter()
        .map(|l| match l.shape {
            LightShape::Point { .. } => "point",
            LightShape::Spot { .. } => "spot",
            LightShape::Directional { .. } => "directional",
            LightShape::Rect { .. } => "rect",
            LightShape::Disk { .. } => "disk",
            LightShape::Sphere { .. } => "sphere",
            LightShape::Cylinder { .. } => "cylinder",
            LightShape::EmissiveMesh { .. } => "emissive_mesh",
        })
        .collect();
    assert_eq!(
        kinds,
        [
            "point",
            "spot",
            "directional",
            "directional",
            "rect",
            "disk",
            "sphere",
            "cylinder",
            "emissive_mesh"
        ]
    );
    // 3 punctual samples + a soft sun and 5 area lights × 16 (the quality override).
    assert_eq!(direct_samples(&s).len(), 3 + 6 * 16);
    assert_eq!(
        s.lights[3].shape,
        LightShape::Directional {
            direction: [-0.4, -1.0, 0.3],
            angle: 6f32.to_radians()
        }
    );
    assert!(s.lights[3].is_area() && !s.lights[2].is_area());
    let LightShape::EmissiveMesh { mesh } = s.lights[8].shape else {
        unreachable!()
    };
    let glow = &s.materials[s.meshes[mesh].material];
    assert_eq!(glow.emissive, [8.0, 6.4, 4.0]);
    assert!(!glow.double_sided);
    assert_eq!(s.ambient, [0.02; 3]);
}

#[test]
fn a_gltf_reference_is_relative_to_the_file() {
    let s = load(&fox().display().to_string()).unwrap();
    assert_eq!(s.lights.len(), 2, "the file's lights, no framing light");
    assert_eq!(s.camera.position, [2.0, 1.0, 2.0]);
    let (_, hi) = s.bounds().unwrap();
    assert!(hi[1] < 1.0, "scaled to metres: {hi:?}");
}

fn parse_err(text: &str) -> SceneError {
    match parse_scene_file(text, "test.toml", None) {
        Ok(_) => panic!("accepted:\n{text}"),
        Err(e) => e,
    }
}

#[test]
fn mistakes_are_reported() {
    let e = parse_err("version = 1\nexposur = 2.0\n");
    assert!(e.to_string().contains("exposur"), "{e}");
    let e = parse_err(
        "version = 1\n[[object]]\ntype = \"sphere\"\ncenter = [0,0,0]\nradius = 1.0\ncolour = [1,0,0]\n",
    );
    assert!(e.to_string().contains("colour"), "{e}");
    let e = parse_err("version = 1\n[[object]]\ntype = \"torus\"\ncenter = [0,0,0]\n");
    assert!(e.to_string().contains("torus"), "{e}");
    let e = parse_err("version = 2\n");
    assert!(
        matches!(
            e,
            SceneError::Version {
                found: 2,
                supported: 1,
                ..
            }
        ),
        "{e}"
    );
    let e = parse_err("name = \"x\"\n");
    assert!(e.to_string().contains("version"), "{e}");
    let e = parse_err(
        "version = 1\n[[object]]\ntype = \"box\"\ncenter = [0,0,0]\nsize = [1,1,1]\nmaterial = \"gold\"\n",
    );
    assert!(e.to_string().contains("unknown material \"gold\""), "{e}");
    let e = parse_err(
        "version = 1\n[[light]]\ntype = \"emissive_mesh\"\nobject = \"nothing\"\nradiance = 1.0\n",
    );
    assert!(e.to_string().contains("nothing"), "{e}");
    let e = parse_err("version = 1\n[gltf]\npath = \"missing.glb\"\n");
    assert!(matches!(e, SceneError::Io { .. }), "{e}");
    assert!(e.to_string().contains("test.toml") || e.to_string().contains("missing.glb"));
}

#[test]
fn load_dispatches_on_names_and_extensions() {
    assert_eq!(load("balls").unwrap().name, "balls");
    assert!(matches!(
        load("model.fbx"),
        Err(SceneError::UnknownInput { .. })
    ));
    // OBJ and PLY models are read as models (here: missing files).
    assert!(matches!(load("model.obj"), Err(SceneError::Io { .. })));
    assert!(matches!(load("model.PLY"), Err(SceneError::Io { .. })));
    assert!(matches!(
        load("ballz"),
        Err(SceneError::UnknownInput { .. })
    ));
    let fox = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/Fox/Fox.glb");
    let s = load(&fox.display().to_string()).unwrap();
    assert_eq!(s.lights.len(), 1, "a bare glTF gets the framing light");
}

#[test]
fn a_file_without_lights_or_camera_is_completed() {
    let text = "version = 1\n[[object]]\ntype = \"sphere\"\ncenter = [0, 1, 0]\nradius = 1.0\n";
    let s = parse_scene_file(text, "bare.toml", None).unwrap();
    assert_eq!(s.lights.len(), 1);
    assert_eq!(s.meshes.len(), 1, "objects given: no ground added");
    assert_ne!(
        s.camera.position,
        lightfold_scene::Scene::new("x").camera.position
    );
}

/// `shadow_map_sizing`: per light from the mismatch factor by default; a `shadow_map_size` alone
/// fixes every map; the rule's bounds and target can be set; bad ones are refused or replaced
/// with a reported issue.
#[test]
fn shadow_map_sizing_parses_and_fixed_sizes_stay_fixed() {
    use lightfold_scene::{MapSizing, defaults};
    let base = "version = 1\n[[object]]\ntype = \"sphere\"\ncenter = [0, 1, 0]\nradius = 1.0\n";
    let with = |q: &str| parse_scene_file(&format!("{base}[quality]\n{q}\n"), "t.toml", None);
    let s = parse_scene_file(base, "t.toml", None).unwrap();
    assert_eq!(
        s.quality.map_sizing,
        MapSizing::Mismatch(defaults::MAP_MISMATCH)
    );
    let s = with("shadow_map_size = 1024").unwrap();
    assert_eq!(
        (s.quality.shadow_map_size, s.quality.map_sizing),
        (1024, MapSizing::Fixed)
    );
    let s = with("shadow_map_sizing = \"fixed\"").unwrap();
    assert_eq!(s.quality.map_sizing, MapSizing::Fixed);
    let s = with("shadow_map_size = 256\nshadow_map_sizing = \"mismatch\"").unwrap();
    assert_eq!(
        (s.quality.shadow_map_size, s.quality.map_sizing),
        (256, MapSizing::Mismatch(defaults::MAP_MISMATCH))
    );
    let s = with("shadow_map_sizing = { target = 1.0, max = 4096 }").unwrap();
    let MapSizing::Mismatch(m) = s.quality.map_sizing else {
        panic!("{:?}", s.quality.map_sizing)
    };
    assert_eq!(
        (m.target, m.min, m.max),
        (1.0, defaults::MAP_MISMATCH.min, 4096)
    );
    // Above the shared limit, or no target: the default rule replaces it (a validation issue).
    for bad in [
        "{ max = 16384 }",
        "{ target = 0.0 }",
        "{ min = 2048, max = 512 }",
    ] {
        let s = with(&format!("shadow_map_sizing = {bad}")).map_err(|e| e.to_string());
        assert_eq!(
            s.map(|s| s.quality.map_sizing),
            Ok(MapSizing::Mismatch(defaults::MAP_MISMATCH)),
            "{bad}"
        );
    }
    // Unknown keys and words are refused.
    assert!(with("shadow_map_sizing = { tarket = 1.0 }").is_err());
    assert!(with("shadow_map_sizing = \"huge\"").is_err());
}

#[test]
fn transmission_makes_a_translucent_caster() {
    let s = load(&example("glass.toml")).unwrap();
    let red = s
        .materials
        .iter()
        .find(|m| m.name == "red glass")
        .expect("red glass");
    assert_eq!(
        red.transmission,
        Some(lightfold_scene::Transmission {
            color: [0.9, 0.1, 0.1],
            coverage: false,
        })
    );
    let floor = s.materials.iter().find(|m| m.name == "floor").unwrap();
    assert!(!floor.is_translucent());
    let translucent = (0..s.meshes.len())
        .filter(|&m| s.is_translucent_mesh(m))
        .count();
    assert_eq!(translucent, 3, "three panes");
    // Out of range is clamped by validation, never brightens.
    let mut bad = s.clone();
    bad.materials[1].transmission = Some(lightfold_scene::Transmission {
        color: [2.0, f32::NAN, -1.0],
        coverage: false,
    });
    let report = bad.sanitize();
    assert!(!report.is_clean());
    assert_eq!(
        bad.materials[1].transmission.unwrap().color,
        [1.0, 0.0, 0.0]
    );
    // Finite but above 1 (glass that would amplify light): reported and clamped too.
    let mut bright = s.clone();
    bright.materials[1].transmission = Some(lightfold_scene::Transmission {
        color: [5.0, 5.0, 0.5],
        coverage: false,
    });
    assert!(!bright.sanitize().is_clean());
    assert_eq!(
        bright.materials[1].transmission.unwrap().color,
        [1.0, 1.0, 0.5]
    );
    // The same through a scene file.
    let text = std::fs::read_to_string(example("glass.toml"))
        .unwrap()
        .replacen("[0.9, 0.1, 0.1]", "[5, 5, 5]", 1);
    let base = std::path::Path::new(&example("glass.toml"))
        .parent()
        .unwrap()
        .to_path_buf();
    let parsed = lightfold_scene::parse_scene_file(&text, "glass.toml", Some(&base)).unwrap();
    let red = parsed
        .materials
        .iter()
        .find(|m| m.name == "red glass")
        .unwrap();
    assert_eq!(red.transmission.unwrap().color, [1.0; 3]);
}

/// A session's scene written as a file over its base builds the same scene: the built-in's
/// meshes and materials, the edited lights (moved, added, one removed), camera and exposure.
#[test]
fn a_session_file_over_a_base_builds_the_same_scene() {
    use lightfold_scene::file::save::session_file;
    for base in ["balls", "cornell", "carousel"] {
        let mut s = load(base).unwrap();
        if let Some(LightShape::Rect { center, .. } | LightShape::Sphere { center, .. }) =
            s.lights.first_mut().map(|l| &mut l.shape)
        {
            center[0] += 0.25;
        }
        s.lights.push(lightfold_scene::Light {
            name: "added".into(),
            shape: LightShape::Disk {
                center: [0.1, 2.5, 0.3],
                normal: [0.0, -1.0, 0.0],
                radius: 0.2,
            },
            color: [0.9, 0.5, 0.25],
            power: 7.5,
            range: None,
            samples: 9,
        });
        s.camera.position[1] += 0.5;
        s.camera.fov_y_deg = 41.0;
        s.camera.width = 64;
        s.exposure = 1.5;
        s.quality.samples_per_area_light = Some(4);
        s.quality.shadow_map_size = 768;
        s.quality.filter = lightfold_scene::ShadowFilter::Pcf { taps: 3 };
        let file = session_file(&s, base).unwrap();
        let text = to_toml(&file).unwrap();
        let back = parse_scene_file(&text, "saved.toml", None).unwrap();
        assert_eq!(back.name, s.name, "{base}");
        assert_eq!(back.camera, s.camera, "{base}");
        assert_eq!(back.exposure, s.exposure, "{base}");
        assert_eq!(back.quality, s.quality, "{base}");
        assert_eq!(back.meshes, s.meshes, "{base}: meshes");
        assert_eq!(back.lights.len(), s.lights.len(), "{base}");
        for (a, b) in back.lights.iter().zip(&s.lights) {
            assert_eq!(a.name, b.name, "{base}");
            assert_eq!(a.color, b.color, "{base}: {}", a.name);
            assert_eq!(a.power, b.power, "{base}: {}", a.name);
            assert_eq!(a.samples, b.samples, "{base}: {}", a.name);
            // Spot angles travel in degrees: equal to rounding.
            assert_eq!(a.shape, b.shape, "{base}: {}", a.name);
        }
        assert_eq!(direct_samples(&back), direct_samples(&s), "{base}: samples");
    }
}

/// A base is one level deep, inside the file's folder, and the file's own settings replace
/// the base's: a base scene file keeps its lights when the file names none.
#[test]
fn a_base_is_resolved_inside_the_folder_and_one_level_deep() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::copy(example("lights.toml"), dir.path().join("lights.toml")).unwrap();
    let base = load(&example("lights.toml")).unwrap();
    let write = |name: &str, text: &str| {
        let p = dir.path().join(name);
        std::fs::write(&p, text).unwrap();
        p.display().to_string()
    };
    let keep = write(
        "keep.toml",
        "version = 1\nexposure = 2.0\n[base]\nscene = \"lights.toml\"\n",
    );
    let s = load(&keep).unwrap();
    assert_eq!(s.lights, base.lights);
    assert_eq!(s.meshes, base.meshes);
    assert_eq!(s.exposure, 2.0);
    assert_eq!(s.name, base.name);
    let nested = write(
        "nested.toml",
        "version = 1\n[base]\nscene = \"keep.toml\"\n",
    );
    let e = load(&nested).unwrap_err().to_string();
    assert!(e.contains("one level deep"), "{e}");
    let outside = write(
        "outside.toml",
        "version = 1\n[base]\nscene = \"../x.toml\"\n",
    );
    let e = load(&outside).unwrap_err().to_string();
    assert!(e.contains("base.scene"), "{e}");
    let two = write(
        "two.toml",
        "version = 1\n[base]\nscene = \"balls\"\n[gltf]\npath = \"m.glb\"\n",
    );
    let e = load(&two).unwrap_err().to_string();
    assert!(e.contains("[base] and [gltf]"), "{e}");
}
