//! Each operator against pixels computed by hand from the paper's equations (§3, eq. 2–7). Values
//! are dyadic so the expected results are exact; both the fast and the reference version are held
//! to them.

use crate::common;

use common::{Owned, run};
use lightfold_compositor::ops::{self, MAX_VALUE, OpError, Operator};
use lightfold_protocol::Layer;
use serde_json::json;

fn band(layers: &[(Layer, &[f32])]) -> Owned {
    let pixels = layers[0].1.len() / layers[0].0.channels();
    Owned {
        pixels,
        layers: layers.iter().map(|(l, d)| (*l, d.to_vec())).collect(),
    }
}

/// Runs both versions and checks them against `expected` exactly.
fn check(op: &dyn Operator, inputs: &[Owned], expected: &[(Layer, &[f32])]) {
    let pixels = inputs[0].pixels;
    for scalar in [true, false] {
        let out = run(op, inputs, pixels, scalar);
        for (layer, want) in expected {
            assert_eq!(
                out.layer(*layer),
                *want,
                "{} scalar={scalar} {layer:?}",
                op.name()
            );
        }
    }
}

const P: [f32; 6] = [0.25, 0.5, 0.75, 1.0, 1.5, 2.0];
const I1: [f32; 6] = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0];
const I2: [f32; 6] = [8.0, 0.0, 0.5, 0.25, 2.0, 1.0];

#[test]
fn accumulate_paper_eq3() {
    // p1 = p0 + c1 ⊙ I1 + c2 ⊙ I2, diffuse and specular alike.
    let op = ops::create("accumulate", &json!({"colors": [[0.5, 1, 2], [1, 0.5, 4]]})).unwrap();
    let inputs = [
        band(&[(Layer::Illumination, &P)]),
        band(&[(Layer::Illumination, &I1)]),
        band(&[(Layer::Illumination, &I2)]),
    ];
    let want = [
        0.25 + 0.5 + 8.0,
        0.5 + 2.0 + 0.0,
        0.75 + 6.0 + 2.0,
        1.0 + 2.0 + 0.25,
        1.5 + 5.0 + 1.0,
        2.0 + 12.0 + 4.0,
    ];
    check(&*op, &inputs, &[(Layer::Illumination, &want)]);
}

#[test]
fn accumulate_split_colours_first_stage_and_empty_band() {
    // The paper's separate c^d and c^s; no upstream (first stage); the second node's band is
    // empty (range-culled) and contributes nothing.
    let op = ops::create(
        "accumulate",
        &json!({"upstream": false, "colors": [
            {"diffuse": [2, 2, 2], "specular": [0.5, 0.5, 0.5]}, [9, 9, 9]]}),
    )
    .unwrap();
    let inputs = [band(&[(Layer::Illumination, &I1)]), Owned::zeros(1, &[])];
    let want = [2.0, 4.0, 6.0, 2.0, 2.5, 3.0];
    check(&*op, &inputs, &[(Layer::Illumination, &want)]);
}

#[test]
fn accumulate_eq4_uniform_specular() {
    // p^s_n = p^s_{n-1} + (m^s ⊙ c^s_n) I^s_n.
    let op = ops::create(
        "accumulate",
        &json!({"colors": [[2, 2, 2]], "specular_color": [0.5, 0.25, 1]}),
    )
    .unwrap();
    let inputs = [
        band(&[(Layer::Illumination, &P)]),
        band(&[(Layer::Illumination, &I1)]),
    ];
    let want = [2.25, 4.5, 6.75, 1.0 + 4.0, 1.5 + 2.5, 2.0 + 12.0];
    check(&*op, &inputs, &[(Layer::Illumination, &want)]);
}

#[test]
fn accumulate_eq6_ambient_folding() {
    // p^d_n = p^d_{n-1} + c^d_n (I^d_n + I^a), I^a = 1 (every material has m^a = m^d).
    let op = ops::create(
        "accumulate",
        &json!({"colors": [[0.5, 1, 2]], "ambient": {"input": 1}}),
    )
    .unwrap();
    let inputs = [
        band(&[(Layer::Illumination, &P)]),
        band(&[(Layer::Illumination, &I1)]),
    ];
    let want = [0.25 + 1.0, 0.5 + 3.0, 0.75 + 8.0, 3.0, 6.5, 14.0];
    check(&*op, &inputs, &[(Layer::Illumination, &want)]);
    // An empty band on the folding node still adds the ambient term.
    let inputs = [band(&[(Layer::Illumination, &P)]), Owned::zeros(1, &[])];
    let want = [0.75, 1.5, 2.75, 1.0, 1.5, 2.0];
    check(&*op, &inputs, &[(Layer::Illumination, &want)]);
}

#[test]
fn accumulate_eq7_ambient_mask_layer() {
    // I^a per pixel: 1 where m^a = m^d, 0 elsewhere (two pixels).
    let op = ops::create(
        "accumulate",
        &json!({"upstream": false, "colors": [[2, 2, 2]], "ambient": {"input": 0, "mask": "layer"}}),
    )
    .unwrap();
    let ill: Vec<f32> = [I1, I1].concat();
    let mask = [1.0, 1.0, 1.0, 0.0, 0.0, 0.0];
    let inputs = [band(&[
        (Layer::Illumination, &ill),
        (Layer::AmbientMask, &mask),
    ])];
    let want = [
        4.0, 6.0, 8.0, 8.0, 10.0, 12.0, // I^a = 1
        2.0, 4.0, 6.0, 8.0, 10.0, 12.0, // I^a = 0
    ];
    check(&*op, &inputs, &[(Layer::Illumination, &want)]);
    // The mask is its own layer: an input with the material's m^a (`ambient`) instead is refused.
    let with_ma = [band(&[
        (Layer::Illumination, &ill),
        (Layer::Ambient, &mask),
    ])];
    let mut out = Owned::zeros(2, &[Layer::Illumination]);
    let views: Vec<_> = with_ma.iter().map(Owned::view).collect();
    assert!(matches!(
        op.apply(&views, &mut out.view_mut()),
        Err(OpError::MissingLayer {
            layer: Layer::AmbientMask,
            ..
        })
    ));
}

#[test]
fn eq7_mask_fold_equals_the_ambient_layer() {
    // Two pixels, one material each: m^a = m^d and m^a = 0. Eq. 7 (c^a folded at a node of
    // colour c^a, masked by I^a = m^a ⊘ m^d, then m^d ⊙ the sum) equals eq. 2's ambient layer
    // (m^d ⊙ the sum + c^a ⊙ m^a).
    let ca = [2.0, 0.5, 4.0];
    let md = [0.5, 0.25, 1.0, 0.25, 0.5, 0.75];
    let ma = [0.5, 0.25, 1.0, 0.0, 0.0, 0.0];
    let mask = [1.0, 1.0, 1.0, 0.0, 0.0, 0.0];
    let ill: Vec<f32> = [I1, I2].concat();
    let materials = band(&[(Layer::Diffuse, &md), (Layer::Ambient, &ma)]);
    let single = |ambient: bool| {
        let mut p = json!({"stage": "single"});
        if ambient {
            p["ambient_color"] = json!(ca);
        }
        ops::create("material", &p).unwrap()
    };
    // Eq. 2: the node of colour c^a sums its own light only; the ambient layer adds c^a ⊙ m^a.
    let plain = ops::create(
        "accumulate",
        &json!({"upstream": false, "colors": [ca], "specular_color": [0, 0, 0]}),
    )
    .unwrap();
    let masked = ops::create(
        "accumulate",
        &json!({"upstream": false, "colors": [ca], "specular_color": [0, 0, 0],
                "ambient": {"input": 0, "mask": "layer"}}),
    )
    .unwrap();
    for scalar in [true, false] {
        let sum = run(&*plain, &[band(&[(Layer::Illumination, &ill)])], 2, scalar);
        let eq2 = run(&*single(true), &[sum, materials.clone()], 2, scalar);
        let folded = run(
            &*masked,
            &[band(&[
                (Layer::Illumination, &ill),
                (Layer::AmbientMask, &mask),
            ])],
            2,
            scalar,
        );
        let eq7 = run(&*single(false), &[folded, materials.clone()], 2, scalar);
        assert_eq!(
            eq7.layer(Layer::Radiance),
            eq2.layer(Layer::Radiance),
            "scalar={scalar}"
        );
        // Negative control: the mask read as all ones (eq. 6) adds c^a where m^a = 0.
        let uniform = ops::create(
            "accumulate",
            &json!({"upstream": false, "colors": [ca], "specular_color": [0, 0, 0],
                    "ambient": {"input": 0, "mask": "uniform"}}),
        )
        .unwrap();
        let folded = run(
            &*uniform,
            &[band(&[(Layer::Illumination, &ill)])],
            2,
            scalar,
        );
        let eq6 = run(&*single(false), &[folded, materials.clone()], 2, scalar);
        assert_ne!(eq6.layer(Layer::Radiance), eq2.layer(Layer::Radiance));
    }
}

#[test]
fn accumulate_value_policy() {
    let op = ops::create("accumulate", &json!({"colors": [[1, 1, 2]]})).unwrap();
    let up = [f32::NAN, -1.0, f32::INFINITY, 1.0, 3e38, 1.0];
    let local = [1.0, f32::NEG_INFINITY, 1.0, f32::NAN, 3e38, -0.0];
    let inputs = [
        band(&[(Layer::Illumination, &up)]),
        band(&[(Layer::Illumination, &local)]),
    ];
    // NaN and negatives read as 0, +Inf as MAX; overflowing sums saturate at MAX.
    let want = [1.0, 0.0, MAX_VALUE, 1.0, MAX_VALUE, 1.0];
    check(&*op, &inputs, &[(Layer::Illumination, &want)]);
}

const MD: [f32; 3] = [0.5, 0.25, 1.0];
const MS: [f32; 3] = [0.25, 1.0, 0.5];
const MA: [f32; 3] = [1.0, 0.5, 0.0];
const E: [f32; 3] = [0.125, 0.0, 4.0];

#[test]
fn material_paper_nodes() {
    let mat = |stage: &str, extra: serde_json::Value| {
        let mut p = json!({"stage": stage});
        p.as_object_mut()
            .unwrap()
            .extend(extra.as_object().unwrap().clone());
        ops::create("material", &p).unwrap()
    };
    let ill = band(&[(Layer::Illumination, &I1)]);
    // Specular node N+1: p^s ⊙ S, diffuse passes.
    let s = band(&[(Layer::Specular, &MS)]);
    let after_s = [1.0, 2.0, 3.0, 1.0, 5.0, 3.0];
    check(
        &*mat("specular", json!({})),
        &[ill.clone(), s],
        &[(Layer::Illumination, &after_s)],
    );
    // Diffuse node N+2: p^d ⊙ D + p^s.
    let d = band(&[(Layer::Diffuse, &MD)]);
    let after_d = [0.5 + 1.0, 0.5 + 5.0, 3.0 + 3.0];
    check(
        &*mat("diffuse", json!({})),
        &[band(&[(Layer::Illumination, &after_s)]), d.clone()],
        &[(Layer::Radiance, &after_d)],
    );
    // Ambient node N+3: + A ⊙ c^a.
    let a = band(&[(Layer::Ambient, &MA)]);
    let after_a = [1.5 + 2.0, 5.5 + 0.25, 6.0];
    check(
        &*mat("ambient", json!({"ambient_color": [2, 0.5, 8]})),
        &[band(&[(Layer::Radiance, &after_d)]), a],
        &[(Layer::Radiance, &after_a)],
    );
    // Emissive node N+4: E + p.
    let e = band(&[(Layer::Emissive, &E)]);
    let after_e = [3.625, 5.75, 10.0];
    check(
        &*mat("emissive", json!({})),
        &[band(&[(Layer::Radiance, &after_a)]), e],
        &[(Layer::Radiance, &after_e)],
    );
    // The single stage of eq. 2 with every layer gives the four nodes' result.
    let all = band(&[
        (Layer::Diffuse, &MD),
        (Layer::Specular, &MS),
        (Layer::Ambient, &MA),
        (Layer::Emissive, &E),
    ]);
    let single = mat(
        "single",
        json!({"specular": true, "emissive": true, "ambient_color": [2, 0.5, 8]}),
    );
    check(
        &*single,
        &[ill.clone(), all],
        &[(Layer::Radiance, &after_e)],
    );
    // Eq. 5: one material node over a pre-multiplied specular sum.
    let eq5 = [0.5 + 4.0, 0.5 + 5.0, 3.0 + 6.0];
    check(
        &*mat("single", json!({})),
        &[ill, d],
        &[(Layer::Radiance, &eq5)],
    );
}

#[test]
fn depth_nearest_and_ties() {
    let op = ops::create("depth", &json!({"inputs": 3})).unwrap();
    // Pixel 0: 5, 3, 3 → input 1 (tie with 2 goes to the lower index).
    // Pixel 1: NaN, 7, +Inf → input 1; pixel 2: all NaN → input 0, depth +Inf.
    let z = [
        [5.0, f32::NAN, f32::NAN],
        [3.0, 7.0, f32::NAN],
        [3.0, f32::INFINITY, f32::NAN],
    ];
    let inputs: Vec<Owned> = (0..3)
        .map(|i| {
            let ill: Vec<f32> = (0..18).map(|k| (i * 100 + k) as f32).collect();
            band(&[(Layer::Depth, &z[i]), (Layer::Illumination, &ill)])
        })
        .collect();
    let mut ill = Vec::new();
    ill.extend((0..6).map(|k| (100 + k) as f32));
    ill.extend((6..12).map(|k| (100 + k) as f32));
    ill.extend((12..18).map(|k| k as f32));
    check(
        &*op,
        &inputs,
        &[
            (Layer::Depth, &[3.0, 7.0, f32::INFINITY]),
            (Layer::Illumination, &ill),
        ],
    );
    // Reversed-Z: larger is nearer, NaN and negatives are the far plane 0.
    let rev = ops::create("depth", &json!({"inputs": 3, "reversed_z": true})).unwrap();
    let mut ill = Vec::new();
    ill.extend((0..6).map(|k| k as f32));
    ill.extend((6..12).map(|k| (200 + k) as f32));
    ill.extend((12..18).map(|k| k as f32));
    check(
        &*rev,
        &inputs,
        &[
            (Layer::Depth, &[5.0, f32::INFINITY, 0.0]),
            (Layer::Illumination, &ill),
        ],
    );
}

#[test]
fn depth_with_zero_empty_reads_a_node_eye_depth() {
    // Render nodes write eye depth with 0 where no surface covers the pixel (a sort-last part's
    // background): under `zero_is_empty` that never wins, and a pixel no input covers leaves 0.
    let op = ops::create("depth", &json!({"inputs": 2, "zero_is_empty": true})).unwrap();
    // Pixel 0: 0 (empty), 4 → input 1; pixel 1: 2, 0 → input 0; pixel 2: both empty → input 0,
    // depth 0; pixel 3: 3, 3 → input 0 (tie).
    let z = [[0.0, 2.0, 0.0, 3.0], [4.0, 0.0, 0.0, 3.0]];
    let inputs: Vec<Owned> = (0..2)
        .map(|i| {
            let ill: Vec<f32> = (0..24).map(|k| (i * 100 + k) as f32).collect();
            band(&[(Layer::Depth, &z[i]), (Layer::Illumination, &ill)])
        })
        .collect();
    let mut ill: Vec<f32> = (0..6).map(|k| (100 + k) as f32).collect();
    ill.extend((6..24).map(|k| k as f32));
    check(
        &*op,
        &inputs,
        &[
            (Layer::Depth, &[4.0, 2.0, 0.0, 3.0]),
            (Layer::Illumination, &ill),
        ],
    );
    // The control: read linearly, an empty 0 is the nearest and wins pixels 0 and 1.
    let linear = ops::create("depth", &json!({"inputs": 2})).unwrap();
    let out: Vec<f32> = (0..24)
        .map(|k| if (6..12).contains(&k) { 100 + k } else { k } as f32)
        .collect();
    check(
        &*linear,
        &inputs,
        &[
            (Layer::Depth, &[0.0, 0.0, 0.0, 3.0]),
            (Layer::Illumination, &out),
        ],
    );
    // It reads linear depth only.
    assert!(
        ops::create(
            "depth",
            &json!({"inputs": 2, "zero_is_empty": true, "reversed_z": true})
        )
        .is_err()
    );
}

#[test]
fn merge_puts_layers_of_inputs_together() {
    // Input 0 gives its illumination (and carries a diffuse layer merge does not take); input 1
    // its depth (bit for bit, NaN and 0 included) and diffuse.
    let op = ops::create(
        "merge",
        &json!({"inputs": [["illumination"], ["depth", "diffuse"]]}),
    )
    .unwrap();
    let sig = op.signature();
    assert_eq!(
        sig.outputs,
        [Layer::Illumination, Layer::Depth, Layer::Diffuse]
    );
    let z = [f32::NAN, 0.0];
    let d = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6];
    let il: [f32; 12] = [
        1.0,
        f32::NAN,
        -2.0,
        f32::INFINITY,
        5.0,
        6.0,
        7.0,
        8.0,
        9.0,
        10.0,
        11.0,
        12.0,
    ];
    let inputs = [
        band(&[(Layer::Illumination, &il), (Layer::Diffuse, &[9.0; 6])]),
        band(&[(Layer::Depth, &z), (Layer::Diffuse, &d)]),
    ];
    let mut want_il = il;
    want_il[1] = 0.0;
    want_il[2] = 0.0;
    want_il[3] = MAX_VALUE;
    check(
        &*op,
        &inputs,
        &[(Layer::Illumination, &want_il), (Layer::Diffuse, &d)],
    );
    for scalar in [true, false] {
        let out = run(&*op, &inputs, 2, scalar);
        let bits: Vec<u32> = out
            .layer(Layer::Depth)
            .iter()
            .map(|v| v.to_bits())
            .collect();
        assert_eq!(bits, z.map(f32::to_bits), "scalar={scalar}");
    }
    // An input without a layer it should give is refused.
    let mut out = Owned::zeros(2, &sig.outputs);
    let swapped = [inputs[1].clone(), inputs[0].clone()];
    let views: Vec<_> = swapped.iter().map(Owned::view).collect();
    assert!(matches!(
        op.apply(&views, &mut out.view_mut()),
        Err(OpError::MissingLayer { input: 0, .. })
    ));
}

#[test]
fn join_sums_in_order() {
    let op = ops::create("join", &json!({"inputs": 3, "layer": "radiance"})).unwrap();
    let inputs = [
        band(&[(Layer::Radiance, &[1.0, f32::NAN, 2.0])]),
        Owned::zeros(1, &[]),
        band(&[(Layer::Radiance, &[0.5, 4.0, -2.0])]),
    ];
    check(&*op, &inputs, &[(Layer::Radiance, &[1.5, 4.0, 2.0])]);
}

#[test]
fn blend_is_over_back_to_front() {
    // Back R0 = 1 (per channel); a red glass (T = [0.9, 0.1, 0.1], its own 0.05 of reflection)
    // over it; a half-covered white film (α = 0.5: R = 0.5·0.8, T = 0.5) nearest.
    // out = R2 + T2 ⊙ (R1 + T1 ⊙ R0).
    let op = ops::create("blend", &json!({"inputs": 3})).unwrap();
    let inputs = [
        band(&[(Layer::Radiance, &[1.0, 1.0, 1.0])]),
        band(&[
            (Layer::Radiance, &[0.05, 0.05, 0.05]),
            (Layer::Transmittance, &[0.9, 0.1, 0.1]),
        ]),
        band(&[
            (Layer::Radiance, &[0.4, 0.4, 0.4]),
            (Layer::Transmittance, &[0.5, 0.5, 0.5]),
        ]),
    ];
    let want: Vec<f32> = [0.9f32, 0.1, 0.1]
        .iter()
        .map(|t| 0.4 + 0.5 * (0.05 + t * 1.0))
        .collect();
    check(&*op, &inputs, &[(Layer::Radiance, &want)]);
    // Order matters: the film behind the glass tints differently.
    let swapped = [inputs[0].clone(), inputs[2].clone(), inputs[1].clone()];
    let out = common::run(&*op, &swapped, 1, false);
    assert_ne!(out.layer(Layer::Radiance), &want[..]);
    // An empty front band (no layer there) lets the back through; hostile transmittance is
    // clamped to [0, 1] (NaN hides: 0), hostile radiance follows the value policy.
    let inputs = [
        band(&[(Layer::Radiance, &[2.0, 2.0, 2.0, 2.0, 2.0, 2.0])]),
        Owned::zeros(2, &[]),
        band(&[
            (
                Layer::Radiance,
                &[f32::NAN, -1.0, 0.25, f32::INFINITY, 0.0, 0.0],
            ),
            (
                Layer::Transmittance,
                &[f32::NAN, 3.0, -1.0, 0.5, f32::INFINITY, 0.25],
            ),
        ]),
    ];
    check(
        &*op,
        &inputs,
        &[(Layer::Radiance, &[0.0, 2.0, 0.25, MAX_VALUE, 2.0, 0.5])],
    );
    // Fewer than two inputs is not a blend.
    assert!(matches!(
        ops::create("blend", &json!({"inputs": 1})),
        Err(OpError::BadParam { .. })
    ));
}

#[test]
fn output_linear_and_srgb8() {
    let op = ops::Output::new(&json!({"exposure": 2.0})).unwrap();
    let lin = [0.25, f32::NAN, -1.0, f32::INFINITY, 0.001, 0.5];
    let inputs = [band(&[(Layer::Radiance, &lin)])];
    check(
        &op,
        &inputs,
        &[(Layer::Radiance, &[0.25, 0.0, 0.0, MAX_VALUE, 0.001, 0.5])],
    );
    // sRGB(2·0.25) = 0.7354 → 188; 2·0.001 = 0.002 is on the linear segment: 12.92·0.002·255
    // = 6.59 → 7; Inf is white; 2·0.5 = 1 → 255.
    let want = [188, 0, 0, 255, 7, 255];
    let mut fast = [0u8; 6];
    let mut reference = [0u8; 6];
    op.encode_srgb8(&lin, &mut fast).unwrap();
    op.encode_srgb8_scalar(&lin, &mut reference).unwrap();
    assert_eq!(fast, want);
    assert_eq!(reference, want);
    assert!(matches!(
        op.encode_srgb8(&lin, &mut [0u8; 5]),
        Err(OpError::BufferLength { .. })
    ));
}

#[test]
fn registry_and_errors() {
    let names: Vec<&str> = ops::registry().iter().map(|(n, _)| *n).collect();
    assert_eq!(
        names,
        [
            "accumulate",
            "material",
            "depth",
            "join",
            "merge",
            "output",
            "penumbra",
            "blend"
        ]
    );
    let err = ops::create("over", &json!({})).unwrap_err();
    assert_eq!(
        err.to_string(),
        "unknown operator \"over\" (known: accumulate, material, depth, join, merge, output, penumbra, blend)"
    );
    for (name, params) in [
        ("accumulate", json!({"colors": [[1, -1, 1]]})),
        ("accumulate", json!({"colors": []})),
        ("accumulate", json!({"colors": [[1, 1, 1]], "colour": 1})),
        (
            "accumulate",
            json!({"colors": [[1, 1, 1]], "ambient": {"input": 0}}),
        ),
        ("material", json!({"stage": "ambient"})),
        ("material", json!({"stage": "diffuse", "emissive": true})),
        ("depth", json!({"inputs": 2, "layers": ["depth"]})),
        ("join", json!({"inputs": 2, "layer": "depth"})),
        ("blend", json!({"inputs": 0})),
        ("blend", json!({"inputs": 2, "layer": "radiance"})),
        ("output", json!({"exposure": -1.0})),
        ("output", json!([1, 2])),
        ("merge", json!({"inputs": []})),
        ("merge", json!({"inputs": [["illumination"], []]})),
        (
            "merge",
            json!({"inputs": [["illumination"], ["illumination"]]}),
        ),
        ("merge", json!({"inputs": [["albedo"]]})),
        ("merge", json!({"inputs": [["depth"]], "layer": "depth"})),
    ] {
        let e = ops::create(name, &params).expect_err(&params.to_string());
        assert!(
            matches!(e, OpError::BadParam { .. }),
            "{name} {params}: {e}"
        );
    }
}

#[test]
fn set_params_updates_colours_not_shape() {
    let mut op = ops::create("accumulate", &json!({"colors": [[1, 1, 1], [1, 1, 1]]})).unwrap();
    // FrameParams::colors shape: [[input index, colour], …].
    op.set_params(&json!({"input_colors": [[2, [4, 4, 4]]]}))
        .unwrap();
    let inputs = [
        band(&[(Layer::Illumination, &P)]),
        band(&[(Layer::Illumination, &I1)]),
        band(&[(Layer::Illumination, &[1.0; 6])]),
    ];
    let want: Vec<f32> = (0..6).map(|k| P[k] + I1[k] + 4.0).collect();
    check(&*op, &inputs, &[(Layer::Illumination, &want)]);
    assert!(matches!(
        op.set_params(&json!({"colors": [[1, 1, 1]]})),
        Err(OpError::SignatureChange { .. })
    ));
    assert!(
        op.set_params(&json!({"input_colors": [[0, [1, 1, 1]]]}))
            .is_err()
    );
    // A failed update leaves the operator as it was.
    check(&*op, &inputs, &[(Layer::Illumination, &want)]);
}

#[test]
fn band_checks() {
    let op = ops::create("accumulate", &json!({"colors": [[1, 1, 1]]})).unwrap();
    let short = band(&[(Layer::Illumination, &[1.0; 5])]);
    let ok = band(&[(Layer::Illumination, &[1.0; 6])]);
    let mut out = Owned::zeros(1, &[Layer::Illumination]);
    let views = [ok.view()];
    assert!(matches!(
        op.apply(&views, &mut out.view_mut()),
        Err(OpError::InputCount {
            expected: 2,
            got: 1,
            ..
        })
    ));
    let mut s = short.clone();
    s.pixels = 1;
    let views = [ok.view(), s.view()];
    assert!(matches!(
        op.apply(&views, &mut out.view_mut()),
        Err(OpError::InputLength { input: 1, .. })
    ));
    let mut none = Owned::zeros(1, &[]);
    let views = [ok.view(), ok.view()];
    assert!(matches!(
        op.apply_scalar(&views, &mut none.view_mut()),
        Err(OpError::MissingOutput { .. })
    ));
}
