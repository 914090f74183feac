//! Sanitising degenerate input: every problem is reported, fixed or dropped, and afterwards the
//! scene validates clean with every index in range.

use lightfold_scene::primitives;
use lightfold_scene::sampling::direct_samples;
use lightfold_scene::{Issue, Light, LightShape, Material, Mesh, Scene, Texture};

fn messy() -> Scene {
    let mut s = Scene::new("messy");
    let m = s.add_material(Material::diffuse("grey", [0.5; 3]));
    // 0: NaN position, a zero-area triangle, an out-of-range index, a zero normal.
    let mut a = primitives::plane(
        "a",
        [0.0; 3],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 1.0],
        2,
        m,
    );
    a.positions[8] = [f32::NAN, 0.0, 0.0];
    a.indices.extend_from_slice(&[0, 1, 2]); // collinear: the first row of the grid
    a.indices.extend_from_slice(&[0, 1, 99]);
    a.normals[0] = [0.0; 3];
    s.add_mesh(a);
    // 1: nothing usable → dropped; the emissive light on mesh 2 must be renumbered.
    s.add_mesh(Mesh {
        name: "empty".into(),
        positions: vec![[0.0; 3]; 3],
        normals: vec![],
        uvs: vec![[0.0; 2]; 2],
        tangents: Vec::new(),
        indices: vec![0, 0, 0],
        material: m,
    });
    // 2: a sphere with a dangling material.
    s.add_mesh(primitives::sphere("ball", [0.0, 1.0, 0.0], 0.5, 8, 4, 7));
    s.materials.push(Material {
        diffuse_texture: Some(5),
        shininess: f32::NAN,
        ..Material::diffuse("broken", [0.5; 3])
    });
    s.textures.push(Texture {
        name: "short".into(),
        width: 4,
        height: 4,
        srgb: true,
        rgba8: vec![0; 10],
    });
    let light = |shape, power| Light {
        name: "l".into(),
        shape,
        color: [1.0; 3],
        power,
        range: Some(-1.0),
        samples: 0,
    };
    s.lights = vec![
        light(LightShape::EmissiveMesh { mesh: 2 }, 1.0),
        light(LightShape::EmissiveMesh { mesh: 1 }, 1.0),
        light(
            LightShape::Rect {
                center: [0.0, 2.0, 0.0],
                normal: [0.0, -2.0, 0.0],
                u_axis: [1.0, 1.0, 0.0],
                size: [1.0, 1.0],
            },
            5.0,
        ),
        light(LightShape::Point { position: [0.0; 3] }, f32::INFINITY),
        light(
            LightShape::Disk {
                center: [0.0; 3],
                normal: [0.0; 3],
                radius: 1.0,
            },
            1.0,
        ),
    ];
    s.camera.fov_y_deg = 0.0;
    s.camera.width = 0;
    s.exposure = f32::NAN;
    s
}

#[test]
fn sanitize_reports_and_fixes_everything() {
    let mut s = messy();
    let before = s.validate();
    // (NaN != NaN, so compare canonical hashes rather than values.)
    assert_eq!(
        s.content_hash(),
        messy().content_hash(),
        "validate does not change the scene"
    );
    let report = s.sanitize();
    assert_eq!(before, report, "validate reports what sanitize fixes");
    let has = |f: &dyn Fn(&Issue) -> bool| report.issues.iter().any(f);
    assert!(
        has(&|i| matches!(i, Issue::NonFinitePositions { count: 1, .. })),
        "{report}"
    );
    assert!(has(&|i| matches!(
        i,
        Issue::IndexOutOfRange { count: 1, .. }
    )));
    assert!(has(&|i| matches!(i, Issue::DegenerateTriangles { .. })));
    assert!(has(&|i| matches!(i, Issue::BadNormals { count: 1, .. })));
    assert!(has(&|i| matches!(i, Issue::EmptyMesh { .. })));
    assert!(has(&|i| matches!(
        i,
        Issue::AttributeCount {
            attribute: "uvs",
            ..
        }
    )));
    assert!(has(&|i| matches!(
        i,
        Issue::MaterialOutOfRange { material: 7, .. }
    )));
    assert!(has(&|i| matches!(
        i,
        Issue::TextureOutOfRange { texture: 5, .. }
    )));
    assert!(has(&|i| matches!(i, Issue::TextureSize { .. })));
    assert!(has(&|i| matches!(i, Issue::BadMaterial { .. })));
    assert!(has(&|i| matches!(i, Issue::BadExposure)));
    assert!(has(&|i| matches!(i, Issue::BadCamera { .. })));
    println!("{report}");

    assert!(s.validate().is_clean(), "{}", s.validate());
    assert_eq!(s.meshes.len(), 2);
    // Dropped: the light on the empty mesh, the infinite point light, the zero-normal disk.
    assert_eq!(s.lights.len(), 2);
    assert_eq!(s.lights[0].shape, LightShape::EmissiveMesh { mesh: 1 });
    let LightShape::Rect { u_axis, .. } = s.lights[1].shape else {
        panic!("rect kept")
    };
    assert!(
        u_axis[1].abs() < 1e-6,
        "u axis projected into the light's plane: {u_axis:?}"
    );
    assert!(s.lights.iter().all(|l| l.samples >= 1 && l.range.is_none()));
    for m in &s.meshes {
        assert!(m.material < s.materials.len());
        assert!(m.indices.iter().all(|&i| (i as usize) < m.positions.len()));
        assert!(m.positions.iter().flatten().all(|c| c.is_finite()));
    }
    assert!(!direct_samples(&s).is_empty());
    // Sanitising is idempotent.
    assert!(s.sanitize().is_clean());
}

#[test]
fn clean_scenes_stay_untouched() {
    for name in lightfold_scene::builtin_names() {
        let s = lightfold_scene::builtin(name).unwrap();
        let mut t = s.clone();
        assert!(t.sanitize().is_clean(), "{name}");
        assert_eq!(s, t);
    }
}
