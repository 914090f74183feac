//! Built-in scenes generated in code, echoing the paper's Fig. 3: "balls" (the default), "box",
//! "plant", "animal" — each lit by 32 point samples — a Cornell box, "carousel", where an
//! object spins and an area light travels (a scene file compiled into the crate), and "city", a
//! procedural city of a chosen number of triangles (`city:4M`) for scaling measurements.
//!
//! They need no files: the Fox model of "animal" is compiled into the crate.

mod animal;
mod balls;
mod boxes;
mod city;
mod cornell;
mod plant;

use crate::defaults;
use crate::error::SceneError;
use crate::model::{Camera, Light, LightShape, Material, Scene};
use crate::shading::{V3, normalize, sub};

/// The fixed built-ins. The generated `city` / `city:N` is accepted by name too ([`is_builtin`])
/// but not listed: at a million triangles it is no scene to run every test over.
const NAMES: &[&str] = &["balls", "box", "plant", "animal", "cornell", "carousel"];

/// The "carousel" scene file.
const CAROUSEL: &str = include_str!("carousel.toml");

/// The names [`builtin`] accepts; the first is the default scene.
pub fn builtin_names() -> &'static [&'static str] {
    NAMES
}

/// Whether `name` names a built-in scene: one of [`builtin_names`], or `city:N` (a city of N
/// triangles).
pub fn is_builtin(name: &str) -> bool {
    NAMES.contains(&name) || city::requested(name).is_some()
}

/// Builds the built-in scene `name`.
pub fn builtin(name: &str) -> Result<Scene, SceneError> {
    if let Some(triangles) = city::requested(name) {
        let triangles = triangles.map_err(SceneError::BuiltinSize)?;
        return Ok(city::build(triangles));
    }
    let scene = match name {
        "balls" => balls::build(),
        "box" => boxes::build(),
        "plant" => plant::build(),
        "animal" => animal::build()?,
        "cornell" => cornell::build(),
        "carousel" => crate::file::parse_scene_file(CAROUSEL, "built-in scene carousel", None)?,
        _ => {
            return Err(SceneError::UnknownBuiltin {
                name: name.to_string(),
                known: format!("{}, city[:N]", NAMES.join(", ")),
            });
        }
    };
    Ok(scene)
}

/// A camera at the default image size.
fn camera(position: V3, target: V3, fov_y_deg: f32) -> Camera {
    Camera {
        position,
        target,
        up: [0.0, 1.0, 0.0],
        fov_y_deg,
        width: defaults::WIDTH,
        height: defaults::HEIGHT,
    }
}

/// A square one-sided rectangular light at `center` facing `aim`, `u_axis` horizontal.
fn rect_light(name: &str, center: V3, aim: V3, side: f32, radiance: f32, color: V3) -> Light {
    let normal = normalize(sub(aim, center));
    // A horizontal u axis keeps the grid aligned with the ground (any axis ⊥ normal would do).
    let mut u_axis = normalize(crate::shading::cross([0.0, 1.0, 0.0], normal));
    if u_axis == [0.0; 3] {
        u_axis = [1.0, 0.0, 0.0];
    }
    Light {
        name: name.to_string(),
        shape: LightShape::Rect {
            center,
            normal,
            u_axis,
            size: [side, side],
        },
        color,
        power: radiance,
        range: None,
        samples: defaults::SAMPLES_PER_AREA_LIGHT,
    }
}

/// A diffuse material with a Blinn-Phong highlight.
fn shiny(name: &str, diffuse: V3, specular: f32, shininess: f32) -> Material {
    Material {
        specular: [specular; 3],
        shininess,
        ..Material::diffuse(name, diffuse)
    }
}
