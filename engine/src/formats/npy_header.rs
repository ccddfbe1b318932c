//! The shape in a NumPy `.npy` header, read before `npyz` allocates anything, so the DEM and
//! volume readers can check sizes against their limits first.

use crate::InputError;

/// Deepest bracket nesting accepted in a header (a structured dtype of nested records needs ~4).
const MAX_HEADER_NESTING: usize = 8;

/// The `shape` tuple of the header's dictionary; `None` when the header has no readable shape
/// (npyz then reports the problem). Errors name `format` (the caller's format label).
pub(crate) fn header_shape(
    bytes: &[u8],
    format: &'static str,
) -> Result<Option<Vec<u64>>, InputError> {
    let corrupt = |detail: String| InputError::Corrupt { format, detail };
    let truncated = || corrupt("truncated header".into());
    // Magic (6) + version (2) + header length (u16 for v1, u32 for v2/v3).
    let (len, start): (usize, usize) = match bytes.get(6) {
        Some(1) => {
            let l = bytes.get(8..10).ok_or_else(truncated)?;
            (usize::from(u16::from_le_bytes([l[0], l[1]])), 10)
        }
        Some(2 | 3) => {
            let l = bytes.get(8..12).ok_or_else(truncated)?;
            (u32::from_le_bytes([l[0], l[1], l[2], l[3]]) as usize, 12)
        }
        _ => return Err(corrupt("unknown .npy version".into())),
    };
    let text = bytes
        .get(start..start.saturating_add(len))
        .ok_or_else(truncated)?;
    let text = String::from_utf8_lossy(text);
    // npyz's header parser backtracks exponentially on nested brackets (found by the `dem_npy`
    // fuzz target: 21 nested `{` took over 10 s). A real header is a flat dict; a structured
    // dtype nests lists of tuples a few levels deep. Deeper nesting is refused before npyz runs.
    let mut depth = 0usize;
    for c in text.chars() {
        match c {
            '{' | '[' | '(' => {
                depth += 1;
                if depth > MAX_HEADER_NESTING {
                    return Err(corrupt(format!(
                        "header nests brackets deeper than {MAX_HEADER_NESTING} levels"
                    )));
                }
            }
            '}' | ']' | ')' => depth = depth.saturating_sub(1),
            _ => {}
        }
    }
    let Some(at) = text.find("'shape'").or_else(|| text.find("\"shape\"")) else {
        return Ok(None);
    };
    let after = &text[at..];
    let (Some(open), Some(close)) = (after.find('('), after.find(')')) else {
        return Ok(None);
    };
    if close < open {
        return Ok(None);
    }
    after[open + 1..close]
        .split(',')
        .map(|p| p.trim().trim_end_matches('L'))
        .filter(|p| !p.is_empty())
        .map(|p| {
            p.parse::<u64>()
                .map_err(|_| corrupt(format!("shape entry {p:?} is not a size")))
        })
        .collect::<Result<Vec<_>, _>>()
        .map(Some)
}
