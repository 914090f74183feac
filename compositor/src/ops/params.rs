//! Parameter plumbing shared by the operators: JSON → typed parameters with unknown keys
//! rejected, colour validation, layer names, and the merge `set_params` applies.

use super::OpError;
use lightfold_protocol::Layer;
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

/// A colour parameter must be finite and non-negative: it multiplies sanitised values, and a
/// negative or NaN factor would break the never-NaN, never-negative policy.
pub(crate) fn check_rgb(op: &'static str, what: &str, rgb: [f32; 3]) -> Result<(), OpError> {
    if rgb.iter().all(|c| c.is_finite() && *c >= 0.0) {
        Ok(())
    } else {
        Err(OpError::BadParam {
            op,
            reason: format!("{what} must be finite and non-negative, got {rgb:?}"),
        })
    }
}

/// A layer by its lowercase name, as pipeline files and parameters spell it.
pub fn layer_from_name(name: &str) -> Option<Layer> {
    Layer::ALL.into_iter().find(|l| layer_name(*l) == name)
}

/// The lowercase name of a layer.
pub fn layer_name(layer: Layer) -> &'static str {
    match layer {
        Layer::Illumination => "illumination",
        Layer::Diffuse => "diffuse",
        Layer::Specular => "specular",
        Layer::Ambient => "ambient",
        Layer::Emissive => "emissive",
        Layer::Depth => "depth",
        Layer::Radiance => "radiance",
    }
}

/// Deserialises a layer from its lowercase name.
pub(crate) fn de_layer<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Layer, D::Error> {
    let s: String = serde::Deserialize::deserialize(d)?;
    layer_from_name(&s).ok_or_else(|| serde::de::Error::custom(format!("unknown layer {s:?}")))
}

/// Deserialises a list of layers from their lowercase names.
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

/// Serialises a layer as its lowercase name.
pub(crate) fn ser_layer<S: serde::Serializer>(l: &Layer, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(layer_name(*l))
}

/// Serialises a list of layers as their lowercase names.
pub(crate) fn ser_layers<S: serde::Serializer>(ls: &[Layer], s: S) -> Result<S::Ok, S::Error> {
    s.collect_seq(ls.iter().map(|l| layer_name(*l)))
}
