//! ESRI ASCII grid (`.asc`): a header of `key value` lines — `ncols`, `nrows`,
//! `xllcorner`|`xllcenter`, `yllcorner`|`yllcenter`, `cellsize` (or GDAL's `dx`/`dy`),
//! optional `NODATA_value` — keys case-insensitive, in any order, then `ncols × nrows`
//! whitespace-separated numbers, row 0 north.
//!
//! The format carries no CRS (a `.prj` sidecar is not uploaded with it), so we guess, and say so:
//! **if `cellsize` < 1 and the whole extent lies within longitude [−180, 180] and latitude
//! [−90, 90], the grid is taken as geographic WGS84 (EPSG 4326)** and the cell size converted to
//! metres at the centre latitude; otherwise the units are taken as metres in an unknown projected
//! CRS (`maunga_whau_volcano.asc`: 10 m cells at origin 0,0). A metre grid with sub-metre cells
//! near the origin would be misread as degrees — `DemOptions::cell_size` overrides the cell size
//! (in metres) for such files.
//!
//! A body with fewer values than `ncols × nrows` (a truncated upload) or with more is
//! [`InputError::Corrupt`]; so is any token that is not a number. The declared size is checked
//! against `max_cells` and against the file length (each value needs at least two bytes) before
//! the grid is allocated.

use super::geo::{cell_size_metres, georef_from};
use super::{check_cells, DemOptions};
use crate::error::InputError;
use crate::geom::heightfield::Dem;

const FORMAT: &str = "ESRI ASCII grid";

fn corrupt(detail: impl Into<String>) -> InputError {
    InputError::Corrupt {
        format: FORMAT,
        detail: detail.into(),
    }
}

const KEYS: [&str; 10] = [
    "ncols",
    "nrows",
    "xllcorner",
    "xllcenter",
    "yllcorner",
    "yllcenter",
    "cellsize",
    "dx",
    "dy",
    "nodata_value",
];

/// True when the text starts (after whitespace) with an `ncols` or `nrows` key.
pub(super) fn looks_like_asc(bytes: &[u8]) -> bool {
    let start = bytes
        .iter()
        .position(|b| !b.is_ascii_whitespace())
        .unwrap_or(0);
    let head = &bytes[start..bytes.len().min(start + 5)];
    head.eq_ignore_ascii_case(b"ncols") || head.eq_ignore_ascii_case(b"nrows")
}

#[derive(Default)]
struct Header {
    ncols: Option<u64>,
    nrows: Option<u64>,
    x: Option<(f64, bool)>, // (value, is_center)
    y: Option<(f64, bool)>,
    cellsize: Option<f64>,
    dx: Option<f64>,
    dy: Option<f64>,
    nodata: Option<f64>,
}

pub(super) fn decode(bytes: &[u8], opts: &DemOptions) -> Result<Dem, InputError> {
    let text = std::str::from_utf8(bytes).map_err(|e| corrupt(format!("not text: {e}")))?;
    let mut header = Header::default();
    let mut rest = text;
    // Header lines: a known key then one number.
    loop {
        let line_end = rest.find('\n').map_or(rest.len(), |i| i + 1);
        let line = &rest[..line_end];
        let mut parts = line.split_whitespace();
        let Some(key) = parts.next() else {
            if line_end == 0 || line_end >= rest.len() {
                break;
            }
            rest = &rest[line_end..]; // blank line
            continue;
        };
        let key = key.to_ascii_lowercase();
        if !KEYS.contains(&key.as_str()) {
            break;
        }
        let value = parts
            .next()
            .ok_or_else(|| corrupt(format!("header key {key} has no value")))?;
        let num: f64 = value
            .parse()
            .map_err(|_| corrupt(format!("header {key} = {value:?} is not a number")))?;
        let count = |v: f64| -> Result<u64, InputError> {
            if v.fract() == 0.0 && (0.0..1e15).contains(&v) {
                Ok(v as u64)
            } else {
                Err(corrupt(format!("{key} = {value} is not a cell count")))
            }
        };
        match key.as_str() {
            "ncols" => header.ncols = Some(count(num)?),
            "nrows" => header.nrows = Some(count(num)?),
            "xllcorner" => header.x = Some((num, false)),
            "xllcenter" => header.x = Some((num, true)),
            "yllcorner" => header.y = Some((num, false)),
            "yllcenter" => header.y = Some((num, true)),
            "cellsize" => header.cellsize = Some(num),
            "dx" => header.dx = Some(num),
            "dy" => header.dy = Some(num),
            _ => header.nodata = Some(num),
        }
        rest = &rest[line_end..];
    }
    let missing = |k: &str| corrupt(format!("header has no {k}"));
    let ncols = header.ncols.ok_or_else(|| missing("ncols"))?;
    let nrows = header.nrows.ok_or_else(|| missing("nrows"))?;
    let (x, x_center) = header.x.ok_or_else(|| missing("xllcorner or xllcenter"))?;
    let (y, y_center) = header.y.ok_or_else(|| missing("yllcorner or yllcenter"))?;
    let cdx = header
        .dx
        .or(header.cellsize)
        .ok_or_else(|| missing("cellsize"))?;
    let cdy = header.dy.or(header.cellsize).unwrap_or(cdx);
    if !(cdx.is_finite()
        && cdx > 0.0
        && cdy.is_finite()
        && cdy > 0.0
        && x.is_finite()
        && y.is_finite())
    {
        return Err(corrupt(format!(
            "cell size {cdx} × {cdy} at ({x}, {y}) is not usable"
        )));
    }

    check_cells(ncols, nrows, opts.max_cells)?;
    let cells = (ncols * nrows) as usize;
    // Every value takes at least one digit and one separator (the last may end the file).
    if cells > rest.len() / 2 + 1 {
        return Err(corrupt(format!(
            "truncated: {cells} values declared but only {} bytes of data",
            rest.len()
        )));
    }

    let mut heights = Vec::with_capacity(cells);
    let nodata = header.nodata;
    for tok in rest.split_ascii_whitespace() {
        if heights.len() == cells {
            return Err(corrupt(format!("more values than ncols × nrows = {cells}")));
        }
        let v: f64 = tok.parse().map_err(|_| {
            corrupt(format!(
                "value {} ({tok:?}) is not a number",
                heights.len() + 1
            ))
        })?;
        heights.push(if Some(v) == nodata || v.is_nan() {
            f32::NAN
        } else {
            v as f32
        });
    }
    if heights.len() < cells {
        return Err(corrupt(format!(
            "truncated: {} values, ncols × nrows = {cells}",
            heights.len()
        )));
    }

    let (width, height) = (ncols as usize, nrows as usize);
    let x0 = if x_center { x - cdx / 2.0 } else { x };
    let y0 = if y_center { y - cdy / 2.0 } else { y };
    let top = y0 + nrows as f64 * cdy;
    let right = x0 + ncols as f64 * cdx;
    let geographic =
        cdx < 1.0 && cdy < 1.0 && x0 >= -180.0 && right <= 180.0 && y0 >= -90.0 && top <= 90.0;
    let transform = [x0, cdx, 0.0, top, 0.0, -cdy];
    let (dx, dy) = match opts.cell_size {
        Some(c) => (c, c),
        None => cell_size_metres(&transform, width, height, geographic, 1.0),
    };
    let epsg = geographic.then_some(4326);
    Ok(Dem {
        width,
        height,
        heights,
        dx,
        dy,
        georef: georef_from(transform, epsg, geographic, nodata),
    })
}
