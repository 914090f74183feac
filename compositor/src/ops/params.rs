//! Parameter plumbing shared by the operators: JSON → the typed parameters of
//! `lightfold_protocol::pipeline` with unknown keys rejected, their validation errors as
//! `OpError`s, and the merge `set_params` applies. Layer names are the protocol's.

use super::OpError;
use lightfold_protocol::{Layer, ParamError};
use serde::de::DeserializeOwned;
use serde_json::{Map, Value};

/// Parses `params` (`null` = `{}`) into `T`, naming the operator in the error.
pub(crate) fn parse<T: DeserializeOwned>(op: &'static str, params: &Value) -> Result<T, OpError> {
    let v = match params {
        Value::Null => Value::Object(Map::new()),
        Value::Object(_) => params.clone(),
        other => {
            return Err(OpError::BadParam {
                op,
                reason: format!("expected a JSON object, got {other}"),
            });
        }
    };
    serde_json::from_value(v).map_err(|e| OpError::BadParam {
        op,
        reason: e.to_string(),
    })
}

/// Overlays the keys of `patch` (an object, or null for no change) on `current`.
pub(crate) fn merge(op: &'static str, current: &Value, patch: &Value) -> Result<Value, OpError> {
    let mut out = match current {
        Value::Object(m) => m.clone(),
        _ => Map::new(),
    };
    match patch {
        Value::Null => {}
        Value::Object(m) => {
            for (k, v) in m {
                out.insert(k.clone(), v.clone());
            }
        }
        other => {
            return Err(OpError::BadParam {
                op,
                reason: format!("expected a JSON object, got {other}"),
            });
        }
    }
    Ok(Value::Object(out))
}

pub use lightfold_protocol::pipeline::{layer_from_name, layer_name};

impl From<ParamError> for OpError {
    fn from(e: ParamError) -> OpError {
        OpError::BadParam {
            op: e.op,
            reason: e.reason,
        }
    }
}

/// Deserialises a list of layers from their lowercase names (pipeline files).
pub(crate) fn de_layers<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Vec<Layer>, D::Error> {
    let names: Vec<String> = serde::Deserialize::deserialize(d)?;
    names
        .iter()
        .map(|s| {
            layer_from_name(s)
                .ok_or_else(|| serde::de::Error::custom(format!("unknown layer {s:?}")))
        })
        .collect()
}
