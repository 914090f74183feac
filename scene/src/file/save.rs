//! Scene files written from a scene: a light as its `[[light]]` table, and a session's scene (a
//! base, its camera, exposure, ambient and lights as edited) as a file that builds the same
//! scene again.

use super::spec::{
    BaseRef, CameraSpec, FilterSpec, LightSpec, MismatchSpec, PatternSpec, QualitySpec, SceneFile,
    SizingSpec, SizingWord, VERSION,
};
use crate::model::{Light, LightShape, MapSizing, Quality, SamplePattern, Scene, ShadowFilter};

/// The `[[light]]` table of `light` in `scene` (whose meshes name an emissive mesh light's
/// object). An emissive mesh light whose mesh has no name of its own in the scene (empty, or
/// shared with another mesh) cannot be written.
pub fn light_spec(light: &Light, scene: &Scene) -> Result<LightSpec, String> {
    let name = Some(light.name.clone()).filter(|n| !n.is_empty());
    let (color, power) = (light.color, light.power);
    Ok(match light.shape {
        LightShape::Point { position } => LightSpec::Point {
            name,
            position,
            intensity: power,
            color,
            range: light.range,
        },
        LightShape::Spot {
            position,
            direction,
            inner_angle,
            outer_angle,
        } => LightSpec::Spot {
            name,
            position,
            direction,
            intensity: power,
            inner_angle_deg: inner_angle.to_degrees(),
            outer_angle_deg: outer_angle.to_degrees(),
            color,
            range: light.range,
        },
        LightShape::Directional { direction, angle } => LightSpec::Directional {
            name,
            direction,
            irradiance: power,
            color,
            angle_deg: angle.to_degrees(),
            samples: (angle > 0.0).then_some(light.samples),
        },
        LightShape::Rect {
            center,
            normal,
            u_axis,
            size,
        } => LightSpec::Rect {
            name,
            center,
            size,
            normal,
            u_axis,
            radiance: power,
            color,
            samples: light.samples,
        },
        LightShape::Disk {
            center,
            normal,
            radius,
        } => LightSpec::Disk {
            name,
            center,
            normal,
            radius,
            radiance: power,
            color,
            samples: light.samples,
        },
        LightShape::Sphere { center, radius } => LightSpec::Sphere {
            name,
            center,
            radius,
            radiance: power,
            color,
            samples: light.samples,
        },
        LightShape::Cylinder {
            center,
            axis,
            length,
            radius,
        } => LightSpec::Cylinder {
            name,
            center,
            axis,
            length,
            radius,
            radiance: power,
            color,
            samples: light.samples,
        },
        LightShape::EmissiveMesh { mesh } => {
            let object = scene
                .meshes
                .get(mesh)
                .map(|m| m.name.clone())
                .filter(|n| !n.is_empty())
                .filter(|n| scene.meshes.iter().filter(|m| &m.name == n).count() == 1)
                .ok_or_else(|| {
                    format!(
                        "light {:?} glows from mesh {mesh}, which has no name of its own to \
                         write",
                        light.name
                    )
                })?;
            let two_sided = scene
                .materials
                .get(scene.meshes[mesh].material)
                .is_some_and(|m| m.double_sided);
            LightSpec::EmissiveMesh {
                name,
                object,
                radiance: power,
                color,
                two_sided,
                samples: light.samples,
            }
        }
    })
}

/// The light a `[[light]]` table makes (the `index`-th light of a file, for its default name).
/// An emissive mesh light names an object of a scene file, so it is made only in one.
pub fn light_of(spec: &LightSpec, index: usize) -> Result<Light, String> {
    if matches!(spec, LightSpec::EmissiveMesh { .. }) {
        return Err("an emissive mesh light is its object's: it is made in a scene file".into());
    }
    super::build::light(spec, index, &mut Scene::new(""), &Default::default())
}

/// The `[quality]` table that sets every quality option to `q`'s.
pub fn quality_spec(q: &Quality) -> Result<QualitySpec, String> {
    Ok(QualitySpec {
        samples_per_area_light: q.samples_per_area_light,
        pattern: Some(match q.pattern {
            SamplePattern::Grid => PatternSpec::Grid,
            SamplePattern::Jittered => PatternSpec::Jittered,
            SamplePattern::Halton => PatternSpec::Halton,
        }),
        seed: Some(q.seed),
        shadow_map_size: Some(q.shadow_map_size),
        shadow_map_sizing: Some(match q.map_sizing {
            MapSizing::Fixed => SizingSpec::Word(SizingWord::Fixed),
            MapSizing::Mismatch(m) => SizingSpec::Mismatch(MismatchSpec {
                target: Some(m.target),
                min: Some(m.min),
                max: Some(m.max),
            }),
        }),
        filter: Some(match q.filter {
            ShadowFilter::None => FilterSpec::None,
            ShadowFilter::Pcf2x2 => FilterSpec::Pcf2x2,
            ShadowFilter::Pcf { taps: 3 } => FilterSpec::Pcf3x3,
            ShadowFilter::Pcf { taps: 5 } => FilterSpec::Pcf5x5,
            ShadowFilter::Cell {
                taps: crate::defaults::CELL_TAPS,
            } => FilterSpec::Cell,
            ShadowFilter::Pcf { taps } | ShadowFilter::Cell { taps } => {
                return Err(format!(
                    "a {taps}×{taps} shadow filter has no scene-file name"
                ));
            }
        }),
        depth_bias: Some(q.depth_bias),
        slope_bias: Some(q.slope_bias),
        lights_per_node: Some(q.lights_per_node),
        indirect: Some(q.indirect),
        indirect_clamp: q.indirect_clamp,
        area_specular: Some(q.area_specular),
    })
}

/// The scene file that builds `scene` from `base` (a built-in's name, or a path relative to
/// where the file is read): the base, then `scene`'s camera, exposure, ambient, quality and
/// lights, which replace the base's. What else `scene` has must be the base's own (a session edits only
/// camera and lights).
pub fn session_file(scene: &Scene, base: &str) -> Result<SceneFile, String> {
    let c = &scene.camera;
    let lights = scene
        .lights
        .iter()
        .map(|l| light_spec(l, scene))
        .collect::<Result<Vec<_>, _>>()?;
    if lights.is_empty() {
        return Err(
            "the scene has no lights; a file without lights keeps its base's, so it cannot \
             say so"
                .into(),
        );
    }
    Ok(SceneFile {
        version: VERSION,
        name: Some(scene.name.clone()),
        ambient: Some(scene.ambient),
        exposure: Some(scene.exposure),
        specular: true,
        base: Some(BaseRef {
            scene: base.to_string(),
        }),
        gltf: None,
        obj: None,
        ply: None,
        usd: None,
        camera: Some(CameraSpec {
            position: c.position,
            target: c.target,
            up: c.up,
            fov_y_deg: c.fov_y_deg,
            width: c.width,
            height: c.height,
        }),
        quality: Some(quality_spec(&scene.quality)?),
        materials: Vec::new(),
        objects: Vec::new(),
        lights,
        motions: Vec::new(),
        moves: Vec::new(),
    })
}
