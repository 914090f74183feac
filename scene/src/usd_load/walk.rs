//! The walk over a composed stage: each prim's world transform (its `xformOpOrder` stack over
//! its parent's), visibility and purpose, and the prim types that become meshes, lights and the
//! camera; the typed reads of attribute values the converters share.

use super::resolve::{Confined, Shared};
use crate::limits::{self, LimitError};
use crate::model::Scene;
use crate::model_file::ModelOptions;
use glam::{DMat4, DVec3};
use openusd::schemas::geom::{Imageable, Xformable};
use openusd::sdf::{self, Value};
use openusd::usd::{Prim, PrimPredicate, SchemaBase, SchemaKind, Stage, TimeCode};
use std::collections::{BTreeSet, HashMap};
use std::rc::Rc;

/// Most prims one stage may compose (instance proxies included). Nested references compose
/// exponentially many prims from a few bytes, and the crate's composition keeps about 20 kB per
/// prim of such a stage: at this limit a 2 kB stage of eight levels of eight references took
/// 15 s and 1.5 GB before it was refused (unbounded, it grew to 22 GB and was killed).
pub const MAX_PRIMS: u64 = 1 << 16;

pub(super) enum Error {
    Usd(String),
    Limit(LimitError),
}

/// `?` on the crate's results: the error with its causes, after `what`.
pub(super) trait At<T> {
    fn at(self, what: &dyn std::fmt::Display) -> Result<T, Error>;
}

impl<T, E: std::fmt::Display> At<T> for Result<T, E> {
    fn at(self, what: &dyn std::fmt::Display) -> Result<T, Error> {
        self.map_err(|e| Error::Usd(format!("{what}: {e:#}")))
    }
}

/// Any prim, seen as transformable (its `xformOp` stack, visibility, purpose).
pub(super) struct AnyPrim(pub Prim);

impl SchemaBase for AnyPrim {
    const KIND: SchemaKind = SchemaKind::ConcreteTyped;
    fn prim(&self) -> &Prim {
        &self.0
    }
}
impl Imageable for AnyPrim {}
impl Xformable for AnyPrim {}

/// What the converters build and share while the stage is walked.
pub(super) struct Reader<'a> {
    pub time: TimeCode,
    pub ignored: &'a mut BTreeSet<String>,
    pub scene: Scene,
    /// Material index by bound material (or display colour) and sidedness.
    pub materials: HashMap<(String, bool), usize>,
    pub points: u64,
    pub triangles: u64,
    pub has_camera: bool,
    pub emissive_meshes: Vec<usize>,
    pub stage: &'a Stage,
    /// The stage's time codes, for time-sampled transforms (`super::motion`).
    pub clock: Clock,
    /// What time-sampled transforms animate, once one does.
    pub motion: Option<crate::animation::Animation>,
    /// Local transforms evaluated for animation so far (bounded).
    pub evaluations: u64,
}

/// The stage's time codes: its start and end, and how many make a second.
pub(super) struct Clock {
    pub start: f64,
    pub end: f64,
    pub per_second: f64,
}

pub(super) fn convert(
    shared: Rc<Shared>,
    name: &str,
    opts: &ModelOptions,
    ignored: &mut BTreeSet<String>,
) -> Result<(Scene, bool), Error> {
    let root_id = shared.root_id.clone();
    let stage = Stage::builder()
        .resolver(Confined(shared))
        .open(&root_id)
        .at(&"cannot open the stage")?;
    composition_errors(&stage)?;
    let authored = stage.has_authored_time_code_range();
    let time = if authored {
        TimeCode::new(stage.start_time_code())
    } else {
        TimeCode::EARLIEST
    };
    let per_second = stage.time_codes_per_second();
    let clock = Clock {
        start: if authored {
            stage.start_time_code()
        } else {
            f64::NEG_INFINITY
        },
        end: if authored {
            stage.end_time_code()
        } else {
            f64::INFINITY
        },
        per_second: if per_second.is_finite() && per_second > 0.0 {
            per_second
        } else {
            24.0
        },
    };
    let root = root_frame(&stage, opts)?;
    let mut r = Reader {
        time,
        ignored,
        scene: Scene::new(name),
        materials: HashMap::new(),
        points: 0,
        triangles: 0,
        has_camera: false,
        emissive_meshes: Vec::new(),
        stage: &stage,
        clock,
        motion: None,
        evaluations: 0,
    };
    // Depth first, each prim with its parent's world transform, as `Stage::traverse` walks with
    // instance proxies (active, loaded, defined, not abstract), but counted as it goes: nested
    // references can compose exponentially many prims from a few bytes.
    let mut stack = vec![(sdf::Path::abs_root(), root, Rc::new(Vec::new()))];
    let mut walked = 0u64;
    while let Some((path, frame, times)) = stack.pop() {
        let (frame, times) = if path == sdf::Path::abs_root() {
            (frame, times)
        } else {
            walked += 1;
            super::count("prims", walked, MAX_PRIMS)?;
            let status = stage.prim_status(path.clone()).at(&path)?;
            if !PrimPredicate::DEFAULT.matches(status) {
                continue;
            }
            match visit(&mut r, &path, frame, &times, root)? {
                Some(next) => next,
                None => continue,
            }
        };
        let names = stage.prim(path.clone()).child_names().at(&path)?;
        // The crate loops forever over a path with a malformed name (found by fuzzing).
        if let Some(bad) = names.iter().find(|n| !is_identifier(n.as_str())) {
            return Err(Error::Usd(format!(
                "a prim under {} is named {:?}, which is not an identifier",
                truncate(path.as_str(), 200),
                truncate(bad.as_str(), 64)
            )));
        }
        for name in names.iter().rev() {
            if let Ok(child) = path.append_path(name.as_str()) {
                stack.push((child, frame, Rc::clone(&times)));
            }
        }
    }
    if let Some(mut anim) = r.motion.take() {
        // A mesh light's samples lie on its mesh, and lights move rigidly with nodes only:
        // an emissive mesh stays where it is at the start.
        let before = anim.meshes.len();
        anim.meshes
            .retain(|m| !r.emissive_meshes.contains(&(m.mesh as usize)));
        if anim.meshes.len() < before {
            r.ignored
                .insert("time-sampled transforms of emissive meshes (held at the start)".into());
        }
        r.scene.animation = Some(anim);
    }
    crate::obj_load::add_emissive_lights(&mut r.scene, &r.emissive_meshes);
    composition_errors(&stage)?;
    Ok((r.scene, r.has_camera))
}

/// A prim's world transform at the start, and the time codes it is sampled at (ascending).
type Placed = (DMat4, Rc<Vec<f64>>);

/// Converts the prim at `path` under its parent's world transform (and the time codes its
/// parent's world transform is sampled at); its own world transform and time codes, or `None`
/// when it and its subtree are not rendered.
fn visit(
    r: &mut Reader,
    path: &sdf::Path,
    parent: DMat4,
    parent_times: &Rc<Vec<f64>>,
    root: DMat4,
) -> Result<Option<Placed>, Error> {
    let prim = r.stage.prim(path.clone());
    let type_name = prim
        .type_name()
        .at(path)?
        .map(|t| t.as_str().to_string())
        .unwrap_or_default();
    if token(&prim, "visibility", r.time)?.as_deref() == Some("invisible")
        || matches!(
            token(&prim, "purpose", r.time)?.as_deref(),
            Some("guide" | "proxy")
        )
    {
        return Ok(None);
    }
    let x = AnyPrim(prim.clone());
    let order = x.xform_op_order().at(path)?.unwrap_or_default();
    // Checked before the crate composes the stack: it hangs on a property name that is not one
    // (an unterminated string in the file makes one; found by fuzzing).
    if let Some(bad) = order.iter().find(|op| !is_op_name(op)) {
        return Err(Error::Usd(format!(
            "{}: xformOpOrder names {:?}, which is not an xformOp",
            truncate(path.as_str(), 200),
            truncate(bad, 64)
        )));
    }
    let local = x.local_to_parent_transform(r.time).at(path)?;
    let resets = x.resets_xform_stack().at(path)?;
    let above = if resets { root } else { parent };
    // The time codes this prim's world transform is sampled at: its own ops' and, unless it
    // resets the stack, its parent's.
    let mut own = Vec::new();
    for op in order.iter().take(64) {
        let op = op.strip_prefix("!invert!").unwrap_or(op);
        let attribute = prim.attribute(op);
        if op.starts_with("xformOp:") && attribute.num_time_samples().at(path)? > 1 {
            let span = r.clock.start..=r.clock.end;
            own.extend(attribute.time_samples_in_interval(span).at(path)?);
        }
    }
    let times = if own.is_empty() && !resets {
        Rc::clone(parent_times)
    } else {
        let inherited: &[f64] = if resets { &[] } else { parent_times };
        Rc::new(super::motion::merge(inherited, &own, r.ignored))
    };
    let world = above * DMat4::from_cols_array(&local.0);
    let (meshes, lights) = (r.scene.meshes.len(), r.scene.lights.len());
    match type_name.as_str() {
        "Mesh" => super::mesh::read(r, &prim, world)?,
        "Camera" => super::light::camera(r, &prim, world)?,
        "RectLight" | "DiskLight" | "SphereLight" | "CylinderLight" | "DistantLight" => {
            super::light::light(r, &prim, &type_name, world)?
        }
        "DomeLight" | "DomeLight_1" => {
            r.ignored.insert("DomeLight (environment light)".into());
        }
        "" | "Xform" | "Scope" | "Material" | "Shader" | "NodeGraph" | "SkelRoot" => {}
        "GeomSubset" => {
            r.ignored
                .insert("GeomSubset (per-face materials: a mesh's own material is used)".into());
        }
        t => {
            r.ignored.insert(format!("{} prims", truncate(t, 32)));
        }
    }
    let read = (meshes..r.scene.meshes.len(), lights..r.scene.lights.len());
    if times.len() >= 2 && (!read.0.is_empty() || !read.1.is_empty()) {
        super::motion::animate(r, path, &times, world, root, read.0, read.1)?;
    }
    Ok(Some((world, times)))
}

/// Whether `name` is a USD identifier: a letter (Unicode, as USD 24 allows) or `_`, then letters,
/// digits or `_`.
pub(super) fn is_identifier(name: &str) -> bool {
    name.chars()
        .next()
        .is_some_and(|c| c.is_alphabetic() || c == '_')
        && name.chars().all(|c| c.is_alphanumeric() || c == '_')
}

/// Whether an `xformOpOrder` entry names an op: `!resetXformStack!`, or `xformOp:` and a
/// namespaced identifier, optionally after `!invert!`.
fn is_op_name(op: &str) -> bool {
    if op == "!resetXformStack!" {
        return true;
    }
    let op = op.strip_prefix("!invert!").unwrap_or(op);
    op.strip_prefix("xformOp:").is_some_and(|rest| {
        !rest.is_empty()
            && rest.split(':').all(|part| {
                part.chars()
                    .next()
                    .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
                    && part.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
            })
    })
}

/// The stage's units and up axis under the placement `opts` asks for: positions in metres,
/// Y up (a Z-up stage is turned −90° about X).
fn root_frame(stage: &Stage, opts: &ModelOptions) -> Result<DMat4, Error> {
    let meters = match stage.stage_metadata("metersPerUnit").at(&"metersPerUnit")? {
        Some(v) => number(&v).filter(|m| m.is_finite() && *m > 0.0),
        None => None,
    }
    .unwrap_or(1.0);
    let up = match stage.stage_metadata("upAxis").at(&"upAxis")? {
        Some(Value::Token(t)) => t.as_str().to_string(),
        Some(Value::String(s)) => s,
        _ => "Y".into(),
    };
    let turn = if up == "Z" {
        DMat4::from_rotation_x(-std::f64::consts::FRAC_PI_2)
    } else {
        DMat4::IDENTITY
    };
    Ok(
        DMat4::from_translation(DVec3::from(opts.translation.map(f64::from)))
            * DMat4::from_scale(DVec3::splat(f64::from(opts.scale) * meters))
            * turn,
    )
}

fn composition_errors(stage: &Stage) -> Result<(), Error> {
    let errors = stage.composition_errors();
    match errors.first() {
        None => Ok(()),
        Some(first) if errors.len() == 1 => Err(Error::Usd(format!("composition error: {first}"))),
        Some(first) => Err(Error::Usd(format!(
            "composition error: {first} (and {} more)",
            errors.len() - 1
        ))),
    }
}

pub(super) fn truncate(s: &str, chars: usize) -> String {
    if s.chars().count() <= chars {
        s.to_string()
    } else {
        format!("{}…", s.chars().take(chars).collect::<String>())
    }
}

/// The value of attribute `name` at `time` (its default when it has no samples).
pub(super) fn value(prim: &Prim, name: &str, time: TimeCode) -> Result<Option<Value>, Error> {
    prim.attribute(name)
        .get_at::<Value>(time)
        .at(&format_args!("{}.{name}", prim.path().as_str()))
}

fn wrong(prim: &Prim, name: &str, expected: &str) -> Error {
    Error::Usd(format!(
        "{}.{name} is not {expected}",
        truncate(prim.path().as_str(), 200)
    ))
}

fn number(v: &Value) -> Option<f64> {
    Some(match v {
        Value::Float(x) => f64::from(*x),
        Value::Double(x) => *x,
        Value::Half(x) => f64::from(x.to_f32()),
        Value::Int(x) => f64::from(*x),
        Value::Uint(x) => f64::from(*x),
        Value::Int64(x) => *x as f64,
        _ => return None,
    })
}

/// A number (float, double, half or integer).
pub(super) fn scalar(prim: &Prim, name: &str, time: TimeCode) -> Result<Option<f64>, Error> {
    match value(prim, name, time)? {
        None => Ok(None),
        Some(v) => number(&v)
            .map(Some)
            .ok_or_else(|| wrong(prim, name, "a number")),
    }
}

pub(super) fn boolean(prim: &Prim, name: &str, time: TimeCode) -> Result<Option<bool>, Error> {
    match value(prim, name, time)? {
        None => Ok(None),
        Some(Value::Bool(b)) => Ok(Some(b)),
        Some(v) => number(&v)
            .map(|x| Some(x != 0.0))
            .ok_or_else(|| wrong(prim, name, "a bool")),
    }
}

pub(super) fn token(prim: &Prim, name: &str, time: TimeCode) -> Result<Option<String>, Error> {
    match value(prim, name, time)? {
        None => Ok(None),
        Some(Value::Token(t)) => Ok(Some(t.as_str().to_string())),
        Some(Value::String(s)) => Ok(Some(s)),
        Some(_) => Err(wrong(prim, name, "a token")),
    }
}

/// A 3-vector (or colour); the first element of an array of them (`primvars:displayColor`).
pub(super) fn vec3(prim: &Prim, name: &str, time: TimeCode) -> Result<Option<[f32; 3]>, Error> {
    let v = match value(prim, name, time)? {
        None => return Ok(None),
        Some(v) => v,
    };
    let first = match &v {
        Value::Vec3f(a) => Some([a.x, a.y, a.z]),
        Value::Vec3d(a) => Some([a.x as f32, a.y as f32, a.z as f32]),
        Value::Vec3h(a) => Some([a.x.to_f32(), a.y.to_f32(), a.z.to_f32()]),
        Value::Vec3fVec(_) | Value::Vec3dVec(_) | Value::Vec3hVec(_) => {
            return Ok(vec3s(v, prim, name)?.first().copied());
        }
        _ => None,
    };
    first
        .map(Some)
        .ok_or_else(|| wrong(prim, name, "a 3-vector"))
}

fn vec3s(v: Value, prim: &Prim, name: &str) -> Result<Vec<[f32; 3]>, Error> {
    Ok(match v {
        Value::Vec3fVec(a) => a.into_iter().map(|a| [a.x, a.y, a.z]).collect(),
        Value::Vec3dVec(a) => a
            .into_iter()
            .map(|a| [a.x as f32, a.y as f32, a.z as f32])
            .collect(),
        Value::Vec3hVec(a) => a
            .into_iter()
            .map(|a| [a.x.to_f32(), a.y.to_f32(), a.z.to_f32()])
            .collect(),
        _ => return Err(wrong(prim, name, "an array of 3-vectors")),
    })
}

/// An array of 3-vectors (points, normals).
pub(super) fn vec3_array(
    prim: &Prim,
    name: &str,
    time: TimeCode,
) -> Result<Option<Vec<[f32; 3]>>, Error> {
    value(prim, name, time)?
        .map(|v| vec3s(v, prim, name))
        .transpose()
}

/// An array of 2-vectors (texture coordinates).
pub(super) fn vec2_array(
    prim: &Prim,
    name: &str,
    time: TimeCode,
) -> Result<Option<Vec<[f32; 2]>>, Error> {
    Ok(Some(match value(prim, name, time)? {
        None => return Ok(None),
        Some(Value::Vec2fVec(a)) => a.into_iter().map(|a| [a.x, a.y]).collect(),
        Some(Value::Vec2dVec(a)) => a.into_iter().map(|a| [a.x as f32, a.y as f32]).collect(),
        Some(Value::Vec2hVec(a)) => a
            .into_iter()
            .map(|a| [a.x.to_f32(), a.y.to_f32()])
            .collect(),
        Some(_) => return Err(wrong(prim, name, "an array of 2-vectors")),
    }))
}

/// An array of integers (face counts, indices).
pub(super) fn int_array(
    prim: &Prim,
    name: &str,
    time: TimeCode,
) -> Result<Option<Vec<i64>>, Error> {
    Ok(Some(match value(prim, name, time)? {
        None => return Ok(None),
        Some(Value::IntVec(a)) => a.into_iter().map(i64::from).collect(),
        Some(Value::UintVec(a)) => a.into_iter().map(i64::from).collect(),
        Some(Value::Int64Vec(a)) => a,
        Some(_) => return Err(wrong(prim, name, "an array of integers")),
    }))
}

/// A primvar's `interpolation` metadata (`vertex`, `faceVarying`, `uniform`, `constant`).
pub(super) fn interpolation(prim: &Prim, name: &str) -> Result<Option<String>, Error> {
    Ok(
        match prim
            .attribute(name)
            .get_metadata::<Value>("interpolation")
            .at(&format_args!("{}.{name}", prim.path().as_str()))?
        {
            Some(Value::Token(t)) => Some(t.as_str().to_string()),
            Some(Value::String(s)) => Some(s),
            _ => None,
        },
    )
}

/// Checks the running triangle count after a mesh adds `more`.
pub(super) fn add_triangles(r: &mut Reader, more: u64) -> Result<(), Error> {
    r.triangles += more;
    limits::check_triangles(r.triangles).map_err(Error::Limit)
}
