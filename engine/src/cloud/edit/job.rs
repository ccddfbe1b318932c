//! The parameters of one `cloud-edit` job (internal: the server's cloud scenes submit it, SPEC
//! §3.1–3.3): the edit, the state of the version it starts from, and the scene's decoder options.

use super::Edit;
use crate::cloud::params::CloudParams;
use crate::cloud::state::CloudState;
use crate::params::{deserialize_params, Limits};
use crate::ParamError;

/// Parameters of one cloud edit job: the edit, the state of the version it starts from, and the
/// scene's decoder options.
#[derive(Debug, Clone, PartialEq)]
pub struct CloudEditParams {
    /// `sun-color`, `ambient` or `sun-direction`.
    pub kind: String,
    /// The base version's state.
    pub base: CloudState,
    pub edit: Edit,
    /// The edit as sent, kept for the canonical form (request keys).
    pub raw_edit: serde_json::Value,
    pub bounds: Option<[[f64; 3]; 2]>,
    pub dims: Option<[usize; 3]>,
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct WireCloudEdit {
    kind: String,
    base: serde_json::Value,
    edit: serde_json::Value,
    #[serde(default)]
    bounds: Option<serde_json::Value>,
    #[serde(default)]
    dims: Option<serde_json::Value>,
}

impl CloudEditParams {
    /// Validates `{"kind", "base", "edit", "bounds"?, "dims"?}`; errors inside the edit are named
    /// `edit.<field>`.
    pub fn from_json(v: &serde_json::Value, limits: &Limits) -> Result<Self, ParamError> {
        let w: WireCloudEdit = deserialize_params(v)?;
        let base = CloudState::from_json(&w.base)
            .map_err(|e| ParamError::new(format!("base.{}", e.field), e.detail))?;
        let edit = Edit::from_json(&w.kind, &w.edit, limits)
            .map_err(|e| ParamError::new(format!("edit.{}", e.field), e.detail))?;
        // The decoder options are validated by the cloud pipeline's own rules.
        let mut opts = serde_json::Map::new();
        for (k, val) in [("bounds", w.bounds), ("dims", w.dims)] {
            if let Some(val) = val {
                opts.insert(k.to_string(), val);
            }
        }
        let p = CloudParams::from_json(&serde_json::Value::Object(opts), limits)?;
        Ok(Self {
            kind: w.kind,
            base,
            edit,
            raw_edit: w.edit,
            bounds: p.bounds().map(|(lo, hi)| [lo, hi]),
            dims: p.dims(),
        })
    }

    /// The canonical form (request keys): the edit as sent, the rest resolved.
    pub fn canonical(&self) -> serde_json::Value {
        serde_json::json!({
            "kind": self.kind,
            "base": self.base,
            "edit": self.raw_edit,
            "bounds": self.bounds,
            "dims": self.dims,
        })
    }
}
