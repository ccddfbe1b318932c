//! The engine's error boundary: bad parameters and bad input files. Everything after decoding and
//! validation is infallible apart from cancellation.

/// A parameter is unknown, of the wrong type, or out of range. `field` is the JSON path
/// (`camera.fov_deg`).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{field}: {detail}")]
pub struct ParamError {
    pub field: String,
    pub detail: String,
}

impl ParamError {
    pub fn new(field: impl Into<String>, detail: impl Into<String>) -> Self {
        Self {
            field: field.into(),
            detail: detail.into(),
        }
    }
}

/// An input file could not be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum InputError {
    /// Not a format this pipeline reads (maps to 415).
    #[error("unsupported format: {0}")]
    UnsupportedFormat(String),
    /// A recognised format whose bytes are truncated or inconsistent (maps to 422).
    #[error("corrupt {format} file: {detail}")]
    Corrupt {
        format: &'static str,
        detail: String,
    },
    /// The declared size exceeds a configured limit; refused before allocating (maps to 413).
    #[error("input too large: {what} is {actual}, the limit is {max}")]
    TooLarge {
        what: &'static str,
        actual: u64,
        max: u64,
    },
    /// The file is readable but cannot be used (all nodata, a 1×1 grid, …) (maps to 422).
    #[error("{0}")]
    Unusable(String),
    /// A parameter needed to interpret the input is missing or wrong (e.g. `cell_size` for PNG).
    #[error(transparent)]
    Param(#[from] ParamError),
}
