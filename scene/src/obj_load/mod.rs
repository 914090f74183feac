//! Wavefront OBJ loading (with its MTL material libraries) into a [`Scene`], through the `tobj`
//! crate: every group and object becomes a mesh (split where the material changes), polygons are
//! fan-triangulated, and materials map to lightfold's as `docs/scenes.md` § OBJ and MTL says
//! (`mtl.rs`). Emissive materials (`Ke`) make their meshes emissive-mesh lights. Features it does
//! not use are listed in one warning.
//!
//! Untrusted input: before `tobj` sees a byte, one pass over the file ([`scan`]) checks that it
//! is UTF-8 text, that every number parses, that every face index names an element the file
//! defines, and counts what the file would make (positions, triangles, meshes) against
//! [`crate::limits`], so a hostile file gets an error naming the line, never an allocation that
//! its counts ask for. Material libraries and textures are read only inside the model's folder and
//! only from regular files, under the same byte budgets as a glTF's buffers and images; `tobj`
//! is additionally guarded against panics.

mod mtl;

use crate::error::SceneError;
use crate::gltf_load::{Imported, flat_shaded, model_folder};
use crate::limits::{self, Budget, LimitError};
use crate::model::{Light, LightShape, Material, Mesh, Scene};
use crate::model_file::{ModelOptions, finish, stem};
use std::borrow::Cow;
use std::collections::BTreeSet;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;
use std::str::SplitWhitespace;

/// Point samples of each emissive-mesh light an OBJ makes, while there are at most
/// [`EMISSIVE_SAMPLES`] / 16 of them; beyond, the total is shared (at least one each).
pub const EMISSIVE_LIGHT_SAMPLES: u32 = crate::defaults::SAMPLES_PER_AREA_LIGHT;
/// Point samples of all an OBJ's emissive-mesh lights together, once there are many.
pub const EMISSIVE_SAMPLES: u32 = 1024;

/// Loads an `.obj` file (and the material libraries and textures it names) with default options.
pub fn load_obj(path: &Path) -> Result<Scene, SceneError> {
    load_obj_with(path, &ModelOptions::default())
}

/// Loads an `.obj` file.
pub fn load_obj_with(path: &Path, opts: &ModelOptions) -> Result<Scene, SceneError> {
    let label = path.display().to_string();
    let bytes = crate::gltf_load::read_model(path)?;
    let imported = import(
        &bytes,
        &label,
        &stem(path, "obj"),
        Some(model_folder(path)),
        opts,
    )?;
    finish(imported, &label, opts.complete, "OBJ")
}

/// Loads OBJ text; `label` names it in errors, `base` is the folder its material libraries and
/// textures are read in (and must stay inside); without `base` it may name none.
pub fn load_obj_slice(
    bytes: &[u8],
    label: &str,
    base: Option<&Path>,
    opts: &ModelOptions,
) -> Result<Scene, SceneError> {
    let imported = import(bytes, label, label, base, opts)?;
    finish(imported, label, opts.complete, "OBJ")
}

/// The OBJ and MTL features a model uses that lightfold does not render, as the loader's warning
/// lists them (empty when everything it uses is rendered).
pub fn ignored_features(path: &Path) -> Result<Vec<String>, SceneError> {
    let label = path.display().to_string();
    let bytes = crate::gltf_load::read_model(path)?;
    let opts = ModelOptions {
        complete: false,
        ..ModelOptions::default()
    };
    Ok(import(&bytes, &label, &label, Some(model_folder(path)), &opts)?.ignored)
}

pub(crate) fn import(
    bytes: &[u8],
    label: &str,
    name: &str,
    base: Option<&Path>,
    opts: &ModelOptions,
) -> Result<Imported, SceneError> {
    let err = |message: String| SceneError::Obj {
        path: label.to_string(),
        message,
    };
    let limit = |e: LimitError| SceneError::limit(label, e);
    if bytes.len() as u64 > limits::MAX_SCENE_BYTES {
        return Err(limit(LimitError::Bytes {
            what: "the model's files",
            bytes: bytes.len() as u64,
        }));
    }
    let files = Budget::new("the model's files");
    files.take(bytes.len() as u64).map_err(limit)?;
    let decoded = Budget::new("the model's decoded textures");
    let mut ignored = BTreeSet::new();
    let found = scan(bytes, &mut ignored).map_err(|e| match e {
        ScanError::Line(line, message) => err(format!("line {line}: {message}")),
        ScanError::Limit(line, e) => err(format!("line {line}: {e} (see `lightfold defaults`)")),
        ScanError::Index(message) => err(message),
    })?;
    let libraries =
        mtl::Libraries::load(&found.mtllibs, base, &files, &mut ignored).map_err(err)?;
    // `tobj` makes faces of polylines with three or more points: they become comments here.
    let text: Cow<[u8]> = if found.polylines.is_empty() {
        Cow::Borrowed(bytes)
    } else {
        let mut copy = bytes.to_vec();
        for &at in &found.polylines {
            copy[at] = b'#';
        }
        Cow::Owned(copy)
    };
    let options = tobj::LoadOptions {
        single_index: true,
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
    };
    let parsed = catch_unwind(AssertUnwindSafe(|| {
        tobj::load_obj_buf(&mut std::io::Cursor::new(&text[..]), &options, |p| {
            libraries.get(p)
        })
    }))
    .map_err(|p| err(format!("the OBJ reader panicked: {}", panic_text(&p))))?;
    let (models, materials) = parsed.map_err(|e| err(format!("the OBJ reader failed: {e}")))?;
    drop(text);
    // The libraries were read and checked above; `tobj` reports no error of its own for them.
    let materials = materials.unwrap_or_default();
    let mut scene = Scene::new(name);
    let mut converter = mtl::Converter::new(base, &files, &decoded, &mut ignored);
    let mut by_id: Vec<Option<usize>> = vec![None; materials.len()];
    let mut default_material = None;
    let mut emissive_meshes = Vec::new();
    for model in models {
        // `tobj` names what comes before any `o` or `g` "unnamed_object": the model's name here.
        let mesh_name = match model.name.as_str() {
            "unnamed_object" => name.to_string(),
            _ => model.name,
        };
        let Some((mesh, id)) = model_mesh(mesh_name, model.mesh, converter.ignored_mut()) else {
            continue;
        };
        let material = match id.filter(|&i| i < materials.len()) {
            Some(i) => match by_id[i] {
                Some(k) => k,
                None => {
                    let m = converter
                        .convert(&materials[i], libraries.folder_of(i))
                        .map_err(err)?;
                    let k = scene.add_material(m);
                    by_id[i] = Some(k);
                    k
                }
            },
            None => *default_material
                .get_or_insert_with(|| scene.add_material(Material::diffuse("default", [0.8; 3]))),
        };
        let mut mesh = Mesh { material, ..mesh };
        opts.place(&mut mesh);
        if scene.materials[material].emissive.iter().any(|&c| c > 0.0) {
            emissive_meshes.push(scene.meshes.len());
        }
        scene.meshes.push(mesh);
    }
    scene.textures = converter.into_textures();
    add_emissive_lights(&mut scene, &emissive_meshes);
    let ignored: Vec<String> = ignored.into_iter().collect();
    if !ignored.is_empty() {
        tracing::warn!(scene = name, ignored = %ignored.join(", "), "OBJ features ignored");
    }
    Ok(Imported {
        scene,
        has_camera: false,
        ignored,
    })
}

/// One `tobj` model as a mesh (in the file's coordinates, material 0) and its material id;
/// `None` for a model without triangles.
fn model_mesh(
    name: String,
    m: tobj::Mesh,
    ignored: &mut BTreeSet<String>,
) -> Option<(Mesh, Option<usize>)> {
    if m.indices.len() < 3 {
        return None;
    }
    let n = m.positions.len() / 3;
    let positions: Vec<[f32; 3]> = m
        .positions
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    let mut normals: Vec<[f32; 3]> = m
        .normals
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    if !normals.is_empty() && normals.len() != n {
        ignored.insert("normals on only some corners of a group (flat normals used)".into());
        normals.clear();
    }
    // OBJ texture coordinates run up from the image's bottom; lightfold's (glTF's) down from
    // its top.
    let mut uvs: Vec<[f32; 2]> = m
        .texcoords
        .chunks_exact(2)
        .map(|c| [c[0], 1.0 - c[1]])
        .collect();
    if !uvs.is_empty() && uvs.len() != n {
        ignored.insert("texture coordinates on only some corners of a group".into());
        uvs.clear();
    }
    if !m.vertex_color.is_empty() {
        ignored.insert("vertex colours".into());
    }
    let mut indices = m.indices;
    indices.truncate(indices.len() - indices.len() % 3);
    let has_normals = !normals.is_empty();
    let mesh = Mesh {
        name,
        positions,
        normals,
        uvs,
        tangents: Vec::new(),
        indices,
        material: 0,
    };
    let mesh = if has_normals {
        mesh
    } else {
        flat_shaded(mesh).0
    };
    Some((mesh, m.material_id))
}

/// Every mesh with an emissive material lights the scene: an emissive-mesh light of radiance
/// `max(Ke)` and colour `Ke / max(Ke)`, emitting along the counter-clockwise face normal (the
/// material is one-sided).
pub(crate) fn add_emissive_lights(scene: &mut Scene, meshes: &[usize]) {
    if meshes.is_empty() {
        return;
    }
    let per_light =
        (EMISSIVE_SAMPLES / meshes.len().max(1) as u32).clamp(1, EMISSIVE_LIGHT_SAMPLES);
    for &k in meshes {
        let ke = scene.materials[scene.meshes[k].material].emissive;
        let power = ke[0].max(ke[1]).max(ke[2]);
        if !(power.is_finite() && power > 0.0) {
            continue;
        }
        scene.lights.push(Light {
            name: format!("{} (emissive)", scene.meshes[k].name),
            shape: LightShape::EmissiveMesh { mesh: k },
            color: ke.map(|c| c / power),
            power,
            range: None,
            samples: per_light,
        });
    }
}

fn panic_text(p: &Box<dyn std::any::Any + Send>) -> String {
    p.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".into())
}

/// What one pass over an OBJ finds before `tobj` reads it.
#[derive(Debug, Default)]
struct Scan {
    /// `mtllib` arguments as `tobj` reads them, with their line.
    mtllibs: Vec<(usize, String)>,
    /// Byte offsets of polyline statements of three or more points.
    polylines: Vec<usize>,
}

#[derive(Debug)]
enum ScanError {
    Line(usize, String),
    Limit(usize, LimitError),
    Index(String),
}

/// The largest 1-based index faces name of one kind, and the first line naming it.
#[derive(Debug, Default)]
struct Highest {
    index: u64,
    line: usize,
}

/// Checks an OBJ's text and counts what it makes (see the module's documentation).
fn scan(bytes: &[u8], ignored: &mut BTreeSet<String>) -> Result<Scan, ScanError> {
    let mut out = Scan::default();
    // Positions, texture coordinates and normals defined so far.
    let mut counts = [0u64; 3];
    let mut highest: [Highest; 3] = Default::default();
    let (mut triangles, mut meshes, mut pending) = (0u64, 0u64, false);
    let mut unknown = 0usize;
    let mut offset = 0usize;
    for (k, raw) in bytes.split(|&b| b == b'\n').enumerate() {
        let line_no = k + 1;
        let start = offset;
        offset += raw.len() + 1;
        let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
        let line = std::str::from_utf8(raw)
            .map_err(|_| ScanError::Line(line_no, "not UTF-8 text".into()))?;
        let bad = |m: String| ScanError::Line(line_no, m);
        let mut words = line.split_whitespace();
        let Some(keyword) = words.next() else {
            continue;
        };
        match keyword {
            "v" | "vt" | "vn" => vertex(keyword, words, line, &mut counts, line_no)?,
            "f" | "l" => {
                let mut corners = 0u64;
                for w in words {
                    corner(w, &counts, &mut highest, line_no)?;
                    corners += 1;
                }
                if keyword == "l" {
                    ignored.insert("polylines (l)".into());
                    if corners >= 3 {
                        out.polylines.push(start + line.find('l').unwrap_or(0));
                    }
                    continue;
                }
                if corners == 0 {
                    return Err(bad("a face without corners".into()));
                }
                if corners < 3 {
                    ignored.insert("faces of one or two corners (points, lines)".into());
                }
                triangles += corners.saturating_sub(2);
                limits::check_triangles(triangles).map_err(|e| ScanError::Limit(line_no, e))?;
                pending = true;
            }
            "o" | "g" | "usemtl" => {
                if pending {
                    meshes += 1;
                    pending = false;
                    limits::check_count("meshes", meshes, limits::MAX_MODEL_MESHES)
                        .map_err(|e| ScanError::Limit(line_no, e))?;
                }
                if keyword == "usemtl"
                    && line
                        .split_once(' ')
                        .is_none_or(|(_, m)| m.trim().is_empty())
                {
                    return Err(bad("`usemtl` without a material name".into()));
                }
            }
            "mtllib" => {
                // As `tobj` reads it: the rest of the line after the first space.
                let arg = line.split_once(' ').unwrap_or_default().1.trim();
                if arg.is_empty() {
                    return Err(bad("`mtllib` without a file name".into()));
                }
                out.mtllibs.push((line_no, arg.to_string()));
            }
            _ => ignore_statement(keyword, words, ignored, &mut unknown),
        }
    }
    if pending {
        meshes += 1;
        limits::check_count("meshes", meshes, limits::MAX_MODEL_MESHES)
            .map_err(|e| ScanError::Limit(bytes.split(|&b| b == b'\n').count(), e))?;
    }
    let kinds = ["position", "texture coordinate", "normal"];
    for (kind, h) in highest.iter().enumerate() {
        if h.index > counts[kind] {
            return Err(ScanError::Index(format!(
                "line {}: a face names {} {} but the file defines {}",
                h.line, kinds[kind], h.index, counts[kind]
            )));
        }
    }
    Ok(out)
}

/// Checks one `v`, `vt` or `vn` statement on line `line_no` (its number count, a position's
/// weight) and counts it, against the limit, in `counts` (positions, texture coordinates, normals).
fn vertex(
    keyword: &str,
    words: SplitWhitespace,
    line: &str,
    counts: &mut [u64; 3],
    line_no: usize,
) -> Result<(), ScanError> {
    let bad = |m: String| ScanError::Line(line_no, m);
    let kind = match keyword {
        "v" => 0,
        "vt" => 1,
        _ => 2,
    };
    let mut numbers = 0;
    for w in words {
        w.parse::<f32>()
            .map_err(|_| bad(format!("{w:?} in a `{keyword}` is not a number")))?;
        numbers += 1;
    }
    let fine = match kind {
        0 => matches!(numbers, 3 | 4 | 6),
        1 => (2..=3).contains(&numbers),
        _ => numbers == 3,
    };
    if !fine {
        let expected = ["3, 4 or 6", "2 or 3", "3"][kind];
        return Err(bad(format!(
            "a `{keyword}` has {numbers} numbers ({expected} expected)"
        )));
    }
    if kind == 0 && numbers == 4 {
        let w: f32 = line
            .split_whitespace()
            .nth(4)
            .map_or(1.0, |w| w.parse().unwrap_or(1.0));
        if w == 0.0 {
            return Err(bad("a vertex weight w of 0".into()));
        }
    }
    counts[kind] += 1;
    let what = ["positions", "texture coordinates", "normals"][kind];
    limits::check_count(what, counts[kind], limits::MAX_VERTICES)
        .map_err(|e| ScanError::Limit(line_no, e))?;
    Ok(())
}

/// Notes in `ignored` what a statement lightfold does not render stands for; a comment is
/// nothing, and unknown statements are named (the first eight, counted in `unknown`).
fn ignore_statement(
    keyword: &str,
    mut words: SplitWhitespace,
    ignored: &mut BTreeSet<String>,
    unknown: &mut usize,
) {
    match keyword {
        "s" => {
            if !matches!(words.next(), Some("off" | "0")) {
                ignored.insert("smoothing groups (normals as given, else flat)".into());
            }
        }
        "p" => {
            ignored.insert("points (p)".into());
        }
        "vp" | "cstype" | "deg" | "bmat" | "step" | "curv" | "curv2" | "surf" | "parm" | "trim"
        | "hole" | "scrv" | "sp" | "end" | "con" | "ctech" | "stech" => {
            ignored.insert("free-form curves and surfaces".into());
        }
        "mg" => {
            ignored.insert("merging groups (mg)".into());
        }
        "lod" | "bevel" | "c_interp" | "d_interp" | "shadow_obj" | "trace_obj" => {
            ignored.insert(format!("display and rendering attributes ({keyword})"));
        }
        "usemap" | "maplib" => {
            ignored.insert("texture map libraries (usemap, maplib)".into());
        }
        w if w.starts_with('#') => {}
        w => {
            // Listed by name, a few at most: a hostile file could hold millions of them.
            *unknown += 1;
            if *unknown <= 8 {
                ignored.insert(format!("unknown statement {:?}", truncate(w, 32)));
            } else {
                ignored.insert("further unknown statements".into());
            }
        }
    }
}

/// Checks one face corner `v`, `v/vt`, `v//vn` or `v/vt/vn`: a relative (negative) index
/// against what is defined so far, an absolute one later against the whole file.
fn corner(
    w: &str,
    counts: &[u64; 3],
    highest: &mut [Highest; 3],
    line_no: usize,
) -> Result<(), ScanError> {
    let bad = |m: String| ScanError::Line(line_no, m);
    let kinds = ["position", "texture coordinate", "normal"];
    let mut parts = 0;
    for (kind, part) in w.split('/').enumerate() {
        parts += 1;
        if kind > 2 {
            return Err(bad(format!(
                "face corner {w:?} has more than three indices"
            )));
        }
        if part.is_empty() {
            if kind == 0 {
                return Err(bad(format!("face corner {w:?} has no position index")));
            }
            continue;
        }
        let i: i64 = part
            .parse()
            .map_err(|_| bad(format!("face corner {w:?}: {part:?} is not an index")))?;
        match i {
            0 => {
                return Err(bad(format!(
                    "face corner {w:?} names {} 0 (OBJ indices start at 1)",
                    kinds[kind]
                )));
            }
            i if i < 0 => {
                if i.unsigned_abs() > counts[kind] {
                    return Err(bad(format!(
                        "face corner {w:?} names {} {i}, before the first ({} defined so far)",
                        kinds[kind], counts[kind]
                    )));
                }
            }
            i => {
                let i = i as u64;
                if i > highest[kind].index {
                    highest[kind] = Highest {
                        index: i,
                        line: line_no,
                    };
                }
            }
        }
    }
    debug_assert!(parts >= 1);
    Ok(())
}

fn truncate(s: &str, chars: usize) -> String {
    s.chars().take(chars).collect()
}
