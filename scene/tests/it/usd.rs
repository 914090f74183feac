//! USD stages (written with Pixar's usd-core by `scripts/usd-testdata.py`): a stage with each
//! UsdLux light type lightfold reads loads to the scene written by hand as a TOML file (meshes,
//! materials, lights, camera, and the image of both), in text, binary and package form, and a
//! loader that ignored `exposure` or `normalize` would be caught; materials, units, up axis and
//! composition (references, payloads, sublayers, instances) map as `docs/scenes.md` says; paths
//! outside the folder, cycles and malformed stages are clear errors.

use crate::support;
use lightfold_scene::usd_load::ignored_features;
use lightfold_scene::{
    AlphaMode, LightShape, ModelOptions, Scene, load, load_scene_file, load_usd_slice,
    load_usd_with, parse_scene_file,
};
use std::path::{Path, PathBuf};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

fn unplaced() -> ModelOptions {
    ModelOptions {
        complete: false,
        binary_usd: false,
        ..ModelOptions::default()
    }
}

/// [`unplaced`], with binary layers trusted.
fn trusted() -> ModelOptions {
    ModelOptions {
        binary_usd: true,
        ..unplaced()
    }
}

fn close(a: f32, b: f32, tol: f32) -> bool {
    (a - b).abs() <= tol * (1.0 + a.abs().max(b.abs()))
}

fn close_all(a: &[f32], b: &[f32], tol: f32) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| close(*x, *y, tol))
}

/// A mesh's triangles as corner lists (position, normal), each turned to start at its least
/// corner (winding kept), sorted: equal for the same surface whatever the vertex order.
fn triangles(mesh: &lightfold_scene::Mesh) -> Vec<[f32; 18]> {
    let key = |p: [f32; 3]| p.map(|c| (c * 1e4).round() as i64);
    let mut out: Vec<[f32; 18]> = mesh
        .indices
        .chunks_exact(3)
        .map(|t| {
            let first = (0..3)
                .min_by_key(|&k| key(mesh.positions[t[k] as usize]))
                .unwrap();
            let mut row = [0.0; 18];
            for j in 0..3 {
                let i = t[(first + j) % 3] as usize;
                row[j * 6..j * 6 + 3].copy_from_slice(&mesh.positions[i]);
                row[j * 6 + 3..j * 6 + 6].copy_from_slice(&mesh.normals[i]);
            }
            row
        })
        .collect();
    out.sort_by_key(|row| row.map(|c| (c * 1e4).round() as i64));
    out
}

fn shape_numbers(s: &LightShape) -> (&'static str, Vec<f32>) {
    match s {
        LightShape::Point { position } => ("point", position.to_vec()),
        LightShape::Spot {
            position,
            direction,
            inner_angle,
            outer_angle,
        } => (
            "spot",
            [&position[..], direction, &[*inner_angle, *outer_angle]].concat(),
        ),
        LightShape::Directional { direction, angle } => {
            ("directional", [&direction[..], &[*angle]].concat())
        }
        LightShape::Rect {
            center,
            normal,
            u_axis,
            size,
        } => ("rect", [&center[..], normal, u_axis, size].concat()),
        LightShape::Disk {
            center,
            normal,
            radius,
        } => ("disk", [&center[..], normal, &[*radius]].concat()),
        LightShape::Sphere { center, radius } => ("sphere", [&center[..], &[*radius]].concat()),
        LightShape::Cylinder {
            center,
            axis,
            length,
            radius,
        } => (
            "cylinder",
            [&center[..], axis, &[*length, *radius]].concat(),
        ),
        LightShape::EmissiveMesh { mesh } => ("emissive mesh", vec![*mesh as f32]),
    }
}

/// Whether two scenes hold the same meshes (triangles and materials), lights and camera within
/// float tolerance; the first difference otherwise.
fn same_scene(want: &Scene, got: &Scene) -> Result<(), String> {
    if want.meshes.len() != got.meshes.len() {
        return Err(format!(
            "{} meshes, want {}",
            got.meshes.len(),
            want.meshes.len()
        ));
    }
    for w in &want.meshes {
        let g = got
            .meshes
            .iter()
            .find(|m| m.name == w.name)
            .ok_or(format!("no mesh {:?}", w.name))?;
        let (tw, tg) = (triangles(w), triangles(g));
        if tw.len() != tg.len() || tw.iter().zip(&tg).any(|(a, b)| !close_all(a, b, 1e-5)) {
            return Err(format!("mesh {:?}: triangles {tg:?}, want {tw:?}", w.name));
        }
        let (mw, mg) = (&want.materials[w.material], &got.materials[g.material]);
        if !close_all(&mw.diffuse, &mg.diffuse, 1e-6)
            || mw.specular != mg.specular
            || mw.shininess != mg.shininess
            || mw.emissive != mg.emissive
            || mw.double_sided != mg.double_sided
            || mw.pbr != mg.pbr
            || mw.alpha_mode != mg.alpha_mode
            || mw.transmission != mg.transmission
        {
            return Err(format!("mesh {:?}: material {mg:?}, want {mw:?}", w.name));
        }
    }
    if want.lights.len() != got.lights.len() {
        return Err(format!(
            "{} lights, want {}",
            got.lights.len(),
            want.lights.len()
        ));
    }
    for (w, g) in want.lights.iter().zip(&got.lights) {
        let (kw, nw) = shape_numbers(&w.shape);
        let (kg, ng) = shape_numbers(&g.shape);
        if w.name != g.name
            || kw != kg
            || !close_all(&nw, &ng, 1e-5)
            || !close(w.power, g.power, 1e-6)
            || !close_all(&w.color, &g.color, 1e-6)
            || w.samples != g.samples
            || w.range != g.range
        {
            return Err(format!("light {:?}: {g:?}, want {w:?}", w.name));
        }
    }
    let (cw, cg) = (&want.camera, &got.camera);
    if !close_all(&cw.position, &cg.position, 1e-5)
        || !close_all(&cw.target, &cg.target, 1e-5)
        || !close_all(&cw.up, &cg.up, 1e-5)
        || !close(cw.fov_y_deg, cg.fov_y_deg, 1e-5)
        || (cw.width, cw.height) != (cg.width, cg.height)
    {
        return Err(format!("camera {cg:?}, want {cw:?}"));
    }
    Ok(())
}

/// Mean absolute difference of two scenes' images (the test tracer, 64 × 43, linear RGB) over
/// the mean of the first.
fn image_difference(a: &Scene, b: &Scene) -> f64 {
    let render = |s: &Scene| {
        let samples = lightfold_scene::sampling::direct_samples(s);
        support::render(s, &samples, 64, 43).image.data
    };
    let (ia, ib) = (render(a), render(b));
    let diff: f64 = ia
        .iter()
        .zip(&ib)
        .map(|(x, y)| f64::from((x - y).abs()))
        .sum();
    let mean: f64 = ia.iter().map(|x| f64::from(x.abs())).sum();
    diff / mean.max(1e-12)
}

fn hand_written() -> Scene {
    load_scene_file(&data("usd-lights.toml")).unwrap()
}

#[test]
fn a_stage_with_each_light_type_loads_to_the_scene_written_by_hand() {
    let want = hand_written();
    for file in ["lights.usda", "lights.usdc", "lights.usdz"] {
        let path = data("usd").join(file);
        let got = load_usd_with(&path, &trusted()).unwrap_or_else(|e| panic!("{file}: {e}"));
        if let Err(e) = same_scene(&want, &got) {
            panic!("{file}: {e}");
        }
        if file.ends_with(".usda") {
            assert!(ignored_features(&path).unwrap().is_empty(), "{file}");
        }
        let d = image_difference(&want, &got);
        assert!(d < 1e-4, "{file}: images differ by {d}");
    }
}

#[test]
fn a_loader_that_ignored_exposure_or_normalize_would_be_caught() {
    let want = hand_written();
    let got = load_usd_with(&data("usd/lights.usda"), &unplaced()).unwrap();
    // What the panel would get with its exposure (+1) ignored, and the disk with `normalize`
    // ignored (its area, π·1², not divided out).
    let mut no_exposure = got.clone();
    no_exposure.lights[0].power /= 2.0;
    let mut no_normalize = got.clone();
    no_normalize.lights[1].power *= std::f32::consts::PI;
    for (control, light) in [(&no_exposure, "Panel"), (&no_normalize, "Disk")] {
        let e = same_scene(&want, control).unwrap_err();
        assert!(e.starts_with(&format!("light {light:?}")), "{e}");
        let d = image_difference(&want, control);
        assert!(d > 0.01, "{light}: the images differ by only {d}");
    }
}

#[test]
fn a_stage_loads_directly_and_from_a_scene_file() {
    let direct = load(data("usd/lights.usda").to_str().unwrap()).unwrap();
    assert_eq!(direct.name, "lights");
    assert_eq!(direct.lights.len(), 7);
    // The stage's camera is kept (completion only frames a scene without one).
    assert!(close(direct.camera.fov_y_deg, 37.8493, 1e-5));
    let dir = crate::obj::scratch("usd-scene-file");
    std::fs::copy(data("usd/lights.usda"), dir.join("lights.usda")).unwrap();
    let text = "version = 1\n[usd]\npath = \"lights.usda\"\nscale = 2.0\n\
                [[object]]\ntype = \"sphere\"\nname = \"ball\"\ncenter = [0.0, 3.0, 0.0]\n\
                radius = 0.5\n";
    let scene = parse_scene_file(text, "with-usd.toml", Some(&dir)).unwrap();
    assert_eq!(scene.lights.len(), 7);
    assert!(scene.meshes.iter().any(|m| m.name == "ball"));
    // Placed at scale 2: the panel is twice as high and wide, its radiance unchanged.
    let LightShape::Rect { center, size, .. } = scene.lights[0].shape else {
        panic!("{:?}", scene.lights[0]);
    };
    assert_eq!((center, size), ([-4.0, 6.0, 0.0], [4.0, 2.0]));
    assert_eq!(scene.lights[0].power, 8.0);
    assert_eq!(scene.camera.position, [0.0, 6.0, 20.0]);
    let e = parse_scene_file(
        "version = 1\n[usd]\npath = \"lights.usda\"\n[ply]\npath = \"x.ply\"\n",
        "two.toml",
        Some(&dir),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("[ply] and [usd]"), "{e}");
}

#[test]
fn preview_surfaces_units_and_up_axis_map_to_lightfold() {
    let path = data("usd/materials.usda");
    let scene = load_usd_with(&path, &unplaced()).unwrap();
    assert_eq!(scene.meshes.len(), 2);
    let quad = &scene.meshes[0];
    assert_eq!(quad.name, "Quad");
    // 100 cm in Z-up becomes 1 m in the XZ plane (Z up → −Y forward), facing +Y.
    for p in &quad.positions {
        assert!(close(p[0].abs(), 0.5, 1e-6) && p[1].abs() < 1e-6 && close(p[2].abs(), 0.5, 1e-6));
    }
    assert!(
        quad.normals
            .iter()
            .all(|n| close_all(n, &[0.0, 1.0, 0.0], 1e-6))
    );
    let gold = &scene.materials[quad.material];
    let pbr = gold.pbr.unwrap();
    assert_eq!(
        (pbr.base_color, pbr.metallic, pbr.roughness),
        ([1.0, 0.8, 0.3], 1.0, 0.25)
    );
    assert!(!gold.double_sided);
    // The triangle glows (an emissive-mesh light of its emissive colour), is half transparent,
    // left-handed (its winding turned to lightfold's), and has per-corner texture coordinates.
    let tri = &scene.meshes[1];
    let glow = &scene.materials[tri.material];
    assert_eq!(glow.emissive, [2.0, 4.0, 1.0]);
    assert_eq!(glow.alpha, 0.5);
    assert_eq!(glow.alpha_mode, AlphaMode::Mask { cutoff: 0.5 });
    assert!(glow.transmission.is_some_and(|t| t.coverage));
    assert_eq!(scene.lights.len(), 2);
    assert_eq!(scene.lights[1].shape, LightShape::EmissiveMesh { mesh: 1 });
    // The tube at UsdLux's fallbacks (length 1, radius 0.5) in centimetres, along X.
    let LightShape::Cylinder {
        center,
        axis,
        length,
        radius,
    } = scene.lights[0].shape
    else {
        panic!("{:?}", scene.lights[0]);
    };
    assert!(close_all(&center, &[0.0; 3], 1e-6) && close_all(&axis, &[1.0, 0.0, 0.0], 1e-6));
    assert!(close(length, 0.01, 1e-6) && close(radius, 0.005, 1e-6));
    assert_eq!(scene.lights[0].power, 1.0);
    assert_eq!(
        (scene.lights[1].power, scene.lights[1].color),
        (4.0, [0.5, 1.0, 0.25])
    );
    assert!(tri.positions.iter().all(|p| close(p[1], 0.5, 1e-6)));
    assert!(
        tri.normals
            .iter()
            .all(|n| close_all(n, &[0.0, -1.0, 0.0], 1e-6))
    );
    let mut uvs = tri.uvs.clone();
    uvs.sort_by(|a, b| a.partial_cmp(b).unwrap());
    assert_eq!(uvs, vec![[0.0, 0.0], [0.0, 1.0], [1.0, 1.0]]);
    let ignored = ignored_features(&path).unwrap();
    for word in ["Cube prims", "UsdPreviewSurface clearcoat"] {
        assert!(ignored.iter().any(|i| i.contains(word)), "{ignored:?}");
    }
    assert_eq!(ignored.len(), 2, "{ignored:?}");
}

#[test]
fn a_mesh_with_mesh_light_api_is_an_emissive_mesh_light() {
    let path = data("usd/meshlight.usda");
    let scene = load_usd_with(&path, &unplaced()).unwrap();
    let panel = scene.meshes.iter().position(|m| m.name == "Panel").unwrap();
    assert_eq!(scene.lights.len(), 1);
    let l = &scene.lights[0];
    assert_eq!(l.shape, LightShape::EmissiveMesh { mesh: panel });
    // 6 · 2^1 over the panel's 2 m².
    assert!(close(l.power, 6.0, 1e-6), "{}", l.power);
    assert_eq!(l.color, [1.0, 0.5, 0.25]);
    let glow = &scene.materials[scene.meshes[panel].material];
    assert_eq!(glow.emissive, [6.0, 3.0, 1.5]);
    // Its triangles face down (counter-clockwise seen from below).
    assert!(
        scene.meshes[panel]
            .normals
            .iter()
            .all(|n| close_all(n, &[0.0, -1.0, 0.0], 1e-6))
    );
    assert!(ignored_features(&path).unwrap().is_empty());
}

#[test]
fn references_payloads_sublayers_and_instances_compose() {
    let scene = load_usd_with(&data("usd/composed.usda"), &unplaced()).unwrap();
    let mut names: Vec<&str> = scene.meshes.iter().map(|m| m.name.as_str()).collect();
    names.sort();
    assert_eq!(names, ["Ground", "Mesh", "Mesh"]);
    // The two instances of the referenced box, each at its own place.
    let mut xs: Vec<f32> = scene
        .meshes
        .iter()
        .filter(|m| m.name == "Mesh")
        .map(|m| m.positions.iter().map(|p| p[0]).sum::<f32>() / m.positions.len() as f32)
        .collect();
    xs.sort_by(|a, b| a.partial_cmp(b).unwrap());
    assert!(
        close(xs[0], -1.5, 1e-6) && close(xs[1], 1.5, 1e-6),
        "{xs:?}"
    );
    // The payload's light.
    assert_eq!(scene.lights.len(), 1);
    let LightShape::Rect { center, .. } = scene.lights[0].shape else {
        panic!("{:?}", scene.lights[0]);
    };
    assert_eq!(center, [0.0, 4.0, 0.0]);
    assert_eq!(scene.lights[0].power, 5.0);
}

fn has(text: &str, words: &[&str]) {
    for w in words {
        assert!(text.contains(w), "{w:?} not in: {text}");
    }
}

#[test]
fn paths_outside_the_folder_and_cycles_are_refused() {
    for (file, words) in [
        (
            "outside.usda",
            &["invalid USD", "refused", "outside the stage's folder"][..],
        ),
        ("absolute.usda", &["refused", "/etc/hosts.usda"][..]),
        (
            "sublayer_outside.usda",
            &["refused", "outside the stage's folder"][..],
        ),
        ("cycle_a.usda", &["composition error", "cycle"][..]),
    ] {
        let e = load_usd_with(&data("usd").join(file), &unplaced())
            .unwrap_err()
            .to_string();
        has(&e, words);
    }
    // A symbolic link inside the folder that leads out of it is refused too.
    let dir = crate::obj::scratch("usd-link");
    std::fs::copy(data("usd/parts/box.usda"), dir.join("../secret.usda")).unwrap();
    std::os::unix::fs::symlink(dir.join("../secret.usda"), dir.join("link.usda")).unwrap();
    let stage = "#usda 1.0\ndef \"A\" (references = @./link.usda@) {}\n";
    std::fs::write(dir.join("stage.usda"), stage).unwrap();
    let e = load_usd_with(&dir.join("stage.usda"), &unplaced())
        .unwrap_err()
        .to_string();
    has(&e, &["refused", "link.usda", "outside the stage's folder"]);
    // Bytes without a folder may name no file at all.
    let text = "#usda 1.0\ndef \"A\" (references = @./parts/box.usda@) {}\n";
    let e = load_usd_slice(text.as_bytes(), "bytes.usda", None, &unplaced())
        .unwrap_err()
        .to_string();
    has(&e, &["refused", "without a folder"]);
}

const MESH: &str =
    "#usda 1.0\ndef Mesh \"M\" {\n  point3f[] points = [(0,0,0), (1,0,0), (0,1,0)]\n";

fn mesh_err(rest: &str) -> String {
    let text = format!("{MESH}{rest}\n}}\n");
    load_usd_slice(text.as_bytes(), "m.usda", None, &unplaced())
        .unwrap_err()
        .to_string()
}

#[test]
fn malformed_and_oversized_stages_are_clear_errors() {
    // A control that loads.
    let ok =
        format!("{MESH}int[] faceVertexCounts = [3]\nint[] faceVertexIndices = [0, 1, 2]\n}}\n");
    let scene = load_usd_slice(ok.as_bytes(), "ok.usda", None, &unplaced()).unwrap();
    assert_eq!(scene.triangle_count(), 1);
    for (rest, words) in [
        (
            "int[] faceVertexCounts = [3]\nint[] faceVertexIndices = [0, 1, 7]",
            &["/M", "faceVertexIndices[2] is 7", "outside its 3 points"][..],
        ),
        (
            "int[] faceVertexCounts = [3]\nint[] faceVertexIndices = [0, -1, 2]",
            &["faceVertexIndices[1] is -1"][..],
        ),
        (
            "int[] faceVertexCounts = [3, 3]\nint[] faceVertexIndices = [0, 1, 2, 0]",
            &["add up to 6", "faceVertexIndices has 4"][..],
        ),
        (
            "int[] faceVertexCounts = [3]\nint[] faceVertexIndices = [0, 1, 2, 0]",
            &["add up to 3", "has 4"][..],
        ),
        (
            "int[] faceVertexCounts = [2, 1]\nint[] faceVertexIndices = [0, 1, 2]",
            &["faceVertexCounts[0] is 2", "at least 3"][..],
        ),
        (
            "float[] faceVertexCounts = [3]\nint[] faceVertexIndices = [0, 1, 2]",
            &["faceVertexCounts is not an array of integers"][..],
        ),
    ] {
        let e = mesh_err(rest);
        has(&e, &["m.usda: invalid USD"]);
        has(&e, words);
    }
    for (bytes, words) in [
        (
            &b"\x00\xff garbage \x01"[..],
            &["invalid USD", "cannot open the stage"][..],
        ),
        (&b"PXR-USDC\x00\x00garbage"[..], &["invalid USD"][..]),
        (&b"PK\x03\x04garbage"[..], &["invalid USD"][..]),
        (
            &b"#usda 1.0\ndef Mesh \"M\" { point3f[] points = [(0,0"[..],
            &["invalid USD"][..],
        ),
    ] {
        let e = load_usd_slice(bytes, "g.usd", None, &unplaced())
            .unwrap_err()
            .to_string();
        has(&e, words);
    }
    // A binary layer whose token index is out of range made `openusd` 0.6 panic (found by the
    // fuzzer; its input is kept in fuzz/crashes/usd/): the loader turns that into an error.
    let crash = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../fuzz/crashes/usd/crash-d656f14611a19219949ba0781643b4c30491aaed");
    let bytes = std::fs::read(crash).unwrap();
    let e = load_usd_slice(&bytes, "crash.usdc", None, &trusted())
        .unwrap_err()
        .to_string();
    has(
        &e,
        &[
            "crash.usdc: invalid USD",
            "the USD reader panicked",
            "index out of bounds",
        ],
    );
    // An unterminated string that makes an xformOpOrder entry of the rest of the file hung the
    // crate's composition (found by the fuzzer; kept in fuzz/crashes/usd/): refused first.
    let hang = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../fuzz/crashes/usd/timeout-116c92cdcb3e285b42ec373b56dfe075e0876e6f");
    let bytes = std::fs::read(hang).unwrap();
    let e = load_usd_slice(&bytes, "hang.usda", None, &unplaced())
        .unwrap_err()
        .to_string();
    has(
        &e,
        &[
            "hang.usda: invalid USD",
            "/World/Occluder: xformOpOrder names",
            "not an xformOp",
        ],
    );
    // So did a connection whose `<…>` target is not closed (the same find, a run later).
    let hang = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../fuzz/crashes/usd/timeout-116d0914e2bdb3318b615a0aabdd92acb22c5170");
    let bytes = std::fs::read(hang).unwrap();
    let e = load_usd_slice(&bytes, "hang2.usda", None, &unplaced())
        .unwrap_err()
        .to_string();
    has(
        &e,
        &[
            "/Root/Looks/Gold.outputs:surface connects to",
            "is not a prim or property path",
        ],
    );
    // And a prim whose name is not an identifier (NUL bytes, spaces: a later run).
    let hang = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../fuzz/crashes/usd/timeout-7b2409dc8e9080f878185548a7f1ca95b0dc827e");
    let bytes = std::fs::read(hang).unwrap();
    let e = load_usd_slice(&bytes, "hang3.usda", None, &unplaced())
        .unwrap_err()
        .to_string();
    has(
        &e,
        &["a prim under / is named", "which is not an identifier"],
    );
    // Counts beyond the limits are refused before a mesh is built: one face of 10 000 003
    // corners (20 MB of text) is 10 000 001 triangles.
    let mut big = String::with_capacity(20_000_200);
    big.push_str(MESH);
    big.push_str("int[] faceVertexCounts = [10000003]\nint[] faceVertexIndices = [0");
    for _ in 1..10_000_003u32 {
        big.push_str(",0");
    }
    big.push_str("]\n}\n");
    let e = load_usd_slice(big.as_bytes(), "big.usda", None, &unplaced())
        .unwrap_err()
        .to_string();
    has(&e, &["big.usda", "10000001 triangles", "at most 10000000"]);
}

#[test]
fn composition_that_multiplies_prims_is_bounded() {
    // Three levels of 64 children, each referencing the next level: 266 240 prims from 6 kB
    // (nested references compose exponentially many); the walk stops at the limit.
    let mut text = String::from("#usda 1.0\n");
    for level in 0..3 {
        text.push_str(&format!("def \"L{level}\"\n{{\n"));
        for k in 0..64 {
            if level < 2 {
                let next = level + 1;
                text.push_str(&format!(
                    "    def \"c{k}\" (references = </L{next}>) {{}}\n"
                ));
            } else {
                text.push_str(&format!("    def \"c{k}\" {{}}\n"));
            }
        }
        text.push_str("}\n");
    }
    let start = std::time::Instant::now();
    let e = load_usd_slice(text.as_bytes(), "bomb.usda", None, &unplaced())
        .unwrap_err()
        .to_string();
    has(&e, &["bomb.usda", "65537 prims", "at most 65536"]);
    assert!(start.elapsed().as_secs() < 60, "{:?}", start.elapsed());
}

/// Binary layers are read only from trusted files (`ModelOptions::binary_usd`): the reader
/// allocates the counts a binary layer claims, so by default a `.usdc`, and a `.usdz` holding
/// one, is refused with why and how to convert it; the same files load when trusted (above).
#[test]
fn binary_layers_are_refused_unless_trusted() {
    for file in ["lights.usdc", "lights.usdz"] {
        let e = load_usd_with(&data("usd").join(file), &unplaced())
            .expect_err(file)
            .to_string();
        assert!(e.contains("binary USD layer"), "{file}: {e}");
        assert!(e.contains("LIGHTFOLD_TRUST_BINARY_USD=1"), "{file}: {e}");
        assert!(e.contains("usdcat"), "{file}: {e}");
    }
    // Control: text layers are read without it.
    load_usd_with(&data("usd").join("lights.usda"), &unplaced()).unwrap();
}

/// Time-sampled transforms animate what they place: a mesh under a translated parent and its
/// own turn, and a light under the parent, posed at any time as USD interpolates the samples
/// (positions worked out by hand), holding the ends; a mesh without samples stays.
#[test]
fn time_sampled_transforms_animate_meshes_and_lights() {
    let path = data("usd/moving.usda");
    let scene = load_usd_with(&path, &unplaced()).unwrap();
    let ignored = ignored_features(&path).unwrap();
    assert!(
        !ignored.iter().any(|i| i.contains("time-sampled")),
        "{ignored:?}"
    );
    let anim = scene.animation.as_ref().expect("the stage animates");
    assert_eq!(
        (anim.nodes.len(), anim.meshes.len(), anim.lights.len()),
        (2, 1, 1)
    );
    assert!(
        (anim.duration() - 2.0).abs() < 1e-6,
        "48 time codes at 24 a second"
    );
    let blade = scene.meshes.iter().position(|m| m.name == "Blade").unwrap();
    let floor = scene.meshes.iter().position(|m| m.name == "Floor").unwrap();
    // The blade's corner (1, 1, 0) at rest: turned about y by 45° per second, shifted by the
    // parent's translation (linear between its samples).
    let k = scene.meshes[blade]
        .positions
        .iter()
        .position(|p| close_all(p, &[1.0, 1.0, 0.0], 1e-6))
        .expect("the corner at rest");
    let corner = |t: f32| -> [f32; 3] { scene.pose_meshes(t)[blade].positions[k] };
    let s = std::f32::consts::FRAC_1_SQRT_2;
    let (c, sn) = (22.5f32.to_radians().cos(), 22.5f32.to_radians().sin());
    for (t, want) in [
        (0.0, [1.0, 1.0, 0.0]),
        (0.5, [1.0 + c, 1.0, -sn]),
        (1.0, [2.0 + s, 1.0, -s]),
        (2.0, [2.0, 1.0, 1.0]),
        (5.0, [2.0, 1.0, 1.0]),
    ] {
        let got = corner(t);
        assert!(
            close_all(&got, &want, 1e-4),
            "t = {t}: {got:?}, want {want:?}"
        );
    }
    let posed = scene.pose_meshes(1.0);
    assert_eq!(
        posed[floor], scene.meshes[floor],
        "the floor has no samples"
    );
    // The lamp rides the parent: (0, 3, 0) shifted.
    let lamp = |t: f32| scene.samples_at(t)[0].position;
    assert!(
        close_all(&lamp(0.0), &[0.0, 3.0, 0.0], 1e-5),
        "{:?}",
        lamp(0.0)
    );
    assert!(
        close_all(&lamp(1.0), &[2.0, 3.0, 0.0], 1e-5),
        "{:?}",
        lamp(1.0)
    );
    assert!(
        close_all(&lamp(1.5), &[2.0, 3.0, 1.0], 1e-5),
        "{:?}",
        lamp(1.5)
    );
}

/// A `DistantLight`'s `angle` makes a soft sun: sampled as an area light, and without
/// `normalize` its radiance gives the irradiance `π·L·sin²(angle/2)` of its disk; an angle past
/// 90° is narrowed to it and listed.
#[test]
fn a_distant_lights_angle_makes_a_soft_sun() {
    let dir = crate::obj::scratch("usd-soft-sun");
    let stage = |angle: &str| {
        let text = format!(
            "#usda 1.0\ndef DistantLight \"Sun\" {{\n  float inputs:intensity = 1000\n  \
             float inputs:angle = {angle}\n}}\n"
        );
        let path = dir.join(format!("sun{angle}.usda"));
        std::fs::write(&path, text).unwrap();
        path
    };
    let path = stage("4.0");
    let scene = load_usd_with(&path, &unplaced()).unwrap();
    let sun = &scene.lights[0];
    let want = 1000.0 * std::f64::consts::PI * 2f64.to_radians().sin().powi(2);
    assert!(
        close(sun.power, want as f32, 1e-6),
        "{} vs {want}",
        sun.power
    );
    assert_eq!(
        sun.shape,
        LightShape::Directional {
            direction: [0.0, 0.0, -1.0],
            angle: 4f32.to_radians()
        }
    );
    assert!(sun.is_area());
    assert_eq!(lightfold_scene::sampling::direct_samples(&scene).len(), 16);
    assert!(ignored_features(&path).unwrap().is_empty());
    // Parallel at angle 0: one sample, the radiance read as irradiance.
    let flat = load_usd_with(&stage("0.0"), &unplaced()).unwrap();
    assert!(!flat.lights[0].is_area() && flat.lights[0].power == 1000.0);
    let wide_path = stage("120.0");
    let wide = load_usd_with(&wide_path, &unplaced()).unwrap();
    assert!(matches!(wide.lights[0].shape,
        LightShape::Directional { angle, .. } if angle == std::f32::consts::FRAC_PI_2));
    let ignored = ignored_features(&wide_path).unwrap();
    assert!(
        ignored.iter().any(|i| i.contains("narrowed")),
        "{ignored:?}"
    );
}
