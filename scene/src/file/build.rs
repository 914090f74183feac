//! Building a [`Scene`] from a parsed scene file: the model (glTF, OBJ, PLY or USD; if any), primitive objects with
//! their materials, lights, camera, ambient, exposure and quality; then completion of whatever is
//! missing (camera, lights) exactly as for a bare glTF.

use super::spec::{
    CameraSpec, FilterSpec, LightSpec, ObjectSpec, PatternSpec, SceneFile, SizingSpec, SizingWord,
};
use crate::error::SceneError;
use crate::framing;
use crate::gltf_load::{self, GltfOptions};
use crate::model::{
    Camera, Light, LightShape, MapSizing, Material, Mesh, Quality, SamplePattern, Scene,
    ShadowFilter,
};
use crate::model_file::ModelOptions;
use crate::primitives;
use crate::shadow_views::Mismatch;
use glam::{Affine3A, Quat, Vec3};
use std::collections::HashMap;
use std::path::Path;

/// Builds the scene of a parsed scene file labelled `label`, reading its model inside the folder
/// `base`, and completes whatever the file leaves out.
pub(super) fn build(
    file: &SceneFile,
    label: &str,
    base: Option<&Path>,
) -> Result<Scene, SceneError> {
    let err = |m: String| file_error(label, m);
    let name = scene_name(file, label);
    check_one_model(file).map_err(err)?;
    let (mut scene, gltf_camera) = load_model(file, label, base, &name)?;
    if file.name.is_some() || file.base.is_none() {
        scene.name = name;
    }
    let by_name = add_materials(file, &mut scene).map_err(err)?;
    let mut objects = add_objects(file, label, &mut scene, &by_name)?;
    if file.base.is_some() {
        name_base_meshes(&scene, &mut objects);
        if !file.lights.is_empty() {
            // The file's lights are the scene's: they replace the base's.
            scene.lights.clear();
        }
    }
    for (i, l) in file.lights.iter().enumerate() {
        let light = light(l, i, &mut scene, &objects).map_err(err)?;
        scene.lights.push(light);
    }
    crate::animation::apply_motions(&mut scene, &file.motions, &objects).map_err(err)?;
    crate::moves::check(&scene, &file.moves).map_err(err)?;
    scene.apply_moves(&file.moves);
    apply_settings(file, &mut scene);
    let has_camera = file.camera.is_some() || gltf_camera;
    framing::complete_with(&mut scene, has_camera, file.objects.is_empty());
    let report = scene.sanitize();
    if !report.is_clean() {
        tracing::warn!(file = label, %report, "scene sanitised");
    }
    Ok(scene)
}

/// Wraps a message about the scene file `label` in a [`SceneError::SceneFile`].
fn file_error(label: &str, message: String) -> SceneError {
    SceneError::SceneFile {
        path: label.to_string(),
        message,
    }
}

/// Returns the scene's name: the file's `name`, else the stem of its label, else "scene".
fn scene_name(file: &SceneFile, label: &str) -> String {
    file.name.clone().unwrap_or_else(|| {
        Path::new(label)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "scene".into())
    })
}

/// Refuses a file that names more than one model or base table.
fn check_one_model(file: &SceneFile) -> Result<(), String> {
    let models = [
        file.base.as_ref().map(|_| "[base]"),
        file.gltf.as_ref().map(|_| "[gltf]"),
        file.obj.as_ref().map(|_| "[obj]"),
        file.ply.as_ref().map(|_| "[ply]"),
        file.usd.as_ref().map(|_| "[usd]"),
    ];
    let named: Vec<&str> = models.into_iter().flatten().collect();
    if named.len() > 1 {
        return Err(format!(
            "a scene file takes one model or base ([base], [gltf], [obj], [ply] or [usd]); this one has {}",
            named.join(" and ")
        ));
    }
    Ok(())
}

/// Loads the file's base or model, or starts an empty scene named `name`; the flag says whether
/// the loaded scene brought its own camera.
fn load_model(
    file: &SceneFile,
    label: &str,
    base: Option<&Path>,
    name: &str,
) -> Result<(Scene, bool), SceneError> {
    // A model's path, read only inside the scene file's folder.
    let model_path = |table: &str, relative: &str| {
        let folder = base.unwrap_or(Path::new("."));
        crate::input::resolve_inside(folder, relative, "the scene file's").map_err(|e| match e.io {
            Some(path) => SceneError::Io {
                path: path.display().to_string(),
                message: e.message,
            },
            None => file_error(label, format!("{table}.path: {}", e.message)),
        })
    };
    let placed = |scale: f32, translation: [f32; 3]| ModelOptions {
        scale,
        translation,
        complete: false,
        ..ModelOptions::default()
    };
    Ok(if let Some(b) = &file.base {
        (load_base(&b.scene, base, label)?, true)
    } else if let Some(g) = &file.gltf {
        let path = model_path("gltf", &g.path)?;
        let bytes = gltf_load::read_model(&path)?;
        let opts = GltfOptions {
            scale: g.scale,
            translation: g.translation,
            complete: false,
            animation: g.animation.clone(),
        };
        let label = path.display().to_string();
        let imported = gltf_load::import(
            &bytes,
            &label,
            name,
            Some(gltf_load::model_folder(&path)),
            &opts,
        )?;
        (imported.scene, imported.has_camera)
    } else if let Some(o) = &file.obj {
        let path = model_path("obj", &o.path)?;
        let bytes = gltf_load::read_model(&path)?;
        let label = path.display().to_string();
        let imported = crate::obj_load::import(
            &bytes,
            &label,
            name,
            Some(gltf_load::model_folder(&path)),
            &placed(o.scale, o.translation),
        )?;
        (imported.scene, false)
    } else if let Some(p) = &file.ply {
        let path = model_path("ply", &p.path)?;
        let bytes = gltf_load::read_model(&path)?;
        let label = path.display().to_string();
        let imported =
            crate::ply_load::import(&bytes, &label, name, &placed(p.scale, p.translation))?;
        (imported.scene, false)
    } else if let Some(u) = &file.usd {
        let path = model_path("usd", &u.path)?;
        let bytes = gltf_load::read_model(&path)?;
        let label = path.display().to_string();
        let imported = crate::usd_load::import(
            &bytes,
            &label,
            name,
            Some(gltf_load::model_folder(&path)),
            &placed(u.scale, u.translation),
        )?;
        (imported.scene, imported.has_camera)
    } else {
        (Scene::new(name), false)
    })
}

/// Adds the file's materials to the scene and returns their indices by name; a name defined
/// twice is an error.
fn add_materials<'a>(
    file: &'a SceneFile,
    scene: &mut Scene,
) -> Result<HashMap<&'a str, usize>, String> {
    let mut by_name: HashMap<&str, usize> = HashMap::new();
    for m in &file.materials {
        if by_name.contains_key(m.name.as_str()) {
            return Err(format!("material {:?} is defined twice", m.name));
        }
        let k = scene.add_material(Material {
            name: m.name.clone(),
            diffuse: m.diffuse,
            diffuse_texture: None,
            specular: m.specular,
            shininess: m.shininess,
            ambient: m.ambient,
            emissive: m.emissive,
            alpha: 1.0,
            alpha_mode: crate::model::AlphaMode::Opaque,
            double_sided: m.double_sided,
            transmission: m.transmission.map(|color| crate::model::Transmission {
                color,
                coverage: false,
            }),
            pbr: None,
        });
        by_name.insert(&m.name, k);
    }
    Ok(by_name)
}

/// Builds the file's primitive objects into the scene, checking the triangle limit before each,
/// and returns their mesh indices by object name; a name used twice is an error.
fn add_objects(
    file: &SceneFile,
    label: &str,
    scene: &mut Scene,
    by_name: &HashMap<&str, usize>,
) -> Result<HashMap<String, usize>, SceneError> {
    let mut objects: HashMap<String, usize> = HashMap::new();
    let mut triangles = scene.triangle_count() as u64;
    for (i, o) in file.objects.iter().enumerate() {
        // Counted before each object is built: each is bounded (segments, rings and divisions
        // are clamped), their number is not.
        triangles += object_triangles(o);
        crate::limits::check_triangles(triangles).map_err(|e| SceneError::limit(label, e))?;
        let (mesh, obj_name) =
            object_mesh(o, i, scene, by_name).map_err(|m| file_error(label, m))?;
        if objects.insert(obj_name.clone(), mesh).is_some() {
            return Err(file_error(
                label,
                format!("object name {obj_name:?} is used twice"),
            ));
        }
    }
    Ok(objects)
}

/// Names a base's meshes as objects too, where their names are unique (an emissive mesh light of
/// the base names its mesh); the file's own objects keep their names.
fn name_base_meshes(scene: &Scene, objects: &mut HashMap<String, usize>) {
    let mut seen: HashMap<&str, usize> = HashMap::new();
    for m in &scene.meshes {
        *seen.entry(m.name.as_str()).or_default() += 1;
    }
    for (k, m) in scene.meshes.iter().enumerate() {
        if seen.get(m.name.as_str()) == Some(&1) && !m.name.is_empty() {
            objects.entry(m.name.clone()).or_insert(k);
        }
    }
}

/// Applies the file's camera, ambient, exposure, quality and specular switch to the scene; a
/// scene without a base starts from no ambient and an exposure of one.
fn apply_settings(file: &SceneFile, scene: &mut Scene) {
    if let Some(c) = &file.camera {
        scene.camera = camera(c);
    }
    if file.base.is_none() {
        scene.ambient = [0.0; 3];
        scene.exposure = 1.0;
    }
    if let Some(a) = file.ambient {
        scene.ambient = a;
    }
    if let Some(e) = file.exposure {
        scene.exposure = e;
    }
    if let Some(q) = &file.quality {
        apply_quality(&mut scene.quality, q);
    }
    if !file.specular {
        for m in &mut scene.materials {
            m.specular = [0.0; 3];
        }
    }
}

/// The scene of a `[base]`: a built-in, or a scene file (without a base of its own) or model
/// inside the file's folder.
fn load_base(reference: &str, folder: Option<&Path>, label: &str) -> Result<Scene, SceneError> {
    if crate::builtin::is_builtin(reference) {
        return crate::builtin::builtin(reference);
    }
    let folder = folder.unwrap_or(Path::new("."));
    let path = crate::input::resolve_inside(folder, reference, "the scene file's").map_err(
        |e| match e.io {
            Some(path) => SceneError::Io {
                path: path.display().to_string(),
                message: e.message,
            },
            None => SceneError::file(label, format!("base.scene: {}", e.message)),
        },
    )?;
    let toml = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("toml"));
    if toml {
        let base_label = path.display().to_string();
        let parsed = super::read_scene_file(&path)?;
        if parsed.base.is_some() {
            return Err(SceneError::file(
                label,
                format!(
                    "base.scene: {reference:?} has a [base] of its own; a base is one level deep"
                ),
            ));
        }
        return build(
            &parsed,
            &base_label,
            Some(crate::gltf_load::model_folder(&path)),
        );
    }
    crate::load(&path.to_string_lossy())
}

fn camera(c: &CameraSpec) -> Camera {
    Camera {
        position: c.position,
        target: c.target,
        up: c.up,
        fov_y_deg: c.fov_y_deg,
        width: c.width,
        height: c.height,
    }
}

/// The material index for an object: its named material, or a new one from its inline diffuse
/// colour (grey when neither is given).
fn look(
    scene: &mut Scene,
    by_name: &HashMap<&str, usize>,
    object: &str,
    material: &Option<String>,
    diffuse: &Option<[f32; 3]>,
) -> Result<usize, String> {
    match (material, diffuse) {
        (Some(_), Some(_)) => Err(format!(
            "object {object:?} gives both `material` and `diffuse`; use one"
        )),
        (Some(m), None) => by_name
            .get(m.as_str())
            .copied()
            .ok_or_else(|| format!("object {object:?} uses unknown material {m:?}")),
        (None, d) => Ok(scene.add_material(Material::diffuse(object, d.unwrap_or([0.8; 3])))),
    }
}

/// At most how many triangles `o` builds (with the clamps of [`object_mesh`]).
fn object_triangles(o: &ObjectSpec) -> u64 {
    match o {
        ObjectSpec::Plane { divisions, .. } => 2 * u64::from((*divisions).clamp(1, 256)).pow(2),
        ObjectSpec::Box { .. } => 12,
        ObjectSpec::Sphere {
            segments, rings, ..
        } => 2 * u64::from((*segments).clamp(3, 1024)) * u64::from((*rings).clamp(2, 512)),
        ObjectSpec::Cylinder { segments, .. } => 4 * u64::from((*segments).clamp(3, 1024)),
    }
}

fn object_mesh(
    o: &ObjectSpec,
    index: usize,
    scene: &mut Scene,
    by_name: &HashMap<&str, usize>,
) -> Result<(usize, String), String> {
    let default_name = |kind: &str| format!("{kind} {index}");
    let mesh: Mesh = match o {
        ObjectSpec::Plane {
            name,
            center,
            normal,
            u_axis,
            size,
            divisions,
            material,
            diffuse,
        } => {
            let n = name.clone().unwrap_or_else(|| default_name("plane"));
            let m = look(scene, by_name, &n, material, diffuse)?;
            primitives::plane(
                &n,
                *center,
                *normal,
                *u_axis,
                *size,
                (*divisions).min(256),
                m,
            )
        }
        ObjectSpec::Box {
            name,
            center,
            size,
            rotation_y_deg,
            material,
            diffuse,
        } => {
            let n = name.clone().unwrap_or_else(|| default_name("box"));
            let m = look(scene, by_name, &n, material, diffuse)?;
            let half = size.map(|s| 0.5 * s);
            if *rotation_y_deg == 0.0 {
                // Built in place so an axis-aligned box has exactly the coordinates written.
                primitives::cuboid(&n, *center, half, m)
            } else {
                let mut mesh = primitives::cuboid(&n, [0.0; 3], half, m);
                mesh.transform(&Affine3A::from_rotation_translation(
                    Quat::from_rotation_y(rotation_y_deg.to_radians()),
                    Vec3::from(*center),
                ));
                mesh
            }
        }
        ObjectSpec::Sphere {
            name,
            center,
            radius,
            segments,
            rings,
            material,
            diffuse,
        } => {
            let n = name.clone().unwrap_or_else(|| default_name("sphere"));
            let m = look(scene, by_name, &n, material, diffuse)?;
            primitives::sphere(
                &n,
                *center,
                *radius,
                (*segments).min(1024),
                (*rings).min(512),
                m,
            )
        }
        ObjectSpec::Cylinder {
            name,
            base,
            radius,
            height,
            segments,
            material,
            diffuse,
        } => {
            let n = name.clone().unwrap_or_else(|| default_name("cylinder"));
            let m = look(scene, by_name, &n, material, diffuse)?;
            primitives::cylinder(&n, *base, *radius, *height, (*segments).min(1024), m)
        }
    };
    let name = mesh.name.clone();
    Ok((scene.add_mesh(mesh), name))
}

/// Builds light `index` of a scene file; an emissive-mesh light also gives its object a glowing
/// material of its own.
pub(super) fn light(
    l: &LightSpec,
    index: usize,
    scene: &mut Scene,
    objects: &HashMap<String, usize>,
) -> Result<Light, String> {
    Ok(match l {
        LightSpec::EmissiveMesh {
            name,
            object,
            radiance,
            color,
            two_sided,
            samples,
        } => {
            let mesh = *objects
                .get(object)
                .ok_or_else(|| format!("emissive_mesh light names unknown object {object:?}"))?;
            // A material of its own: the object glows with exactly the light's radiance.
            let base = scene.materials[scene.meshes[mesh].material].clone();
            let glow = scene.add_material(Material {
                name: format!("{} (emissive)", base.name),
                emissive: color.map(|c| c * radiance),
                double_sided: *two_sided,
                transmission: None,
                ..base
            });
            scene.meshes[mesh].material = glow;
            make_light(
                light_name(name, "emissive mesh", index),
                LightShape::EmissiveMesh { mesh },
                *color,
                *radiance,
                None,
                *samples,
            )
        }
        LightSpec::Rect { .. }
        | LightSpec::Disk { .. }
        | LightSpec::Sphere { .. }
        | LightSpec::Cylinder { .. } => area_light(l, index),
        _ => punctual_light(l, index),
    })
}

/// Returns a light's name: the given one, else `"{kind} light {index}"`.
fn light_name(name: &Option<String>, kind: &str, index: usize) -> String {
    name.clone()
        .unwrap_or_else(|| format!("{kind} light {index}"))
}

/// Assembles a [`Light`] from its parts.
fn make_light(
    name: String,
    shape: LightShape,
    color: [f32; 3],
    power: f32,
    range: Option<f32>,
    samples: u32,
) -> Light {
    Light {
        name,
        shape,
        color,
        power,
        range,
        samples,
    }
}

/// Builds a point, spot or directional light (one sample each); `l` is none of the area kinds.
fn punctual_light(l: &LightSpec, index: usize) -> Light {
    match l {
        LightSpec::Point {
            name,
            position,
            intensity,
            color,
            range,
        } => make_light(
            light_name(name, "point", index),
            LightShape::Point {
                position: *position,
            },
            *color,
            *intensity,
            *range,
            1,
        ),
        LightSpec::Spot {
            name,
            position,
            direction,
            intensity,
            inner_angle_deg,
            outer_angle_deg,
            color,
            range,
        } => make_light(
            light_name(name, "spot", index),
            LightShape::Spot {
                position: *position,
                direction: *direction,
                inner_angle: inner_angle_deg.to_radians(),
                outer_angle: outer_angle_deg.to_radians(),
            },
            *color,
            *intensity,
            *range,
            1,
        ),
        LightSpec::Directional {
            name,
            direction,
            irradiance,
            color,
            angle_deg,
            samples,
        } => make_light(
            light_name(name, "directional", index),
            LightShape::Directional {
                direction: *direction,
                angle: angle_deg.to_radians(),
            },
            *color,
            *irradiance,
            None,
            // A soft sun's parallel lights, as an area light's points; ignored when parallel.
            samples.unwrap_or(if *angle_deg > 0.0 {
                crate::defaults::SAMPLES_PER_AREA_LIGHT
            } else {
                1
            }),
        ),
        _ => unreachable!("light() passes only point, spot and directional lights here"),
    }
}

/// Builds a rect, disk, sphere or cylinder light, with no range window; `l` is one of those kinds.
fn area_light(l: &LightSpec, index: usize) -> Light {
    match l {
        LightSpec::Rect {
            name,
            center,
            size,
            normal,
            u_axis,
            radiance,
            color,
            samples,
        } => make_light(
            light_name(name, "rect", index),
            LightShape::Rect {
                center: *center,
                normal: *normal,
                u_axis: *u_axis,
                size: *size,
            },
            *color,
            *radiance,
            None,
            *samples,
        ),
        LightSpec::Disk {
            name,
            center,
            normal,
            radius,
            radiance,
            color,
            samples,
        } => make_light(
            light_name(name, "disk", index),
            LightShape::Disk {
                center: *center,
                normal: *normal,
                radius: *radius,
            },
            *color,
            *radiance,
            None,
            *samples,
        ),
        LightSpec::Sphere {
            name,
            center,
            radius,
            radiance,
            color,
            samples,
        } => make_light(
            light_name(name, "sphere", index),
            LightShape::Sphere {
                center: *center,
                radius: *radius,
            },
            *color,
            *radiance,
            None,
            *samples,
        ),
        LightSpec::Cylinder {
            name,
            center,
            axis,
            length,
            radius,
            radiance,
            color,
            samples,
        } => make_light(
            light_name(name, "cylinder", index),
            LightShape::Cylinder {
                center: *center,
                axis: *axis,
                length: *length,
                radius: *radius,
            },
            *color,
            *radiance,
            None,
            *samples,
        ),
        _ => unreachable!("light() passes only rect, disk, sphere and cylinder lights here"),
    }
}

fn apply_quality(q: &mut Quality, s: &super::spec::QualitySpec) {
    if s.samples_per_area_light.is_some() {
        q.samples_per_area_light = s.samples_per_area_light;
    }
    if let Some(p) = s.pattern {
        q.pattern = match p {
            PatternSpec::Grid => SamplePattern::Grid,
            PatternSpec::Jittered => SamplePattern::Jittered,
            PatternSpec::Halton => SamplePattern::Halton,
        };
    }
    if let Some(f) = s.filter {
        q.filter = match f {
            FilterSpec::None => ShadowFilter::None,
            FilterSpec::Pcf2x2 => ShadowFilter::Pcf2x2,
            FilterSpec::Pcf3x3 => ShadowFilter::Pcf { taps: 3 },
            FilterSpec::Pcf5x5 => ShadowFilter::Pcf { taps: 5 },
            FilterSpec::Cell => ShadowFilter::Cell {
                taps: crate::defaults::CELL_TAPS,
            },
        };
    }
    q.seed = s.seed.unwrap_or(q.seed);
    q.shadow_map_size = s.shadow_map_size.unwrap_or(q.shadow_map_size);
    let d = crate::defaults::MAP_MISMATCH;
    q.map_sizing = match (s.shadow_map_sizing, s.shadow_map_size) {
        (Some(SizingSpec::Word(SizingWord::Fixed)), _) | (None, Some(_)) => MapSizing::Fixed,
        (Some(SizingSpec::Word(SizingWord::Mismatch)), _) => MapSizing::Mismatch(d),
        (Some(SizingSpec::Mismatch(m)), _) => MapSizing::Mismatch(Mismatch {
            target: m.target.unwrap_or(d.target),
            min: m.min.unwrap_or(d.min),
            max: m.max.unwrap_or(d.max),
        }),
        (None, None) => q.map_sizing,
    };
    q.depth_bias = s.depth_bias.unwrap_or(q.depth_bias);
    q.slope_bias = s.slope_bias.unwrap_or(q.slope_bias);
    q.lights_per_node = s.lights_per_node.unwrap_or(q.lights_per_node);
    q.indirect = s.indirect.unwrap_or(q.indirect);
    q.indirect_clamp = s.indirect_clamp.or(q.indirect_clamp);
    q.area_specular = s.area_specular.unwrap_or(q.area_specular);
}
