//! (in progress)
use super::DemOptions;
use crate::error::InputError;
use crate::geom::heightfield::Dem;
pub(super) fn decode(_b: &[u8], _n: Option<&str>, _o: &DemOptions) -> Result<Dem, InputError> {
    Err(InputError::UnsupportedFormat("not yet".into()))
}
pub(super) fn side_for_len(_l: usize) -> Option<usize> {
    None
}
