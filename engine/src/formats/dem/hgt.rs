//! SRTM `.hgt` tiles: a square of big-endian `i16` heights in metres, 1201 × 1201 (3″) or
//! 3601 × 3601 (1″) samples, row 0 north, void = −32768 → NaN. Any other size is refused.
//!
//! The file carries no header; its position comes from the name, `N35E139.hgt` (case-insensitive,
//! anything after the seven-character tile name is ignored, e.g. `N35E139.SRTMGL1.hgt`): the tile's
//! south-west *sample* lies on latitude 35°, longitude 139°, and samples sit on whole multiples of
//! the spacing, so the cell corners of the GDAL transform are half a cell outside the whole
//! degrees. CRS: EPSG 4326. A name that does not parse leaves the tile without georeferencing; it
//! then needs `cell_size` (metres), like a PNG.

use super::geo::{cell_size_metres, georef_from};
use super::{check_cells, required_cell_size, DemOptions};
use crate::error::InputError;
use crate::geom::heightfield::{Dem, GeoRef};

const FORMAT: &str = "SRTM HGT";
const VOID: i16 = -32768;

/// Side of the square tile whose file is `len` bytes long, if it is an SRTM size.
pub(super) fn side_for_len(len: usize) -> Option<usize> {
    [1201usize, 3601].into_iter().find(|s| s * s * 2 == len)
}

/// (south latitude, west longitude) of the tile named like `N35E139…` or `s01w075…`.
pub(crate) fn parse_tile_name(filename: &str) -> Option<(i32, i32)> {
    let base = filename.rsplit(['/', '\\']).next()?;
    let b = base.as_bytes();
    if b.len() < 7 {
        return None;
    }
    let digits = |s: &[u8]| -> Option<i32> {
        s.iter().try_fold(0i32, |acc, &c| {
            c.is_ascii_digit().then(|| acc * 10 + i32::from(c - b'0'))
        })
    };
    let lat = digits(&b[1..3])?;
    let lon = digits(&b[4..7])?;
    let lat = match b[0].to_ascii_uppercase() {
        b'N' => lat,
        b'S' => -lat,
        _ => return None,
    };
    let lon = match b[3].to_ascii_uppercase() {
        b'E' => lon,
        b'W' => -lon,
        _ => return None,
    };
    ((-90..90).contains(&lat) && (-180..180).contains(&lon)).then_some((lat, lon))
}

pub(super) fn decode(
    bytes: &[u8],
    filename: Option<&str>,
    opts: &DemOptions,
) -> Result<Dem, InputError> {
    let side = side_for_len(bytes.len()).ok_or_else(|| InputError::Corrupt {
        format: FORMAT,
        detail: format!(
            "{} bytes; an SRTM tile is 1201² or 3601² big-endian 16-bit samples \
             (2,884,802 or 25,934,402 bytes)",
            bytes.len()
        ),
    })?;
    check_cells(side as u64, side as u64, opts.max_cells)?;
    let heights: Vec<f32> = bytes
        .chunks_exact(2)
        .map(|c| match i16::from_be_bytes([c[0], c[1]]) {
            VOID => f32::NAN,
            v => f32::from(v),
        })
        .collect();
    let (dx, dy, georef) = match filename.and_then(parse_tile_name) {
        Some((lat, lon)) => {
            let res = 1.0 / (side - 1) as f64;
            let transform = [
                f64::from(lon) - res / 2.0,
                res,
                0.0,
                f64::from(lat) + 1.0 + res / 2.0,
                0.0,
                -res,
            ];
            let (dx, dy) = cell_size_metres(&transform, side, side, true, 1.0);
            (
                dx,
                dy,
                georef_from(transform, Some(4326), true, Some(f64::from(VOID))),
            )
        }
        None => {
            let c = required_cell_size(
                opts,
                "an .hgt file whose name is not a tile name like N35E139.hgt",
            )?;
            (
                c,
                c,
                GeoRef {
                    nodata: Some(f64::from(VOID)),
                    ..GeoRef::default()
                },
            )
        }
    };
    Ok(Dem {
        width: side,
        height: side,
        heights,
        dx,
        dy,
        georef,
    })
}

#[cfg(test)]
mod tests {
    use super::parse_tile_name;

    #[test]
    fn tile_names() {
        assert_eq!(parse_tile_name("N35E139.hgt"), Some((35, 139)));
        assert_eq!(parse_tile_name("dir/s01w075.SRTMGL1.hgt"), Some((-1, -75)));
        assert_eq!(parse_tile_name("N35E1x9.hgt"), None);
        assert_eq!(parse_tile_name("dem.hgt"), None);
        assert_eq!(parse_tile_name("N95E000.hgt"), None);
    }
}
