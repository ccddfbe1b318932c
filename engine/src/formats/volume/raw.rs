//! Raw little-endian `float32` volumes (SPEC §3): `nx·ny·nz` values, x fastest, no header. The
//! shape comes from [`VolumeOptions::dims`] and the byte length must be exactly `4·nx·ny·nz` — a
//! length that merely suffices would accept a file of another shape or with a header.

use super::{check_voxels, Decoded, VolumeOptions};
use crate::error::{InputError, ParamError};

pub(super) fn decode(bytes: &[u8], opts: &VolumeOptions) -> Result<Decoded, InputError> {
    let Some(dims) = opts.dims else {
        return Err(ParamError::new(
            "dims",
            "required for raw float32 volumes ([nx, ny, nz], x fastest)",
        )
        .into());
    };
    let n = check_voxels(dims.map(|d| d as u64), opts.max_voxels)?;
    let expected = (n as u64).saturating_mul(4);
    if bytes.len() as u64 != expected {
        return Err(InputError::Corrupt {
            format: "raw float32",
            detail: format!(
                "{} bytes, but dims {dims:?} need exactly {expected} (4 bytes per voxel)",
                bytes.len()
            ),
        });
    }
    let density = bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    Ok(Decoded {
        dims,
        density,
        bounds: None,
    })
}
