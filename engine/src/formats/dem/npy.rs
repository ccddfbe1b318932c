//! NumPy `.npy` height grids through `npyz`: 2-D arrays (rows, columns), row 0 north, of
//! `f4`/`f8`/`i1`/`i2`/`i4`/`i8`/`u1`/`u2`/`u4`/`u8`, either byte order, C order (Fortran order is
//! transposed to rows × columns on read). Height = value × `vertical_scale` (default 1, applied
//! to every dtype, so a float array in kilometres can be scaled as well). NaN is nodata; integer
//! arrays have no nodata.
//!
//! `cell_size` defaults to **1 m** when not given: an array has no units at all, and a unit grid
//! is what `numpy.gradient` and friends assume; a caller that knows better passes `cell_size`.
//!
//! The shape is read from the header text and checked (product overflow, `max_cells`, bytes
//! present) before `npyz` parses it — `npyz` multiplies the shape unchecked — and before the data
//! is read.

use std::io::Read;

use npyz::{DType, Deserialize, NpyFile, NpyHeader, Order, TypeChar};

use super::{check_cells, DemOptions};
use crate::error::InputError;
use crate::geom::heightfield::{Dem, GeoRef};

const FORMAT: &str = "NPY";

fn corrupt(detail: impl std::fmt::Display) -> InputError {
    InputError::Corrupt {
        format: FORMAT,
        detail: detail.to_string(),
    }
}

pub(super) fn decode(bytes: &[u8], opts: &DemOptions) -> Result<Dem, InputError> {
    if let Some(dims) = crate::formats::npy_header::header_shape(bytes, FORMAT)? {
        // A shape whose product (zero dimensions aside) overflows is refused before npyz
        // multiplies it out.
        let product = dims
            .iter()
            .filter(|&&d| d != 0)
            .try_fold(1u64, |acc, &d| acc.checked_mul(d));
        if product.is_none() {
            return Err(InputError::TooLarge {
                what: "DEM cells (the NPY shape's elements)",
                actual: u64::MAX,
                max: opts.max_cells,
            });
        }
        if dims.len() == 2 {
            check_cells(dims[1], dims[0], opts.max_cells)?;
        }
    }
    let mut data: &[u8] = bytes;
    let header = NpyHeader::from_reader(&mut data).map_err(corrupt)?;
    let shape = header.shape().to_vec();
    let [rows, cols] = shape[..] else {
        return Err(InputError::Unusable(format!(
            "the .npy array has shape {shape:?}; a DEM is a 2-D array (rows, columns)"
        )));
    };
    check_cells(cols, rows, opts.max_cells)?;
    let DType::Plain(ts) = header.dtype() else {
        return Err(InputError::UnsupportedFormat(
            "structured .npy dtypes are not height grids".to_string(),
        ));
    };
    let size = ts.size_field();
    let n = rows * cols;
    if (data.len() as u64) < n.saturating_mul(size) {
        return Err(corrupt(format!(
            "truncated: {n} elements of {size} bytes declared, {} bytes present",
            data.len()
        )));
    }
    let order = header.order();
    let file = NpyFile::with_header(header, data);
    let values: Vec<f64> = match (ts.type_char(), size) {
        (TypeChar::Float, 4) => read::<f32, _>(file, f64::from)?,
        (TypeChar::Float, 8) => read::<f64, _>(file, |v| v)?,
        (TypeChar::Int, 1) => read::<i8, _>(file, f64::from)?,
        (TypeChar::Int, 2) => read::<i16, _>(file, f64::from)?,
        (TypeChar::Int, 4) => read::<i32, _>(file, f64::from)?,
        (TypeChar::Int, 8) => read::<i64, _>(file, |v| v as f64)?,
        (TypeChar::Uint, 1) => read::<u8, _>(file, f64::from)?,
        (TypeChar::Uint, 2) => read::<u16, _>(file, f64::from)?,
        (TypeChar::Uint, 4) => read::<u32, _>(file, f64::from)?,
        (TypeChar::Uint, 8) => read::<u64, _>(file, |v| v as f64)?,
        _ => {
            return Err(InputError::UnsupportedFormat(format!(
                ".npy dtype {ts}; heights must be float32/64 or an integer type"
            )))
        }
    };
    let (width, height) = (cols as usize, rows as usize);
    let scale = opts.vertical_scale.unwrap_or(1.0);
    let at = |r: usize, c: usize| match order {
        Order::C => values[r * width + c],
        Order::Fortran => values[c * height + r],
    };
    let mut heights = Vec::with_capacity(width * height);
    for r in 0..height {
        for c in 0..width {
            heights.push((at(r, c) * scale) as f32);
        }
    }
    let cell = opts.cell_size.unwrap_or(1.0);
    Ok(Dem {
        width,
        height,
        heights,
        dx: cell,
        dy: cell,
        georef: GeoRef::default(),
    })
}

fn read<T: Deserialize, R: Read>(
    file: NpyFile<R>,
    to_f64: impl Fn(T) -> f64,
) -> Result<Vec<f64>, InputError> {
    let reader = file.data::<T>().map_err(corrupt)?;
    reader
        .map(|v| v.map(&to_f64))
        .collect::<Result<Vec<f64>, _>>()
        .map_err(corrupt)
}
