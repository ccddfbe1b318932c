//! JSON bodies parsed into [`serde_json::Value`] with duplicate object keys refused.
//!
//! RFC 8259 leaves the meaning of `{"width": 64, "width": 4096}` to the reader; serde_json keeps
//! the last, other parsers the first. A request whose meaning depends on the parser is refused,
//! naming the key, rather than run with a guess (and two spellings of one request would also
//! get two request keys).

use std::cell::RefCell;
use std::fmt;

use serde::de::{self, DeserializeSeed, Deserializer, MapAccess, SeqAccess, Visitor};
use serde_json::{Map, Number, Value};

/// The largest integer every f64 up to it represents exactly (2^53).
const MAX_EXACT: f64 = 9_007_199_254_740_992.0;

/// Why a body is not one unambiguous JSON value.
#[derive(Debug)]
pub(crate) enum StrictJsonError {
    /// Not JSON (serde_json's message, with line and column).
    Syntax(serde_json::Error),
    /// An object holds this key twice: its path from the root (`camera.fov_deg`,
    /// `strokes[0].x`).
    Duplicate(String),
}

/// Parses `bytes` as one JSON value, refusing duplicate keys in any object.
pub(crate) fn from_slice(bytes: &[u8]) -> Result<Value, StrictJsonError> {
    let dup = RefCell::new(None);
    let mut de = serde_json::Deserializer::from_slice(bytes);
    let parsed = Seed {
        path: String::new(),
        dup: &dup,
    }
    .deserialize(&mut de)
    .and_then(|v| de.end().map(|()| v));
    match (parsed, dup.into_inner()) {
        (_, Some(path)) => Err(StrictJsonError::Duplicate(path)),
        (Ok(v), None) => Ok(v),
        (Err(e), None) => Err(StrictJsonError::Syntax(e)),
    }
}

/// The problem for a duplicate key at `path`: inside a pipeline's parameters (`in_params`) an
/// invalid parameter (422) named like every other parameter error, elsewhere a bad request (400)
/// naming the field.
pub(crate) fn duplicate_problem(path: String, in_params: bool) -> crate::error::ApiError {
    const DETAIL: &str = "the key is given twice in one object; give each key once";
    if in_params {
        phenomena_engine::ParamError::new(path, DETAIL).into()
    } else {
        crate::error::ApiError::bad_field(path, DETAIL)
    }
}

/// Builds a `Value` like serde_json's own, remembering where it is.
struct Seed<'a> {
    path: String,
    dup: &'a RefCell<Option<String>>,
}

impl Seed<'_> {
    fn child(&self, key: &str) -> String {
        if self.path.is_empty() {
            key.to_string()
        } else {
            format!("{}.{key}", self.path)
        }
    }
}

impl<'de> DeserializeSeed<'de> for Seed<'_> {
    type Value = Value;

    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<Value, D::Error> {
        d.deserialize_any(self)
    }
}

impl<'de> Visitor<'de> for Seed<'_> {
    type Value = Value;

    fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("any JSON value")
    }

    fn visit_bool<E: de::Error>(self, v: bool) -> Result<Value, E> {
        Ok(Value::Bool(v))
    }

    fn visit_i64<E: de::Error>(self, v: i64) -> Result<Value, E> {
        Ok(Value::from(v))
    }

    fn visit_u64<E: de::Error>(self, v: u64) -> Result<Value, E> {
        Ok(Value::from(v))
    }

    fn visit_f64<E: de::Error>(self, v: f64) -> Result<Value, E> {
        // JSON Schema counts `3.0` as an integer: an integral number (exact in an f64) becomes
        // one, so integer fields (`width`, `version`, pixel coordinates) accept it, and number
        // fields read the same value either way.
        if v.fract() == 0.0 && v.abs() <= MAX_EXACT {
            return Ok(Value::from(v as i64));
        }
        Ok(Number::from_f64(v).map_or(Value::Null, Value::Number))
    }

    fn visit_str<E: de::Error>(self, v: &str) -> Result<Value, E> {
        Ok(Value::String(v.to_string()))
    }

    fn visit_string<E: de::Error>(self, v: String) -> Result<Value, E> {
        Ok(Value::String(v))
    }

    fn visit_unit<E: de::Error>(self) -> Result<Value, E> {
        Ok(Value::Null)
    }

    fn visit_none<E: de::Error>(self) -> Result<Value, E> {
        Ok(Value::Null)
    }

    fn visit_some<D: Deserializer<'de>>(self, d: D) -> Result<Value, D::Error> {
        d.deserialize_any(self)
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Value, A::Error> {
        let mut out = Vec::new();
        loop {
            let seed = Seed {
                path: format!("{}[{}]", self.path, out.len()),
                dup: self.dup,
            };
            match seq.next_element_seed(seed)? {
                Some(v) => out.push(v),
                None => return Ok(Value::Array(out)),
            }
        }
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Value, A::Error> {
        let mut out = Map::new();
        while let Some(key) = map.next_key::<String>()? {
            let path = self.child(&key);
            if out.contains_key(&key) {
                *self.dup.borrow_mut() = Some(path);
                return Err(de::Error::custom("duplicate key"));
            }
            let v = map.next_value_seed(Seed {
                path,
                dup: self.dup,
            })?;
            out.insert(key, v);
        }
        Ok(Value::Object(out))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_like_serde_json_without_duplicates() {
        let text = br#"{"a": [1, -2, 2.5, "x", null, true, {"b": {}}], "c": 18446744073709551615}"#;
        let strict = from_slice(text).unwrap();
        let plain: Value = serde_json::from_slice(text).unwrap();
        assert_eq!(strict, plain);
    }

    #[test]
    fn integral_numbers_are_integers() {
        let v = from_slice(br#"{"w": 3.0, "x": -0.0, "y": 2.5, "z": 1e300, "n": 4e15}"#).unwrap();
        assert_eq!(v["w"].as_u64(), Some(3));
        assert_eq!(v["x"].as_i64(), Some(0));
        assert_eq!(v["y"].as_f64(), Some(2.5));
        assert!(v["z"].is_f64());
        assert_eq!(v["n"].as_u64(), Some(4_000_000_000_000_000));
    }

    #[test]
    fn a_duplicate_key_is_named_by_its_path() {
        for (text, path) in [
            (r#"{"width": 1, "width": 2}"#, "width"),
            (
                r#"{"camera": {"fov_deg": 30, "fov_deg": 40}}"#,
                "camera.fov_deg",
            ),
            (
                r#"{"strokes": [{"x": 1}, {"x": 1, "y": 2, "x": 3}]}"#,
                "strokes[1].x",
            ),
        ] {
            match from_slice(text.as_bytes()) {
                Err(StrictJsonError::Duplicate(p)) => assert_eq!(p, path, "{text}"),
                other => panic!("{text}: {other:?}"),
            }
        }
    }

    #[test]
    fn syntax_errors_and_trailing_bytes_stay_syntax_errors() {
        for text in ["{", "{} x", "[1,]", ""] {
            assert!(
                matches!(from_slice(text.as_bytes()), Err(StrictJsonError::Syntax(_))),
                "{text}"
            );
        }
    }
}
