//! The configured [`Limits`] and the wire helpers every pipeline's parameters use:
//! [`deserialize_params`] (unknown names rejected, errors naming the field), [`range`] and
//! [`image_size`].

use crate::ParamError;

/// Input and output size limits (configured by the server; the CLI uses the defaults).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// Largest input grid, cells (DEM) or voxels (volume). Checked from the file header before
    /// the grid is allocated.
    pub max_input_cells: u64,
    /// Largest output image, pixels.
    pub max_output_pixels: u64,
    /// Largest input mesh, triangles (vertices: 3×). Checked from the file's counts before the
    /// mesh is allocated.
    pub max_input_triangles: u64,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_input_cells: 8192 * 8192,
            max_output_pixels: 7680 * 4320,
            max_input_triangles: 4_000_000,
        }
    }
}

/// Deserialises wire parameters, naming the offending field (`camera.fov_deg`) on error.
pub fn deserialize_params<T: serde::de::DeserializeOwned>(
    v: &serde_json::Value,
) -> Result<T, ParamError> {
    if !v.is_object() {
        return Err(ParamError::new("params", "must be a JSON object"));
    }
    serde_path_to_error::deserialize(v).map_err(|e| {
        // The path names the offending field itself, unknown names included (`camera.fovdeg`).
        let path = e.path().to_string();
        let field = if path == "." {
            "params".to_string()
        } else {
            path
        };
        let inner = e.into_inner().to_string();
        ParamError::new(field, inner)
    })
}

/// `v`, or `default` when absent, checked to lie in `lo..=hi` (NaN is refused); the error names
/// `field`.
pub fn range<T: PartialOrd + std::fmt::Display + Copy>(
    field: &str,
    v: Option<T>,
    default: T,
    lo: T,
    hi: T,
) -> Result<T, ParamError> {
    let x = v.unwrap_or(default);
    // `!(lo <= x && x <= hi)` also rejects NaN.
    if !(lo <= x && x <= hi) {
        return Err(ParamError::new(
            field,
            format!("must be between {lo} and {hi}, got {x}"),
        ));
    }
    Ok(x)
}

/// Validates the output image size (`width`, `height`; each 16–8192, `default` when absent) against
/// the output pixel limit.
pub fn image_size(
    width: Option<u32>,
    height: Option<u32>,
    default: (u32, u32),
    limits: &Limits,
) -> Result<(u32, u32), ParamError> {
    let w = range("width", width, default.0, 16, 8192)?;
    let h = range("height", height, default.1, 16, 8192)?;
    if u64::from(w) * u64::from(h) > limits.max_output_pixels {
        return Err(ParamError::new(
            "width",
            format!(
                "{w}×{h} exceeds the output limit of {} pixels",
                limits.max_output_pixels
            ),
        ));
    }
    Ok((w, h))
}
