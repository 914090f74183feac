//! OBJ/MTL models: built-in scenes written as OBJ load back to the same triangles and materials;
//! MTL statements map as `docs/scenes.md` says; a model alone is completed like a glTF, and a
//! scene file names one with `[obj]`; hostile files (paths out of the folder, indices out of
//! range, counts beyond the limits, malformed statements) are clear errors, beside a control that
//! loads.

use lightfold_scene::obj_load::ignored_features;
use lightfold_scene::{
    AlphaMode, LightShape, ModelOptions, Scene, builtin, load, load_obj, load_obj_slice,
    load_obj_with, parse_scene_file,
};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// A scratch folder `root/model` for one test, with `root/secret.mtl` and `root/secret.png`
/// beside it: what an escaping path would read.
pub(crate) fn scratch(test: &str) -> PathBuf {
    let root = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join("obj")
        .join(test);
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir_all(root.join("model")).unwrap();
    std::fs::write(root.join("secret.mtl"), "newmtl secret\nKd 1 0 0\n").unwrap();
    png(&root.join("secret.png"), [255, 0, 0, 255]);
    root.join("model")
}

/// A 2×2 PNG of one colour.
pub(crate) fn png(path: &Path, rgba: [u8; 4]) {
    image::RgbaImage::from_pixel(2, 2, image::Rgba(rgba))
        .save(path)
        .unwrap();
}

/// Writes `scene`'s meshes as `dir/NAME.obj` (one `o` per mesh, positions, normals and texture
/// coordinates as they are) and its materials as `dir/NAME.mtl`, every number as Rust prints it
/// (which reads back to the same `f32`).
pub(crate) fn write_obj(scene: &Scene, dir: &Path, name: &str) -> PathBuf {
    let mut mtl = String::new();
    for m in &scene.materials {
        assert!(m.pbr.is_none() && m.diffuse_texture.is_none(), "{}", m.name);
        let [r, g, b] = m.diffuse;
        let [sr, sg, sb] = m.specular;
        let [ar, ag, ab] = m.ambient;
        writeln!(mtl, "newmtl {}", m.name).unwrap();
        writeln!(mtl, "Kd {r} {g} {b}\nKs {sr} {sg} {sb}\nKa {ar} {ag} {ab}").unwrap();
        writeln!(mtl, "Ns {}", m.shininess).unwrap();
        if m.emissive.iter().any(|&c| c > 0.0) {
            let [er, eg, eb] = m.emissive;
            writeln!(mtl, "Ke {er} {eg} {eb}").unwrap();
        }
        if let Some(t) = m.transmission {
            let [tr, tg, tb] = t.color;
            writeln!(mtl, "Tf {tr} {tg} {tb}").unwrap();
            if t.coverage {
                writeln!(mtl, "d {}", m.alpha).unwrap();
            } else {
                writeln!(mtl, "illum 4").unwrap();
            }
        }
    }
    std::fs::write(dir.join(format!("{name}.mtl")), mtl).unwrap();
    let mut obj = format!("# {name}\nmtllib {name}.mtl\n");
    let (mut v, mut vt, mut vn) = (1usize, 1usize, 1usize);
    for mesh in &scene.meshes {
        writeln!(obj, "o {}", mesh.name).unwrap();
        writeln!(obj, "usemtl {}", scene.materials[mesh.material].name).unwrap();
        for [x, y, z] in &mesh.positions {
            writeln!(obj, "v {x} {y} {z}").unwrap();
        }
        for [u, w] in &mesh.uvs {
            writeln!(obj, "vt {u} {}", 1.0 - w).unwrap();
        }
        for [x, y, z] in &mesh.normals {
            writeln!(obj, "vn {x} {y} {z}").unwrap();
        }
        let corner = |i: u32| {
            let i = i as usize;
            match (mesh.uvs.is_empty(), mesh.normals.is_empty()) {
                (true, true) => format!("{}", v + i),
                (true, false) => format!("{}//{}", v + i, vn + i),
                (false, true) => format!("{}/{}", v + i, vt + i),
                (false, false) => format!("{}/{}/{}", v + i, vt + i, vn + i),
            }
        };
        for t in mesh.indices.chunks_exact(3) {
            writeln!(obj, "f {} {} {}", corner(t[0]), corner(t[1]), corner(t[2])).unwrap();
        }
        v += mesh.positions.len();
        vt += mesh.uvs.len();
        vn += mesh.normals.len();
    }
    let path = dir.join(format!("{name}.obj"));
    std::fs::write(&path, obj).unwrap();
    path
}

/// Each mesh's triangles as corners (position, normal, uv), in order.
pub(crate) fn corners(mesh: &lightfold_scene::Mesh) -> Vec<([f32; 3], [f32; 3], [f32; 2])> {
    mesh.indices
        .iter()
        .map(|&i| {
            let i = i as usize;
            (
                mesh.positions[i],
                mesh.normals.get(i).copied().unwrap_or_default(),
                mesh.uvs.get(i).copied().unwrap_or_default(),
            )
        })
        .collect()
}

fn unplaced() -> ModelOptions {
    ModelOptions {
        complete: false,
        ..ModelOptions::default()
    }
}

/// The same meshes (names, triangles corner by corner) and, mesh by mesh, the same materials.
fn assert_same_model(built: &Scene, loaded: &Scene) {
    assert_eq!(loaded.meshes.len(), built.meshes.len(), "{}", built.name);
    for (a, b) in built.meshes.iter().zip(&loaded.meshes) {
        assert_eq!(b.name, a.name);
        let (ca, cb) = (corners(a), corners(b));
        assert_eq!(ca.len(), cb.len(), "mesh {}", a.name);
        for (x, y) in ca.iter().zip(&cb) {
            // Positions and normals exactly; texture coordinates through OBJ's flipped v.
            assert_eq!((x.0, x.1), (y.0, y.1), "mesh {}", a.name);
            assert!((x.2[0] - y.2[0]).abs() < 1e-6 && (x.2[1] - y.2[1]).abs() < 1e-6);
        }
        let (ma, mb) = (&built.materials[a.material], &loaded.materials[b.material]);
        assert_eq!(mb.name, ma.name);
        assert_eq!(mb.diffuse, ma.diffuse, "{}", ma.name);
        assert_eq!(mb.specular, ma.specular, "{}", ma.name);
        assert_eq!(mb.shininess, ma.shininess, "{}", ma.name);
        assert_eq!(mb.ambient, ma.ambient, "{}", ma.name);
        assert_eq!(mb.emissive, ma.emissive, "{}", ma.name);
        assert_eq!(mb.double_sided, ma.double_sided, "{}", ma.name);
        assert_eq!(mb.transmission, ma.transmission, "{}", ma.name);
        assert_eq!(mb.alpha_mode, ma.alpha_mode, "{}", ma.name);
    }
    assert_eq!(loaded.triangle_count(), built.triangle_count());
    assert!(loaded.validate().is_clean(), "{}", loaded.validate());
}

#[test]
fn builtins_written_as_obj_load_to_the_same_triangles_and_materials() {
    let dir = scratch("builtins");
    for name in ["balls", "box", "cornell"] {
        let built = builtin(name).unwrap();
        let path = write_obj(&built, &dir, name);
        let loaded = load_obj_with(&path, &unplaced()).unwrap();
        assert_eq!(loaded.name, name);
        assert_same_model(&built, &loaded);
        assert!(ignored_features(&path).unwrap().is_empty(), "{name}");
        if name == "cornell" {
            // The emissive panel (Ke) lights the room: an emissive-mesh light of its radiance
            // and colour, where the built-in has a rectangle at the same place.
            let panel = loaded
                .meshes
                .iter()
                .position(|m| m.name == "light panel")
                .unwrap();
            assert_eq!(loaded.lights.len(), 1);
            let l = &loaded.lights[0];
            assert_eq!(l.shape, LightShape::EmissiveMesh { mesh: panel });
            let rect = &built.lights[0];
            assert!((l.power - rect.power).abs() < 1e-4, "{}", l.power);
            for k in 0..3 {
                assert!((l.color[k] - rect.color[k]).abs() < 1e-5, "{:?}", l.color);
            }
            assert_eq!(l.samples, 16);
        } else {
            assert!(loaded.lights.is_empty(), "{name}");
        }
    }
}

#[test]
fn an_obj_alone_is_completed_like_a_gltf() {
    let dir = scratch("alone");
    let built = builtin("balls").unwrap();
    let path = write_obj(&built, &dir, "balls");
    let s = load(&path.display().to_string()).unwrap();
    // A framed camera, the framing light and a ground plane, as for a glTF without them.
    assert_eq!(s.meshes.len(), built.meshes.len() + 1);
    assert_eq!(s.meshes.last().unwrap().name, "ground");
    assert_eq!(s.lights.len(), 1);
    assert_eq!(s.lights[0].name, "framing light");
    let mut bare = load_obj_with(&path, &unplaced()).unwrap();
    lightfold_scene::framing::complete(&mut bare, false);
    bare.sanitize();
    assert_eq!(s, bare);
    assert_eq!(s.camera.fov_y_deg, 40.0);
    // With an emissive material the model has its light: no framing light, no ground.
    let path = write_obj(&builtin("cornell").unwrap(), &dir, "cornell");
    let s = load_obj(&path).unwrap();
    assert_eq!(s.lights.len(), 1);
    assert!(matches!(s.lights[0].shape, LightShape::EmissiveMesh { .. }));
    assert!(s.meshes.iter().all(|m| m.name != "ground"));
}

#[test]
fn a_scene_file_names_an_obj() {
    let dir = scratch("scene_file");
    let built = builtin("box").unwrap();
    write_obj(&built, &dir, "box");
    let toml = r#"
version = 1
[obj]
path = "box.obj"
scale = 2.0
translation = [0.0, 1.0, 0.0]
[camera]
position = [0.0, 2.0, 8.0]
target = [0.0, 1.0, 0.0]
fov_y_deg = 40.0
[[light]]
type = "point"
position = [0.0, 5.0, 0.0]
intensity = 10.0
"#;
    let s = parse_scene_file(toml, "box.toml", Some(&dir)).unwrap();
    assert_eq!(s.meshes.len(), built.meshes.len());
    assert_eq!(s.lights.len(), 1);
    for (a, b) in built.meshes.iter().zip(&s.meshes) {
        for (p, q) in corners(a).iter().zip(&corners(b)) {
            let p = p.0;
            assert_eq!(q.0, [2.0 * p[0], 2.0 * p[1] + 1.0, 2.0 * p[2]]);
        }
    }
    // One model per file, and the path stays in the scene file's folder.
    let two = "version = 1\n[gltf]\npath = \"a.glb\"\n[obj]\npath = \"box.obj\"\n";
    let e = parse_scene_file(two, "two.toml", Some(&dir))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("takes one model") && e.contains("[gltf] and [obj]"),
        "{e}"
    );
    let out = "version = 1\n[obj]\npath = \"../secret.mtl\"\n";
    let e = parse_scene_file(out, "out.toml", Some(&dir))
        .unwrap_err()
        .to_string();
    assert!(e.contains("obj.path") && e.contains("leads outside"), "{e}");
}

#[test]
fn mtl_statements_map_to_materials() {
    let dir = scratch("mtl");
    png(&dir.join("wood.png"), [200, 100, 50, 255]);
    std::fs::create_dir_all(dir.join("mats/tex")).unwrap();
    png(&dir.join("mats/tex/grain.png"), [10, 20, 30, 255]);
    std::fs::write(
        dir.join("mats/lib.mtl"),
        "newmtl textured\nKd 0.5\nmap_Kd -s 2 2 1 -clamp on tex/grain.png\n\
         newmtl pbr\nKd 0.9 0.1 0.1\nPr 0.25\nPm 1\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("a.mtl"),
        "newmtl glossy\nKd 0.2 0.3 0.4\nKs 0.5 0.5 0.5\nNs 120\nKa 0.1 0.1 0.1\nmap_Kd wood.png\n\
         map_Ks wood.png\nNi 1.5\n\
         newmtl glass\nKd 0.9 0.9 0.9\nTf 0.9 0.1 0.1\nillum 4\n\
         newmtl veil\nKd 0.2 0.8 0.2\nd 0.25\n\
         newmtl filter\nKd 1 1 1\nTf 0.1 0.2 0.9\n\
         newmtl opaque\nKd 0.3 0.3 0.3\nTf 1 1 1\nillum 2\n\
         newmtl lamp\nKd 0 0 0\nKe 4 2 1\n",
    )
    .unwrap();
    let mut obj = String::from("mtllib a.mtl\nmtllib mats/lib.mtl\nmtllib a.mtl\n");
    obj.push_str("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n");
    for m in [
        "glossy", "glass", "veil", "filter", "opaque", "lamp", "textured", "pbr", "missing",
    ] {
        obj.push_str(&format!("g {m}\nusemtl {m}\nf 1/1 2/2 3/3\n"));
    }
    obj.push_str("g plain\nf 1 2 3\n");
    let path = dir.join("m.obj");
    std::fs::write(&path, obj).unwrap();
    let s = load_obj_with(&path, &unplaced()).unwrap();
    let mat = |mesh: &str| {
        let m = s.meshes.iter().find(|m| m.name == mesh).unwrap();
        &s.materials[m.material]
    };
    let glossy = mat("glossy");
    assert_eq!(
        (
            glossy.diffuse,
            glossy.specular,
            glossy.shininess,
            glossy.ambient
        ),
        ([0.2, 0.3, 0.4], [0.5; 3], 120.0, [0.1; 3])
    );
    let tex = &s.textures[glossy.diffuse_texture.unwrap()];
    assert!(tex.srgb && tex.width == 2 && tex.rgba8[..4] == [200, 100, 50, 255]);
    // OBJ's v runs up the image, lightfold's down it.
    let m = s.meshes.iter().find(|m| m.name == "glossy").unwrap();
    assert_eq!(corners(m)[0].2, [0.0, 1.0]);
    let glass = mat("glass");
    assert!(glass.is_filter() && glass.transmission.unwrap().color == [0.9, 0.1, 0.1]);
    let veil = mat("veil");
    let t = veil.transmission.unwrap();
    assert!(t.coverage && t.color == [0.2, 0.8, 0.2] && veil.alpha == 0.25);
    assert_eq!(veil.alpha_mode, AlphaMode::Mask { cutoff: 0.5 });
    assert_eq!(
        mat("filter").transmission.map(|t| (t.color, t.coverage)),
        Some(([0.1, 0.2, 0.9], false))
    );
    assert!(mat("opaque").transmission.is_none());
    let lamp = mat("lamp");
    assert_eq!(lamp.emissive, [4.0, 2.0, 1.0]);
    assert!(!lamp.double_sided);
    let textured = mat("textured");
    assert_eq!(textured.diffuse, [0.5; 3]);
    let grain = &s.textures[textured.diffuse_texture.unwrap()];
    assert_eq!(grain.rgba8[..4], [10, 20, 30, 255]);
    let pbr = mat("pbr").pbr.unwrap();
    assert_eq!(
        (pbr.base_color, pbr.metallic, pbr.roughness),
        ([0.9, 0.1, 0.1], 1.0, 0.25)
    );
    // An undefined material, and no material: the grey default.
    assert_eq!(mat("missing").diffuse, [0.8; 3]);
    assert_eq!(mat("plain").name, "default");
    // The lamp lights the scene; `a.mtl` named twice adds its materials once.
    assert_eq!(s.lights.len(), 1);
    assert_eq!(s.lights[0].power, 4.0);
    assert_eq!(s.lights[0].color, [1.0, 0.5, 0.25]);
    let ignored = ignored_features(&path).unwrap();
    for f in [
        "textures other than map_Kd (map_Ks)",
        "index of refraction (Ni)",
        "texture options (-o, -s, -clamp, …)",
    ] {
        assert!(ignored.iter().any(|i| i == f), "{ignored:?} lacks {f:?}");
    }
}

#[test]
fn polygons_fan_and_what_is_not_rendered_is_listed() {
    let text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0.5 1.5 0\n\
                s 1\np 1\nl 1 2 3\ncurv 0 1 1 2\nf 1 2 3 5 4\nf 1 2\n";
    let dir = scratch("fan");
    let path = dir.join("fan.obj");
    std::fs::write(&path, text).unwrap();
    let s = load_obj_with(&path, &unplaced()).unwrap();
    // One pentagon: three triangles; the polyline is not a face.
    assert_eq!(s.triangle_count(), 3);
    assert_eq!(s.meshes[0].normals.len(), 9, "flat normals, unwelded");
    let ignored = ignored_features(&path).unwrap();
    for f in [
        "polylines (l)",
        "points (p)",
        "free-form curves and surfaces",
        "smoothing groups (normals as given, else flat)",
        "faces of one or two corners (points, lines)",
    ] {
        assert!(ignored.iter().any(|i| i == f), "{ignored:?} lacks {f:?}");
    }
    // Relative indices count back from the last defined.
    let s = load_obj_slice(
        b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\n",
        "rel.obj",
        None,
        &unplaced(),
    )
    .unwrap();
    assert_eq!(s.triangle_count(), 1);
}

fn obj_err(dir: &Path, obj: &str) -> String {
    let path = dir.join("h.obj");
    std::fs::write(&path, obj).unwrap();
    match load_obj(&path) {
        Ok(_) => panic!("{obj:?} loaded"),
        Err(e) => e.to_string(),
    }
}

fn has(text: &str, words: &[&str]) {
    for w in words {
        assert!(text.contains(w), "{text:?} lacks {w:?}");
    }
}

const TRI: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n";

#[test]
fn files_outside_the_model_folder_are_refused() {
    let dir = scratch("paths");
    std::fs::write(dir.join("ok.mtl"), "newmtl ok\nKd 1 1 1\nmap_Kd ok.png\n").unwrap();
    png(&dir.join("ok.png"), [1, 2, 3, 255]);
    // The control: a library and a texture inside the folder load.
    let control = format!("mtllib ok.mtl\n{TRI}usemtl ok\nf 1/1 2/2 3/3\n");
    let path = dir.join("control.obj");
    std::fs::write(&path, &control).unwrap();
    let s = load_obj(&path).unwrap();
    assert_eq!(s.textures.len(), 1);

    let e = obj_err(&dir, &format!("mtllib ../secret.mtl\n{TRI}f 1 2 3\n"));
    has(
        &e,
        &["invalid OBJ", "line 1", "leads outside the model's folder"],
    );
    let e = obj_err(&dir, &format!("mtllib /etc/passwd\n{TRI}f 1 2 3\n"));
    has(&e, &["absolute path"]);
    let e = obj_err(&dir, &format!("mtllib C:\\Windows\\x.mtl\n{TRI}f 1 2 3\n"));
    has(&e, &["absolute path"]);
    std::os::unix::fs::symlink(dir.join("../secret.mtl"), dir.join("link.mtl")).unwrap();
    let e = obj_err(&dir, &format!("mtllib link.mtl\n{TRI}f 1 2 3\n"));
    has(&e, &["resolves to", "outside the model's folder"]);
    // Textures the library names, likewise.
    for (tex, words) in [
        ("../secret.png", &["leads outside the model's folder"][..]),
        ("/etc/passwd", &["absolute path"][..]),
        ("..\\secret.png", &["leads outside the model's folder"][..]),
        ("missing.png", &["cannot read"][..]),
    ] {
        std::fs::write(dir.join("t.mtl"), format!("newmtl t\nmap_Kd {tex}\n")).unwrap();
        let e = obj_err(
            &dir,
            &format!("mtllib t.mtl\n{TRI}usemtl t\nf 1/1 2/2 3/3\n"),
        );
        has(&e, &["material \"t\"", "map_Kd"]);
        has(&e, words);
    }
    // A folder, not a file.
    std::fs::create_dir_all(dir.join("lib.mtl")).unwrap();
    let e = obj_err(&dir, &format!("mtllib lib.mtl\n{TRI}f 1 2 3\n"));
    has(&e, &["not a regular file (a folder)"]);
    // Given as bytes without a folder, it names no file.
    let e = load_obj_slice(b"mtllib ok.mtl\n", "bytes.obj", None, &unplaced())
        .unwrap_err()
        .to_string();
    has(&e, &["without a folder"]);
}

#[test]
fn malformed_and_oversized_files_are_clear_errors() {
    let dir = scratch("malformed");
    for (obj, words) in [
        (
            format!("{TRI}f 1 2 99\n"),
            &["line 7", "names position 99", "defines 3"][..],
        ),
        (
            format!("{TRI}f 1/9 2/1 3/1\n"),
            &["texture coordinate 9"][..],
        ),
        (
            format!("{TRI}f 1//1 2//1 3//1\n"),
            &["normal 1", "defines 0"][..],
        ),
        (
            format!("{TRI}f -4 -2 -1\n"),
            &["line 7", "before the first"][..],
        ),
        (format!("{TRI}f 0 1 2\n"), &["indices start at 1"][..]),
        (
            format!("{TRI}f 1/1/1/1 2 3\n"),
            &["more than three indices"][..],
        ),
        (format!("{TRI}f a b c\n"), &["is not an index"][..]),
        (format!("{TRI}f\n"), &["a face without corners"][..]),
        (
            "v 1 2\n".to_string(),
            &["line 1", "2 numbers (3, 4 or 6 expected)"][..],
        ),
        ("v 1 2 x\n".to_string(), &["\"x\"", "not a number"][..]),
        ("v 1 2 3 0\n".to_string(), &["weight w of 0"][..]),
        ("vn 1 2\n".to_string(), &["3 expected"][..]),
        ("mtllib\n".to_string(), &["without a file name"][..]),
        ("usemtl\n".to_string(), &["without a material name"][..]),
    ] {
        let e = obj_err(&dir, &obj);
        has(&e, &["h.obj: invalid OBJ"]);
        has(&e, words);
    }
    let e = load_obj_slice(b"v 0 0 0\n\xff\xfe\n", "bin.obj", None, &unplaced())
        .unwrap_err()
        .to_string();
    has(&e, &["line 2", "not UTF-8"]);
    // MTL lines too, named by library and line.
    std::fs::write(dir.join("bad.mtl"), "newmtl a\nKd 1 2\n").unwrap();
    let e = obj_err(&dir, &format!("mtllib bad.mtl\n{TRI}f 1 2 3\n"));
    has(&e, &["mtllib \"bad.mtl\"", "line 2", "1 or 3 expected"]);
    // Counts beyond the limits are refused as they are read, before anything is kept: one
    // polygon of 10 000 003 corners (20 MB of text) is 10 000 001 triangles.
    let mut big = String::with_capacity(20_000_020);
    big.push_str(TRI);
    big.push('f');
    for _ in 0..10_000_003u32 {
        big.push_str(" 1");
    }
    big.push('\n');
    let e = load_obj_slice(big.as_bytes(), "big.obj", None, &unplaced())
        .unwrap_err()
        .to_string();
    has(&e, &["line 7", "10000001 triangles", "at most 10000000"]);
    // Many materials switching: meshes are counted, not made.
    let mut many = String::from(TRI);
    for k in 0..70_000 {
        writeln!(many, "g g{k}\nf 1 2 3").unwrap();
    }
    let e = load_obj_slice(many.as_bytes(), "many.obj", None, &unplaced())
        .unwrap_err()
        .to_string();
    has(&e, &["65537 meshes", "at most 65536"]);
}
