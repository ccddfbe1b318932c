//! The cloud pipelines' inputs (SPEC §3): the density volume in its world box, a scene version's
//! ambient field and an edit's render layers, as named auxiliary inputs.

use super::state::AmbientField;
use crate::formats::volume::{decode_volume, VolumeOptions};
use crate::geom::Volume;
use crate::params::Limits;
use crate::InputError;

/// The name of the auxiliary input holding a cloud scene version's ambient field.
pub const AMBIENT_FIELD: &str = "ambient.bin";

/// The name of a cloud edit's optional auxiliary input holding the layers of the base
/// version's render at the edit's view (`layers.bin` of that render): a sun-colour edit then
/// reads them instead of decoding the volume and marching.
pub const LAYERS: &str = super::layers::LAYERS_FILE;

/// Decodes a cloud volume. Its world box is the user's `bounds` or SPEC §3's default, the unit
/// cube scaled to the grid's aspect — not the box the file's own geometry implies (an NRRD's
/// spacings, an OpenVDB transform): κ is per world unit, so a file in centimetres or in voxel
/// units would otherwise make the same κ mean wildly different clouds. The file's box is still
/// reported by the decoders for those who pass it as `bounds`. `bounds` and `dims` are the
/// scene's decoder options (validated by [`super::CloudParams`]).
pub fn decode(
    bytes: &[u8],
    filename: Option<&str>,
    bounds: Option<[[f64; 3]; 2]>,
    dims: Option<[usize; 3]>,
    limits: &Limits,
) -> Result<Volume, InputError> {
    let opts = VolumeOptions {
        max_voxels: limits.max_input_cells,
        dims,
        bounds: bounds.map(|[lo, hi]| (lo, hi)),
    };
    let mut volume = decode_volume(bytes, filename, &opts)?;
    if opts.bounds.is_none() {
        volume.bounds = Volume::default_bounds(volume.dims);
    }
    Ok(volume)
}

/// The version's per-voxel ambient field among the auxiliary inputs ([`AMBIENT_FIELD`]), if any.
pub fn ambient_field(
    named_inputs: &[(String, Vec<u8>)],
    volume: &Volume,
) -> Result<Option<AmbientField>, InputError> {
    named_inputs
        .iter()
        .find(|(name, _)| name == AMBIENT_FIELD)
        .map(|(_, bytes)| AmbientField::from_bytes(bytes, volume.len()))
        .transpose()
}
