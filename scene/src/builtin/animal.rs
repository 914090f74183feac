//! "animal": the Fox model (Khronos glTF sample, CC0 / CC-BY 4.0, `assets/Fox/LICENSE.md`),
//! compiled into the crate, scaled from centimetres to metres and shown in its rest pose among a
//! few stones and a log under one area light of 32 samples (the paper's bottom-right setting).

use super::{camera, rect_light};
use crate::error::SceneError;
use crate::gltf_load::{GltfOptions, load_gltf_slice};
use crate::model::{Material, Scene};
use crate::primitives;
use glam::{Affine3A, Quat, Vec3};

const FOX_GLB: &[u8] = include_bytes!("../../../assets/Fox/Fox.glb");

pub(super) fn build() -> Result<Scene, SceneError> {
    let opts = GltfOptions {
        scale: 0.01,
        translation: [0.0; 3],
        complete: false,
        animation: None,
    };
    let mut s = load_gltf_slice(FOX_GLB, "assets/Fox/Fox.glb", None, &opts)?;
    s.name = "animal".into();
    let ground = s.add_material(Material::diffuse("ground", [0.55, 0.6, 0.45]));
    s.add_mesh(primitives::plane(
        "ground",
        [0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [12.0, 12.0],
        1,
        ground,
    ));
    let stone = s.add_material(Material::diffuse("stone", [0.45, 0.44, 0.42]));
    for (i, (x, z, r)) in [(0.75, -0.35, 0.16), (-0.55, 0.55, 0.11), (0.5, 0.75, 0.08)]
        .into_iter()
        .enumerate()
    {
        let mut m = primitives::sphere(&format!("stone{i}"), [0.0; 3], r, 24, 12, stone);
        // Flattened stones sitting on the ground.
        m.transform(&Affine3A::from_scale_rotation_translation(
            Vec3::new(1.3, 0.6, 1.0),
            Quat::from_rotation_y(0.7 * i as f32),
            Vec3::new(x, 0.6 * r, z),
        ));
        s.add_mesh(m);
    }
    let wood = s.add_material(Material::diffuse("log", [0.4, 0.27, 0.15]));
    let mut log = primitives::cylinder("log", [0.0; 3], 0.09, 1.3, 16, wood);
    log.transform(&Affine3A::from_rotation_translation(
        Quat::from_rotation_y(0.4) * Quat::from_rotation_z(std::f32::consts::FRAC_PI_2),
        Vec3::new(0.45, 0.09, -0.9),
    ));
    s.add_mesh(log);
    let mut light = rect_light(
        "sun",
        [-1.3, 2.2, 1.2],
        [0.0, 0.3, 0.0],
        0.8,
        45.0,
        [1.0, 0.95, 0.88],
    );
    light.samples = 32;
    s.lights = vec![light];
    s.camera = camera([2.2, 1.2, 2.0], [0.0, 0.35, -0.1], 38.0);
    let report = s.sanitize();
    if !report.is_clean() {
        tracing::warn!(%report, "animal scene sanitised");
    }
    Ok(s)
}
