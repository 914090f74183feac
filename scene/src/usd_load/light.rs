//! UsdLux lights, `UsdGeomCamera` and materials (`UsdPreviewSurface`, else the display colour).
//!
//! A light's radiance (or point intensity, or irradiance) is `intensity · 2^exposure`, in the
//! light's `color`; with `normalize` it is divided by the light's world-space area (rect
//! `w·h`, disk `π r²`, sphere `4π r²`, cylinder `2π r·length`, a mesh light its triangles') so that its power does not
//! depend on its size. Area
//! lights emit along −Z of their frame (a sphere outward); their sizes take the frame's scale.
//! A sphere with `treatAsPoint` is a point light of intensity `L·π r²` (the power of the sphere
//! it stands for), a spot with `shaping:cone:angle`. A distant light's irradiance is
//! `intensity · 2^exposure` when normalized, else what that radiance gives over the disk of its
//! `angle` (`π·sin²(angle/2)`; an angle of 0 reads it as irradiance); its `angle` makes it a soft
//! sun, sampled like an area light. A cylinder light emits from its curved side (`2π·r·length`
//! when normalized) along the frame's X axis.

use super::walk::{At, Error, Reader, boolean, scalar, token, value, vec3};
use crate::model::{
    AlphaMode, Camera, Light, LightShape, Material, MetallicRoughness, Transmission,
};
use glam::{DMat4, DVec3};
use openusd::schemas::shade::{Channel, read_preview_surface};
use openusd::sdf;
use openusd::usd::Prim;
use std::f64::consts::PI;

fn to3(v: DVec3) -> [f32; 3] {
    v.as_vec3().to_array()
}

/// A light input: `inputs:NAME`, or `NAME` as UsdLux wrote it before 21.02.
fn input<T>(
    prim: &Prim,
    name: &str,
    t: openusd::usd::TimeCode,
    read: fn(&Prim, &str, openusd::usd::TimeCode) -> Result<Option<T>, Error>,
) -> Result<Option<T>, Error> {
    match read(prim, &format!("inputs:{name}"), t)? {
        Some(v) => Ok(Some(v)),
        None => read(prim, name, t),
    }
}

/// What every UsdLux light emits: `intensity · 2^exposure` in `color`, and whether it is
/// normalized by its area.
struct Emission {
    radiance: f64,
    color: [f32; 3],
    normalize: bool,
}

fn emission(r: &mut Reader, prim: &Prim, default_intensity: f64) -> Result<Emission, Error> {
    let t = r.time;
    let bad = |m: String| Error::Usd(format!("light {}: {m}", prim.path().as_str()));
    let intensity = input(prim, "intensity", t, scalar)?.unwrap_or(default_intensity);
    let exposure = input(prim, "exposure", t, scalar)?.unwrap_or(0.0);
    let color = input(prim, "color", t, vec3)?.unwrap_or([1.0; 3]);
    let normalize = input(prim, "normalize", t, boolean)?.unwrap_or(false);
    if input(prim, "enableColorTemperature", t, boolean)? == Some(true) {
        r.ignored
            .insert("light colour temperature (inputs:color is used)".into());
    }
    for name in ["diffuse", "specular"] {
        if input(prim, name, t, scalar)?.is_some_and(|v| v != 1.0) {
            r.ignored
                .insert("light diffuse and specular multipliers".into());
        }
    }
    if input(prim, "shadow:enable", t, boolean)? == Some(false) {
        r.ignored
            .insert("lights without shadows (ShadowAPI: they cast them)".into());
    }
    let radiance = intensity * exposure.exp2();
    if !(radiance.is_finite() && radiance >= 0.0) {
        return Err(bad(format!(
            "intensity {intensity} · 2^{exposure} is not a finite, non-negative radiance"
        )));
    }
    Ok(Emission {
        radiance,
        color,
        normalize,
    })
}

/// A mesh with `MeshLightAPI` (or `LightAPI`) as an emissive-mesh light of its emission
/// (normalized by the mesh's world-space area), glowing with it in a material of its own.
pub(super) fn mesh_light(r: &mut Reader, prim: &Prim, mesh: usize) -> Result<(), Error> {
    let Emission {
        radiance,
        color,
        normalize,
    } = emission(r, prim, 1.0)?;
    let m = &r.scene.meshes[mesh];
    let area: f64 = m
        .indices
        .chunks_exact(3)
        .map(|t| {
            let [a, b, c] =
                [0, 1, 2].map(|k| DVec3::from(m.positions[t[k] as usize].map(f64::from)));
            (b - a).cross(c - a).length() / 2.0
        })
        .sum();
    let power = if normalize {
        if !area.is_finite() || area <= 0.0 {
            r.ignored
                .insert("normalized mesh lights without area".into());
            return Ok(());
        }
        radiance / area
    } else {
        radiance
    };
    super::count(
        "materials",
        r.scene.materials.len() as u64 + 1,
        crate::limits::MAX_MODEL_MATERIALS,
    )?;
    let glow = Material {
        emissive: color.map(|c| (f64::from(c) * power) as f32),
        ..r.scene.materials[m.material].clone()
    };
    let name = prim.path().name().unwrap_or("mesh light").to_string();
    r.scene.meshes[mesh].material = r.scene.add_material(glow);
    r.scene.lights.push(Light {
        name,
        shape: LightShape::EmissiveMesh { mesh },
        color,
        power: power as f32,
        range: None,
        samples: crate::defaults::SAMPLES_PER_AREA_LIGHT,
    });
    Ok(())
}

pub(super) fn light(r: &mut Reader, prim: &Prim, kind: &str, world: DMat4) -> Result<(), Error> {
    let t = r.time;
    let name = prim.path().name().unwrap_or("light").to_string();
    let bad = |m: String| Error::Usd(format!("light {}: {m}", prim.path().as_str()));
    let default_intensity = if kind == "DistantLight" { 50000.0 } else { 1.0 };
    let Emission {
        radiance,
        color,
        normalize,
    } = emission(r, prim, default_intensity)?;
    let center = world.transform_point3(DVec3::ZERO);
    let [x, y, z] = [DVec3::X, DVec3::Y, DVec3::Z].map(|a| world.transform_vector3(a));
    let back = (-z).normalize_or_zero();
    let size = |name: &str, default: f64, scale: f64| -> Result<f64, Error> {
        let v = input(prim, name, t, scalar)?.unwrap_or(default) * scale;
        if v.is_finite() && v > 0.0 {
            Ok(v)
        } else {
            Err(bad(format!("inputs:{name} gives a size of {v}")))
        }
    };
    let cone = input(prim, "shaping:cone:angle", t, scalar)?;
    let point_like = kind == "SphereLight" && boolean(prim, "treatAsPoint", t)? == Some(true);
    if cone.is_some() && !point_like {
        r.ignored
            .insert("shaping:cone on area lights (they emit over the hemisphere)".into());
    }
    for name in ["shaping:focus", "shaping:ies:file"] {
        if input(prim, name, t, value)?.is_some() {
            r.ignored.insert("shaping:focus and IES profiles".into());
        }
    }
    let (shape, power) = match kind {
        "RectLight" => {
            let size = [
                size("width", 1.0, x.length())?,
                size("height", 1.0, y.length())?,
            ];
            if input(prim, "texture:file", t, value)?.is_some() {
                r.ignored.insert("RectLight textures".into());
            }
            let area = size[0] * size[1];
            let shape = LightShape::Rect {
                center: to3(center),
                normal: to3(back),
                u_axis: to3(x.normalize_or_zero()),
                size: size.map(|s| s as f32),
            };
            (shape, if normalize { radiance / area } else { radiance })
        }
        "DiskLight" => {
            let radius = size("radius", 0.5, (x.length() + y.length()) / 2.0)?;
            let shape = LightShape::Disk {
                center: to3(center),
                normal: to3(back),
                radius: radius as f32,
            };
            let area = PI * radius * radius;
            (shape, if normalize { radiance / area } else { radiance })
        }
        "SphereLight" => {
            let scale = (x.length() + y.length() + z.length()) / 3.0;
            let radius = size("radius", 0.5, scale)?;
            let area = 4.0 * PI * radius * radius;
            let radiance = if normalize { radiance / area } else { radiance };
            if point_like {
                let position = to3(center);
                let shape = match cone {
                    Some(angle) => {
                        let outer = angle.clamp(0.0, 90.0).to_radians();
                        let softness =
                            input(prim, "shaping:cone:softness", t, scalar)?.unwrap_or(0.0);
                        LightShape::Spot {
                            position,
                            direction: to3(back),
                            inner_angle: (outer * (1.0 - softness.clamp(0.0, 1.0))) as f32,
                            outer_angle: outer as f32,
                        }
                    }
                    None => LightShape::Point { position },
                };
                (shape, radiance * PI * radius * radius)
            } else {
                let shape = LightShape::Sphere {
                    center: to3(center),
                    radius: radius as f32,
                };
                (shape, radiance)
            }
        }
        "CylinderLight" => {
            // Along the frame's X axis, the radius across it; the caps do not emit.
            let length = size("length", 1.0, x.length())?;
            let radius = size("radius", 0.5, (y.length() + z.length()) / 2.0)?;
            if boolean(prim, "treatAsLine", t)? == Some(true) {
                r.ignored.insert(
                    "CylinderLight treatAsLine (drawn as the cylinder of its radius)".into(),
                );
            }
            let shape = LightShape::Cylinder {
                center: to3(center),
                axis: to3(x.normalize_or_zero()),
                length: length as f32,
                radius: radius as f32,
            };
            let area = 2.0 * PI * radius * length;
            (shape, if normalize { radiance / area } else { radiance })
        }
        _ => {
            // The light's apparent diameter in degrees; the sun's 0.53 is UsdLux's fallback.
            let angle = input(prim, "angle", t, scalar)?.unwrap_or(0.53);
            if !(angle.is_finite() && angle >= 0.0) {
                return Err(bad(format!("inputs:angle is {angle}")));
            }
            let widest = f64::from(crate::limits::MAX_SUN_ANGLE).to_degrees();
            if angle > widest {
                r.ignored.insert(format!(
                    "DistantLight angles above {widest}° (narrowed to it)"
                ));
            }
            let angle = angle.min(widest);
            let half = angle.to_radians() / 2.0;
            // The irradiance of a disk of radiance L and half-angle α on a surface facing it:
            // ∫ L·cos θ dω over the cap = π·L·sin²α.
            let irradiance = if normalize || angle == 0.0 {
                radiance
            } else {
                radiance * PI * half.sin().powi(2)
            };
            let shape = LightShape::Directional {
                direction: to3(back),
                angle: angle.to_radians() as f32,
            };
            (shape, irradiance)
        }
    };
    let mut light = Light {
        name,
        shape,
        color,
        power: power as f32,
        range: None,
        samples: 1,
    };
    if light.is_area() {
        light.samples = crate::defaults::SAMPLES_PER_AREA_LIGHT;
    }
    r.scene.lights.push(light);
    Ok(())
}

/// The first perspective camera: looking along −Z of its frame, Y up; the vertical field of
/// view `2·atan(verticalAperture / (2·focalLength))`, the image's aspect the apertures'.
pub(super) fn camera(r: &mut Reader, prim: &Prim, world: DMat4) -> Result<(), Error> {
    let t = r.time;
    if r.has_camera {
        r.ignored
            .insert("cameras after the first (the first is used)".into());
        return Ok(());
    }
    if token(prim, "projection", t)?.as_deref() == Some("orthographic") {
        r.ignored.insert("orthographic cameras".into());
        return Ok(());
    }
    if scalar(prim, "fStop", t)?.is_some_and(|f| f > 0.0) {
        r.ignored.insert("depth of field (fStop)".into());
    }
    let focal = scalar(prim, "focalLength", t)?.unwrap_or(50.0);
    let vertical = scalar(prim, "verticalAperture", t)?.unwrap_or(15.2908);
    let horizontal = scalar(prim, "horizontalAperture", t)?.unwrap_or(20.955);
    let fov = 2.0 * (vertical / (2.0 * focal)).atan().to_degrees();
    let aspect = horizontal / vertical;
    if !(fov.is_finite() && fov > 0.0 && fov < 180.0 && aspect.is_finite() && aspect > 0.0) {
        return Err(Error::Usd(format!(
            "camera {}: focal length {focal} and apertures {horizontal} × {vertical} give no \
             field of view",
            prim.path().as_str()
        )));
    }
    let position = world.transform_point3(DVec3::ZERO);
    let forward = world.transform_vector3(-DVec3::Z).normalize_or_zero();
    let up = world.transform_vector3(DVec3::Y).normalize_or_zero();
    let width = crate::defaults::WIDTH;
    let height =
        ((f64::from(width) / aspect).round() as u32).clamp(1, crate::limits::MAX_IMAGE_SIDE);
    r.scene.camera = Camera {
        position: to3(position),
        target: to3(position + forward),
        up: to3(up),
        fov_y_deg: fov as f32,
        width,
        height,
    };
    r.has_camera = true;
    Ok(())
}

/// The material bound to `prim` (`material:binding` on it or its closest ancestor).
fn bound_material(prim: &Prim) -> Result<Option<sdf::Path>, Error> {
    let stage = prim.stage();
    let mut at = Some(prim.path().clone());
    while let Some(path) = at {
        if path == sdf::Path::abs_root() {
            break;
        }
        let targets = stage
            .prim(path.clone())
            .relationship("material:binding")
            .targets()
            .at(&path)?;
        if let Some(first) = targets.into_iter().next() {
            return Ok(Some(first));
        }
        at = path.parent();
    }
    Ok(None)
}

/// Most prims of one material network checked before the crate reads it.
const MAX_NETWORK_PRIMS: usize = 256;

/// Whether `path` is a plain prim or property path (`/A/B`, `/A/B.ns:name`): the crate loops
/// forever over some malformed ones a text layer can hold (an unterminated `<…>` target; found
/// by fuzzing), so the paths the material reader will follow are checked first.
pub(super) fn is_plain_path(path: &str) -> bool {
    let ident = |s: &str| {
        s.chars()
            .next()
            .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
            && s.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
    };
    let (prim, property) = match path.split_once('.') {
        Some((prim, property)) => (prim, Some(property)),
        None => (path, None),
    };
    prim.strip_prefix('/')
        .is_some_and(|rest| rest.split('/').all(ident))
        && property.is_none_or(|p| p.split(':').all(ident))
}

/// Checks the material at `material` and every prim its connections reach (its shaders) for
/// connections the crate could not follow.
fn check_network(stage: &openusd::usd::Stage, material: &sdf::Path) -> Result<(), Error> {
    let bad = |what: &str, path: &str| {
        Error::Usd(format!(
            "{what} {:?} is not a prim or property path",
            super::walk::truncate(path, 120)
        ))
    };
    if !is_plain_path(material.as_str()) {
        return Err(bad("material:binding target", material.as_str()));
    }
    let mut queue = vec![material.clone()];
    let mut seen = std::collections::HashSet::new();
    while let Some(at) = queue.pop() {
        if !seen.insert(at.clone()) {
            continue;
        }
        if seen.len() > MAX_NETWORK_PRIMS {
            return Err(Error::Usd(format!(
                "material {}: more than {MAX_NETWORK_PRIMS} prims in its network",
                material.as_str()
            )));
        }
        let prim = stage.prim(at.clone());
        for attribute in prim.attributes().at(&at)? {
            for target in attribute.connections().at(&at)? {
                if !is_plain_path(target.as_str()) {
                    return Err(bad(
                        &format!("{} connects to", attribute.path().as_str()),
                        target.as_str(),
                    ));
                }
                queue.push(target.prim_path());
            }
        }
        queue.extend(
            prim.children()
                .at(&at)?
                .into_iter()
                .map(|c| c.path().clone()),
        );
    }
    Ok(())
}

/// The index of `prim`'s material (made once per bound material or display colour and
/// sidedness).
pub(super) fn material(r: &mut Reader, prim: &Prim, double_sided: bool) -> Result<usize, Error> {
    let t = r.time;
    let bound = bound_material(prim)?;
    let surface = match &bound {
        Some(m) => {
            check_network(r.stage, m)?;
            read_preview_surface(r.stage, m).at(m)?
        }
        None => None,
    };
    if bound.is_some() && surface.is_none() {
        r.ignored
            .insert("materials other than UsdPreviewSurface (the display colour is used)".into());
    }
    let (key, name) = match (&bound, &surface) {
        (Some(m), Some(_)) => (
            m.as_str().to_string(),
            m.name().unwrap_or("material").to_string(),
        ),
        _ => {
            let c = vec3(prim, "primvars:displayColor", t)?.unwrap_or([0.5; 3]);
            (format!("displayColor {c:?}"), "displayColor".to_string())
        }
    };
    if let Some(&k) = r.materials.get(&(key.clone(), double_sided)) {
        return Ok(k);
    }
    super::count(
        "materials",
        r.scene.materials.len() as u64 + 1,
        crate::limits::MAX_MODEL_MATERIALS,
    )?;
    let material = match surface {
        Some(s) => preview_surface(r, &name, &s, double_sided),
        None => {
            let c = vec3(prim, "primvars:displayColor", t)?.unwrap_or([0.5; 3]);
            Material {
                double_sided,
                ..Material::diffuse(&name, c)
            }
        }
    };
    let k = r.scene.add_material(material);
    r.materials.insert((key, double_sided), k);
    Ok(k)
}

/// `UsdPreviewSurface` as glTF metallic-roughness (its defaults where unauthored: diffuse
/// 0.18, roughness 0.5, metallic 0, opacity 1); `emissiveColor` is emitted radiance and makes
/// the mesh an emissive-mesh light. Opacity below 1 is glTF's BLEND (or MASK at
/// `opacityThreshold`).
fn preview_surface(
    r: &mut Reader,
    name: &str,
    s: &openusd::schemas::shade::ReadPreviewSurface,
    double_sided: bool,
) -> Material {
    let mut textured = false;
    let mut color = |c: &Channel<openusd::gf::Vec3f>, default: [f32; 3]| match c {
        Channel::Value(v) => [v.x, v.y, v.z],
        Channel::Texture(_) => {
            textured = true;
            default
        }
        Channel::Unset => default,
    };
    let diffuse = color(&s.diffuse_color, [0.18; 3]);
    let emissive = color(&s.emissive_color, [0.0; 3]);
    let mut scalar = |c: &Channel<f32>, default: f32| match c {
        Channel::Value(v) => *v,
        Channel::Texture(_) => {
            textured = true;
            default
        }
        Channel::Unset => default,
    };
    let metallic = scalar(&s.metallic, 0.0).clamp(0.0, 1.0);
    let roughness = scalar(&s.roughness, 0.5).clamp(0.0, 1.0);
    let opacity = scalar(&s.opacity, 1.0).clamp(0.0, 1.0);
    let threshold = scalar(&s.opacity_threshold, 0.0);
    if textured || s.normal.is_set() || s.occlusion.is_set() {
        r.ignored.insert("UsdPreviewSurface textures".into());
    }
    if s.specular_color.is_set() {
        r.ignored
            .insert("UsdPreviewSurface specularColor (the specular workflow)".into());
    }
    if s.clearcoat.is_set() {
        r.ignored.insert("UsdPreviewSurface clearcoat".into());
    }
    if matches!(s.ior, Channel::Value(v) if v != 1.5) {
        r.ignored
            .insert("UsdPreviewSurface ior (read as 1.5, glTF's)".into());
    }
    let pbr = MetallicRoughness::new(diffuse, metallic, roughness);
    let (alpha_mode, transmission) = if opacity >= 1.0 {
        (AlphaMode::Opaque, None)
    } else if threshold > 0.0 {
        (AlphaMode::Mask { cutoff: threshold }, None)
    } else {
        (
            AlphaMode::Mask { cutoff: 0.5 },
            Some(Transmission {
                color: diffuse.map(|c| c.clamp(0.0, 1.0)),
                coverage: true,
            }),
        )
    };
    Material {
        emissive,
        alpha: opacity,
        alpha_mode,
        transmission,
        double_sided,
        ..Material::metallic_roughness(name, pbr)
    }
}
