//! The integration tests of `coordinator`, one binary (each file of this folder a module).

mod plan_scenes;

mod plan_budget;
mod plan_formats;
mod plan_gloss;
mod plan_peels;
mod plan_props;
mod plan_rules;
mod plan_tiles;
mod replan;

/// An operator's parameters as JSON (each f32 in its shortest decimal form, so `0.1` compares
/// equal), for assertions on single fields.
pub fn params(op: &lightfold_protocol::OpSpec) -> serde_json::Value {
    let text = serde_json::to_string(op).expect("operators serialise");
    let mut v: serde_json::Value = serde_json::from_str(&text).expect("and read back");
    v.as_object_mut()
        .and_then(|m| m.remove(op.name()))
        .expect("an operator is an object of one key")
}
