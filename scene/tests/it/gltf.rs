//! glTF loading: every public model (copied with its licence into `assets/`) loads, is completed with a camera,
//! ground and area light, and is clean; broken files give errors naming the file and the problem.

use crate::support;

use lightfold_scene::sampling::direct_samples;
use lightfold_scene::{AlphaMode, GltfOptions, SceneError, load_gltf, load_gltf_with};
use std::path::{Path, PathBuf};

fn shared(model: &str, file: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../assets")
        .join(model)
        .join(file)
}

#[test]
fn public_models_load_and_are_completed() {
    let cases = [
        ("AlphaBlendModeTest", "AlphaBlendModeTest.gltf"),
        ("BoxTextured", "BoxTextured.gltf"),
        ("CesiumMan", "CesiumMan.gltf"),
        ("FlightHelmet", "FlightHelmet.gltf"),
        ("Fox", "Fox.glb"),
    ];
    for (model, file) in cases {
        let t = std::time::Instant::now();
        let s = load_gltf(&shared(model, file)).unwrap_or_else(|e| panic!("{e}"));
        println!(
            "{model}: {} meshes, {} triangles, {} materials, {} textures, {} lights, bounds {:?}, {:?}",
            s.meshes.len(),
            s.triangle_count(),
            s.materials.len(),
            s.textures.len(),
            s.lights.len(),
            s.bounds(),
            t.elapsed()
        );
        assert!(s.triangle_count() > 0, "{model}");
        assert_eq!(s.lights.len(), 1, "{model}: the framing light");
        assert!(s.validate().is_clean(), "{model}: {}", s.validate());
        let view = support::render(&s, &direct_samples(&s), 160, 120);
        let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("scene-previews");
        std::fs::create_dir_all(&dir).unwrap();
        view.image
            .write_png(&dir.join(format!("{model}.png")), s.exposure)
            .unwrap();
    }
}

/// A scratch folder for hand-made files, unique per test.
fn scratch(test: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join("gltf-broken")
        .join(test);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// One triangle: three positions then three u16 indices (padded), as a .gltf + .bin pair.
/// `edit` may change the JSON text before it is written.
fn triangle_case(test: &str, indices: [u16; 3], edit: impl Fn(String) -> String) -> PathBuf {
    let dir = scratch(test);
    let mut bin = Vec::new();
    for p in [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
        for c in p {
            bin.extend_from_slice(&c.to_le_bytes());
        }
    }
    for i in indices {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    bin.extend_from_slice(&[0, 0]);
    std::fs::write(dir.join("tri.bin"), &bin).unwrap();
    let json = r#"{
  "asset": {"version": "2.0"},
  "scene": 0,
  "scenes": [{"nodes": [0]}],
  "nodes": [{"mesh": 0}],
  "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
  "buffers": [{"uri": "tri.bin", "byteLength": 44}],
  "bufferViews": [
    {"buffer": 0, "byteOffset": 0, "byteLength": 36},
    {"buffer": 0, "byteOffset": 36, "byteLength": 6}
  ],
  "accessors": [
    {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
     "min": [0, 0, 0], "max": [1, 1, 0]},
    {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"}
  ]
}"#;
    let path = dir.join("tri.gltf");
    std::fs::write(&path, edit(json.to_string())).unwrap();
    path
}

fn expect_error(path: &Path, words: &[&str]) -> String {
    let err = match load_gltf(path) {
        Ok(_) => panic!("{} loaded but is broken", path.display()),
        Err(e) => e,
    };
    let text = err.to_string();
    assert!(text.contains(&path.display().to_string()), "{text}");
    for w in words {
        assert!(text.contains(w), "{text:?} lacks {w:?}");
    }
    text
}

#[test]
fn a_hand_made_triangle_loads_with_flat_normals() {
    let path = triangle_case("good", [0, 1, 2], |j| j);
    let opts = GltfOptions {
        complete: false,
        ..GltfOptions::default()
    };
    let s = load_gltf_with(&path, &opts).unwrap();
    assert_eq!(s.triangle_count(), 1);
    assert_eq!(s.meshes[0].normals, vec![[0.0, 0.0, 1.0]; 3]);
    assert!(s.lights.is_empty());
    // The default material (none given) is a grey diffuse.
    assert_eq!(s.materials[s.meshes[0].material].diffuse, [0.8; 3]);
    let completed = load_gltf(&path).unwrap();
    assert_eq!(completed.lights.len(), 1);
    assert_eq!(completed.meshes.len(), 2, "the ground plane is added");
}

#[test]
fn truncated_glb_is_an_error() {
    let dir = scratch("truncated");
    let bytes = std::fs::read(shared("Fox", "Fox.glb")).unwrap();
    for cut in [10, 20, 1000, bytes.len() / 2, bytes.len() - 1] {
        let path = dir.join(format!("cut{cut}.glb"));
        std::fs::write(&path, &bytes[..cut]).unwrap();
        println!("{}", expect_error(&path, &["invalid glTF"]));
    }
}

#[test]
fn missing_buffer_file_is_an_error() {
    let dir = scratch("missing-bin");
    let src = shared("BoxTextured", "BoxTextured.gltf");
    let path = dir.join("BoxTextured.gltf");
    std::fs::copy(src, &path).unwrap();
    println!("{}", expect_error(&path, &["buffer 0", "BoxTextured0.bin"]));
}

#[test]
fn short_buffer_is_an_error() {
    let path = triangle_case("short-bin", [0, 1, 2], |j| {
        j.replace("\"byteLength\": 44", "\"byteLength\": 400")
    });
    println!(
        "{}",
        expect_error(&path, &["buffer 0 holds 44 bytes but declares 400"])
    );
}

#[test]
fn bad_accessors_are_errors() {
    // More elements than the view holds.
    let path = triangle_case("count", [0, 1, 2], |j| {
        j.replace(
            "\"count\": 3, \"type\": \"VEC3\"",
            "\"count\": 30, \"type\": \"VEC3\"",
        )
    });
    println!(
        "{}",
        expect_error(&path, &["accessor 0", "POSITION", "exceed buffer view 0"])
    );
    // A view that runs past its buffer.
    let path = triangle_case("view", [0, 1, 2], |j| {
        j.replace(
            "\"byteOffset\": 36, \"byteLength\": 6",
            "\"byteOffset\": 40, \"byteLength\": 6",
        )
    });
    println!("{}", expect_error(&path, &["buffer view 1"]));
    // Positions declared as VEC2.
    let path = triangle_case("type", [0, 1, 2], |j| {
        j.replace(
            "\"count\": 3, \"type\": \"VEC3\"",
            "\"count\": 3, \"type\": \"VEC2\"",
        )
    });
    println!("{}", expect_error(&path, &["accessor 0"]));
    // An accessor index that does not exist.
    let path = triangle_case("dangling", [0, 1, 2], |j| {
        j.replace("\"indices\": 1", "\"indices\": 7")
    });
    println!("{}", expect_error(&path, &["validation failed"]));
}

#[test]
fn out_of_range_vertex_index_is_an_error() {
    let path = triangle_case("index", [0, 1, 9], |j| j);
    println!(
        "{}",
        expect_error(&path, &["index 9 is out of range (3 vertices)"])
    );
}

#[test]
fn malformed_structure_is_an_error() {
    let path = triangle_case("json", [0, 1, 2], |j| j[..j.len() / 2].to_string());
    println!("{}", expect_error(&path, &["invalid glTF"]));
    let path = triangle_case("cycle", [0, 1, 2], |j| {
        j.replace(
            "\"nodes\": [{\"mesh\": 0}]",
            "\"nodes\": [{\"mesh\": 0, \"children\": [1]}, {\"children\": [0]}]",
        )
    });
    println!("{}", expect_error(&path, &["node"]));
    let path = triangle_case("uri", [0, 1, 2], |j| {
        j.replace("\"uri\": \"tri.bin\"", "\"uri\": \"tri%ff.bin\"")
    });
    println!("{}", expect_error(&path, &["UTF-8"]));
    let path = triangle_case("scheme", [0, 1, 2], |j| {
        j.replace(
            "\"uri\": \"tri.bin\"",
            "\"uri\": \"http://example.invalid/tri.bin\"",
        )
    });
    println!("{}", expect_error(&path, &["unsupported URI scheme"]));
}

#[test]
fn missing_file_is_an_io_error() {
    let path = scratch("absent").join("absent.glb");
    let e = load_gltf(&path).unwrap_err();
    assert!(matches!(e, SceneError::Io { .. }));
    // The path once, and why.
    let text = e.to_string();
    assert_eq!(text.matches("absent.glb").count(), 1, "{text}");
    assert!(text.starts_with("cannot read "), "{text}");
}

#[test]
fn the_khronos_models_use_nothing_that_is_not_rendered() {
    // Every texture of every model in assets/ is shaded: base colour, metallic-roughness,
    // normal, occlusion, emissive. Control: an emissive texture on a second UV set is reported.
    for (model, file) in [
        ("AlphaBlendModeTest", "AlphaBlendModeTest.gltf"),
        ("BoxTextured", "BoxTextured.gltf"),
        ("CesiumMan", "CesiumMan.gltf"),
        ("FlightHelmet", "FlightHelmet.gltf"),
        ("Fox", "Fox.glb"),
    ] {
        let ignored =
            lightfold_scene::ignored_features(&shared(model, file), &GltfOptions::default())
                .unwrap();
        // The Fox's other animation clips are the one thing left (one plays at a time).
        assert!(
            ignored
                .iter()
                .all(|f| f.starts_with("animations other than")),
            "{model}: {ignored:?}"
        );
    }
    let helmet = load_gltf(&shared("FlightHelmet", "FlightHelmet.gltf")).unwrap();
    let pbr: Vec<_> = helmet.materials.iter().filter_map(|m| m.pbr).collect();
    assert!(!pbr.is_empty());
    assert!(pbr.iter().all(|p| p.normal_texture.is_some()
        && p.metallic_roughness_texture.is_some()
        && p.occlusion_texture.is_some()));
    // TANGENT is read: unit, handedness ±1, and (placed by the same world matrices) along the
    // direction of +u and with the handedness each triangle's UVs give, nearly everywhere.
    let (mut agree, mut total) = (0usize, 0usize);
    for m in helmet.meshes.iter().filter(|m| !m.tangents.is_empty()) {
        assert_eq!(m.tangents.len(), m.positions.len(), "{}", m.name);
        for t in m.indices.chunks_exact(3) {
            let i = [t[0], t[1], t[2]].map(|i| i as usize);
            let own = lightfold_scene::shading::triangle_tangent(
                i.map(|i| m.positions[i]),
                i.map(|i| m.uvs[i]),
            );
            if own[3] == 0.0 {
                continue;
            }
            total += 1;
            let v = m.tangents[i[0]];
            let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            assert!((len - 1.0).abs() < 1e-4 && v[3].abs() == 1.0, "{v:?}");
            let cos = v[0] * own[0] + v[1] * own[1] + v[2] * own[2];
            if cos > 0.7 && v[3] == own[3] {
                agree += 1;
            }
        }
    }
    eprintln!("FlightHelmet tangents agreeing with their triangles: {agree} of {total}");
    assert!(
        total > 10_000 && agree as f64 > 0.95 * total as f64,
        "{agree} of {total}"
    );
    // Data textures are linear, colour textures sRGB.
    for p in &pbr {
        for t in [
            p.normal_texture,
            p.metallic_roughness_texture,
            p.occlusion_texture,
        ] {
            assert!(!helmet.textures[t.unwrap()].srgb);
        }
    }
    let path = triangle_case("second-uv-set", [0, 1, 2], |j| {
        j.replacen(
            r#""asset": {"version": "2.0"},"#,
            r#""asset": {"version": "2.0"},
  "materials": [{"emissiveTexture": {"index": 0, "texCoord": 1}}],
  "textures": [{"source": 0}],
  "images": [{"uri": "data:image/png;base64,iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mP8z8DwHwAFBQIAX8jx0gAAAABJRU5ErkJggg=="}],"#,
            1,
        )
        .replace(
            r#""attributes": {"POSITION": 0}, "indices": 1"#,
            r#""attributes": {"POSITION": 0}, "indices": 1, "material": 0"#,
        )
    });
    let ignored = lightfold_scene::ignored_features(&path, &GltfOptions::default()).unwrap();
    assert_eq!(
        ignored,
        vec!["textures on TEXCOORD_1+ (TEXCOORD_0 used)".to_string()]
    );
}

#[test]
fn missing_tangents_are_generated_by_mikktspace() {
    // The FlightHelmet with its TANGENT attributes taken out: the loader computes MikkTSpace
    // tangents, which must agree with the ones the model ships (its exporter's MikkTSpace).
    // Control: each triangle's own tangent, the fallback before, agrees less.
    let folder = shared("FlightHelmet", "FlightHelmet.gltf");
    let json = std::fs::read_to_string(&folder).unwrap();
    let stripped = regex_free_strip(&json);
    assert!(!stripped.contains("TANGENT") && json.contains("TANGENT"));
    let opts = GltfOptions::default();
    let base = folder.parent().unwrap();
    let shipped = load_gltf(&folder).unwrap();
    let made =
        lightfold_scene::load_gltf_slice(stripped.as_bytes(), "helmet", Some(base), &opts).unwrap();
    let (mut agree, mut total, mut own_agree) = (0usize, 0usize, 0usize);
    for (a, b) in shipped.meshes.iter().zip(&made.meshes) {
        if a.tangents.is_empty() {
            continue;
        }
        assert_eq!(b.tangents.len(), b.positions.len(), "{}", b.name);
        assert!(b.positions.len() >= a.positions.len());
        // Corners compared through the indices (split vertices are appended copies).
        for (t, (&ia, &ib)) in a.indices.iter().zip(&b.indices).enumerate() {
            let (ta, tb) = (a.tangents[ia as usize], b.tangents[ib as usize]);
            assert_eq!(a.positions[ia as usize], b.positions[ib as usize]);
            total += 1;
            let cos = |u: [f32; 4]| ta[0] * u[0] + ta[1] * u[1] + ta[2] * u[2];
            if cos(tb) > 0.9 && ta[3] == tb[3] {
                agree += 1;
            }
            let tri = t / 3 * 3;
            let i = [0, 1, 2].map(|k| a.indices[tri + k] as usize);
            let own = lightfold_scene::shading::triangle_tangent(
                i.map(|i| a.positions[i]),
                i.map(|i| a.uvs[i]),
            );
            if cos(own) > 0.9 && ta[3] == own[3] {
                own_agree += 1;
            }
        }
    }
    eprintln!(
        "FlightHelmet corners whose MikkTSpace tangent agrees with the shipped one: {agree} of {total}; triangles' own: {own_agree}"
    );
    assert!(
        total > 200_000 && agree as f64 > 0.97 * total as f64,
        "{agree} of {total}"
    );
    assert!(own_agree < agree, "{own_agree} vs {agree}");
}

/// The glTF text without its `"TANGENT": N` attribute entries.
fn regex_free_strip(json: &str) -> String {
    let mut out = String::with_capacity(json.len());
    let mut rest = json;
    while let Some(at) = rest.find("\"TANGENT\"") {
        let (head, tail) = rest.split_at(at);
        // Drop a separating comma before it, then the key and its number.
        let head = head.trim_end();
        let head = head.strip_suffix(',').unwrap_or(head);
        out.push_str(head);
        let after_key = &tail["\"TANGENT\"".len()..];
        let value_end = after_key.find([',', '}']).unwrap_or(after_key.len());
        let mut next = &after_key[value_end..];
        if head.ends_with('{') {
            next = next.strip_prefix(',').unwrap_or(next);
        }
        rest = next;
    }
    out.push_str(rest);
    out
}

#[test]
fn alpha_modes_and_textures_are_read() {
    let s = load_gltf(&shared("AlphaBlendModeTest", "AlphaBlendModeTest.gltf")).unwrap();
    let masks = s
        .materials
        .iter()
        .filter(|m| matches!(m.alpha_mode, AlphaMode::Mask { .. }))
        .count();
    assert!(masks >= 2, "MASK and BLEND materials become masks: {masks}");
    let cutoffs: Vec<f32> = s
        .materials
        .iter()
        .filter_map(|m| match m.alpha_mode {
            AlphaMode::Mask { cutoff } => Some(cutoff),
            AlphaMode::Opaque => None,
        })
        .collect();
    assert!(cutoffs.contains(&0.5), "{cutoffs:?}");
    let tex = &s.textures[0];
    assert!(tex.srgb);
    assert_eq!(tex.rgba8.len(), (tex.width * tex.height * 4) as usize);
    let boxed = load_gltf(&shared("BoxTextured", "BoxTextured.gltf")).unwrap();
    assert!(boxed.materials.iter().any(|m| m.diffuse_texture.is_some()));
}

#[test]
fn fox_is_scaled_and_skinned_upright() {
    let opts = GltfOptions {
        scale: 0.01,
        complete: false,
        ..GltfOptions::default()
    };
    let s = load_gltf_with(&shared("Fox", "Fox.glb"), &opts).unwrap();
    let (lo, hi) = s.bounds().unwrap();
    // The rest pose stands on the ground, under a metre tall, about 1.5 m nose to tail.
    assert!(
        lo[1].abs() < 0.02 && (0.5..1.0).contains(&hi[1]),
        "{lo:?} {hi:?}"
    );
    assert!((1.0..2.0).contains(&(hi[2] - lo[2])), "{lo:?} {hi:?}");
}

#[test]
fn blend_and_transmission_make_translucent_casters() {
    // BLEND: the eye keeps its 0.5 cut-out; shadows filter by the base colour where it covers.
    let s = load_gltf(&shared("AlphaBlendModeTest", "AlphaBlendModeTest.gltf")).unwrap();
    let blend = s
        .materials
        .iter()
        .find(|m| m.name == "MatBlend")
        .expect("MatBlend");
    assert_eq!(blend.alpha_mode, AlphaMode::Mask { cutoff: 0.5 });
    let t = blend.transmission.expect("BLEND lets light through");
    assert!(t.coverage);
    assert!(
        s.materials
            .iter()
            .filter(|m| m.name != "MatBlend")
            .all(|m| m.transmission.is_none()),
        "OPAQUE and MASK materials stay opaque casters"
    );
    // KHR_materials_transmission: τ of the light passes, tinted by the base colour; the diffuse
    // share that passes is no longer reflected.
    let path = triangle_case("transmission", [0, 1, 2], |j| {
        j.replacen(
            r#""asset": {"version": "2.0"},"#,
            r#""asset": {"version": "2.0"},
  "extensionsUsed": ["KHR_materials_transmission"],
  "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [0.5, 1.0, 0.25, 1.0],
    "metallicFactor": 0.0},
    "extensions": {"KHR_materials_transmission": {"transmissionFactor": 0.8}}}],"#,
            1,
        )
        .replace(
            r#""attributes": {"POSITION": 0}, "indices": 1"#,
            r#""attributes": {"POSITION": 0}, "indices": 1, "material": 0"#,
        )
    });
    let opts = GltfOptions {
        complete: false,
        ..GltfOptions::default()
    };
    let s = load_gltf_with(&path, &opts).unwrap();
    let m = &s.materials[s.meshes[0].material];
    let t = m.transmission.expect("transmissive");
    assert!(!t.coverage);
    for (got, want) in t.color.iter().zip([0.4, 0.8, 0.2]) {
        assert!((got - want).abs() < 1e-6, "{:?}", t.color);
    }
    // m^d = c_diff ⊙ (1 − F0): (1 − τ)·base, less the dielectric's F0 = 0.04.
    for (got, want) in m.diffuse.iter().zip([0.1, 0.2, 0.05]) {
        assert!((got - want * 0.96).abs() < 1e-6, "{:?}", m.diffuse);
    }
    assert_eq!(m.pbr.map(|p| p.transmission), Some(0.8));
}
