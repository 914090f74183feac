//! Completing a scene that has geometry but no camera or no lights (every public glTF sample
//! model is like this): a camera framed on the bounds, a ground plane under them, and one
//! rectangular area light sized to them, so any model renders with soft shadows.

use crate::defaults;
use crate::model::{Camera, Light, LightShape, Material, Scene};
use crate::primitives;
use crate::shading::{V3, add, cross, dot, length, normalize, scale, sub};

/// Point samples of the added light: one area light × 32, like the built-ins.
pub const FRAMING_LIGHT_SAMPLES: u32 = 2 * defaults::SAMPLES_PER_AREA_LIGHT;
/// Irradiance (W/m²) the added light delivers at the centre of the bounds.
const TARGET_IRRADIANCE: f32 = 3.0;
const FRAMING_FOV_Y_DEG: f32 = 40.0;

/// Centre and radius of the scene's bounds (a unit sphere at the origin when empty).
fn sphere(scene: &Scene) -> (V3, f32) {
    match scene.bounds() {
        Some((lo, hi)) => {
            let c = scale(add(lo, hi), 0.5);
            (c, (0.5 * length(sub(hi, lo))).max(1e-3))
        }
        None => ([0.0; 3], 1.0),
    }
}

/// A camera in front of and above the bounds, looking at their centre, near enough that the
/// bounding box just fits the view (10 % margin).
pub fn framed_camera(scene: &Scene) -> Camera {
    let (lo, hi) = scene.bounds().unwrap_or(([-1.0; 3], [1.0; 3]));
    let c = scale(add(lo, hi), 0.5);
    let dir = normalize([0.0, 0.35, 1.0]);
    let right = normalize(cross([0.0, 1.0, 0.0], dir));
    let up = cross(dir, right);
    let (width, height) = (scene.camera.width.max(1), scene.camera.height.max(1));
    let t = 0.9 * (FRAMING_FOV_Y_DEG.to_radians() * 0.5).tan();
    let aspect = width as f32 / height as f32;
    // Each corner needs depth z ≥ |y|/t and z ≥ |x|/(t·aspect), with z = D − o·dir.
    let mut dist: f32 = 1e-3;
    for k in 0..8 {
        let corner = [0, 1, 2].map(|a| if k >> a & 1 == 0 { lo[a] } else { hi[a] });
        let o = sub(corner, c);
        let need = (dot(o, up).abs() / t).max(dot(o, right).abs() / (t * aspect));
        dist = dist.max(dot(o, dir) + need);
    }
    Camera {
        position: add(c, scale(dir, dist)),
        target: c,
        up: [0.0, 1.0, 0.0],
        fov_y_deg: FRAMING_FOV_Y_DEG,
        width,
        height,
    }
}

/// Adds a grey ground plane just under the bounds, eight radii wide.
pub fn add_ground(scene: &mut Scene) {
    let (lo, _) = scene.bounds().unwrap_or(([-1.0; 3], [1.0; 3]));
    let (c, r) = sphere(scene);
    let m = scene.add_material(Material::diffuse("ground", [0.6, 0.6, 0.6]));
    scene.add_mesh(primitives::plane(
        "ground",
        [c[0], lo[1] - 1e-4 * r, c[2]],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [8.0 * r, 8.0 * r],
        1,
        m,
    ));
}

/// Adds one square area light of side `r` above, left of and in front of the bounds, aimed at
/// their centre, with a radiance giving about 3 W/m² there.
pub fn add_area_light(scene: &mut Scene) {
    let (c, r) = sphere(scene);
    let center = add(c, [-1.2 * r, 2.2 * r, 1.2 * r]);
    let to_c = sub(c, center);
    let d = length(to_c);
    let normal = normalize(to_c);
    let u_axis = normalize(cross([0.0, 1.0, 0.0], normal));
    let side = r;
    // E ≈ L·A·cos θ_light·cos θ_ground / d², the light faces the centre (cos θ_light = 1).
    let cos_ground = dot(scale(normal, -1.0), [0.0, 1.0, 0.0]).max(0.1);
    let radiance = TARGET_IRRADIANCE * d * d / (side * side * cos_ground);
    scene.lights.push(Light {
        name: "framing light".into(),
        shape: LightShape::Rect {
            center,
            normal,
            u_axis,
            size: [side, side],
        },
        color: [1.0, 1.0, 1.0],
        power: radiance,
        range: None,
        samples: FRAMING_LIGHT_SAMPLES,
    });
}

/// Fills in what is missing: a framed camera when `has_camera` is false; a ground plane and an
/// area light when the scene has no lights.
pub fn complete(scene: &mut Scene, has_camera: bool) {
    complete_with(scene, has_camera, true);
}

/// As [`complete`], adding the ground plane only when `ground` is true (a scene file that builds
/// its own floor does not want a second one).
pub fn complete_with(scene: &mut Scene, has_camera: bool, ground: bool) {
    let needs_light = scene.lights.is_empty();
    // Light and camera are fitted to the model alone, before the ground widens the bounds.
    if needs_light {
        add_area_light(scene);
    }
    if !has_camera {
        scene.camera = framed_camera(scene);
    }
    if needs_light && ground {
        add_ground(scene);
    }
}
