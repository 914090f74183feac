//! PLY models: built-in scenes written as PLY (ASCII and both binary byte orders, per-vertex
//! colour and normals) load back to the same triangles with their diffuse colours; polygons
//! fan, face colours and flat normals are read; smooth colours are grouped to a bounded number of
//! materials; a model alone is completed like a glTF and a scene file names one with `[ply]`;
//! hostile files (indices out of range, counts beyond the limits or the file, malformed headers)
//! are clear errors, beside a control that loads.

use lightfold_scene::ply_load::{MAX_COLOUR_MATERIALS, ignored_features};
use lightfold_scene::shading::srgb_to_linear;
use lightfold_scene::{ModelOptions, Scene, builtin, load, load_ply_slice, load_ply_with};
use std::path::{Path, PathBuf};

#[derive(Debug, Clone, Copy, PartialEq)]
enum Encoding {
    Ascii,
    Little,
    Big,
}

fn scratch(test: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join("ply")
        .join(test);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A material's diffuse colour as the 8-bit sRGB a PLY stores.
fn srgb8(c: [f32; 3]) -> [u8; 3] {
    c.map(lightfold_protocol::srgb::srgb8)
}

/// Every mesh of `scene` in one PLY: positions and normals as they are, each vertex coloured with
/// its mesh's diffuse colour, one triangle per face.
fn write_ply(scene: &Scene, enc: Encoding) -> Vec<u8> {
    let vertices: usize = scene.meshes.iter().map(|m| m.positions.len()).sum();
    let faces = scene.triangle_count();
    let format = match enc {
        Encoding::Ascii => "ascii",
        Encoding::Little => "binary_little_endian",
        Encoding::Big => "binary_big_endian",
    };
    let mut out = format!(
        "ply\nformat {format} 1.0\ncomment {}\nelement vertex {vertices}\n\
         property float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\n\
         element face {faces}\nproperty list uchar int vertex_indices\nend_header\n",
        scene.name
    )
    .into_bytes();
    let f = |out: &mut Vec<u8>, x: f32| match enc {
        Encoding::Ascii => out.extend_from_slice(format!("{x} ").as_bytes()),
        Encoding::Little => out.extend_from_slice(&x.to_le_bytes()),
        Encoding::Big => out.extend_from_slice(&x.to_be_bytes()),
    };
    for m in &scene.meshes {
        let colour = srgb8(scene.materials[m.material].diffuse);
        for (p, n) in m.positions.iter().zip(&m.normals) {
            for &x in p.iter().chain(n) {
                f(&mut out, x);
            }
            match enc {
                Encoding::Ascii => out.extend_from_slice(
                    format!("{} {} {}\n", colour[0], colour[1], colour[2]).as_bytes(),
                ),
                _ => out.extend_from_slice(&colour),
            }
        }
    }
    let mut base = 0u32;
    for m in &scene.meshes {
        for t in m.indices.chunks_exact(3) {
            let t = t.iter().map(|&i| (i + base) as i32);
            match enc {
                Encoding::Ascii => {
                    let t: Vec<String> = t.map(|i| i.to_string()).collect();
                    out.extend_from_slice(format!("3 {}\n", t.join(" ")).as_bytes());
                }
                Encoding::Little => {
                    out.push(3);
                    t.for_each(|i| out.extend_from_slice(&i.to_le_bytes()));
                }
                Encoding::Big => {
                    out.push(3);
                    t.for_each(|i| out.extend_from_slice(&i.to_be_bytes()));
                }
            }
        }
        base += m.positions.len() as u32;
    }
    out
}

/// A mesh's triangles as corners (position, normal), in order.
fn corners(mesh: &lightfold_scene::Mesh) -> Vec<([f32; 3], [f32; 3])> {
    mesh.indices
        .iter()
        .map(|&i| (mesh.positions[i as usize], mesh.normals[i as usize]))
        .collect()
}

fn unplaced() -> ModelOptions {
    ModelOptions {
        complete: false,
        ..ModelOptions::default()
    }
}

#[test]
fn builtins_written_as_ply_load_to_the_same_triangles_and_colours() {
    for name in ["balls", "box", "cornell"] {
        let built = builtin(name).unwrap();
        for enc in [Encoding::Ascii, Encoding::Little, Encoding::Big] {
            let bytes = write_ply(&built, enc);
            let s = load_ply_slice(&bytes, name, &unplaced()).unwrap();
            assert!(s.validate().is_clean(), "{name} {enc:?}: {}", s.validate());
            assert_eq!(s.triangle_count(), built.triangle_count(), "{name} {enc:?}");
            // One mesh per colour: the built-in's triangles of that colour, in order, corner by
            // corner, and a diffuse material of that colour.
            for mesh in &s.meshes {
                let material = &s.materials[mesh.material];
                let key = srgb8(material.diffuse);
                let expected: Vec<_> = built
                    .meshes
                    .iter()
                    .filter(|m| srgb8(built.materials[m.material].diffuse) == key)
                    .flat_map(corners)
                    .collect();
                assert_eq!(corners(mesh), expected, "{name} {enc:?} {}", mesh.name);
                let stored = key.map(|c| srgb_to_linear(f32::from(c) / 255.0));
                assert_eq!(material.diffuse, stored, "{name} {enc:?}");
                assert!(material.specular == [0.0; 3] && material.pbr.is_none());
            }
            for m in &built.meshes {
                let want = built.materials[m.material].diffuse;
                let got = s
                    .materials
                    .iter()
                    .find(|g| srgb8(g.diffuse) == srgb8(want))
                    .unwrap()
                    .diffuse;
                for k in 0..3 {
                    assert!((got[k] - want[k]).abs() < 0.01, "{name}: {got:?} {want:?}");
                }
            }
            assert!(s.lights.is_empty());
        }
    }
}

/// A small PLY: a quad and a pentagon with per-face colours, no normals; a two-corner face; an
/// extra element and texture coordinates.
const FACES: &str = "ply\nformat ascii 1.0\ncomment TextureFile wood.png\nelement vertex 6\n\
property float x\nproperty float y\nproperty float z\nproperty float s\nproperty float t\n\
element face 3\nproperty list uchar uint vertex_indices\n\
property uchar red\nproperty uchar green\nproperty uchar blue\n\
element edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n\
0 0 0 0 0\n1 0 0 1 0\n1 1 0 1 1\n0 1 0 0 1\n0.5 1.5 0 0 0\n2 0 0 0 0\n\
4 0 1 2 3 255 0 0\n5 0 1 2 4 3 0 0 255\n2 0 5 0 255 0\n0 1\n";

#[test]
fn polygons_fan_with_face_colours_and_flat_normals() {
    let s = load_ply_slice(FACES.as_bytes(), "faces.ply", &unplaced()).unwrap();
    assert_eq!(s.triangle_count(), 2 + 3);
    assert_eq!(s.meshes.len(), 2);
    let red = s
        .meshes
        .iter()
        .find(|m| m.name.ends_with("#ff0000"))
        .unwrap();
    assert_eq!(red.indices.len(), 6);
    assert_eq!(red.normals.len(), 6, "flat normals, unwelded");
    assert!(red.normals.iter().all(|n| *n == [0.0, 0.0, 1.0]));
    assert_eq!(s.materials[red.material].diffuse, [1.0, 0.0, 0.0]);
    let blue = s
        .meshes
        .iter()
        .find(|m| m.name.ends_with("#0000ff"))
        .unwrap();
    assert_eq!(blue.indices.len(), 9);
    let dir = scratch("faces");
    let path = dir.join("faces.ply");
    std::fs::write(&path, FACES).unwrap();
    let ignored = ignored_features(&path).unwrap();
    for f in [
        "element \"edge\"",
        "texture coordinates",
        "texture files (comment TextureFile)",
        "faces of fewer than three corners",
    ] {
        assert!(ignored.iter().any(|i| i == f), "{ignored:?} lacks {f:?}");
    }
    // Without colours: one mesh, one grey material.
    let plain = "ply\nformat ascii 1.0\nelement vertex 3\nproperty double x\nproperty double y\n\
                 property double z\nelement face 1\nproperty list uchar int vertex_index\n\
                 end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
    let s = load_ply_slice(plain.as_bytes(), "plain.ply", &unplaced()).unwrap();
    assert_eq!(s.meshes.len(), 1);
    assert_eq!(s.materials[0].diffuse, [0.8; 3]);
}

#[test]
fn float_colours_outside_0_1_are_clamped_before_decoding() {
    // The sRGB decode clamps as the encode does: 2 and +∞ read as 1, −1, −∞ and NaN as 0, not as
    // a brighter-than-white, negative or NaN diffuse colour.
    let text = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                property float z\nproperty float red\nproperty float green\nproperty float blue\n\
                element face 1\nproperty list uchar int vertex_indices\nend_header\n\
                0 0 0 2 -1 0.5\n1 0 0 2 -1 0.5\n0 1 0 2 -1 0.5\n3 0 1 2\n";
    let s = load_ply_slice(text.as_bytes(), "bright.ply", &unplaced()).unwrap();
    assert_eq!(s.materials.len(), 1);
    assert_eq!(s.materials[0].diffuse, [1.0, 0.0, srgb_to_linear(0.5)]);
    // NaN and infinities, which only a binary file can hold.
    let mut bin = text[..text.find("end_header\n").unwrap()]
        .replace("ascii", "binary_little_endian")
        .into_bytes();
    bin.extend_from_slice(b"end_header\n");
    for p in [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]] {
        for v in [p[0], p[1], 0.0, f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            bin.extend_from_slice(&v.to_le_bytes());
        }
    }
    bin.push(3);
    for i in 0..3i32 {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    let s = load_ply_slice(&bin, "nan.ply", &unplaced()).unwrap();
    assert_eq!(s.materials[0].diffuse, [0.0, 1.0, 0.0]);
}

#[test]
fn smooth_colours_are_grouped_into_a_bounded_number_of_materials() {
    // 2 000 triangles, each of its own colour: more than the materials allowed.
    let n = 2000;
    let mut text = format!(
        "ply\nformat ascii 1.0\nelement vertex {}\nproperty float x\nproperty float y\n\
         property float z\nproperty float red\nproperty float green\nproperty float blue\n\
         element face {n}\nproperty list uchar int vertex_indices\nend_header\n",
        3 * n
    );
    for k in 0..n {
        let c = k as f32 / n as f32;
        let x = k as f32;
        for (dx, dy) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)] {
            text.push_str(&format!(
                "{} {dy} 0 {c} {} {}\n",
                x + dx,
                1.0 - c,
                (c * 7.0).fract()
            ));
        }
    }
    for k in 0..n {
        text.push_str(&format!("3 {} {} {}\n", 3 * k, 3 * k + 1, 3 * k + 2));
    }
    let s = load_ply_slice(text.as_bytes(), "smooth.ply", &unplaced()).unwrap();
    assert!(
        s.materials.len() <= MAX_COLOUR_MATERIALS,
        "{}",
        s.materials.len()
    );
    assert!(s.materials.len() > 64, "{}", s.materials.len());
    assert_eq!(s.triangle_count(), n);
}

#[test]
fn a_ply_alone_is_completed_and_a_scene_file_names_one() {
    let dir = scratch("alone");
    let built = builtin("cornell").unwrap();
    std::fs::write(dir.join("cornell.ply"), write_ply(&built, Encoding::Little)).unwrap();
    let path = dir.join("cornell.ply");
    let s = load(&path.display().to_string()).unwrap();
    assert_eq!(s.name, "cornell");
    assert_eq!(s.lights.len(), 1);
    assert_eq!(s.lights[0].name, "framing light");
    assert_eq!(s.meshes.last().unwrap().name, "ground");
    let mut bare = load_ply_with(&path, &unplaced()).unwrap();
    lightfold_scene::framing::complete(&mut bare, false);
    bare.sanitize();
    assert_eq!(s, bare);
    let toml = "version = 1\n[ply]\npath = \"cornell.ply\"\nscale = 0.5\n\
                [[light]]\ntype = \"point\"\nposition = [0.0, 0.9, 0.0]\nintensity = 5.0\n";
    let f = lightfold_scene::parse_scene_file(toml, "c.toml", Some(&dir)).unwrap();
    assert_eq!(f.lights.len(), 1);
    assert_eq!(f.triangle_count(), built.triangle_count());
    let (lo, hi) = f.bounds().unwrap();
    assert!((hi[1] - lo[1] - 1.0).abs() < 1e-5, "{lo:?} {hi:?}");
}

fn ply_err(bytes: &[u8]) -> String {
    match load_ply_slice(bytes, "h.ply", &ModelOptions::default()) {
        Ok(_) => panic!(
            "{:?} loaded",
            String::from_utf8_lossy(&bytes[..bytes.len().min(200)])
        ),
        Err(e) => e.to_string(),
    }
}

fn has(text: &str, words: &[&str]) {
    for w in words {
        assert!(text.contains(w), "{text:?} lacks {w:?}");
    }
}

const HEAD: &str = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n\
property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\n\
end_header\n0 0 0\n1 0 0\n0 1 0\n";

/// A binary little-endian triangle whose header declares `vertices` and `faces` and whose face
/// list declares `corners`, with only three vertices and one face's bytes after it.
fn binary(vertices: u64, faces: u64, corners: u32) -> Vec<u8> {
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {vertices}\nproperty float x\n\
         property float y\nproperty float z\nelement face {faces}\n\
         property list uint int vertex_indices\nend_header\n"
    )
    .into_bytes();
    for p in [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
        for c in p {
            out.extend_from_slice(&c.to_le_bytes());
        }
    }
    out.extend_from_slice(&corners.to_le_bytes());
    for i in [0i32, 1, 2] {
        out.extend_from_slice(&i.to_le_bytes());
    }
    out
}

#[test]
fn hostile_plys_are_clear_errors() {
    // The controls: the same shapes, well formed, load.
    let s = load_ply_slice(format!("{HEAD}3 0 1 2\n").as_bytes(), "ok.ply", &unplaced()).unwrap();
    assert_eq!(s.triangle_count(), 1);
    let s = load_ply_slice(&binary(3, 1, 3), "ok.ply", &unplaced()).unwrap();
    assert_eq!(s.triangle_count(), 1);

    let e = ply_err(format!("{HEAD}3 0 1 9\n").as_bytes());
    has(
        &e,
        &[
            "h.ply: invalid PLY",
            "face 0 names vertex 9",
            "has 3 vertices",
        ],
    );
    let e = ply_err(format!("{HEAD}3 0 1 -1\n").as_bytes());
    has(&e, &["face 0 names a negative vertex index"]);
    // Counts beyond the limits, refused from the header.
    let e = ply_err(&binary(4_000_000_000, 1, 3));
    has(
        &e,
        &[
            "4000000000 vertices",
            "at most 30000000",
            "lightfold defaults",
        ],
    );
    let e = ply_err(&binary(3, 20_000_000, 3));
    has(&e, &["20000000 faces", "at most 10000000"]);
    // Counts within the limits but beyond the bytes that follow the header.
    let e = ply_err(&binary(1_000_000, 1, 3));
    has(
        &e,
        &[
            "declares 1000000 \"vertex\" elements",
            "12000000 bytes",
            "52 bytes follow",
        ],
    );
    // A face list that declares four billion corners draws on the index budget, not memory.
    let e = ply_err(&binary(3, 1, u32::MAX));
    has(&e, &["more than 30000000 vertex indices"]);
    // Malformed headers.
    let e = ply_err(b"plx\n");
    has(&e, &["not a PLY file"]);
    let e = ply_err(b"ply\nformat ascii 1.0\nelement vertex 3\n");
    has(&e, &["no `end_header`"]);
    let e = ply_err(
        HEAD.replace(
            "element face 1",
            "element vertex 1\nproperty float x\nelement face 1",
        )
        .as_bytes(),
    );
    has(&e, &["element \"vertex\" is declared twice"]);
    let e = ply_err(
        HEAD.replace("property float y", "property float x")
            .as_bytes(),
    );
    has(&e, &["declares a property twice"]);
    let e = ply_err(HEAD.replace("property float z\n", "").as_bytes());
    has(&e, &["no scalar `z` property"]);
    let cloud = "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n\
                 property float z\nend_header\n0 0 0\n";
    has(
        &ply_err(cloud.as_bytes()),
        &["no `face` element (a point cloud)"],
    );
    let e = ply_err(
        HEAD.replace("uchar int vertex_indices", "uchar float vertex_indices")
            .as_bytes(),
    );
    has(&e, &["not a list of integers"]);
    // Truncated bodies and bad numbers.
    has(&ply_err(HEAD.as_bytes()), &["\"face\""]);
    let e = ply_err(format!("{HEAD}3 0 1 x\n").as_bytes());
    has(&e, &["element \"face\""]);
    // An ASCII body line beyond the bound.
    let long = format!("{HEAD}3 0 1 2{}\n", " ".repeat(1 << 20));
    has(
        &ply_err(long.as_bytes()),
        &["line 4 of the body holds 1048583 bytes", "at most 1048576"],
    );
    // Through a path, the file is read as any model file is.
    let dir = scratch("hostile");
    std::fs::create_dir_all(dir.join("folder.ply")).unwrap();
    let e = load(&dir.join("folder.ply").display().to_string())
        .unwrap_err()
        .to_string();
    has(&e, &["not a regular file (a folder)"]);
    assert!(Path::new(&dir).exists());
}
