//! The steering state every viewer shares: the camera of the next frame and the lights' colours
//! and power multipliers, with a revision that counts changes. Camera moves are made here, on
//! the state as it is, so viewers steering at once compose their moves instead of overwriting
//! each other's.

use crate::clock::Clock;
use glam::Vec3;
use lightfold_coordinator::control::FrameSpec;
use lightfold_scene::{Camera, Light, Scene};
use std::sync::Arc;

/// Closest the camera may come to its target's up axis, degrees (orbit stops short of the poles).
const POLE_MARGIN_DEG: f32 = 2.0;
/// Largest single move, degrees, and the largest zoom step.
const MAX_TURN_DEG: f32 = 360.0;
const MAX_ZOOM_STEP: f32 = 10.0;
/// Largest colour component and power multiplier a viewer may set.
pub(crate) const MAX_LIGHT_VALUE: f32 = 1000.0;
/// Frame budgets a viewer may set, milliseconds.
pub(crate) const MIN_BUDGET_MS: f32 = 1.0;
pub(crate) const MAX_BUDGET_MS: f32 = 600_000.0;
/// Coordinates beyond this are refused (the scene's own bounds are far smaller).
pub(crate) const MAX_COORDINATE: f32 = 1e7;

/// A steering message that cannot be applied.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SteerError {
    #[error("{0} must be finite numbers")]
    NotFinite(&'static str),
    #[error("{0}")]
    OutOfRange(String),
    #[error("the scene has no light {0}")]
    UnknownLight(u32),
    #[error("{0}")]
    Degenerate(&'static str),
    #[error("{0}")]
    BadLight(String),
    #[error("{0}")]
    BadMove(String),
}

/// A light as the viewers set it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LightSetting {
    /// Linear colour.
    pub color: [f32; 3],
    /// Multiplier of the scene's power (1: as the scene has it).
    pub intensity: f32,
}

impl LightSetting {
    /// A light as it is: its own colour, its power multiplied by 1.
    pub fn of(light: &lightfold_scene::Light) -> LightSetting {
        LightSetting {
            color: light.color,
            intensity: 1.0,
        }
    }
}

/// What the next frame requested shows.
#[derive(Debug, Clone, PartialEq)]
pub struct Steer {
    pub camera: Camera,
    /// The scene's camera (`reset`).
    pub home: Camera,
    pub lights: Vec<LightSetting>,
    /// The scene's lights as edited (`crate::edit`); their colours and powers are what the
    /// settings in `lights` multiply.
    pub scene_lights: Arc<Vec<Light>>,
    /// Whether a viewer edited the lights (frames then carry them).
    pub lights_edited: bool,
    /// The scene animates some of its lights (none may then be removed).
    pub animated_lights: bool,
    /// Clip time of an animated scene, as it plays.
    pub clock: Clock,
    /// The frame budget a viewer set (µs; `Some(None)`: none); `None` until one does (the
    /// session's own, `--frame-budget`, holds).
    pub frame_budget_us: Option<Option<u64>>,
    /// The scene's objects as viewers moved them (`crate::objects`), by mesh.
    pub moves: Arc<Vec<lightfold_scene::moves::MeshMove>>,
    /// Whether a viewer moved objects (frames then carry the moves).
    pub moves_edited: bool,
    /// The scene a viewer opened, which frames carry (`None`: the session's first).
    pub open: Option<Arc<lightfold_coordinator::control::OpenScene>>,
    /// Counts changes, from 0 (the scene as loaded).
    pub revision: u64,
    /// When the revision last changed (the last input), or the state was made.
    pub changed_at: std::time::Instant,
}

impl Steer {
    pub fn new(scene: &Scene) -> Steer {
        Steer {
            camera: scene.camera,
            home: scene.camera,
            lights: scene.lights.iter().map(LightSetting::of).collect(),
            scene_lights: Arc::new(scene.lights.clone()),
            lights_edited: false,
            animated_lights: scene
                .animation
                .as_ref()
                .is_some_and(|a| a.moving_lights(scene.lights.len()).contains(&true)),
            clock: Clock::new(if scene.is_animated() {
                scene.animation.as_ref().map_or(0.0, |a| a.span())
            } else {
                0.0
            }),
            frame_budget_us: None,
            moves: Arc::new(Vec::new()),
            moves_edited: false,
            open: None,
            revision: 0,
            changed_at: std::time::Instant::now(),
        }
    }

    /// Counts a change: a new revision, made now (what the next frame requested shows).
    pub fn changed(&mut self) {
        self.revision += 1;
        self.changed_at = std::time::Instant::now();
    }

    /// Sets the frame budget the planner meets (`None`: none, planning at the scene's quality).
    pub fn set_budget(&mut self, ms: Option<f32>) -> Result<(), SteerError> {
        let us = match ms {
            None => None,
            Some(ms) => {
                finite(&[ms], "frame budget")?;
                if !(MIN_BUDGET_MS..=MAX_BUDGET_MS).contains(&ms) {
                    return Err(SteerError::OutOfRange(format!(
                        "a frame budget is between {MIN_BUDGET_MS} and {MAX_BUDGET_MS} ms"
                    )));
                }
                Some((f64::from(ms) * 1e3).round() as u64)
            }
        };
        self.frame_budget_us = Some(us);
        Ok(())
    }

    /// Jumps to scene time `t`, mapped into the clip (playing on from there if playing).
    pub fn seek(&mut self, t: f32) -> Result<(), SteerError> {
        self.clock.seek(t)
    }

    /// Starts or stops the scene's clock (no-op when already so, or for a still scene).
    pub fn play(&mut self, on: bool) {
        self.clock.play(on);
    }

    /// The frame request for this state: its camera, and every light's colour (colour × power
    /// multiplier: what the compositors' `c_n` scale by).
    pub fn spec(&self) -> FrameSpec {
        FrameSpec {
            camera: Some(lightfold_scene::wire::camera_to_wire(&self.camera)),
            light_colors: self
                .lights
                .iter()
                .enumerate()
                .map(|(i, l)| (i as u32, l.color.map(|c| c * l.intensity)))
                .collect(),
            time: self.clock.animated().then(|| self.clock.now()),
            frame_budget_us: self.frame_budget_us,
            refine: None,
            lights: self.lights_edited.then(|| Arc::clone(&self.scene_lights)),
            scene: self.open.clone(),
            moves: self.moves_edited.then(|| Arc::clone(&self.moves)),
        }
    }

    /// Turns the camera about its target: `yaw` about the up axis, `pitch` about the camera's
    /// right axis (positive raises the camera), stopping short of the poles.
    pub fn orbit(&mut self, yaw_deg: f32, pitch_deg: f32) -> Result<(), SteerError> {
        finite(&[yaw_deg, pitch_deg], "orbit angles")?;
        if yaw_deg.abs() > MAX_TURN_DEG || pitch_deg.abs() > MAX_TURN_DEG {
            return Err(SteerError::OutOfRange(format!(
                "an orbit turns at most {MAX_TURN_DEG}° at a time"
            )));
        }
        let (pos, target, up) = self.view_frame()?;
        let d = pos - target;
        let d = glam::Quat::from_axis_angle(up, yaw_deg.to_radians()) * d;
        // Pitch: the angle between d and up moves by -pitch, kept within the margins.
        let len = d.length();
        let polar = (d.dot(up) / len).clamp(-1.0, 1.0).acos();
        let lo = POLE_MARGIN_DEG.to_radians();
        let hi = std::f32::consts::PI - lo;
        let new_polar = (polar - pitch_deg.to_radians()).clamp(lo, hi);
        let horizontal = d - up * d.dot(up);
        let d = if horizontal.length() < 1e-6 * len {
            d
        } else {
            let h = horizontal.normalize();
            (h * new_polar.sin() + up * new_polar.cos()) * len
        };
        self.set_position(target + d)
    }

    /// Moves camera and target by `x` view widths right and `y` view heights up, at the
    /// target's distance.
    pub fn pan(&mut self, x: f32, y: f32) -> Result<(), SteerError> {
        finite(&[x, y], "pan")?;
        if x.abs() > 100.0 || y.abs() > 100.0 {
            return Err(SteerError::OutOfRange(
                "a pan moves at most 100 views at a time".into(),
            ));
        }
        let (pos, target, up) = self.view_frame()?;
        let forward = (target - pos).normalize();
        let right = forward.cross(up).normalize();
        let true_up = right.cross(forward);
        let dist = (target - pos).length();
        let half_h = dist * (self.camera.fov_y_deg.to_radians() * 0.5).tan();
        let half_w = half_h * self.camera.aspect();
        let offset = right * (x * 2.0 * half_w) + true_up * (y * 2.0 * half_h);
        let (p, t) = (pos + offset, target + offset);
        check_point(p)?;
        check_point(t)?;
        self.camera.position = p.to_array();
        self.camera.target = t.to_array();
        Ok(())
    }

    /// The world shift of `x` view widths right and `y` view heights up at the depth of point
    /// `p` (a point behind the camera at the target's distance): what dragging something at
    /// `p` across the view moves it by.
    pub(crate) fn view_shift(&self, p: Vec3, x: f32, y: f32) -> Result<Vec3, SteerError> {
        let (pos, target, up) = self.view_frame()?;
        let forward = (target - pos).normalize();
        let right = forward.cross(up).normalize();
        let true_up = right.cross(forward);
        let depth = (p - pos).dot(forward);
        let dist = if depth > 1e-3 {
            depth
        } else {
            (target - pos).length()
        };
        let half_h = dist * (self.camera.fov_y_deg.to_radians() * 0.5).tan();
        let half_w = half_h * self.camera.aspect();
        Ok(right * (x * 2.0 * half_w) + true_up * (y * 2.0 * half_h))
    }

    /// Multiplies the distance to the target by `factor` (< 1 moves closer).
    pub fn zoom(&mut self, factor: f32) -> Result<(), SteerError> {
        finite(&[factor], "zoom")?;
        if !(1.0 / MAX_ZOOM_STEP..=MAX_ZOOM_STEP).contains(&factor) {
            return Err(SteerError::OutOfRange(format!(
                "a zoom step is between 1/{MAX_ZOOM_STEP} and {MAX_ZOOM_STEP}"
            )));
        }
        let (pos, target, _) = self.view_frame()?;
        let d = (pos - target) * factor;
        if d.length() < 1e-4 {
            return Err(SteerError::Degenerate("the camera would reach its target"));
        }
        self.set_position(target + d)
    }

    /// Sets the camera (the image size stays the scene's).
    pub fn set_camera(
        &mut self,
        position: [f32; 3],
        target: [f32; 3],
        up: [f32; 3],
        fov_y_deg: f32,
    ) -> Result<(), SteerError> {
        finite(&position, "camera position")?;
        finite(&target, "camera target")?;
        finite(&up, "camera up")?;
        finite(&[fov_y_deg], "field of view")?;
        if !(1.0..=179.0).contains(&fov_y_deg) {
            return Err(SteerError::OutOfRange(
                "the field of view is between 1° and 179°".into(),
            ));
        }
        let next = Camera {
            position,
            target,
            up,
            fov_y_deg,
            ..self.camera
        };
        let before = std::mem::replace(&mut self.camera, next);
        if let Err(e) = self.view_frame().and_then(|(p, t, _)| {
            check_point(p)?;
            check_point(t)
        }) {
            self.camera = before;
            return Err(e);
        }
        Ok(())
    }

    pub fn reset(&mut self) {
        self.camera = self.home;
    }

    /// Sets a light's colour (linear) and power multiplier.
    pub fn set_light(
        &mut self,
        index: u32,
        color: [f32; 3],
        intensity: f32,
    ) -> Result<(), SteerError> {
        finite(&color, "light colour")?;
        finite(&[intensity], "light intensity")?;
        let ok = |v: f32| (0.0..=MAX_LIGHT_VALUE).contains(&v);
        if !color.iter().all(|&c| ok(c)) || !ok(intensity) {
            return Err(SteerError::OutOfRange(format!(
                "light colours and intensities are between 0 and {MAX_LIGHT_VALUE}"
            )));
        }
        let l = self
            .lights
            .get_mut(index as usize)
            .ok_or(SteerError::UnknownLight(index))?;
        *l = LightSetting { color, intensity };
        Ok(())
    }

    /// Position, target and unit up of the camera; an error if they make no view.
    pub(crate) fn view_frame(&self) -> Result<(Vec3, Vec3, Vec3), SteerError> {
        let pos = Vec3::from(self.camera.position);
        let target = Vec3::from(self.camera.target);
        let up = Vec3::from(self.camera.up);
        let d = pos - target;
        if d.length() < 1e-6 || up.length() < 1e-6 {
            return Err(SteerError::Degenerate(
                "the camera sits on its target or has no up",
            ));
        }
        if d.normalize().cross(up.normalize()).length() < 1e-6 {
            return Err(SteerError::Degenerate("the camera looks along its up axis"));
        }
        Ok((pos, target, up.normalize()))
    }

    fn set_position(&mut self, p: Vec3) -> Result<(), SteerError> {
        check_point(p)?;
        self.camera.position = p.to_array();
        Ok(())
    }
}

pub(crate) fn finite(v: &[f32], what: &'static str) -> Result<(), SteerError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(SteerError::NotFinite(what))
    }
}

pub(crate) fn check_point(p: Vec3) -> Result<(), SteerError> {
    if p.is_finite() && p.abs().max_element() <= MAX_COORDINATE {
        Ok(())
    } else {
        Err(SteerError::OutOfRange(format!(
            "coordinates are within ±{MAX_COORDINATE}"
        )))
    }
}
