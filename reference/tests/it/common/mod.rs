//! Scene builders and closed forms shared by the reference tests.

use lightfold_scene::primitives::{cuboid, plane};
use lightfold_scene::shading::{V3, cross, length, normalize, sub};
use lightfold_scene::{Camera, Light, LightShape, Material, Mesh, Quality, Scene};

pub(crate) fn camera(position: V3, target: V3, up: V3, fov: f32, w: u32, h: u32) -> Camera {
    Camera {
        position,
        target,
        up,
        fov_y_deg: fov,
        width: w,
        height: h,
    }
}

pub(crate) fn scene(
    meshes: Vec<Mesh>,
    materials: Vec<Material>,
    lights: Vec<Light>,
    cam: Camera,
) -> Scene {
    Scene {
        name: "test".into(),
        meshes,
        materials,
        textures: Vec::new(),
        lights,
        camera: cam,
        ambient: [0.0; 3],
        exposure: 1.0,
        quality: Quality::default(),
        animation: None,
    }
}

/// A 20 m ground plane at y = 0 facing +y with material 0.
pub(crate) fn ground(material: usize) -> Mesh {
    plane(
        "ground",
        [0.0; 3],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [20.0, 20.0],
        1,
        material,
    )
}

pub(crate) fn point_light(position: V3, power: f32) -> Light {
    Light {
        name: "point".into(),
        shape: LightShape::Point { position },
        color: [1.0; 3],
        power,
        range: None,
        samples: 1,
    }
}

/// A downward-facing rectangle light at height `y` of size `w × d` centred over `(cx, cz)`.
pub(crate) fn rect_light(center: V3, size: [f32; 2], radiance: f32, samples: u32) -> Light {
    Light {
        name: "rect".into(),
        shape: LightShape::Rect {
            center,
            normal: [0.0, -1.0, 0.0],
            u_axis: [1.0, 0.0, 0.0],
            size,
        },
        color: [1.0; 3],
        power: radiance,
        range: None,
        samples,
    }
}

/// Camera straight above the origin looking down (image rows run along +z).
pub(crate) fn top_camera(height: f32, fov: f32, w: u32, h: u32) -> Camera {
    camera([0.0, height, 0.0], [0.0; 3], [0.0, 0.0, -1.0], fov, w, h)
}

/// Where the centre ray of pixel `(x, y)` meets the plane y = 0.
pub(crate) fn ground_point(cam: &Camera, x: u32, y: u32) -> V3 {
    let d = cam.ray_dir(x as f32 + 0.5, y as f32 + 0.5);
    let o = cam.position;
    let t = -o[1] / d[1];
    [o[0] + t * d[0], 0.0, o[2] + t * d[2]]
}

/// Lambert's formula: irradiance at `p` (unit normal `n`) from a uniformly emitting polygon of
/// radiance `l` (vertices in order, polygon wholly above the tangent plane), in f64.
pub(crate) fn polygon_irradiance(p: V3, n: V3, verts: &[V3], l: f64) -> f64 {
    let p = p.map(f64::from);
    let n = n.map(f64::from);
    let v: Vec<[f64; 3]> = verts
        .iter()
        .map(|q| {
            let d = [0, 1, 2].map(|k| f64::from(q[k]) - p[k]);
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            d.map(|c| c / len)
        })
        .collect();
    let mut sum = 0.0;
    for i in 0..v.len() {
        let a = v[i];
        let b = v[(i + 1) % v.len()];
        let c = [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ];
        let cl = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
        let theta = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2])
            .clamp(-1.0, 1.0)
            .acos();
        sum += theta * (c[0] * n[0] + c[1] * n[1] + c[2] * n[2]) / cl;
    }
    (0.5 * l * sum).abs()
}

/// The four corners of a rectangle light, in order.
pub(crate) fn rect_corners(center: V3, normal: V3, u_axis: V3, size: [f32; 2]) -> [V3; 4] {
    let u = normalize(u_axis);
    let v = cross(normalize(normal), u);
    let c = |a: f32, b: f32| -> V3 {
        [0, 1, 2].map(|k| center[k] + a * size[0] * 0.5 * u[k] + b * size[1] * 0.5 * v[k])
    };
    [c(-1.0, -1.0), c(1.0, -1.0), c(1.0, 1.0), c(-1.0, 1.0)]
}

/// Closed-form diffuse radiance from a point light of intensity `i` at `light` on the ground.
pub(crate) fn point_on_ground(light: V3, p: V3, i: f32, albedo: f32) -> f64 {
    let d = sub(light, p);
    let r = f64::from(length(d));
    let cos = f64::from(d[1]) / r;
    f64::from(i) * cos / (r * r) / std::f64::consts::PI * f64::from(albedo)
}

/// A box occluder.
pub(crate) fn occluder(center: V3, half: V3, material: usize) -> Mesh {
    cuboid("box", center, half, material)
}

pub(crate) fn assert_close(got: f64, want: f64, rel: f64, what: &str) {
    let err = (got - want).abs() / want.abs().max(1e-12);
    assert!(
        err <= rel,
        "{what}: got {got}, want {want}, relative error {err:e} > {rel:e}"
    );
}
