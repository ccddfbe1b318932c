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
    /// `actual` is `u64::MAX` when the declared sizes overflow 64 bits when multiplied out
    /// (the message then says so instead of printing the saturated product).
    #[error("input too large: {what} is {}, the limit is {max}", count(*actual))]
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

/// Why a run that decoded and validated its input still cannot produce what was asked: the
/// user's to fix (the server answers with a problem type per kind).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refusal {
    /// Cannot be carried out on this input (a cloud edit dragged from empty sky).
    Unprocessable,
    /// A cloud edit's stroke that misses the cloud (SPEC §3.1, §3.2).
    StrokeMissesCloud,
    /// A cloud edit's stroke on cloud that no sunlight reaches (SPEC §3.1).
    StrokeNotLit,
}

/// A declared count for a message: `u64::MAX` stands for a product that overflowed.
fn count(n: u64) -> String {
    if n == u64::MAX {
        "more than 2^64 (the declared sizes overflow when multiplied)".to_string()
    } else {
        n.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_overflowed_count_is_not_printed_as_a_number() {
        let e = InputError::TooLarge {
            what: "DEM cells",
            actual: u64::MAX,
            max: 1 << 26,
        };
        assert_eq!(
            e.to_string(),
            "input too large: DEM cells is more than 2^64 (the declared sizes overflow when \
             multiplied), the limit is 67108864"
        );
        assert!(!e.to_string().contains("18446744073709551615"));
    }
}
