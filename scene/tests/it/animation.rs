//! Scene time: glTF clips (node TRS, skins, morph weights) and scene-file motions pose the scene
//! as their independent truths say — the loader's own rest-pose skinning, a hand-built glTF's
//! keyframes, a rotation and a path computed by hand — and broken animations are refused.

use lightfold_scene::animation::{Animation, Channel, Interpolation, Target};
use lightfold_scene::sampling::direct_samples;
use lightfold_scene::{GltfOptions, Issue, Scene, builtin, load_gltf_slice, load_gltf_with};
use std::path::{Path, PathBuf};

fn shared(model: &str, file: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../assets")
        .join(model)
        .join(file)
}

fn model(name: &str) -> Scene {
    let (dir, file, scale) = match name {
        "Fox" => ("Fox", "Fox.glb", 0.01),
        _ => ("CesiumMan", "CesiumMan.gltf", 1.0),
    };
    let opts = GltfOptions {
        scale,
        complete: false,
        ..GltfOptions::default()
    };
    load_gltf_with(&shared(dir, file), &opts).unwrap()
}

/// Largest distance between corresponding vertices of two scenes' meshes.
fn max_vertex_gap(a: &Scene, b: &Scene) -> f32 {
    let mut gap = 0.0f32;
    for (ma, mb) in a.meshes.iter().zip(&b.meshes) {
        assert_eq!(ma.positions.len(), mb.positions.len());
        for (p, q) in ma.positions.iter().zip(&mb.positions) {
            let d = (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f32>().sqrt();
            gap = gap.max(d);
        }
    }
    gap
}

fn diagonal(s: &Scene) -> f32 {
    let (lo, hi) = s.bounds().unwrap();
    (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f32>().sqrt()
}

#[test]
fn skinned_models_pose_their_rest_pose_exactly_without_keys() {
    // Independent truth: the loader skins the rest pose itself (joint world matrices from the
    // authored transforms). Posing through the rig with every channel removed must agree.
    for name in ["Fox", "CesiumMan"] {
        let s = model(name);
        let anim = s.animation.as_ref().expect("the model's clip is kept");
        assert!(anim.meshes.iter().any(|r| r.skin.is_some()), "{name}");
        let mut still = s.clone();
        still.animation.as_mut().unwrap().channels.clear();
        let posed = still.pose(0.7);
        let gap = max_vertex_gap(&posed, &s);
        println!(
            "{name}: rest-pose gap {gap:.2e} of diagonal {:.3}",
            diagonal(&s)
        );
        assert!(gap < 1e-5 * diagonal(&s).max(1.0), "{name}: {gap}");
        for (m, r) in posed.meshes.iter().zip(&s.meshes) {
            for (n, q) in m.normals.iter().zip(&r.normals) {
                let d: f32 = (0..3).map(|k| (n[k] - q[k]).abs()).sum();
                assert!(d < 1e-4, "{name}: normal {n:?} vs {q:?}");
            }
        }
    }
}

#[test]
fn skinned_models_move_with_their_clips() {
    for name in ["Fox", "CesiumMan"] {
        let s = model(name);
        assert!(s.is_animated(), "{name}");
        let anim = s.animation.as_ref().unwrap();
        let d = anim.duration();
        assert!(d > 0.5, "{name}: duration {d}");
        let a = s.pose(0.25 * d);
        let b = s.pose(0.6 * d);
        let gap = max_vertex_gap(&a, &b);
        println!(
            "{name} ({:?}, {d:.2} s): vertices move up to {gap:.3} m",
            anim.name
        );
        assert!(gap > 0.01 * diagonal(&s), "{name}: {gap}");
        // The pose stays a body: within twice the rest bounds, normals unit, all finite.
        let (lo, hi) = s.bounds().unwrap();
        let (plo, phi) = a.bounds().unwrap();
        let size = diagonal(&s);
        for k in 0..3 {
            assert!(
                plo[k] > lo[k] - size && phi[k] < hi[k] + size,
                "{name}: {plo:?} {phi:?}"
            );
        }
        for m in &a.meshes {
            for n in &m.normals {
                let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                assert!((len - 1.0).abs() < 1e-3, "{name}: normal length {len}");
            }
        }
        assert!(a.validate().is_clean(), "{name}: {}", a.validate());
        // Looping: one clip later is the same pose.
        assert!(max_vertex_gap(&s.pose(0.25 * d + d), &a) < 1e-4 * size);
    }
}

#[test]
fn a_fox_clip_is_chosen_by_name_and_a_missing_one_is_an_error() {
    let bytes = std::fs::read(shared("Fox", "Fox.glb")).unwrap();
    let opts = |a: &str| GltfOptions {
        scale: 0.01,
        complete: false,
        animation: Some(a.to_string()),
        ..GltfOptions::default()
    };
    let run = load_gltf_slice(&bytes, "Fox.glb", None, &opts("Run")).unwrap();
    assert_eq!(run.animation.as_ref().unwrap().name, "Run");
    let by_index = load_gltf_slice(&bytes, "Fox.glb", None, &opts("1")).unwrap();
    assert_eq!(by_index.animation.as_ref().unwrap().name, "Walk");
    let e = load_gltf_slice(&bytes, "Fox.glb", None, &opts("Dance")).unwrap_err();
    assert!(e.to_string().contains("Survey"), "{e}");
}

/// A GLB of one triangle on node 0, with a morph target lifting vertex 0 by +1 in y, and a clip
/// that moves the node from x = 0 to x = 2 over 1 s (linear), turns it 90° about z by 1 s (step
/// at 0.5 s: 0° then 90°), and takes the weight 0 → 1 over 2 s.
#[test]
fn animation_channels_naming_missing_nodes_or_samplers_are_clear_errors_not_panics() {
    let opts = GltfOptions {
        complete: false,
        ..GltfOptions::default()
    };
    let good = keyed_glb();
    let swap = |from: &str, to: &str| {
        // Same length: the GLB's chunk lengths stay right.
        assert_eq!(from.len(), to.len());
        let at = good
            .windows(from.len())
            .position(|w| w == from.as_bytes())
            .unwrap_or_else(|| panic!("{from}"));
        let mut bad = good.clone();
        bad[at..at + to.len()].copy_from_slice(to.as_bytes());
        bad
    };
    for (what, bad, expect) in [
        (
            "node",
            swap(
                r#""target":{"node":0,"path":"rotation"}"#,
                r#""target":{"node":7,"path":"rotation"}"#,
            ),
            "node 7",
        ),
        (
            "sampler",
            swap(r#"{"sampler":1,"target""#, r#"{"sampler":9,"target""#),
            "sampler 9",
        ),
    ] {
        let hook = std::panic::take_hook();
        // A panic anywhere in the load would print here and fail below.
        std::panic::set_hook(Box::new(|_| {}));
        let got = std::panic::catch_unwind(|| load_gltf_slice(&bad, "keys.glb", None, &opts));
        std::panic::set_hook(hook);
        let err = got
            .unwrap_or_else(|_| panic!("{what}: the load panicked"))
            .expect_err(what)
            .to_string();
        assert!(
            err.contains(expect) && !err.contains("panicked"),
            "{what}: {err}"
        );
    }
    // The control: the unbroken file loads.
    assert!(load_gltf_slice(&good, "keys.glb", None, &opts).is_ok());
}

fn keyed_glb() -> Vec<u8> {
    let mut bin: Vec<u8> = Vec::new();
    let mut f = |v: &[f32]| {
        let at = bin.len();
        for x in v {
            bin.extend_from_slice(&x.to_le_bytes());
        }
        (at, v.len() * 4)
    };
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let views = [
        f(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]), // positions
        f(&[0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]), // morph delta
        f(&[0.0, 1.0]),                                    // translation times
        f(&[0.0, 0.0, 0.0, 2.0, 0.0, 0.0]),                // translations
        f(&[0.0, 0.5]),                                    // rotation times
        f(&[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, h, h]),          // rotations
        f(&[0.0, 2.0]),                                    // weight times
        f(&[0.0, 1.0]),                                    // weights
    ];
    let buffer_views: Vec<String> = views
        .iter()
        .map(|(o, l)| format!(r#"{{"buffer":0,"byteOffset":{o},"byteLength":{l}}}"#))
        .collect();
    let acc = |view: usize, count: usize, ty: &str, minmax: &str| {
        format!(
            r#"{{"bufferView":{view},"componentType":5126,"count":{count},"type":"{ty}"{minmax}}}"#
        )
    };
    let accessors = [
        acc(0, 3, "VEC3", r#","min":[0,0,0],"max":[1,1,0]"#),
        acc(1, 3, "VEC3", r#","min":[0,0,0],"max":[0,1,0]"#),
        acc(2, 2, "SCALAR", r#","min":[0],"max":[1]"#),
        acc(3, 2, "VEC3", ""),
        acc(4, 2, "SCALAR", r#","min":[0],"max":[0.5]"#),
        acc(5, 2, "VEC4", ""),
        acc(6, 2, "SCALAR", r#","min":[0],"max":[2]"#),
        acc(7, 2, "SCALAR", ""),
    ];
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],
        "nodes":[{{"mesh":0}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"targets":[{{"POSITION":1}}]}}],"weights":[0]}}],
        "buffers":[{{"byteLength":{}}}],"bufferViews":[{}],"accessors":[{}],
        "animations":[{{"name":"keys","samplers":[
            {{"input":2,"output":3}},
            {{"input":4,"output":5,"interpolation":"STEP"}},
            {{"input":6,"output":7}}],
          "channels":[
            {{"sampler":0,"target":{{"node":0,"path":"translation"}}}},
            {{"sampler":1,"target":{{"node":0,"path":"rotation"}}}},
            {{"sampler":2,"target":{{"node":0,"path":"weights"}}}}]}}]}}"#,
        bin.len(),
        buffer_views.join(","),
        accessors.join(",")
    );
    let mut json = json.into_bytes();
    while json.len() % 4 != 0 {
        json.push(b' ');
    }
    let mut glb = Vec::new();
    let total = 12 + 8 + json.len() + 8 + bin.len();
    glb.extend_from_slice(b"glTF");
    glb.extend_from_slice(&2u32.to_le_bytes());
    glb.extend_from_slice(&(total as u32).to_le_bytes());
    glb.extend_from_slice(&(json.len() as u32).to_le_bytes());
    glb.extend_from_slice(b"JSON");
    glb.extend_from_slice(&json);
    glb.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    glb.extend_from_slice(b"BIN\0");
    glb.extend_from_slice(&bin);
    glb
}

fn close(a: [f32; 3], b: [f32; 3]) -> bool {
    (0..3).all(|k| (a[k] - b[k]).abs() < 1e-5)
}

#[test]
fn keyframes_translate_turn_and_morph_as_the_keys_say() {
    let opts = GltfOptions {
        complete: false,
        ..GltfOptions::default()
    };
    let s = load_gltf_slice(&keyed_glb(), "keys.glb", None, &opts).unwrap();
    assert!(s.is_animated());
    // The mesh was flat-shaded (no normals): its vertices are the three corners, once each.
    let at = |t: f32| s.pose(t).meshes[0].positions.clone();
    let rest = &s.meshes[0].positions;
    let v0 = rest
        .iter()
        .position(|p| close(*p, [0.0, 0.0, 0.0]))
        .unwrap();
    let v1 = rest
        .iter()
        .position(|p| close(*p, [1.0, 0.0, 0.0]))
        .unwrap();
    // t = 0.25: x moved by 0.5, no turn yet (step), weight 0.125 lifts vertex 0.
    let p = at(0.25);
    assert!(close(p[v0], [0.5, 0.125, 0.0]), "{:?}", p[v0]);
    assert!(close(p[v1], [1.5, 0.0, 0.0]), "{:?}", p[v1]);
    // t = 0.75: x by 1.5, turned 90° about z (x → y), weight 0.375: vertex 0's (0, 0.375, 0)
    // turns to (−0.375, 0, 0).
    let p = at(0.75);
    assert!(close(p[v0], [1.5 - 0.375, 0.0, 0.0]), "{:?}", p[v0]);
    assert!(close(p[v1], [1.5, 1.0, 0.0]), "{:?}", p[v1]);
    // The clip lasts 2 s and loops: t = 2.25 is t = 0.25.
    assert!(close(at(2.25)[v0], at(0.25)[v0]));
    // Normals follow the posed triangle (flat): the turn keeps the triangle in z = 0.
    for n in &s.pose(0.75).meshes[0].normals {
        assert!(close(*n, [0.0, 0.0, 1.0]), "{n:?}");
    }
}

#[test]
fn the_carousel_spins_its_box_and_moves_its_light_as_specified() {
    let s = builtin("carousel").unwrap();
    assert!(s.is_animated());
    let anim = s.animation.as_ref().unwrap();
    let spinner = s.meshes.iter().position(|m| m.name == "spinner").unwrap();
    let moving = anim.moving_meshes(s.meshes.len());
    assert_eq!(
        moving.iter().filter(|&&m| m).count(),
        1,
        "only the spinner moves"
    );
    assert!(moving[spinner]);
    let lights = anim.moving_lights(s.lights.len());
    assert_eq!(lights, vec![true, false]);
    // A quarter of the 8 s turn: every vertex rotated 90° about +y through the box centre
    // (0, 0.9, 0): (x, y, z) → (z, y, −x).
    let posed = s.pose(2.0);
    for (p, q) in posed.meshes[spinner]
        .positions
        .iter()
        .zip(&s.meshes[spinner].positions)
    {
        assert!(close(*p, [q[2], q[1], -q[0]]), "{p:?} from {q:?}");
    }
    // The other meshes stay.
    for (i, (a, b)) in posed.meshes.iter().zip(&s.meshes).enumerate() {
        if i != spinner {
            assert_eq!(a.positions, b.positions);
        }
    }
    // The light path: halfway through the first leg (0.75 s of 1.5 s) it is 1.5 m along +x;
    // its samples moved with it, and the path loops every 6 s.
    let rest = direct_samples(&s);
    let at = s.samples_at(0.75);
    for (a, r) in at.iter().zip(&rest) {
        let shift = if r.light == 0 { 1.5 } else { 0.0 };
        assert!(close(
            a.position,
            [r.position[0] + shift, r.position[1], r.position[2]]
        ));
        assert_eq!(a.direction, r.direction);
    }
    assert_eq!(s.samples_at(6.75), at);
    // The posed light's shape agrees with its posed samples: sampling the posed scene gives the
    // moved samples.
    assert_eq!(direct_samples(&s.pose(0.75)).len(), at.len());
    for (a, b) in direct_samples(&s.pose(0.75)).iter().zip(&at) {
        assert!(
            close(a.position, b.position),
            "{:?} {:?}",
            a.position,
            b.position
        );
    }
    // The spin repeats on its own period (8 s), not the path's (6 s).
    let gap = max_vertex_gap(&s.pose(10.0), &s.pose(2.0));
    assert!(gap < 1e-4, "{gap}");
}

#[test]
fn scene_file_motions_are_checked() {
    let base = r#"
version = 1
[[object]]
type = "box"
name = "b"
center = [0.0, 0.5, 0.0]
size = [1.0, 1.0, 1.0]
[[light]]
type = "point"
name = "p"
position = [0.0, 3.0, 0.0]
intensity = 10.0
"#;
    let cases = [
        (
            "[[motion]]\nobject = \"nope\"\nspin = { axis = [0.0, 1.0, 0.0], period = 2.0 }",
            "unknown object",
        ),
        ("[[motion]]\nobject = \"b\"", "neither"),
        (
            "[[motion]]\nobject = \"b\"\nlight = \"p\"\nspin = { axis = [0.0, 1.0, 0.0], period = 2.0 }",
            "exactly one",
        ),
        (
            "[[motion]]\nobject = \"b\"\nspin = { axis = [0.0, 0.0, 0.0], period = 2.0 }",
            "axis",
        ),
        (
            "[[motion]]\nobject = \"b\"\nspin = { axis = [0.0, 1.0, 0.0], period = 0.0 }",
            "period",
        ),
        (
            "[[motion]]\nlight = \"p\"\npath = { times = [0.0, 0.0], offsets = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]] }",
            "increasing",
        ),
        (
            "[[motion]]\nlight = \"p\"\npath = { times = [0.0], offsets = [] }",
            "offsets",
        ),
        (
            "[[motion]]\nlight = \"p\"\npath = { times = [0.0, 1.0], offsets = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], interpolation = \"cubic\" }",
            "interpolation",
        ),
        ("[[motion]]\nlight = \"p\"\nspeed = 3.0", "unknown field"),
    ];
    for (motion, expect) in cases {
        let text = format!("{base}\n{motion}\n");
        let e = lightfold_scene::parse_scene_file(&text, "t.toml", None).unwrap_err();
        assert!(e.to_string().contains(expect), "{motion}: {e}");
    }
    let ok = format!(
        "{base}\n[[motion]]\nlight = \"p\"\nspin = {{ axis = [0.0, 0.0, 1.0], period = 4.0 }}\npivot = [1.0, 3.0, 0.0]\n"
    );
    let s = lightfold_scene::parse_scene_file(&ok, "t.toml", None).unwrap();
    // A point light turned a quarter about z through (1, 3, 0): from (0, 3, 0) to (1, 2, 0).
    let p = s.samples_at(1.0)[0].position;
    assert!(close(p, [1.0, 2.0, 0.0]), "{p:?}");
}

#[test]
fn broken_animations_are_dropped_and_refused_on_the_wire() {
    let s = builtin("carousel").unwrap();
    assert!(s.validate().is_clean());
    let bytes = s.to_bytes().unwrap();
    assert_eq!(Scene::from_bytes(&bytes).unwrap(), s);
    type Breaker = Box<dyn Fn(&mut Animation)>;
    let breakers: Vec<(&str, Breaker)> = vec![
        ("node", Box::new(|a| a.channels[0].node = 1_000_000)),
        ("times", Box::new(|a| a.channels[0].times.reverse())),
        (
            "values",
            Box::new(|a| {
                a.channels[0].values.pop();
            }),
        ),
        ("nan", Box::new(|a| a.channels[0].values[0] = f32::NAN)),
        ("mesh", Box::new(|a| a.meshes[0].mesh = 999)),
        (
            "vertices",
            Box::new(|a| {
                a.meshes[0].positions.pop();
            }),
        ),
        ("light", Box::new(|a| a.lights[0].light = 7)),
        ("parent", Box::new(|a| a.nodes[0].parent = Some(2))),
        (
            "width",
            Box::new(|a| {
                a.channels.push(Channel {
                    node: 0,
                    target: Target::Rotation,
                    interpolation: Interpolation::Linear,
                    times: vec![0.0],
                    values: vec![0.0; 3],
                    width: 3,
                    repeat: false,
                })
            }),
        ),
    ];
    for (what, breaker) in breakers {
        let mut bad = s.clone();
        breaker(bad.animation.as_mut().unwrap());
        let report = bad.validate();
        assert!(
            report
                .issues
                .iter()
                .any(|i| matches!(i, Issue::BadAnimation { .. })),
            "{what}: {report}"
        );
        let wire = bad.to_bytes().unwrap();
        assert!(Scene::from_bytes(&wire).is_err(), "{what}");
        // Sanitising drops it: the scene stays usable in its rest pose.
        let mut fixed = bad.clone();
        fixed.sanitize();
        assert!(
            fixed.animation.is_none() && fixed.validate().is_clean(),
            "{what}"
        );
        assert_ne!(bad.content_hash(), s.content_hash(), "{what}");
    }
    let mut still = s.clone();
    still.animation = None;
    assert_ne!(still.content_hash(), s.content_hash());
}

#[test]
fn a_clip_is_chosen_only_of_a_gltf() {
    let e = lightfold_scene::load_with_clip("balls", Some("walk")).unwrap_err();
    assert!(
        matches!(e, lightfold_scene::SceneError::ClipOfNonGltf { .. }),
        "{e}"
    );
    assert!(e.to_string().contains("[gltf] table"), "{e}");
    let e = lightfold_scene::load_with_clip("scene.toml", Some("0")).unwrap_err();
    assert!(
        matches!(e, lightfold_scene::SceneError::ClipOfNonGltf { .. }),
        "{e}"
    );
    // Without a clip it is `load`; a glTF's clip by a name it lacks is the glTF loader's error.
    assert_eq!(
        lightfold_scene::load_with_clip("balls", None).unwrap(),
        lightfold_scene::load("balls").unwrap()
    );
    assert!(lightfold_scene::load_with_clip("missing.glb", Some("walk")).is_err());
}
