//! NumPy `.npy` density volumes through `npyz` (SPEC §3): 3-D arrays of shape `(nz, ny, nx)` —
//! C order puts x fastest, exactly [`crate::geom::volume::Volume`]'s layout. `float32`, `float64`,
//! `uint8` and `uint16` in either byte order. Fortran-ordered arrays (`np.asfortranarray`, or
//! arrays saved from Julia/MATLAB) are transposed on read, so the logical index `[z, y, x]` means
//! the same voxel in both orders. 2-D and 4-D arrays are refused: a 2-D slice is not a volume and
//! a 4-D array (time or channels) needs a choice the caller must make.
//!
//! The shape is read from the header text and checked (product overflow, `max_voxels`, bytes
//! present) before `npyz` parses it — `npyz` multiplies the shape unchecked — and before any data
//! is read.

use std::io::Read;

use npyz::{DType, Deserialize, NpyFile, NpyHeader, Order, TypeChar};

use super::{check_voxels, Decoded, VolumeOptions};
use crate::error::InputError;

const FORMAT: &str = "NPY";

fn corrupt(detail: impl std::fmt::Display) -> InputError {
    InputError::Corrupt {
        format: FORMAT,
        detail: detail.to_string(),
    }
}
fn not_3d(shape: &[u64]) -> InputError {
    InputError::Unusable(format!(
        "the .npy array has shape {shape:?}; a density volume is a 3-D array (nz, ny, nx)"
    ))
}

pub(super) fn decode(bytes: &[u8], opts: &VolumeOptions) -> Result<Decoded, InputError> {
    if let Some(shape) = crate::formats::npy_header::header_shape(bytes, FORMAT)? {
        let &[nz, ny, nx] = &shape[..] else {
            return Err(not_3d(&shape));
        };
        check_voxels([nx, ny, nz], opts.max_voxels)?;
    }
    let mut data: &[u8] = bytes;
    let header = NpyHeader::from_reader(&mut data).map_err(corrupt)?;
    let shape = header.shape().to_vec();
    let &[nz, ny, nx] = &shape[..] else {
        return Err(not_3d(&shape));
    };
    let n = check_voxels([nx, ny, nz], opts.max_voxels)?;
    let DType::Plain(ts) = header.dtype() else {
        return Err(InputError::UnsupportedFormat(
            "structured .npy dtypes are not density volumes".to_string(),
        ));
    };
    let size = ts.size_field();
    if (data.len() as u64) < (n as u64).saturating_mul(size) {
        return Err(corrupt(format!(
            "truncated: {n} elements of {size} bytes declared, {} bytes present",
            data.len()
        )));
    }
    let order = header.order();
    let file = NpyFile::with_header(header, data);
    let values: Vec<f32> = match (ts.type_char(), size) {
        (TypeChar::Float, 4) => read::<f32, _>(file, |v| v)?,
        (TypeChar::Float, 8) => read::<f64, _>(file, |v| v as f32)?,
        (TypeChar::Uint, 1) => read::<u8, _>(file, f32::from)?,
        (TypeChar::Uint, 2) => read::<u16, _>(file, f32::from)?,
        _ => {
            return Err(InputError::UnsupportedFormat(format!(
                ".npy dtype {ts}; density volumes must be float32, float64, uint8 or uint16"
            )))
        }
    };
    if values.len() != n {
        return Err(corrupt(format!(
            "{} values read, {n} expected",
            values.len()
        )));
    }
    let dims = [nx as usize, ny as usize, nz as usize];
    let density = match order {
        Order::C => values,
        Order::Fortran => fortran_to_c(&values, dims),
    };
    Ok(Decoded {
        dims,
        density,
        bounds: None,
    })
}

/// A Fortran-ordered `(nz, ny, nx)` array holds `[z, y, x]` at `z + nz·(y + ny·x)`; returns it
/// x fastest. Allocates the output.
fn fortran_to_c(values: &[f32], [nx, ny, nz]: [usize; 3]) -> Vec<f32> {
    let mut out = Vec::with_capacity(values.len());
    for z in 0..nz {
        for y in 0..ny {
            out.extend((0..nx).map(|x| values[z + nz * (y + ny * x)]));
        }
    }
    out
}

fn read<T: Deserialize, R: Read>(
    file: NpyFile<R>,
    to_f32: impl Fn(T) -> f32,
) -> Result<Vec<f32>, InputError> {
    let reader = file.data::<T>().map_err(corrupt)?;
    reader
        .map(|v| v.map(&to_f32))
        .collect::<Result<Vec<f32>, _>>()
        .map_err(corrupt)
}
