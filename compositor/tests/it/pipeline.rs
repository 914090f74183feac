//! Pipelines as data: parsing (TOML, JSON, a configuration's operator list), validation errors
//! that name the stage and the problem, and running bands through the stages.

use crate::common;

use common::{Owned, assert_same_bits, ordinary, rng, run};
use lightfold_compositor::ops::{self, BandMut, BandView, OpError};
use lightfold_compositor::pipeline::{Pipeline, PipelineError, Scratch};
use lightfold_protocol::pipeline::OutputParams;
use lightfold_protocol::{Layer, OpSpec};
use serde_json::json;

const EXAMPLE: &str = r#"
version = 1
[[inputs]]
layers = ["illumination"]
[[inputs]]
layers = ["illumination", "diffuse"]
[[stages]]
name = "sum"
operator = "accumulate"
params = { colors = [[1.0, 0.9, 0.8]] }
inputs = ["input:0", "input:1"]
[[stages]]
name = "shade"
operator = "material"
params = { stage = "single" }
inputs = ["sum", "input:1"]
[[stages]]
name = "out"
operator = "output"
inputs = ["shade"]
"#;

fn inputs(pixels: usize) -> Vec<Owned> {
    let mut r = rng(5);
    vec![
        Owned::random(pixels, &[Layer::Illumination], &mut r, ordinary),
        Owned::random(
            pixels,
            &[Layer::Illumination, Layer::Diffuse],
            &mut r,
            ordinary,
        ),
    ]
}

fn run_pipeline(p: &Pipeline, ins: &[Owned], scalar: bool, scratch: &mut Scratch) -> Owned {
    let pixels = ins[0].pixels;
    let mut out = Owned::zeros(pixels, &p.output_layers());
    let views: Vec<BandView<'_>> = ins.iter().map(Owned::view).collect();
    let mut o: BandMut<'_> = out.view_mut();
    if scalar {
        p.run_scalar(&views, &mut o, scratch).unwrap();
    } else {
        p.run(&views, &mut o, scratch).unwrap();
    }
    drop(o);
    out
}

#[test]
fn toml_pipeline_runs_like_its_operators() {
    let p = Pipeline::from_toml(EXAMPLE).unwrap();
    assert_eq!(p.output_layers(), [Layer::Radiance]);
    assert_eq!(p.input_layers().len(), 2);
    let ins = inputs(777);
    let mut scratch = Scratch::default();
    let fast = run_pipeline(&p, &ins, false, &mut scratch);
    // The same band again with the scratch reused, and a smaller band after it.
    assert_same_bits(&fast, &run_pipeline(&p, &ins, false, &mut scratch), "rerun");
    let small = inputs(3);
    let _ = run_pipeline(&p, &small, false, &mut scratch);
    assert_same_bits(&fast, &run_pipeline(&p, &ins, true, &mut scratch), "scalar");
    // By hand: accumulate, then the single material stage, then output.
    let acc = ops::create("accumulate", &json!({"colors": [[1.0, 0.9, 0.8]]})).unwrap();
    let sum = run(&*acc, &ins, 777, false);
    let mat = ops::create("material", &json!({"stage": "single"})).unwrap();
    let shade = run(&*mat, &[sum, ins[1].clone()], 777, false);
    let out = run(
        &*ops::create("output", &json!({})).unwrap(),
        &[shade],
        777,
        false,
    );
    assert_same_bits(&fast, &out, "by hand");
}

#[test]
fn json_and_toml_agree() {
    let toml_value: toml::Value = toml::from_str(EXAMPLE).unwrap();
    let text = serde_json::to_string(&toml_value).unwrap();
    let a = Pipeline::from_json(&text).unwrap();
    let b = Pipeline::from_toml(EXAMPLE).unwrap();
    let ins = inputs(100);
    let mut s = Scratch::default();
    assert_same_bits(
        &run_pipeline(&a, &ins, false, &mut s),
        &run_pipeline(&b, &ins, false, &mut s),
        "json vs toml",
    );
}

#[test]
fn run_time_params() {
    let mut p = Pipeline::from_toml(EXAMPLE).unwrap();
    let ins = inputs(10);
    let mut s = Scratch::default();
    let before = run_pipeline(&p, &ins, false, &mut s);
    p.set_params("sum", &json!({"input_colors": [[1, [2.0, 2.0, 2.0]]]}))
        .unwrap();
    let after = run_pipeline(&p, &ins, false, &mut s);
    assert_ne!(before, after);
    assert!(matches!(
        p.set_params("nope", &json!({})),
        Err(PipelineError::NoSuchStage { .. })
    ));
    assert!(matches!(
        p.set_params("sum", &json!({"colors": [[1, 1, 1], [1, 1, 1]]})),
        Err(PipelineError::Operator {
            source: OpError::SignatureChange { .. },
            ..
        })
    ));
}

fn err(text: &str) -> String {
    Pipeline::from_toml(text).unwrap_err().to_string()
}

#[test]
fn clear_errors() {
    let cases = [
        (
            EXAMPLE.replace("version = 1", "version = 2"),
            "pipeline version 2 is not supported",
        ),
        (
            EXAMPLE.replace("\"output\"", "\"tonemap\""),
            "stage out: unknown operator \"tonemap\"",
        ),
        (
            EXAMPLE.replace("[\"sum\", \"input:1\"]", "[\"out\", \"input:1\"]"),
            "stage shade: input \"out\" is neither",
        ),
        (
            EXAMPLE.replace("[\"sum\", \"input:1\"]", "[\"sum\", \"input:7\"]"),
            "input \"input:7\" is neither",
        ),
        (
            EXAMPLE.replace("[\"sum\", \"input:1\"]", "[\"sum\"]"),
            "stage shade: the operator takes 2 inputs, 1 are wired",
        ),
        (
            EXAMPLE.replace("[\"sum\", \"input:1\"]", "[\"sum\", \"input:0\"]"),
            "stage shade: input 1 (input:0) does not carry Diffuse",
        ),
        (
            EXAMPLE.replace("name = \"out\"", "name = \"sum\""),
            "stage name \"sum\" is empty, repeated",
        ),
        (
            EXAMPLE.replace(
                "[\"illumination\", \"diffuse\"]",
                "[\"illumination\", \"albedo\"]",
            ),
            "unknown layer \"albedo\"",
        ),
        (
            EXAMPLE.replace("name = \"out\"", "name = \"out\"\ncolour = 1"),
            "unknown field `colour`",
        ),
        (
            EXAMPLE.replace("colors = [[1.0, 0.9, 0.8]]", "colors = [[1.0, -0.9, 0.8]]"),
            "stage sum: operator accumulate: bad parameters",
        ),
        (
            "version = 1\ninputs = []\nstages = []".to_string(),
            "pipeline has no stages",
        ),
    ];
    for (text, want) in cases {
        let got = err(&text);
        assert!(got.contains(want), "expected {want:?} in {got:?}");
    }
    let p = Pipeline::from_toml(EXAMPLE).unwrap();
    let ins = inputs(4);
    let mut out = Owned::zeros(4, &[Layer::Radiance]);
    let e = p
        .run(
            &[ins[0].view()],
            &mut out.view_mut(),
            &mut Scratch::default(),
        )
        .unwrap_err();
    assert!(matches!(
        e,
        PipelineError::BandInputs {
            expected: 2,
            got: 1
        }
    ));
    // A malformed band is reported with its stage.
    let bad = Owned::zeros(5, &[Layer::Illumination]);
    let views = [bad.view(), ins[1].view()];
    let e = p
        .run(&views, &mut out.view_mut(), &mut Scratch::default())
        .unwrap_err();
    assert!(e.to_string().starts_with("stage sum:"), "{e}");
}

#[test]
fn from_ops_convention() {
    let ops = [
        ops::spec_from_json("accumulate", &json!({"colors": [[1, 1, 1]]})).unwrap(),
        ops::spec_from_json("material", &json!({"stage": "single"})).unwrap(),
        ops::spec_from_json("output", &serde_json::Value::Null).unwrap(),
    ];
    let links = [
        vec![Layer::Illumination],
        vec![Layer::Illumination],
        vec![Layer::Diffuse],
    ];
    let p = Pipeline::from_ops(&ops, &links).unwrap();
    assert_eq!(p.output_layers(), [Layer::Radiance]);
    let mut r = rng(9);
    let ins: Vec<Owned> = links
        .iter()
        .map(|l| Owned::random(50, l, &mut r, ordinary))
        .collect();
    let mut s = Scratch::default();
    let got = run_pipeline(&p, &ins, false, &mut s);
    let acc = ops::create("accumulate", &json!({"colors": [[1, 1, 1]]})).unwrap();
    let sum = run(&*acc, &ins[..2], 50, false);
    let mat = ops::create("material", &json!({"stage": "single"})).unwrap();
    let shade = run(&*mat, &[sum, ins[2].clone()], 50, false);
    assert_same_bits(&got, &shade, "from_ops");
    let e = Pipeline::from_ops(&ops[..1], &links).unwrap_err();
    assert!(matches!(e, PipelineError::UnusedInputs { ref unused } if unused == &[2]));
    // Parameters out of range are refused with the operator's reason.
    let mut bad = ops.clone();
    bad[2] = OpSpec::Output(OutputParams { exposure: -1.0 });
    let e = Pipeline::from_ops(&bad, &links).unwrap_err();
    assert!(
        e.to_string()
            .contains("exposure must be finite and non-negative"),
        "{e}"
    );
}
