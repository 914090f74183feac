//! glTF 2.0 loading (`.gltf` with external or embedded buffers, `.glb`) into a world-space
//! [`Scene`]: meshes through the node hierarchy, materials, base-colour textures,
//! KHR_lights_punctual (candela and lux read 1:1 as W/sr and W/m²), perspective cameras and skinned
//! meshes in their rest pose. Features it does not use are listed in one warning.
//!
//! Untrusted input: every index and byte range is checked here; the `gltf` crate is known to
//! panic on some malformed input (URI decoding, its accessor reader), so the walk over the
//! document is additionally guarded and a panic becomes an error naming the file. Buffer and
//! image URIs are read only inside the model's folder and only from regular files; the files of
//! one model together, what their accessors and images decode to, and its triangles are bounded
//! by [`crate::limits`].

mod accessor;
mod animate;
mod material;
mod mesh;
mod tangents;

use crate::error::SceneError;
use crate::framing;
use crate::limits::{self, Budget};
use crate::model::{Camera, Light, LightShape, Material, Scene};
use crate::shading::normalize;
use accessor::Buffers;
use glam::{Mat4, Quat, Vec3};
pub(crate) use mesh::flat_shaded;
use std::collections::BTreeSet;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;

/// How a glTF is placed and completed.
#[derive(Debug, Clone, PartialEq)]
pub struct GltfOptions {
    /// Uniform scale applied at the root (e.g. 0.01 for a model in centimetres).
    pub scale: f32,
    /// Translation applied at the root after scaling.
    pub translation: [f32; 3],
    /// Add a framed camera when the file has none, and a ground plane and area light when it has
    /// no lights ([`crate::framing::complete`]).
    pub complete: bool,
    /// The animation to play (its name or index); `None`: the first, when there is one.
    pub animation: Option<String>,
}

impl Default for GltfOptions {
    fn default() -> Self {
        GltfOptions {
            scale: 1.0,
            translation: [0.0; 3],
            complete: true,
            animation: None,
        }
    }
}

/// A converted document before completion.
pub(crate) struct Imported {
    pub scene: Scene,
    pub has_camera: bool,
    /// The features it uses that are not rendered (also logged as one warning).
    pub ignored: Vec<String>,
}

/// The glTF features a model uses that lightfold does not render, as the loader's warning
/// lists them (empty when everything it uses is rendered).
pub fn ignored_features(path: &Path, opts: &GltfOptions) -> Result<Vec<String>, SceneError> {
    let label = path.display().to_string();
    let bytes = read_model(path)?;
    Ok(import(&bytes, &label, &label, Some(model_folder(path)), opts)?.ignored)
}

/// Loads a `.gltf` or `.glb` file with default options.
pub fn load_gltf(path: &Path) -> Result<Scene, SceneError> {
    load_gltf_with(path, &GltfOptions::default())
}

/// Loads a `.gltf` or `.glb` file.
pub fn load_gltf_with(path: &Path, opts: &GltfOptions) -> Result<Scene, SceneError> {
    let label = path.display().to_string();
    let bytes = read_model(path)?;
    let name = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "gltf".into());
    let imported = import(&bytes, &label, &name, Some(model_folder(path)), opts)?;
    finish(imported, &label, opts)
}

/// The bytes of a `.gltf` or `.glb` file: a regular file of at most
/// [`limits::MAX_SCENE_BYTES`].
pub(crate) fn read_model(path: &Path) -> Result<Vec<u8>, SceneError> {
    crate::input::read_bounded(path, limits::MAX_SCENE_BYTES).map_err(|message| SceneError::Io {
        path: path.display().to_string(),
        message,
    })
}

/// The folder a model's relative URIs are resolved in (`.` for a bare file name).
pub(crate) fn model_folder(path: &Path) -> &Path {
    path.parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

/// Loads glTF or GLB bytes; `label` names them in errors, `base` resolves relative URIs (which
/// must stay inside it); without `base` only embedded and data URIs are read.
pub fn load_gltf_slice(
    bytes: &[u8],
    label: &str,
    base: Option<&Path>,
    opts: &GltfOptions,
) -> Result<Scene, SceneError> {
    finish(import(bytes, label, label, base, opts)?, label, opts)
}

fn finish(mut imported: Imported, label: &str, opts: &GltfOptions) -> Result<Scene, SceneError> {
    if opts.complete {
        framing::complete(&mut imported.scene, imported.has_camera);
    }
    let report = imported.scene.sanitize();
    if !report.is_clean() {
        tracing::warn!(scene = %imported.scene.name, %report, "glTF geometry sanitised");
    }
    imported
        .scene
        .check_limits()
        .map_err(|e| SceneError::limit(label, e))?;
    Ok(imported.scene)
}

pub(crate) fn import(
    bytes: &[u8],
    label: &str,
    name: &str,
    base: Option<&Path>,
    opts: &GltfOptions,
) -> Result<Imported, SceneError> {
    let err = |message: String| SceneError::Gltf {
        path: label.to_string(),
        message,
    };
    if bytes.len() as u64 > limits::MAX_SCENE_BYTES {
        return Err(SceneError::limit(
            label,
            limits::LimitError::Bytes {
                what: "the model's files",
                bytes: bytes.len() as u64,
            },
        ));
    }
    let parsed = catch_unwind(|| parse(bytes))
        .map_err(|p| err(format!("the glTF parser panicked: {}", panic_text(&p))))?;
    let gltf = parsed.map_err(err)?;
    let walk = catch_unwind(AssertUnwindSafe(|| {
        let files = Budget::new("the model's files");
        files.take(bytes.len() as u64).map_err(|e| e.to_string())?;
        convert(
            &gltf.document,
            gltf.blob.as_deref(),
            name,
            base,
            files,
            opts,
        )
    }));
    match walk {
        Ok(r) => r.map_err(err),
        Err(p) => Err(err(format!("the glTF walk panicked: {}", panic_text(&p)))),
    }
}

/// Parses and validates a glTF or GLB. Found by fuzzing, the `gltf` crate panics where its
/// validation does not look: it indexes the accessor a primitive's POSITION names without a
/// bounds check, `Image::source` unwraps an image's `uri`, or a buffer-view image's `mimeType`,
/// when they are missing, and an animation channel's target node and sampler are unwrapped
/// unchecked. All are checked here first.
fn parse(bytes: &[u8]) -> Result<gltf::Gltf, String> {
    let raw = gltf::Gltf::from_slice_without_validation(bytes).map_err(|e| describe(&e))?;
    let root = raw.document.as_json();
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            for index in prim.attributes.values() {
                if index.value() >= root.accessors.len() {
                    return Err(format!(
                        "mesh {m} primitive {p} names accessor {} but the file has {}",
                        index.value(),
                        root.accessors.len()
                    ));
                }
            }
        }
    }
    // Animation channels index their samplers and target nodes, samplers their accessors,
    // unchecked by the crate (`Channel::target().node()` unwraps).
    for (a, anim) in root.animations.iter().enumerate() {
        for (c, ch) in anim.channels.iter().enumerate() {
            let (sampler, node) = (ch.sampler.value(), ch.target.node.value());
            if sampler >= anim.samplers.len() {
                return Err(format!(
                    "animation {a} channel {c} names sampler {sampler} but the animation has {}",
                    anim.samplers.len()
                ));
            }
            if node >= root.nodes.len() {
                return Err(format!(
                    "animation {a} channel {c} targets node {node} but the file has {}",
                    root.nodes.len()
                ));
            }
        }
        for (k, sampler) in anim.samplers.iter().enumerate() {
            for index in [sampler.input.value(), sampler.output.value()] {
                if index >= root.accessors.len() {
                    return Err(format!(
                        "animation {a} sampler {k} names accessor {index} but the file has {}",
                        root.accessors.len()
                    ));
                }
            }
        }
    }
    for (i, image) in root.images.iter().enumerate() {
        match (&image.buffer_view, &image.uri) {
            (Some(_), _) if image.mime_type.is_none() => {
                return Err(format!(
                    "image {i} is stored in a buffer view but has no mimeType"
                ));
            }
            (None, None) => return Err(format!("image {i} has neither a uri nor a bufferView")),
            _ => {}
        }
    }
    let document = gltf::Document::from_json(raw.document.into_json()).map_err(|e| describe(&e))?;
    Ok(gltf::Gltf {
        document,
        blob: raw.blob,
    })
}

fn panic_text(p: &Box<dyn std::any::Any + Send>) -> String {
    p.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".into())
}

fn describe(e: &gltf::Error) -> String {
    match e {
        gltf::Error::Validation(list) => {
            let items: Vec<String> = list
                .iter()
                .take(8)
                .map(|(path, err)| format!("{path}: {err}"))
                .collect();
            format!("validation failed: {}", items.join("; "))
        }
        gltf::Error::Binary(b) => format!("truncated or malformed GLB container: {b}"),
        gltf::Error::Deserialize(j) => format!("malformed JSON: {j}"),
        other => other.to_string(),
    }
}

fn convert(
    doc: &gltf::Document,
    blob: Option<&[u8]>,
    name: &str,
    base: Option<&Path>,
    files: Budget,
    opts: &GltfOptions,
) -> Result<Imported, String> {
    let mut ignored = BTreeSet::new();
    let bufs = load_buffers(doc, blob, base, files)?;
    let root = Mat4::from_scale_rotation_translation(
        Vec3::splat(opts.scale),
        Quat::IDENTITY,
        Vec3::from(opts.translation),
    );
    let world = world_matrices(doc, root)?;

    let mut scene = Scene::new(name);
    let mut loader = material::MaterialLoader::new(&bufs, base, &mut ignored);
    for m in doc.materials() {
        let converted = loader.convert(&m)?;
        scene.materials.push(converted);
    }
    scene.textures = std::mem::take(&mut loader.textures);
    let mut default_material = None;
    let mut has_camera = false;

    let clip = animate::choose(doc, opts.animation.as_deref())?;
    let mut mesh_rigs = Vec::new();
    let mut light_rigs = Vec::new();
    let mut ctx = mesh::NodeContext {
        bufs: &bufs,
        world: &world,
        ignored: &mut ignored,
        triangles: 0,
        rig: clip.is_some(),
    };
    for node in scene_nodes(doc)? {
        let w = world[node.index()];
        if let Some(m) = node.mesh() {
            let mut pick = |i: Option<usize>| match i {
                Some(i) => i,
                None => *default_material.get_or_insert_with(|| {
                    scene.materials.push(Material::diffuse("default", [0.8; 3]));
                    scene.materials.len() - 1
                }),
            };
            for (mesh, rig) in mesh::node_meshes(&node, &m, &mut ctx, &mut pick)? {
                if let Some(mut rig) = rig {
                    rig.mesh = scene.meshes.len() as u32;
                    mesh_rigs.push(rig);
                }
                scene.meshes.push(mesh);
            }
        }
        if let Some(light) = node.light() {
            if clip.is_some() {
                light_rigs.push((scene.lights.len() as u32, node.index(), w));
            }
            scene.lights.push(convert_light(&light, &w));
        }
        if let Some(cam) = node.camera() {
            match cam.projection() {
                gltf::camera::Projection::Perspective(p) if !has_camera => {
                    scene.camera = convert_camera(&p, &w, &scene.camera);
                    has_camera = true;
                }
                gltf::camera::Projection::Perspective(_) => {
                    ctx.ignored.insert("cameras after the first".into());
                }
                gltf::camera::Projection::Orthographic(_) => {
                    ctx.ignored.insert("orthographic cameras".into());
                }
            }
        }
    }
    if let Some(clip) = &clip {
        if doc.animations().len() > 1 {
            ignored.insert(format!(
                "animations other than {:?} (choose with `animation`)",
                clip.name().unwrap_or("the first")
            ));
        }
        let anim = animate::build(doc, clip, &bufs, root, mesh_rigs, light_rigs)?;
        let vertices: Vec<usize> = scene.meshes.iter().map(|m| m.positions.len()).collect();
        anim.check(&vertices, scene.lights.len())
            .map_err(|e| format!("animation {:?}: {e}", anim.name))?;
        scene.animation = Some(anim);
    }
    if doc.scenes().len() > 1 {
        ignored.insert("scenes other than the default".into());
    }
    for ext in doc.extensions_used() {
        if !matches!(
            ext,
            "KHR_lights_punctual"
                | "KHR_materials_emissive_strength"
                | "KHR_materials_transmission"
        ) {
            ignored.insert(format!("extension {ext}"));
        }
    }
    let ignored: Vec<String> = ignored.into_iter().collect();
    if !ignored.is_empty() {
        tracing::warn!(scene = name, ignored = %ignored.join(", "), "glTF features ignored");
    }
    Ok(Imported {
        scene,
        has_camera,
        ignored,
    })
}

fn load_buffers(
    doc: &gltf::Document,
    blob: Option<&[u8]>,
    base: Option<&Path>,
    files: Budget,
) -> Result<Buffers, String> {
    let decoded = Budget::new("the model's decoded buffers, accessors and images");
    let mut data = Vec::new();
    let mut blob_copies = 0;
    for b in doc.buffers() {
        let bytes = match b.source() {
            gltf::buffer::Source::Bin => {
                let blob = blob.ok_or_else(|| {
                    format!(
                        "buffer {} refers to a GLB binary chunk the file lacks",
                        b.index()
                    )
                })?;
                // The first copy is the file's own bytes again; any further one is new memory.
                blob_copies += 1;
                if blob_copies > 1 {
                    decoded
                        .take(blob.len() as u64)
                        .map_err(|e| format!("buffer {}: {e}", b.index()))?;
                }
                blob.to_vec()
            }
            gltf::buffer::Source::Uri(uri) => material::read_uri(uri, base, &files)
                .map_err(|e| format!("buffer {} ({uri}): {e}", b.index()))?,
        };
        if bytes.len() < b.length() {
            return Err(format!(
                "buffer {} holds {} bytes but declares {}",
                b.index(),
                bytes.len(),
                b.length()
            ));
        }
        data.push(bytes);
    }
    Ok(Buffers {
        data,
        files,
        decoded,
    })
}

/// World matrix of every node: `root · parent chain · local`. Rejects nodes with two parents and
/// cycles (which would otherwise recurse forever).
fn world_matrices(doc: &gltf::Document, root: Mat4) -> Result<Vec<Mat4>, String> {
    let n = doc.nodes().len();
    let mut parent = vec![None; n];
    for node in doc.nodes() {
        for child in node.children() {
            let c = child.index();
            if parent[c].is_some() || c == node.index() {
                return Err(format!(
                    "node {c} has more than one parent or is its own child"
                ));
            }
            parent[c] = Some(node.index());
        }
    }
    let local: Vec<Mat4> = doc
        .nodes()
        .map(|nd| Mat4::from_cols_array_2d(&nd.transform().matrix()))
        .collect();
    let mut world: Vec<Option<Mat4>> = vec![None; n];
    for start in 0..n {
        let mut chain = vec![start];
        let mut at = start;
        while world[at].is_none() {
            match parent[at] {
                Some(p) => {
                    if chain.len() > n {
                        return Err(format!("node hierarchy has a cycle through node {start}"));
                    }
                    chain.push(p);
                    at = p;
                }
                None => break,
            }
        }
        let mut acc = match world[at] {
            Some(w) => {
                chain.pop();
                w
            }
            None => root,
        };
        while let Some(k) = chain.pop() {
            acc *= local[k];
            world[k] = Some(acc);
        }
    }
    Ok(world.into_iter().map(|w| w.unwrap_or(root)).collect())
}

/// Nodes of the default scene (or the first; or every root node when there are no scenes), each
/// once, parents before children.
fn scene_nodes(doc: &gltf::Document) -> Result<Vec<gltf::Node<'_>>, String> {
    let roots: Vec<gltf::Node> = match doc.default_scene().or_else(|| doc.scenes().next()) {
        Some(s) => s.nodes().collect(),
        None => {
            let mut child = vec![false; doc.nodes().len()];
            for nd in doc.nodes() {
                for c in nd.children() {
                    child[c.index()] = true;
                }
            }
            doc.nodes().filter(|nd| !child[nd.index()]).collect()
        }
    };
    let mut seen = vec![false; doc.nodes().len()];
    let mut out = Vec::new();
    let mut stack: Vec<gltf::Node> = roots.into_iter().rev().collect();
    while let Some(nd) = stack.pop() {
        if std::mem::replace(&mut seen[nd.index()], true) {
            return Err(format!(
                "node {} is reached twice from the scene",
                nd.index()
            ));
        }
        let children: Vec<gltf::Node> = nd.children().collect();
        stack.extend(children.into_iter().rev());
        out.push(nd);
    }
    Ok(out)
}

fn convert_light(l: &gltf::khr_lights_punctual::Light, w: &Mat4) -> Light {
    let position = w.transform_point3(Vec3::ZERO).to_array();
    let direction = normalize(w.transform_vector3(Vec3::NEG_Z).to_array());
    let shape = match l.kind() {
        gltf::khr_lights_punctual::Kind::Point => LightShape::Point { position },
        gltf::khr_lights_punctual::Kind::Directional => LightShape::Directional {
            direction,
            angle: 0.0,
        },
        gltf::khr_lights_punctual::Kind::Spot {
            inner_cone_angle,
            outer_cone_angle,
        } => LightShape::Spot {
            position,
            direction,
            inner_angle: inner_cone_angle,
            outer_angle: outer_cone_angle,
        },
    };
    Light {
        name: l.name().unwrap_or("light").to_string(),
        shape,
        color: l.color(),
        power: l.intensity(),
        range: l.range(),
        samples: 1,
    }
}

fn convert_camera(p: &gltf::camera::Perspective, w: &Mat4, current: &Camera) -> Camera {
    let position = w.transform_point3(Vec3::ZERO);
    let forward = w.transform_vector3(Vec3::NEG_Z).normalize_or_zero();
    let up = w.transform_vector3(Vec3::Y).normalize_or_zero();
    let width = current.width;
    let height = match p.aspect_ratio() {
        Some(a) if a.is_finite() && a > 0.0 => ((width as f32 / a).round() as u32).max(1),
        _ => current.height,
    };
    Camera {
        position: position.to_array(),
        target: (position + forward).to_array(),
        up: up.to_array(),
        fov_y_deg: p.yfov().to_degrees(),
        width,
        height,
    }
}
