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

/// A direction given as a vector (`sun_direction`, `dust_source`), normalised: any finite vector
/// with a non-zero component (what the OpenAPI schema states: `contains` a non-zero number).
/// The length is taken after scaling by the largest component, so neither huge nor tiny
/// components overflow or underflow. A vector already of unit length (the canonical form read
/// back) is kept bit for bit.
pub fn unit_vector(field: &str, v: [f64; 3]) -> Result<[f64; 3], ParamError> {
    let m = v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    if !m.is_finite() || m == 0.0 {
        return Err(ParamError::new(
            field,
            "must be a finite vector with a non-zero component",
        ));
    }
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if (n - 1.0).abs() < 1e-12 {
        return Ok(v);
    }
    let s = v.map(|x| x / m);
    let l = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt();
    Ok(s.map(|x| x / l))
}

#[cfg(test)]
mod unit_vector_tests {
    use super::unit_vector;

    #[test]
    fn any_vector_with_a_non_zero_component_normalises_and_zero_is_refused() {
        for v in [
            [3.0, 0.0, 4.0],
            [1e300, 1e300, 0.0],
            [5e-324, 0.0, 0.0],
            [0.0, -2.0, 0.0],
        ] {
            let u = unit_vector("d", v).unwrap();
            let l = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt();
            assert!((l - 1.0).abs() < 1e-12, "{v:?} -> {u:?}");
            for (a, b) in u.iter().zip(v) {
                assert_eq!(
                    a.signum() * f64::from(u8::from(*a != 0.0)),
                    b.signum() * f64::from(u8::from(b != 0.0))
                );
            }
        }
        assert_eq!(unit_vector("d", [0.6, 0.8, 0.0]).unwrap(), [0.6, 0.8, 0.0]);
        let e = unit_vector("dust_source", [0.0, -0.0, 0.0]).unwrap_err();
        assert_eq!(e.field, "dust_source");
    }
}
