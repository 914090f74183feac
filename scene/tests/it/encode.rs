//! Scene identity and wire form: content hashes are stable and ignore names, every built-in
//! survives `to_bytes`/`from_bytes` unchanged, and malformed bytes give errors, never panics.

use lightfold_scene::primitives;
use lightfold_scene::{Light, LightShape, Material, Scene, SceneError, builtin, builtin_names};
use proptest::prelude::*;

fn small() -> Scene {
    let mut s = Scene::new("small");
    let m = s.add_material(Material::diffuse("grey", [0.5, 0.5, 0.5]));
    s.add_mesh(primitives::cuboid("box", [0.0, 0.5, 0.0], [0.5; 3], m));
    s.lights.push(Light {
        name: "panel".into(),
        shape: LightShape::Rect {
            center: [0.0, 3.0, 0.0],
            normal: [0.0, -1.0, 0.0],
            u_axis: [1.0, 0.0, 0.0],
            size: [1.0, 1.0],
        },
        color: [1.0; 3],
        power: 10.0,
        range: None,
        samples: 16,
    });
    s
}

#[test]
fn content_hash_is_pinned() {
    // A change here means every cached scene is invalidated: do it on purpose only (last:
    // `Material::pbr` and `Mesh::tangents`, glTF metallic-roughness).
    assert_eq!(
        hex::encode(small().content_hash()),
        "4f0fd480b60f5d7932f1cccd5a5eb0bc5477ec269c7c81dbd8ae854c5d4579e3"
    );
}

#[test]
fn content_hash_ignores_names_and_sees_everything_else() {
    let base = small();
    let h = base.content_hash();
    let mut renamed = small();
    renamed.name = "other".into();
    renamed.meshes[0].name = "cube".into();
    renamed.materials[0].name = "stone".into();
    renamed.lights[0].name = "lamp".into();
    assert_eq!(renamed.content_hash(), h);
    assert_eq!(renamed.asset_hash(), base.asset_hash());

    let mut zero = small();
    zero.camera.target[0] = -0.0;
    assert_eq!(zero.content_hash(), h, "−0.0 hashes as 0.0");

    let changes: Vec<fn(&mut Scene)> = vec![
        |s| {
            let y = &mut s.meshes[0].positions[0][1];
            *y = f32::from_bits(y.to_bits() + 1);
        },
        |s| s.materials[0].diffuse[2] = 0.51,
        |s| s.lights[0].power = 10.5,
        |s| s.camera.fov_y_deg = 46.0,
        |s| s.exposure = 2.0,
        |s| s.ambient = [0.1; 3],
        |s| s.quality.seed = 7,
        |s| s.meshes[0].indices.swap(0, 1),
        |s| {
            s.materials[0].transmission = Some(lightfold_scene::Transmission {
                color: [0.5; 3],
                coverage: false,
            })
        },
        |s| {
            s.materials[0].transmission = Some(lightfold_scene::Transmission {
                color: [0.5; 3],
                coverage: true,
            })
        },
        |s| s.materials[0].pbr = Some(lightfold_scene::MetallicRoughness::new([0.5; 3], 0.0, 1.0)),
        |s| {
            let mut p = lightfold_scene::MetallicRoughness::new([0.5; 3], 0.0, 1.0);
            p.roughness = 0.5;
            s.materials[0].pbr = Some(p)
        },
        |s| {
            let mut p = lightfold_scene::MetallicRoughness::new([0.5; 3], 0.0, 1.0);
            p.occlusion_strength = 0.5;
            s.materials[0].pbr = Some(p)
        },
    ];
    for (i, change) in changes.iter().enumerate() {
        let mut s = small();
        change(&mut s);
        assert_ne!(s.content_hash(), h, "change {i} not seen");
    }
    // Lights and camera are not assets.
    let mut lit = small();
    lit.lights[0].power = 99.0;
    lit.camera.position = [9.0; 3];
    assert_eq!(lit.asset_hash(), base.asset_hash());
}

#[test]
fn builtins_round_trip_through_bytes() {
    for name in builtin_names() {
        let s = builtin(name).unwrap();
        assert!(s.validate().is_clean(), "{name}: {}", s.validate());
        assert_eq!(
            s.content_hash(),
            builtin(name).unwrap().content_hash(),
            "{name}"
        );
        let bytes = s.to_bytes().unwrap();
        let back = Scene::from_bytes(&bytes).unwrap();
        assert_eq!(back, s, "{name}");
        assert_eq!(back.content_hash(), s.content_hash());
        println!(
            "{name}: {} triangles, {} bytes, content {}",
            s.triangle_count(),
            bytes.len(),
            &hex::encode(s.content_hash())[..16]
        );
    }
}

#[test]
fn malformed_bytes_are_errors() {
    let bytes = small().to_bytes().unwrap();
    for cut in [0, 3, 8, 9, bytes.len() / 2, bytes.len() - 1] {
        assert!(
            matches!(
                Scene::from_bytes(&bytes[..cut]),
                Err(SceneError::Decode { .. })
            ),
            "cut {cut}"
        );
    }
    let mut wrong = bytes.clone();
    wrong[0] = b'X';
    assert!(
        Scene::from_bytes(&wrong)
            .unwrap_err()
            .to_string()
            .contains("magic")
    );
    let mut future = bytes.clone();
    future[4] = 9;
    assert!(
        Scene::from_bytes(&future)
            .unwrap_err()
            .to_string()
            .contains("version 9")
    );
    let mut longer = bytes.clone();
    longer.push(0);
    assert!(
        Scene::from_bytes(&longer)
            .unwrap_err()
            .to_string()
            .contains("trailing")
    );
    // A well-formed encoding of an unusable scene is refused too.
    let mut nan = small();
    nan.meshes[0].positions[3] = [f32::NAN, 0.0, 0.0];
    let err = Scene::from_bytes(&nan.to_bytes().unwrap()).unwrap_err();
    assert!(err.to_string().contains("non-finite"), "{err}");
    let mut dangling = small();
    dangling.meshes[0].indices[0] = 1000;
    assert!(Scene::from_bytes(&dangling.to_bytes().unwrap()).is_err());
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 256,
        failure_persistence: None,
        ..ProptestConfig::default()
    })]
    #[test]
    fn random_bytes_never_panic(mut tail in proptest::collection::vec(any::<u8>(), 0..512)) {
        let mut bytes = b"LFSC\x01\x00\x00\x00".to_vec();
        bytes.append(&mut tail);
        let _ = Scene::from_bytes(&bytes);
    }

    #[test]
    fn flipped_bytes_never_panic(at in 0usize..4096, bit in 0u8..8) {
        let mut bytes = small().to_bytes().unwrap();
        let i = at % bytes.len();
        bytes[i] ^= 1 << bit;
        let _ = Scene::from_bytes(&bytes);
    }
}
