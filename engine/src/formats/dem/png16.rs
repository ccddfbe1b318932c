//! (in progress)
use super::DemOptions;
use crate::error::InputError;
use crate::geom::heightfield::Dem;
pub(super) fn decode(_b: &[u8], _o: &DemOptions) -> Result<Dem, InputError> {
    Err(InputError::UnsupportedFormat("not yet".into()))
}
