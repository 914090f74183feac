//! Editing the scene's lights from the page: a light set from a `[[light]]` table (the scene
//! file's vocabulary, `docs/scenes.md`), added, removed, or dragged across the view. Every edit
//! is checked as a scene file's light would be, and bounded (coordinates, samples, the number
//! of lights); an edit that fails changes nothing. The coordinator re-plans over the edited
//! lights (`FrameSpec::lights`).

use crate::camera::{LightSetting, MAX_COORDINATE, Steer, SteerError, check_point, finite};
use glam::Vec3;
use lightfold_scene::file::save::light_of;
use lightfold_scene::file::spec::LightSpec;
use lightfold_scene::limits::{MAX_LIGHT_SAMPLES, MAX_SAMPLES_PER_AREA_LIGHT};
use lightfold_scene::{Light, LightShape};
use std::sync::Arc;

/// Most lights a session may have.
pub(crate) const MAX_LIGHTS: usize = 256;
/// Largest power a viewer may give a light (radiance, intensity or irradiance).
pub(crate) const MAX_POWER: f32 = 1e9;

/// Where a light is, for dragging it and for the page's markers (`None`: a directional light,
/// or a mesh light, which is where its object is).
pub(crate) fn light_position(shape: &LightShape) -> Option<[f32; 3]> {
    match shape {
        LightShape::Point { position } | LightShape::Spot { position, .. } => Some(*position),
        LightShape::Rect { center, .. }
        | LightShape::Disk { center, .. }
        | LightShape::Sphere { center, .. }
        | LightShape::Cylinder { center, .. } => Some(*center),
        LightShape::Directional { .. } | LightShape::EmissiveMesh { .. } => None,
    }
}

fn set_position(shape: &mut LightShape, p: [f32; 3]) {
    match shape {
        LightShape::Point { position } | LightShape::Spot { position, .. } => *position = p,
        LightShape::Rect { center, .. }
        | LightShape::Disk { center, .. }
        | LightShape::Sphere { center, .. }
        | LightShape::Cylinder { center, .. } => *center = p,
        LightShape::Directional { .. } | LightShape::EmissiveMesh { .. } => {}
    }
}

fn bad(m: impl Into<String>) -> SteerError {
    SteerError::BadLight(m.into())
}

/// Checks a light a viewer made: what a scene file's would pass, within the view's bounds.
fn check(light: &Light) -> Result<(), SteerError> {
    lightfold_scene::validate::check_light(light).map_err(bad)?;
    if light.power > MAX_POWER {
        return Err(bad(format!("a light's power is at most {MAX_POWER}")));
    }
    if light.samples > MAX_SAMPLES_PER_AREA_LIGHT {
        return Err(bad(format!(
            "an area light takes at most {MAX_SAMPLES_PER_AREA_LIGHT} samples"
        )));
    }
    let extent = match light.shape {
        LightShape::Rect { size, .. } => size[0].max(size[1]),
        LightShape::Disk { radius, .. } | LightShape::Sphere { radius, .. } => radius,
        LightShape::Cylinder { length, radius, .. } => length.max(radius),
        _ => 0.0,
    };
    if extent > MAX_COORDINATE || light.range.is_some_and(|r| r > MAX_COORDINATE) {
        return Err(bad(format!(
            "a light's size and range are at most {MAX_COORDINATE}"
        )));
    }
    if let Some(p) = light_position(&light.shape) {
        check_point(Vec3::from(p))?;
    }
    Ok(())
}

impl Steer {
    /// The light `index` as a `[[light]]` table says (its colour and power become the light's
    /// own, with the viewers' multiplier back at 1). A mesh light can only be recoloured.
    pub fn edit_light(&mut self, index: u32, spec: &LightSpec) -> Result<(), SteerError> {
        let old = self.not_a_mesh_light(
            index,
            "a mesh light is its object: it can be recoloured, not moved or reshaped",
        )?;
        let mut light = light_of(spec, index as usize).map_err(bad)?;
        if spec_name(spec).is_none() {
            light.name = old.name.clone();
        }
        check(&light)?;
        let mut lights = self.scene_lights.as_ref().clone();
        let mut settings = self.lights.clone();
        settings[index as usize] = LightSetting::of(&light);
        lights[index as usize] = light;
        self.commit(lights, settings)
    }

    /// Adds a light (after the others).
    pub fn add_light(&mut self, spec: &LightSpec) -> Result<(), SteerError> {
        let index = self.scene_lights.len();
        if index >= MAX_LIGHTS {
            return Err(bad(format!("a session has at most {MAX_LIGHTS} lights")));
        }
        let light = light_of(spec, index).map_err(bad)?;
        check(&light)?;
        let mut lights = self.scene_lights.as_ref().clone();
        let mut settings = self.lights.clone();
        settings.push(LightSetting::of(&light));
        lights.push(light);
        self.commit(lights, settings)
    }

    /// Removes light `index`; the lights after it move down one. Refused for the last light
    /// (set its power to 0 instead), a mesh light (its object would still glow), and in a scene
    /// that animates its lights (their motions are bound to their places in the list).
    pub fn remove_light(&mut self, index: u32) -> Result<(), SteerError> {
        self.not_a_mesh_light(
            index,
            "a mesh light is its object (it would still glow): set its power to 0 instead",
        )?;
        if self.scene_lights.len() == 1 {
            return Err(bad(
                "the last light cannot be removed: set its power to 0 instead",
            ));
        }
        if self.animated_lights {
            return Err(bad(
                "this scene animates its lights, whose motions are bound to their places in the \
                 list: set the light's power to 0 instead",
            ));
        }
        let mut lights = self.scene_lights.as_ref().clone();
        let mut settings = self.lights.clone();
        lights.remove(index as usize);
        settings.remove(index as usize);
        self.commit(lights, settings)
    }

    /// Moves light `index` by `x` view widths right and `y` view heights up, at its own distance
    /// from the camera (a light behind the camera moves at the target's distance).
    pub fn drag_light(&mut self, index: u32, x: f32, y: f32) -> Result<(), SteerError> {
        finite(&[x, y], "drag")?;
        if x.abs() > 100.0 || y.abs() > 100.0 {
            return Err(SteerError::OutOfRange(
                "a drag moves at most 100 views at a time".into(),
            ));
        }
        let light = self
            .scene_lights
            .get(index as usize)
            .ok_or(SteerError::UnknownLight(index))?;
        let p = light_position(&light.shape).ok_or_else(|| {
            bad(match light.shape {
                LightShape::EmissiveMesh { .. } => "a mesh light is its object: it cannot be moved",
                _ => "a directional light has no position: turn it with its direction",
            })
        })?;
        let p = Vec3::from(p);
        let moved = p + self.view_shift(p, x, y)?;
        check_point(moved)?;
        let mut lights = self.scene_lights.as_ref().clone();
        set_position(&mut lights[index as usize].shape, moved.to_array());
        self.commit(lights, self.lights.clone())
    }

    /// Light `index`, unless it is a mesh light (then `why`).
    fn not_a_mesh_light(&self, index: u32, why: &str) -> Result<&Light, SteerError> {
        let light = self
            .scene_lights
            .get(index as usize)
            .ok_or(SteerError::UnknownLight(index))?;
        if matches!(light.shape, LightShape::EmissiveMesh { .. }) {
            return Err(bad(why));
        }
        Ok(light)
    }

    /// The lights as the loop put them back after an edit it could not plan: each light's
    /// setting stays where the light is the same, and is the light's own where it is not.
    pub(crate) fn put_back_lights(&mut self, lights: &[Light]) {
        let settings = lights
            .iter()
            .enumerate()
            .map(
                |(i, l)| match (self.scene_lights.get(i), self.lights.get(i)) {
                    (Some(now), Some(set)) if now.shape == l.shape && now.power == l.power => *set,
                    _ => LightSetting::of(l),
                },
            )
            .collect();
        self.lights = settings;
        self.scene_lights = Arc::new(lights.to_vec());
    }

    /// Makes `lights` the session's, with the viewers' colour `settings` (one per light).
    fn commit(
        &mut self,
        lights: Vec<Light>,
        settings: Vec<LightSetting>,
    ) -> Result<(), SteerError> {
        let samples: u64 = lights
            .iter()
            .map(|l| if l.is_area() { u64::from(l.samples) } else { 1 })
            .sum();
        if samples > MAX_LIGHT_SAMPLES {
            return Err(bad(format!(
                "{samples} light samples in all; a scene takes at most {MAX_LIGHT_SAMPLES}"
            )));
        }
        debug_assert_eq!(lights.len(), settings.len());
        self.lights = settings;
        self.scene_lights = Arc::new(lights);
        self.lights_edited = true;
        Ok(())
    }
}

fn spec_name(spec: &LightSpec) -> Option<&String> {
    match spec {
        LightSpec::Point { name, .. }
        | LightSpec::Spot { name, .. }
        | LightSpec::Directional { name, .. }
        | LightSpec::Rect { name, .. }
        | LightSpec::Disk { name, .. }
        | LightSpec::Sphere { name, .. }
        | LightSpec::Cylinder { name, .. }
        | LightSpec::EmissiveMesh { name, .. } => name.as_ref(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightfold_scene::builtin;

    fn spec(v: serde_json::Value) -> LightSpec {
        serde_json::from_value(v).unwrap()
    }

    #[test]
    fn edits_keep_the_other_lights_settings_and_refuse_what_cannot_be() {
        let scene = builtin("balls").unwrap();
        let mut s = Steer::new(&scene);
        assert!(
            s.spec().lights.is_none(),
            "no edit, no lights in the request"
        );
        s.set_light(1, [0.2, 0.4, 0.6], 2.0).unwrap();
        let sphere = spec(serde_json::json!({"type": "sphere", "center": [0, 2, 0],
            "radius": 0.2, "radiance": 5.0, "samples": 8}));
        s.add_light(&sphere).unwrap();
        assert_eq!(s.scene_lights.len(), 3);
        assert_eq!(
            s.lights[1].color,
            [0.2, 0.4, 0.6],
            "light 1 keeps its setting"
        );
        s.remove_light(0).unwrap();
        assert_eq!(
            s.lights[0].color,
            [0.2, 0.4, 0.6],
            "settings move down with their lights"
        );
        assert_eq!(s.lights[0].intensity, 2.0);
        assert_eq!(s.spec().lights.as_deref(), Some(s.scene_lights.as_ref()));
        // The drag moves in the view plane: the light stays at its depth.
        let before = light_position(&s.scene_lights[1].shape).unwrap();
        s.drag_light(1, 0.25, 0.0).unwrap();
        let after = light_position(&s.scene_lights[1].shape).unwrap();
        let (pos, target, _) = s.view_frame().unwrap();
        let f = (target - pos).normalize();
        let depth = |p: [f32; 3]| (Vec3::from(p) - pos).dot(f);
        assert!((depth(before) - depth(after)).abs() < 1e-4);
        assert!((Vec3::from(before) - Vec3::from(after)).length() > 0.1);
        // Refused, changing nothing.
        let was = s.clone();
        let bad = [
            s.clone().drag_light(9, 0.1, 0.0),
            s.clone().drag_light(0, f32::NAN, 0.0),
            s.clone().edit_light(
                0,
                &spec(serde_json::json!({"type": "disk",
                "center": [0, 1, 0], "normal": [0, 0, 0], "radius": 0.1, "radiance": 1.0})),
            ),
            s.clone().edit_light(
                0,
                &spec(serde_json::json!({"type": "point",
                "position": [0, 1, 0], "intensity": 1e12})),
            ),
            s.clone().add_light(&spec(
                serde_json::json!({"type": "rect", "center": [0, 1, 0],
                "size": [1, 1], "normal": [0, -1, 0], "u_axis": [1, 0, 0], "radiance": 1.0,
                "samples": 5000}),
            )),
            s.clone()
                .add_light(&spec(serde_json::json!({"type": "emissive_mesh",
                "object": "floor", "radiance": 1.0}))),
            s.clone()
                .add_light(&spec(serde_json::json!({"type": "directional",
                "direction": [0, -1, 0], "irradiance": 1.0, "angle_deg": 120.0}))),
            s.clone()
                .add_light(&spec(serde_json::json!({"type": "cylinder",
                "center": [0, 1, 0], "axis": [0, 0, 0], "length": 1.0, "radius": 0.1,
                "radiance": 1.0}))),
        ];
        for (i, r) in bad.iter().enumerate() {
            assert!(r.is_err(), "edit {i} was taken");
        }
        assert_eq!(s, was);
        let mut one = Steer::new(&scene);
        one.remove_light(0).unwrap();
        assert!(one.remove_light(0).is_err(), "the last light stays");
        let mut sun = Steer::new(&scene);
        sun.edit_light(
            0,
            &spec(serde_json::json!({"type": "directional",
            "direction": [0, -1, 0], "irradiance": 1.0})),
        )
        .unwrap();
        assert!(
            sun.drag_light(0, 0.1, 0.0).is_err(),
            "a directional light has no position"
        );
        // The page's soft sun and tube: sampled like area lights; the tube drags by its centre.
        let mut soft = Steer::new(&scene);
        soft.add_light(&spec(serde_json::json!({"type": "directional",
            "direction": [0.3, -1, -0.2], "irradiance": 1.0, "angle_deg": 2.0, "samples": 16})))
            .unwrap();
        soft.add_light(&spec(
            serde_json::json!({"type": "cylinder", "center": [0, 2, 0],
            "axis": [1, 0, 0], "length": 1.0, "radius": 0.05, "radiance": 5.0}),
        ))
        .unwrap();
        let n = soft.scene_lights.len();
        assert!(soft.scene_lights[n - 2].is_area() && soft.scene_lights[n - 1].is_area());
        soft.drag_light(n as u32 - 1, 0.1, 0.0).unwrap();
        assert!(soft.drag_light(n as u32 - 2, 0.1, 0.0).is_err());
    }

    #[test]
    fn lights_put_back_by_the_loop_keep_the_settings_of_lights_that_stayed() {
        let scene = builtin("balls").unwrap();
        let mut s = Steer::new(&scene);
        s.set_light(0, [0.5, 0.5, 0.5], 3.0).unwrap();
        s.drag_light(1, 0.2, 0.0).unwrap();
        s.set_light(1, [0.1, 0.2, 0.3], 2.0).unwrap();
        s.add_light(&spec(
            serde_json::json!({"type": "point", "position": [0, 2, 0],
            "intensity": 3.0}),
        ))
        .unwrap();
        // The loop could not plan the drag and the addition: it renders the scene's lights.
        s.put_back_lights(&scene.lights);
        assert_eq!(s.scene_lights.as_ref(), &scene.lights);
        assert_eq!(s.lights.len(), scene.lights.len());
        assert_eq!((s.lights[0].color, s.lights[0].intensity), ([0.5; 3], 3.0));
        assert_eq!(
            s.lights[1],
            crate::camera::LightSetting::of(&scene.lights[1]),
            "light 1 was not the same"
        );
        assert_eq!(
            s.spec().lights.as_deref(),
            Some(&scene.lights),
            "frames carry them"
        );
    }

    #[test]
    fn mesh_lights_and_animated_lights_are_not_removed() {
        let cornell = builtin("cornell").unwrap();
        if let Some(i) = cornell
            .lights
            .iter()
            .position(|l| matches!(l.shape, LightShape::EmissiveMesh { .. }))
        {
            let mut s = Steer::new(&cornell);
            assert!(s.remove_light(i as u32).is_err());
            assert!(s.drag_light(i as u32, 0.1, 0.0).is_err());
        }
        let carousel = builtin("carousel").unwrap();
        let mut s = Steer::new(&carousel);
        assert!(s.animated_lights, "the carousel animates a light");
        assert!(s.remove_light(0).is_err());
        s.drag_light(0, 0.05, 0.0).unwrap();
    }
}
