//! PLY (Stanford polygon file, ASCII or binary) loading into a [`Scene`], through the
//! `ply-rs-bw` crate: the `vertex` element's `x y z`, its normals `nx ny nz` where present and its
//! colour `red green blue`; the `face` element's `vertex_indices` (or `vertex_index`) lists,
//! fan-triangulated, and a per-face colour where present. Features it does not use are listed in
//! one warning.
//!
//! lightfold's meshes carry no per-vertex colour, so colour becomes per-triangle material: each
//! triangle takes its face's colour, or the mean of its corners' (linear), and triangles of one
//! colour form one mesh with one diffuse material. That is exact for a model coloured per part;
//! colours that vary smoothly (a scan) are grouped to at most [`MAX_COLOUR_MATERIALS`] materials,
//! quantised to fewer bits per channel (8, then 6, 5, 4, 3) until they fit, so they come out
//! banded. Colours are read as sRGB-encoded (`uchar` 0–255, `ushort` 0–65535, floats 0–1).
//!
//! Untrusted input: the header is read first, and every count it declares is checked against
//! [`crate::limits`] and against the bytes that follow it before any element is read; an ASCII
//! body's lines are bounded; face lists draw on one budget of indices (three per triangle of the
//! limit) as they are read; every index is checked against the vertex count.

use crate::error::SceneError;
use crate::gltf_load::{Imported, flat_shaded};
use crate::limits::{self, LimitError};
use crate::model::{Material, Mesh, Scene};
use crate::model_file::{ModelOptions, finish, stem};
use lightfold_protocol::srgb::{linear_to_srgb, srgb_to_linear, srgb8};
use ply_rs_bw::parser::{Parser, Reader};
use ply_rs_bw::ply::{
    BeginList, ElementDef, Encoding, Header, Property, PropertyAccess, PropertyAccessResult,
    PropertyType, ScalarType,
};
use std::cell::RefCell;
use std::collections::{BTreeSet, HashMap};
use std::path::Path;

/// Most diffuse materials a coloured PLY is grouped into.
pub const MAX_COLOUR_MATERIALS: usize = 512;
/// Largest PLY header.
pub const MAX_HEADER_BYTES: usize = 1 << 20;
/// Longest line of an ASCII PLY's body.
pub const MAX_ASCII_LINE_BYTES: usize = 1 << 20;

/// Loads a `.ply` file with default options.
pub fn load_ply(path: &Path) -> Result<Scene, SceneError> {
    load_ply_with(path, &ModelOptions::default())
}

/// Loads a `.ply` file.
pub fn load_ply_with(path: &Path, opts: &ModelOptions) -> Result<Scene, SceneError> {
    let label = path.display().to_string();
    let bytes = crate::gltf_load::read_model(path)?;
    let imported = import(&bytes, &label, &stem(path, "ply"), opts)?;
    finish(imported, &label, opts.complete, "PLY")
}

/// Loads PLY bytes; `label` names them in errors.
pub fn load_ply_slice(bytes: &[u8], label: &str, opts: &ModelOptions) -> Result<Scene, SceneError> {
    let imported = import(bytes, label, label, opts)?;
    finish(imported, label, opts.complete, "PLY")
}

/// The PLY features a model uses that lightfold does not render, as the loader's warning lists
/// them.
pub fn ignored_features(path: &Path) -> Result<Vec<String>, SceneError> {
    let label = path.display().to_string();
    let bytes = crate::gltf_load::read_model(path)?;
    let opts = ModelOptions {
        complete: false,
        ..ModelOptions::default()
    };
    Ok(import(&bytes, &label, &label, &opts)?.ignored)
}

pub(crate) fn import(
    bytes: &[u8],
    label: &str,
    name: &str,
    opts: &ModelOptions,
) -> Result<Imported, SceneError> {
    let err = |message: String| SceneError::Ply {
        path: label.to_string(),
        message,
    };
    if bytes.len() as u64 > limits::MAX_SCENE_BYTES {
        return Err(SceneError::limit(
            label,
            LimitError::Bytes {
                what: "the model's files",
                bytes: bytes.len() as u64,
            },
        ));
    }
    let mut ignored = BTreeSet::new();
    let (header, body_start) = read_header(bytes).map_err(&err)?;
    let layout = Layout::of(&header, &mut ignored).map_err(&err)?;
    limits::check_count("vertices", layout.vertices as u64, limits::MAX_VERTICES)
        .map_err(|e| SceneError::limit(label, e))?;
    // Each face is at least one triangle.
    limits::check_count("faces", layout.faces as u64, limits::MAX_TRIANGLES)
        .map_err(|e| SceneError::limit(label, e))?;
    check_body(&header, &bytes[body_start..]).map_err(&err)?;
    let (vertices, faces) = read_body(bytes, &header, &layout).map_err(&err)?;
    let scene = build(name, vertices, faces, &layout, opts, &mut ignored).map_err(&err)?;
    let ignored: Vec<String> = ignored.into_iter().collect();
    if !ignored.is_empty() {
        tracing::warn!(scene = name, ignored = %ignored.join(", "), "PLY features ignored");
    }
    Ok(Imported {
        scene,
        has_camera: false,
        ignored,
    })
}

/// The parsed header and where the body starts. The header's text is checked here first (a
/// bounded size, `end_header` present, no element or property declared twice) since the parser
/// keys both by name.
fn read_header(bytes: &[u8]) -> Result<(Header, usize), String> {
    if !bytes.starts_with(b"ply") {
        return Err("not a PLY file (it does not start with `ply`)".into());
    }
    let mut end = None;
    let mut offset = 0;
    let mut elements: Vec<(String, usize)> = Vec::new();
    for line in bytes[..bytes.len().min(MAX_HEADER_BYTES)].split(|&b| b == b'\n') {
        offset += line.len() + 1;
        let text = String::from_utf8_lossy(line);
        let mut words = text.split_whitespace();
        match words.next() {
            Some("end_header") => {
                end = Some(offset.min(bytes.len()));
                break;
            }
            Some("element") => {
                let name = words.next().unwrap_or_default().to_string();
                if elements.iter().any(|(e, _)| *e == name) {
                    return Err(format!("element {name:?} is declared twice"));
                }
                elements.push((name, 0));
            }
            Some("property") => {
                if let Some(last) = elements.last_mut() {
                    last.1 += 1;
                }
            }
            _ => {}
        }
    }
    let Some(end) = end else {
        return Err(format!(
            "no `end_header` in its first {MAX_HEADER_BYTES} bytes (a truncated or malformed \
             header)"
        ));
    };
    let parser = Parser::<Skip>::new();
    let mut reader = Reader::new(std::io::Cursor::new(&bytes[..end]));
    let header = parser
        .read_header(&mut reader)
        .map_err(|e| format!("header: {e}"))?;
    for (name, properties) in &elements {
        let declared = header.elements.get(name).map_or(0, |e| e.properties.len());
        if declared != *properties {
            return Err(format!(
                "element {name:?} declares a property twice ({properties} property lines, \
                 {declared} names)"
            ));
        }
    }
    Ok((header, end))
}

/// Which properties of the vertex and face elements are read.
#[derive(Debug, Default)]
struct Layout {
    vertices: usize,
    faces: usize,
    normals: bool,
    vertex_colours: bool,
    face_colours: bool,
}

impl Layout {
    fn of(header: &Header, ignored: &mut BTreeSet<String>) -> Result<Layout, String> {
        let vertex = header.elements.get("vertex").ok_or("no `vertex` element")?;
        let face = header
            .elements
            .get("face")
            .ok_or("no `face` element (a point cloud); only meshes are read")?;
        let scalar = |e: &ElementDef, n: &str| {
            matches!(
                e.properties.get(n).map(|p| &p.data_type),
                Some(PropertyType::Scalar(_))
            )
        };
        for axis in ["x", "y", "z"] {
            if !scalar(vertex, axis) {
                return Err(format!(
                    "the `vertex` element has no scalar `{axis}` property"
                ));
            }
        }
        let all = |e: &ElementDef, names: &[&str]| names.iter().all(|n| scalar(e, n));
        let normals = all(vertex, &["nx", "ny", "nz"]);
        let colour_names = |e: &ElementDef| {
            all(e, &["red", "green", "blue"])
                || all(e, &["diffuse_red", "diffuse_green", "diffuse_blue"])
        };
        let list = face
            .properties
            .iter()
            .find(|(n, _)| matches!(n.as_str(), "vertex_indices" | "vertex_index"));
        match list.map(|(_, p)| &p.data_type) {
            Some(PropertyType::List(_, item))
                if !matches!(item, ScalarType::Float | ScalarType::Double) => {}
            Some(_) => return Err("the face index list is not a list of integers".into()),
            None => {
                return Err(
                    "the `face` element has no `vertex_indices` (or `vertex_index`) list".into(),
                );
            }
        }
        for (name, e) in &header.elements {
            if name != "vertex" && name != "face" {
                ignored.insert(format!("element {:?}", truncate(name, 32)));
                continue;
            }
            for (p, _) in &e.properties {
                let used = match p.as_str() {
                    "x" | "y" | "z" => name == "vertex",
                    "nx" | "ny" | "nz" => name == "vertex" && normals,
                    "red" | "green" | "blue" | "diffuse_red" | "diffuse_green" | "diffuse_blue" => {
                        colour_names(e)
                    }
                    "vertex_indices" | "vertex_index" => name == "face",
                    _ => false,
                };
                if !used {
                    let what = match p.as_str() {
                        "s" | "t" | "u" | "v" | "texture_u" | "texture_v" | "texcoord" => {
                            "texture coordinates".to_string()
                        }
                        "alpha" | "diffuse_alpha" => "colour alpha".to_string(),
                        _ => format!("{name} property {:?}", truncate(p, 32)),
                    };
                    ignored.insert(what);
                }
            }
        }
        if header
            .comments
            .iter()
            .any(|c| c.trim_start().starts_with("TextureFile"))
        {
            ignored.insert("texture files (comment TextureFile)".into());
        }
        Ok(Layout {
            vertices: vertex.count,
            faces: face.count,
            normals,
            vertex_colours: colour_names(vertex),
            face_colours: colour_names(face),
        })
    }
}

/// The body is at least as long as the header's counts need (binary: each element's fixed part;
/// ASCII: two bytes per value), and an ASCII body has no line longer than
/// [`MAX_ASCII_LINE_BYTES`]: a few bytes that declare a billion elements are refused here.
fn check_body(header: &Header, body: &[u8]) -> Result<(), String> {
    let mut need: u128 = 0;
    for (name, e) in &header.elements {
        let per: u128 = match header.encoding {
            Encoding::Ascii => 2 * e.properties.len() as u128,
            _ => e
                .properties
                .iter()
                .map(|(_, p)| match &p.data_type {
                    PropertyType::Scalar(s) | PropertyType::List(s, _) => size(s) as u128,
                })
                .sum(),
        };
        let bytes = per * e.count as u128;
        need += bytes;
        if need > body.len() as u128 {
            return Err(format!(
                "the header declares {} {name:?} elements, which take at least {bytes} bytes, \
                 but {} bytes follow it (truncated, or counts that are not the file's)",
                e.count,
                body.len()
            ));
        }
    }
    if header.encoding == Encoding::Ascii
        && let Some((k, line)) = body
            .split(|&b| b == b'\n')
            .enumerate()
            .find(|(_, l)| l.len() > MAX_ASCII_LINE_BYTES)
    {
        return Err(format!(
            "line {} of the body holds {} bytes; at most {MAX_ASCII_LINE_BYTES} are read",
            k + 1,
            line.len()
        ));
    }
    Ok(())
}

fn size(s: &ScalarType) -> usize {
    match s {
        ScalarType::Char | ScalarType::UChar => 1,
        ScalarType::Short | ScalarType::UShort => 2,
        ScalarType::Int | ScalarType::UInt | ScalarType::Float => 4,
        ScalarType::Double => 8,
    }
}

/// One vertex as read: position, normal and (sRGB) colour.
#[derive(Debug, Default, Clone, Copy)]
struct Vertex {
    p: [f32; 3],
    n: [f32; 3],
    c: [f32; 3],
}

/// One face as read: its corners and (sRGB) colour.
#[derive(Debug, Default)]
struct Face {
    corners: Vec<u32>,
    c: [f32; 3],
}

/// An element that is not read (its lists are still parsed, and dropped).
#[derive(Debug)]
struct Skip;

impl PropertyAccess for Skip {
    fn new() -> Self {
        Skip
    }
}

/// A colour channel in 0..=1 from the property's type: integers over their range, floats as
/// they are.
fn channel(p: &Property) -> f32 {
    match *p {
        Property::UChar(v) => f32::from(v) / 255.0,
        Property::UShort(v) => f32::from(v) / 65535.0,
        Property::Float(v) => v,
        Property::Double(v) => v as f32,
        ref other => other.to_f32_lossy().unwrap_or(0.0) / 255.0,
    }
}

fn colour_slot(name: &str) -> Option<usize> {
    match name {
        "red" | "diffuse_red" => Some(0),
        "green" | "diffuse_green" => Some(1),
        "blue" | "diffuse_blue" => Some(2),
        _ => None,
    }
}

impl PropertyAccess for Vertex {
    fn new() -> Self {
        Vertex::default()
    }

    fn set_property(&mut self, name: &str, p: Property) -> PropertyAccessResult {
        let value = || p.to_f32_lossy().unwrap_or(f32::NAN);
        match name {
            "x" => self.p[0] = value(),
            "y" => self.p[1] = value(),
            "z" => self.p[2] = value(),
            "nx" => self.n[0] = value(),
            "ny" => self.n[1] = value(),
            "nz" => self.n[2] = value(),
            n => match colour_slot(n) {
                Some(k) => self.c[k] = channel(&p),
                None => return PropertyAccessResult::Ignored,
            },
        }
        PropertyAccessResult::Set
    }
}

/// What the face lists being read may still take: indices (three per triangle of the limit in
/// all) and triangles. Kept per thread for the element type, which the parser builds itself.
#[derive(Debug)]
struct ListBudget {
    indices_left: u64,
    triangles: u64,
    refused: Option<String>,
}

thread_local! {
    static LISTS: RefCell<Option<ListBudget>> = const { RefCell::new(None) };
}

/// Sets the list budget for one body's faces, and clears it however reading ends.
struct ListScope;

impl ListScope {
    fn new() -> ListScope {
        LISTS.with(|l| {
            *l.borrow_mut() = Some(ListBudget {
                indices_left: 3 * limits::MAX_TRIANGLES,
                triangles: 0,
                refused: None,
            })
        });
        ListScope
    }

    fn refused(&self) -> Option<String> {
        LISTS.with(|l| l.borrow().as_ref().and_then(|b| b.refused.clone()))
    }
}

impl Drop for ListScope {
    fn drop(&mut self) {
        LISTS.with(|l| *l.borrow_mut() = None);
    }
}

/// Whether a face list of `len` indices may be read (taking it from the budget).
fn admit(name: &str, len: usize) -> bool {
    if !matches!(name, "vertex_indices" | "vertex_index") {
        return true;
    }
    LISTS.with(|l| {
        let mut l = l.borrow_mut();
        let Some(b) = l.as_mut() else {
            return true;
        };
        let len = len as u64;
        if len > b.indices_left {
            b.refused = Some(format!(
                "the faces name more than {} vertex indices in all (three per triangle of the \
                 {} limit)",
                3 * limits::MAX_TRIANGLES,
                limits::MAX_TRIANGLES
            ));
            return false;
        }
        b.indices_left -= len;
        b.triangles += len.saturating_sub(2);
        if let Err(e) = limits::check_triangles(b.triangles) {
            b.refused = Some(format!("{e} (see `lightfold defaults`)"));
            return false;
        }
        true
    })
}

macro_rules! admitted {
    ($name:expr, $len:expr) => {
        if admit($name, $len) {
            BeginList::UseSetter
        } else {
            BeginList::UnsupportedType
        }
    };
}

impl PropertyAccess for Face {
    fn new() -> Self {
        Face::default()
    }

    fn begin_list_char(&mut self, name: &str, len: usize) -> BeginList<'_, i8> {
        admitted!(name, len)
    }
    fn begin_list_uchar(&mut self, name: &str, len: usize) -> BeginList<'_, u8> {
        admitted!(name, len)
    }
    fn begin_list_short(&mut self, name: &str, len: usize) -> BeginList<'_, i16> {
        admitted!(name, len)
    }
    fn begin_list_ushort(&mut self, name: &str, len: usize) -> BeginList<'_, u16> {
        admitted!(name, len)
    }
    fn begin_list_int(&mut self, name: &str, len: usize) -> BeginList<'_, i32> {
        admitted!(name, len)
    }
    fn begin_list_uint(&mut self, name: &str, len: usize) -> BeginList<'_, u32> {
        admitted!(name, len)
    }

    fn set_property(&mut self, name: &str, p: Property) -> PropertyAccessResult {
        // A negative index becomes u32::MAX, which the range check refuses.
        fn signed<T: Copy + Into<i64>>(v: &[T]) -> Vec<u32> {
            v.iter()
                .map(|&i| u32::try_from(i.into()).unwrap_or(u32::MAX))
                .collect()
        }
        match name {
            "vertex_indices" | "vertex_index" => {
                self.corners = match p {
                    Property::ListChar(v) => signed(&v),
                    Property::ListUChar(v) => v.into_iter().map(u32::from).collect(),
                    Property::ListShort(v) => signed(&v),
                    Property::ListUShort(v) => v.into_iter().map(u32::from).collect(),
                    Property::ListInt(v) => signed(&v),
                    Property::ListUInt(v) => v,
                    _ => return PropertyAccessResult::UnsupportedType,
                };
            }
            n => match colour_slot(n) {
                Some(k) => self.c[k] = channel(&p),
                None => return PropertyAccessResult::Ignored,
            },
        }
        PropertyAccessResult::Set
    }
}

/// Reads every element in the header's order; keeps the vertices and faces.
fn read_body(
    bytes: &[u8],
    header: &Header,
    layout: &Layout,
) -> Result<(Vec<Vertex>, Vec<Face>), String> {
    let mut reader = Reader::new(std::io::Cursor::new(bytes));
    Parser::<Skip>::new()
        .read_header(&mut reader)
        .map_err(|e| format!("header: {e}"))?;
    let (mut vertices, mut faces) = (Vec::new(), Vec::new());
    for (name, def) in &header.elements {
        let what = |e: ply_rs_bw::parser::ParseError| format!("element {name:?}: {e}");
        match name.as_str() {
            "vertex" => {
                vertices = Parser::<Vertex>::new()
                    .read_payload_for_element(&mut reader, def, header)
                    .map_err(what)?;
            }
            "face" => {
                let scope = ListScope::new();
                faces = Parser::<Face>::new()
                    .read_payload_for_element(&mut reader, def, header)
                    .map_err(|e| scope.refused().unwrap_or_else(|| what(e)))?;
            }
            _ => {
                Parser::<Skip>::new()
                    .read_payload_for_element(&mut reader, def, header)
                    .map_err(what)?;
            }
        }
    }
    debug_assert_eq!(vertices.len(), layout.vertices);
    Ok((vertices, faces))
}

/// Meshes (one per colour) and materials from what was read.
fn build(
    name: &str,
    vertices: Vec<Vertex>,
    faces: Vec<Face>,
    layout: &Layout,
    opts: &ModelOptions,
    ignored: &mut BTreeSet<String>,
) -> Result<Scene, String> {
    let n = vertices.len();
    // Triangles (fans) and each one's linear colour.
    let mut triangles: Vec<[u32; 3]> = Vec::new();
    let mut colours: Vec<[f32; 3]> = Vec::new();
    let coloured = layout.face_colours || layout.vertex_colours;
    for (k, f) in faces.iter().enumerate() {
        if let Some(&bad) = f.corners.iter().find(|&&i| i as usize >= n) {
            return Err(if bad == u32::MAX {
                format!("face {k} names a negative vertex index")
            } else {
                format!("face {k} names vertex {bad} but the file has {n} vertices")
            });
        }
        if f.corners.len() < 3 {
            ignored.insert("faces of fewer than three corners".into());
            continue;
        }
        let face_colour = layout.face_colours.then(|| f.c.map(srgb_to_linear));
        for w in f.corners[1..].windows(2) {
            let t = [f.corners[0], w[0], w[1]];
            triangles.push(t);
            if coloured {
                colours.push(face_colour.unwrap_or_else(|| {
                    let c = t.map(|i| vertices[i as usize].c.map(srgb_to_linear));
                    if c[0] == c[1] && c[1] == c[2] {
                        c[0]
                    } else {
                        [0, 1, 2].map(|a| (c[0][a] + c[1][a] + c[2][a]) / 3.0)
                    }
                }));
            }
        }
    }
    drop(faces);
    let mut scene = Scene::new(name);
    // Triangles grouped by colour: the group of each, and each group's colour.
    let (group_of, groups): (Vec<u32>, Vec<[f32; 3]>) = if coloured {
        group_colours(&colours)
    } else {
        (vec![0; triangles.len()], vec![[0.8; 3]])
    };
    let mut members: Vec<Vec<u32>> = vec![Vec::new(); groups.len()];
    for (t, &g) in group_of.iter().enumerate() {
        members[g as usize].push(t as u32);
    }
    let mut local = vec![u32::MAX; n];
    for (g, colour) in groups.iter().enumerate() {
        if members[g].is_empty() {
            continue;
        }
        let label = if coloured {
            let s = colour.map(srgb8);
            format!("#{:02x}{:02x}{:02x}", s[0], s[1], s[2])
        } else {
            "default".to_string()
        };
        let material = scene.add_material(Material::diffuse(&label, *colour));
        let mut mesh = Mesh {
            name: if coloured {
                format!("{name} {label}")
            } else {
                name.to_string()
            },
            positions: Vec::new(),
            normals: Vec::new(),
            uvs: Vec::new(),
            tangents: Vec::new(),
            indices: Vec::with_capacity(3 * members[g].len()),
            material,
        };
        let mut used = Vec::new();
        for &t in &members[g] {
            for &v in &triangles[t as usize] {
                let slot = &mut local[v as usize];
                if *slot == u32::MAX {
                    *slot = mesh.positions.len() as u32;
                    used.push(v);
                    let vx = &vertices[v as usize];
                    mesh.positions.push(vx.p);
                    if layout.normals {
                        mesh.normals.push(vx.n);
                    }
                }
                mesh.indices.push(*slot);
            }
        }
        for v in used {
            local[v as usize] = u32::MAX;
        }
        let mut mesh = if layout.normals {
            mesh
        } else {
            flat_shaded(mesh).0
        };
        opts.place(&mut mesh);
        scene.add_mesh(mesh);
    }
    Ok(scene)
}

/// Each triangle's group and each group's mean colour: triangles of one 8-bit sRGB colour form a
/// group; beyond [`MAX_COLOUR_MATERIALS`] groups, colours are quantised to fewer bits.
fn group_colours(colours: &[[f32; 3]]) -> (Vec<u32>, Vec<[f32; 3]>) {
    let srgb: Vec<[f32; 3]> = colours.iter().map(|c| c.map(linear_to_srgb)).collect();
    for bits in [8u32, 6, 5, 4, 3] {
        let levels = ((1u32 << bits) - 1) as f32;
        let key = |c: &[f32; 3]| {
            let q = c.map(|x| (x * levels).round() as u32);
            q[0] << 16 | q[1] << 8 | q[2]
        };
        let mut index: HashMap<u32, u32> = HashMap::new();
        let mut group_of = Vec::with_capacity(colours.len());
        let mut too_many = false;
        for c in &srgb {
            let next = index.len() as u32;
            let g = *index.entry(key(c)).or_insert(next);
            if index.len() > MAX_COLOUR_MATERIALS {
                too_many = true;
                break;
            }
            group_of.push(g);
        }
        if too_many && bits > 3 {
            continue;
        }
        let mut sums = vec![[0f64; 4]; index.len()];
        for (c, &g) in colours.iter().zip(&group_of) {
            let s = &mut sums[g as usize];
            for a in 0..3 {
                s[a] += f64::from(c[a]);
            }
            s[3] += 1.0;
        }
        let means = sums
            .iter()
            .map(|s| [0, 1, 2].map(|a| (s[a] / s[3].max(1.0)) as f32))
            .collect();
        return (group_of, means);
    }
    unreachable!("3 bits per channel make at most 512 groups")
}

fn truncate(s: &str, chars: usize) -> String {
    s.chars().take(chars).collect()
}
