//! Hostile inputs change nothing: glTF buffer and image URIs and scene-file paths are read only
//! inside their file's folder and only from regular files, with a size cap checked before
//! reading; samples, triangles, images and shadow maps beyond `lightfold_scene::limits` are clear
//! errors (from scene files, glTF and `Scene::from_bytes` alike); data URIs keep working.

use lightfold_scene::limits::{
    MAX_IMAGE_SIDE, MAX_LIGHT_SAMPLES, MAX_SAMPLES_PER_AREA_LIGHT, MAX_SCENE_BYTES, MAX_TRIANGLES,
};
use lightfold_scene::{GltfOptions, Scene, builtin, load, load_gltf, load_gltf_with};
use std::path::{Path, PathBuf};

/// A scratch folder `root/model` (the model's folder) for one test, with `root/secret.bin`
/// beside it: what an escaping URI would read.
fn scratch(test: &str) -> PathBuf {
    let root = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join("hostile")
        .join(test);
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir_all(root.join("model")).unwrap();
    std::fs::write(root.join("secret.bin"), tri_bin()).unwrap();
    root.join("model")
}

/// Three positions and three u16 indices (padded): 44 bytes.
fn tri_bin() -> Vec<u8> {
    let mut bin = Vec::new();
    for p in [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
        for c in p {
            bin.extend_from_slice(&c.to_le_bytes());
        }
    }
    for i in [0u16, 1, 2] {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    bin.extend_from_slice(&[0, 0]);
    bin
}

/// A one-triangle glTF whose buffer is at `uri`, written as `dir/tri.gltf`; `extra` is spliced
/// into the top-level object (images, textures, materials).
fn triangle(dir: &Path, uri: &str, extra: &str) -> PathBuf {
    let json = format!(
        r#"{{
  "asset": {{"version": "2.0"}},
  "scene": 0,
  "scenes": [{{"nodes": [0]}}],
  "nodes": [{{"mesh": 0}}],
  "meshes": [{{"primitives": [{{"attributes": {{"POSITION": 0}}, "indices": 1}}]}}],
  "buffers": [{{"uri": {uri:?}, "byteLength": 44}}],
  "bufferViews": [
    {{"buffer": 0, "byteOffset": 0, "byteLength": 36}},
    {{"buffer": 0, "byteOffset": 36, "byteLength": 6}}
  ],
  "accessors": [
    {{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
     "min": [0, 0, 0], "max": [1, 1, 0]}},
    {{"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"}}
  ]{extra}
}}"#
    );
    let path = dir.join("tri.gltf");
    std::fs::write(&path, json).unwrap();
    path
}

fn load_err(path: &Path) -> String {
    match load_gltf(path) {
        Ok(_) => panic!("{} loaded", path.display()),
        Err(e) => e.to_string(),
    }
}

fn has(text: &str, words: &[&str]) {
    for w in words {
        assert!(text.contains(w), "{text:?} lacks {w:?}");
    }
}

#[test]
fn buffer_uris_outside_the_model_folder_are_refused() {
    let dir = scratch("escape");
    let secret = dir.parent().unwrap().join("secret.bin");
    let e = load_err(&triangle(&dir, "../secret.bin", ""));
    has(
        &e,
        &["buffer 0", "outside the model's folder", "secret.bin"],
    );
    let e = load_err(&triangle(&dir, "sub/../../secret.bin", ""));
    has(&e, &["outside the model's folder"]);
    let e = load_err(&triangle(&dir, "%2E%2E/secret.bin", ""));
    has(&e, &["outside the model's folder"]);
    let e = load_err(&triangle(&dir, &secret.display().to_string(), ""));
    has(&e, &["is an absolute path"]);
    // A symbolic link inside the folder that points out of it is an escape too.
    std::os::unix::fs::symlink(&secret, dir.join("link.bin")).unwrap();
    let e = load_err(&triangle(&dir, "link.bin", ""));
    has(&e, &["outside the model's folder"]);
    // The same bytes inside the folder load.
    std::fs::write(dir.join("tri.bin"), tri_bin()).unwrap();
    assert_eq!(
        load_gltf(&triangle(&dir, "tri.bin", ""))
            .unwrap()
            .triangle_count(),
        3,
        "the triangle, the ground plane's two"
    );
}

#[test]
fn only_regular_files_are_read() {
    let dir = scratch("devices");
    // /dev/zero used to be read until the kernel killed the process.
    std::os::unix::fs::symlink("/dev/zero", dir.join("zero.bin")).unwrap();
    let e = load_err(&triangle(&dir, "zero.bin", ""));
    has(&e, &["outside the model's folder", "/dev/zero"]);
    let e = load_err(&triangle(&dir, "/dev/zero", ""));
    has(&e, &["absolute path"]);
    let fifo = dir.join("fifo.bin");
    assert!(
        std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success()
    );
    let e = load_err(&triangle(&dir, "fifo.bin", ""));
    has(&e, &["buffer 0", "not a regular file (a FIFO)"]);
    std::fs::create_dir(dir.join("folder.bin")).unwrap();
    let e = load_err(&triangle(&dir, "folder.bin", ""));
    has(&e, &["not a regular file (a folder)"]);
}

#[test]
fn the_size_cap_is_checked_before_reading() {
    let dir = scratch("size");
    // A sparse file: 2 GiB by its metadata, no disk used; refused without a read.
    let big = std::fs::File::create(dir.join("big.bin")).unwrap();
    big.set_len(2 * MAX_SCENE_BYTES).unwrap();
    let t = std::time::Instant::now();
    let e = load_err(&triangle(&dir, "big.bin", ""));
    has(
        &e,
        &[
            "buffer 0",
            &format!("{} bytes, more than", 2 * MAX_SCENE_BYTES),
        ],
    );
    assert!(t.elapsed().as_secs() < 5, "read instead of refused");
    // The model file itself too.
    let model = dir.join("big.glb");
    std::fs::File::create(&model)
        .unwrap()
        .set_len(2 * MAX_SCENE_BYTES)
        .unwrap();
    has(&load_err(&model), &["big.glb", "more than"]);
}

#[test]
fn image_uris_are_confined_too() {
    let dir = scratch("image");
    std::fs::write(dir.join("tri.bin"), tri_bin()).unwrap();
    let extra = r#",
  "images": [{"uri": "../secret.png"}],
  "textures": [{"source": 0}],
  "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]"#;
    let path = triangle(&dir, "tri.bin", extra);
    let json = std::fs::read_to_string(&path)
        .unwrap()
        .replace(r#""indices": 1}"#, r#""indices": 1, "material": 0}"#);
    std::fs::write(&path, json).unwrap();
    let e = load_err(&path);
    has(
        &e,
        &[
            "texture image 0",
            "../secret.png",
            "outside the model's folder",
        ],
    );
}

#[test]
fn oversized_textures_are_refused_before_decoding() {
    let dir = scratch("texture");
    std::fs::write(dir.join("tri.bin"), tri_bin()).unwrap();
    // A valid PNG one pixel high and wider than the limit: refused from its header.
    let wide = image::RgbaImage::new(MAX_IMAGE_SIDE + 1, 1);
    wide.save(dir.join("wide.png")).unwrap();
    let extra = r#",
  "images": [{"uri": "wide.png"}],
  "textures": [{"source": 0}],
  "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]"#;
    let path = triangle(&dir, "tri.bin", extra);
    let json = std::fs::read_to_string(&path)
        .unwrap()
        .replace(r#""indices": 1}"#, r#""indices": 1, "material": 0}"#);
    std::fs::write(&path, json).unwrap();
    let e = load_err(&path);
    has(&e, &["texture image 0", "cannot decode", "limit"]);
}

#[test]
fn data_uris_keep_working() {
    let dir = scratch("data-uri");
    let b64 = base64(&tri_bin());
    let path = triangle(
        &dir,
        &format!("data:application/octet-stream;base64,{b64}"),
        "",
    );
    let opts = GltfOptions {
        complete: false,
        ..GltfOptions::default()
    };
    let s = load_gltf_with(&path, &opts).unwrap();
    assert_eq!(s.triangle_count(), 1);
    // Given as bytes without a folder: embedded data still loads, files are refused.
    let text = std::fs::read(&path).unwrap();
    let s = lightfold_scene::load_gltf_slice(&text, "bytes", None, &opts).unwrap();
    assert_eq!(s.triangle_count(), 1);
    let text = std::fs::read(triangle(&dir, "tri.bin", "")).unwrap();
    let e = lightfold_scene::load_gltf_slice(&text, "bytes", None, &opts).unwrap_err();
    has(&e.to_string(), &["without a folder"]);
}

fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for c in bytes.chunks(3) {
        let n = (c[0] as u32) << 16
            | (*c.get(1).unwrap_or(&0) as u32) << 8
            | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            if k <= c.len() {
                out.push(A[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

#[test]
fn declared_triangles_beyond_the_limit_are_refused_before_reading() {
    let dir = scratch("triangles");
    std::fs::write(dir.join("tri.bin"), tri_bin()).unwrap();
    // A sparse POSITION accessor of 33 M vertices with no data: 11 M triangles from 200 bytes.
    let path = triangle(&dir, "tri.bin", "");
    let json = std::fs::read_to_string(&path)
        .unwrap()
        .replace(r#", "indices": 1}"#, "}")
        .replace(
            r#"{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
     "min": [0, 0, 0], "max": [1, 1, 0]}"#,
            r#"{"componentType": 5126, "count": 33000000, "type": "VEC3",
     "min": [0, 0, 0], "max": [1, 1, 0],
     "sparse": {"count": 1, "indices": {"bufferView": 1, "componentType": 5123},
                "values": {"bufferView": 0}}}"#,
        );
    std::fs::write(&path, json).unwrap();
    let t = std::time::Instant::now();
    let e = load_err(&path);
    has(
        &e,
        &["11000000 triangles", &format!("at most {MAX_TRIANGLES}")],
    );
    assert!(t.elapsed().as_secs() < 5, "decoded instead of refused");
}

/// A scene-file folder with the one-triangle model inside it and `secret.gltf` beside it.
fn scene_dir(test: &str) -> PathBuf {
    let dir = scratch(test);
    std::fs::write(dir.join("tri.bin"), tri_bin()).unwrap();
    triangle(&dir, "tri.bin", "");
    std::fs::copy(
        dir.join("tri.gltf"),
        dir.parent().unwrap().join("secret.gltf"),
    )
    .unwrap();
    std::fs::write(dir.parent().unwrap().join("tri.bin"), tri_bin()).unwrap();
    dir
}

fn scene_err(dir: &Path, body: &str) -> String {
    let path = dir.join("scene.toml");
    std::fs::write(&path, format!("version = 1\n{body}")).unwrap();
    match load(&path.display().to_string()) {
        Ok(_) => panic!("loaded:\n{body}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn scene_file_paths_stay_inside_the_file_folder() {
    let dir = scene_dir("scene-paths");
    let e = scene_err(&dir, "[gltf]\npath = \"../secret.gltf\"\n");
    has(
        &e,
        &["scene.toml", "gltf.path", "outside the scene file's folder"],
    );
    let e = scene_err(&dir, "[gltf]\npath = \"/etc/passwd\"\n");
    has(&e, &["gltf.path", "absolute path"]);
    let e = scene_err(&dir, "[gltf]\npath = \"/dev/zero\"\n");
    has(&e, &["absolute path"]);
    std::os::unix::fs::symlink("/dev/zero", dir.join("zero.glb")).unwrap();
    let e = scene_err(&dir, "[gltf]\npath = \"zero.glb\"\n");
    has(&e, &["outside the scene file's folder"]);
    let path = dir.join("scene.toml");
    std::fs::write(&path, "version = 1\n[gltf]\npath = \"tri.gltf\"\n").unwrap();
    let s = load(&path.display().to_string()).unwrap();
    assert!(s.triangle_count() >= 1);
    // The scene file itself: regular files only.
    let e = load("/dev/zero.toml").unwrap_err().to_string();
    has(&e, &["cannot read"]);
}

#[test]
fn oversized_samples_images_and_maps_in_scene_files_are_errors() {
    let dir = scene_dir("scene-limits");
    let rect = "[[light]]\ntype = \"rect\"\ncenter = [0.0, 2.0, 0.0]\nsize = [1.0, 1.0]\n\
                normal = [0.0, -1.0, 0.0]\nu_axis = [1.0, 0.0, 0.0]\nradiance = 1.0\n";
    // samples = 1e8 used to take 12.5 GB and still run after two minutes.
    let t = std::time::Instant::now();
    let e = scene_err(&dir, &format!("{rect}samples = 100000000\n"));
    has(
        &e,
        &[
            "scene.toml",
            "light \"rect light 0\" asks for 100000000 samples per area light",
            &format!("the limit is {MAX_SAMPLES_PER_AREA_LIGHT}"),
            "lightfold defaults",
        ],
    );
    assert!(t.elapsed().as_secs() < 5);
    let e = scene_err(
        &dir,
        &format!("[quality]\nsamples_per_area_light = 5000\n{rect}"),
    );
    has(&e, &["quality.samples_per_area_light asks for 5000"]);
    let many: String = (0..5).map(|_| format!("{rect}samples = 4000\n")).collect();
    let e = scene_err(&dir, &many);
    has(
        &e,
        &[
            "20000 light samples in all",
            &format!("at most {MAX_LIGHT_SAMPLES}"),
        ],
    );
    let e = scene_err(
        &dir,
        "[camera]\nposition = [0.0, 1.0, 5.0]\ntarget = [0.0, 0.0, 0.0]\nfov_y_deg = 45.0\n\
         width = 16384\nheight = 16384\n",
    );
    has(
        &e,
        &["image 16384x16384 is too large", "at most 8192 per side"],
    );
    let e = scene_err(&dir, "[quality]\nshadow_map_size = 16384\n");
    has(&e, &["shadow-map size 16384 is outside 1..=4096"]);
    let spheres: String = (0..11)
        .map(|i| {
            format!(
                "[[object]]\ntype = \"sphere\"\nname = \"s{i}\"\ncenter = [0.0, 0.0, 0.0]\n\
                 radius = 1.0\nsegments = 1024\nrings = 512\n"
            )
        })
        .collect();
    let t = std::time::Instant::now();
    let e = scene_err(&dir, &spheres);
    has(&e, &["triangles; a scene may have at most 10000000"]);
    assert!(t.elapsed().as_secs() < 30, "{:?}", t.elapsed());
}

#[test]
fn scene_bytes_beyond_the_limits_are_refused() {
    let mut s: Scene = builtin("balls").unwrap();
    s.lights[0].samples = 100_000_000;
    let e = Scene::from_bytes(&s.to_bytes().unwrap()).unwrap_err();
    has(
        &e.to_string(),
        &["cannot decode scene bytes", "asks for 100000000 samples"],
    );
    let mut s: Scene = builtin("balls").unwrap();
    (s.camera.width, s.camera.height) = (16384, 16384);
    let e = Scene::from_bytes(&s.to_bytes().unwrap()).unwrap_err();
    has(&e.to_string(), &["image 16384x16384 is too large"]);
    let mut s: Scene = builtin("balls").unwrap();
    s.quality.shadow_map_size = 1 << 20;
    let e = Scene::from_bytes(&s.to_bytes().unwrap()).unwrap_err();
    has(&e.to_string(), &["shadow-map size 1048576"]);
    let s: Scene = builtin("balls").unwrap();
    assert_eq!(Scene::from_bytes(&s.to_bytes().unwrap()).unwrap(), s);
}

#[test]
fn a_primitive_naming_a_missing_accessor_is_an_error_not_a_panic() {
    // Found by fuzzing (`fuzz/fuzz_targets/gltf.rs`): the gltf crate's validation indexed the
    // POSITION accessor unchecked and panicked (caught, but a panic all the same).
    let dir = scratch("missing-accessor");
    std::fs::write(dir.join("tri.bin"), tri_bin()).unwrap();
    let path = triangle(&dir, "tri.bin", "");
    let json = std::fs::read_to_string(&path)
        .unwrap()
        .replace(r#""POSITION": 0"#, r#""POSITION": 7"#);
    std::fs::write(&path, json).unwrap();
    let e = load_err(&path);
    has(
        &e,
        &["mesh 0 primitive 0 names accessor 7 but the file has 2"],
    );
    assert!(!e.contains("panicked"), "{e}");
}

#[test]
fn an_image_without_a_source_is_an_error_not_a_panic() {
    // Found by fuzzing (`gltf` and `glb` targets): the gltf crate unwraps an image's `uri`, and a
    // buffer-view image's `mimeType`, without its validation having checked they are there.
    let dir = scratch("image-source");
    std::fs::write(dir.join("tri.bin"), tri_bin()).unwrap();
    for (image, words) in [
        (
            r#"{"name": "nothing"}"#,
            "image 0 has neither a uri nor a bufferView",
        ),
        (
            r#"{"bufferView": 0}"#,
            "image 0 is stored in a buffer view but has no mimeType",
        ),
    ] {
        let extra = format!(
            r#",
  "images": [{image}],
  "textures": [{{"source": 0}}],
  "materials": [{{"pbrMetallicRoughness": {{"baseColorTexture": {{"index": 0}}}}}}]"#
        );
        let path = triangle(&dir, "tri.bin", &extra);
        let json = std::fs::read_to_string(&path)
            .unwrap()
            .replace(r#""indices": 1}"#, r#""indices": 1, "material": 0}"#);
        std::fs::write(&path, json).unwrap();
        let e = load_err(&path);
        has(&e, &[words]);
        assert!(!e.contains("panicked"), "{e}");
    }
}
