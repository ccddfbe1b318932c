//! DEM readers: GeoTIFF, ESRI ASCII grid, SRTM `.hgt`, 16-bit greyscale PNG and NumPy `.npy`
//! (SPEC §1, *Input*), all decoded into one [`Dem`]: heights in metres as `f32`, row 0 north,
//! NaN for nodata, cell sizes in metres and the georeferencing needed to write rasters that line
//! up with the input ([`crate::formats::geotiff_write`]).
//!
//! Every reader checks the declared grid size against [`DemOptions::max_cells`] and against the
//! number of bytes actually present *before* allocating the grid, so a 100-byte file that claims
//! 10⁹ × 10⁹ cells costs nothing. Third-party decoders (`tiff`, `png`, `npyz`) run inside
//! [`std::panic::catch_unwind`] as a second line of defence: a panic inside one of them on hostile
//! bytes becomes [`InputError::Corrupt`] instead of taking a worker down.
//!
//! After decoding, every format goes through the same checks: ±∞ heights become nodata, a grid
//! smaller than 3 × 3 or without a single valid cell is [`InputError::Unusable`] (the descriptor
//! needs neighbours), and the cell size must be finite and positive.
//!
//! Cost: one pass over the file plus one `width × height` `f32` allocation (and, for GeoTIFF,
//! the decoder's own buffer of the stored sample type).

mod asc;
pub mod cog;
pub(crate) mod geo;
pub(crate) mod geotiff;
mod hgt;
mod npy;
mod png16;

pub use geo::{metres_per_degree, synthesize_tags};

use crate::error::{InputError, ParamError};
use crate::geom::heightfield::Dem;

/// Options a caller passes; all validated by the caller except where noted.
#[derive(Debug, Clone)]
pub struct DemOptions {
    /// Refuse grids with more cells than this before allocating the grid
    /// ([`InputError::TooLarge`]).
    pub max_cells: u64,
    /// Metres per cell for formats without georeferencing (16-bit PNG, `.npy`, a plain TIFF
    /// without geo tags, an `.hgt` whose name does not give its tile), and an override of the
    /// header `cellsize` for `.asc` (which never carries a CRS). `None` = the format's default:
    /// required for PNG and plain TIFF, 1 m for `.npy`. Must be finite and > 0.
    pub cell_size: Option<f64>,
    /// Metres per stored unit for 16-bit PNG and `.npy` data (any dtype). Default: 1.
    pub vertical_scale: Option<f64>,
}

impl Default for DemOptions {
    /// 64 Mi cells (an 8192 × 8192 grid, 256 MiB of `f32`), no cell size, vertical scale 1.
    fn default() -> Self {
        Self {
            max_cells: 1 << 26,
            cell_size: None,
            vertical_scale: None,
        }
    }
}

/// The DEM formats we read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DemFormat {
    /// TIFF or BigTIFF, with or without GeoTIFF tags.
    GeoTiff,
    /// ESRI ASCII grid (`.asc`).
    EsriAscii,
    /// SRTM `.hgt` tile (big-endian `i16`, 1201² or 3601²).
    Hgt,
    /// 8- or 16-bit greyscale PNG.
    Png16,
    /// NumPy `.npy`.
    Npy,
}

impl DemFormat {
    /// Short name used in error messages.
    pub fn name(self) -> &'static str {
        match self {
            DemFormat::GeoTiff => "GeoTIFF",
            DemFormat::EsriAscii => "ESRI ASCII grid",
            DemFormat::Hgt => "SRTM HGT",
            DemFormat::Png16 => "PNG",
            DemFormat::Npy => "NPY",
        }
    }
}

/// The format detected from magic bytes (and the file name for `.hgt`/`.asc`), without decoding.
///
/// Magic bytes win over the file name: TIFF (`II*\0`, `MM\0*`, BigTIFF `II+\0`, `MM\0+`), PNG,
/// NPY (`\x93NUMPY`). Then a name ending in `.hgt` (or, without a name, a size of exactly
/// 2·1201² or 2·3601² bytes) is HGT, and a name ending in `.asc` or text starting with an
/// `ncols`/`nrows` key is an ESRI ASCII grid.
pub fn sniff(bytes: &[u8], filename: Option<&str>) -> Option<DemFormat> {
    if bytes.starts_with(b"II*\0")
        || bytes.starts_with(b"MM\0*")
        || bytes.starts_with(b"II+\0")
        || bytes.starts_with(b"MM\0+")
    {
        return Some(DemFormat::GeoTiff);
    }
    if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        return Some(DemFormat::Png16);
    }
    if bytes.starts_with(b"\x93NUMPY") {
        return Some(DemFormat::Npy);
    }
    let ext = filename
        .and_then(|n| n.rsplit('.').next().filter(|_| n.contains('.')))
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("hgt") => return Some(DemFormat::Hgt),
        Some("asc") => return Some(DemFormat::EsriAscii),
        _ => {}
    }
    if asc::looks_like_asc(bytes) {
        return Some(DemFormat::EsriAscii);
    }
    if filename.is_none() && hgt::side_for_len(bytes.len()).is_some() {
        return Some(DemFormat::Hgt);
    }
    None
}

/// Decode a DEM of any supported format (see [`sniff`]) into heights in metres.
///
/// Errors: [`InputError::UnsupportedFormat`] when no format matches or the variant is not
/// supported (e.g. a colour PNG), [`InputError::Corrupt`] for truncated or inconsistent bytes,
/// [`InputError::TooLarge`] when `width × height > opts.max_cells` (checked before the grid is
/// allocated), [`InputError::Unusable`] for grids smaller than 3 × 3 or without valid cells,
/// [`InputError::Param`] when a needed `cell_size` is missing or a given option is invalid.
///
/// Allocates the `width × height` grid (plus the decoder's buffer for GeoTIFF and PNG).
pub fn decode_dem(
    bytes: &[u8],
    filename: Option<&str>,
    opts: &DemOptions,
) -> Result<Dem, InputError> {
    check_options(opts)?;
    let format = sniff(bytes, filename).ok_or_else(|| {
        InputError::UnsupportedFormat(
            "not a DEM format we read (GeoTIFF, ESRI ASCII .asc, SRTM .hgt, 16-bit PNG, .npy)"
                .to_string(),
        )
    })?;
    let decoded = std::panic::catch_unwind(|| match format {
        DemFormat::GeoTiff => geotiff::decode(bytes, opts),
        DemFormat::EsriAscii => asc::decode(bytes, opts),
        DemFormat::Hgt => hgt::decode(bytes, filename, opts),
        DemFormat::Png16 => png16::decode(bytes, opts),
        DemFormat::Npy => npy::decode(bytes, opts),
    })
    .unwrap_or_else(|_| {
        Err(InputError::Corrupt {
            format: format.name(),
            detail: "the decoder panicked on malformed data".to_string(),
        })
    })?;
    finish(decoded)
}

fn check_options(opts: &DemOptions) -> Result<(), InputError> {
    if let Some(c) = opts.cell_size {
        if !(c.is_finite() && c > 0.0) {
            return Err(
                ParamError::new("cell_size", "must be a finite number > 0 (metres)").into(),
            );
        }
    }
    if let Some(v) = opts.vertical_scale {
        if !(v.is_finite() && v != 0.0) {
            return Err(
                ParamError::new("vertical_scale", "must be a finite non-zero number").into(),
            );
        }
    }
    Ok(())
}

/// Refuse `width × height` grids over the limit or with a zero side, before allocating.
pub(crate) fn check_cells(width: u64, height: u64, max_cells: u64) -> Result<(), InputError> {
    let cells = width.saturating_mul(height);
    if cells > max_cells {
        return Err(InputError::TooLarge {
            what: "DEM cells",
            actual: cells,
            max: max_cells,
        });
    }
    if width < 3 || height < 3 {
        return Err(InputError::Unusable(format!(
            "the DEM is {width}×{height} cells; at least 3×3 are needed"
        )));
    }
    Ok(())
}

/// Common final checks for every format: ±∞ → nodata, at least 3 × 3 cells, some valid cell,
/// positive finite cell size.
fn finish(mut dem: Dem) -> Result<Dem, InputError> {
    if dem.width < 3 || dem.height < 3 {
        return Err(InputError::Unusable(format!(
            "the DEM is {}×{} cells; at least 3×3 are needed",
            dem.width, dem.height
        )));
    }
    if dem.heights.len() != dem.width * dem.height {
        return Err(InputError::Unusable(
            "decoded height count does not match the grid size".to_string(),
        ));
    }
    let mut any_valid = false;
    for h in &mut dem.heights {
        if h.is_infinite() {
            *h = f32::NAN;
        } else if !h.is_nan() {
            any_valid = true;
        }
    }
    if !any_valid {
        return Err(InputError::Unusable(
            "every cell of the DEM is nodata".to_string(),
        ));
    }
    if !(dem.dx.is_finite() && dem.dx > 0.0 && dem.dy.is_finite() && dem.dy > 0.0) {
        return Err(InputError::Unusable(format!(
            "the DEM's cell size ({} × {} m) is not a positive finite number",
            dem.dx, dem.dy
        )));
    }
    Ok(dem)
}

/// Cell size from `opts.cell_size`, or the error a format without georeferencing gives.
pub(crate) fn required_cell_size(opts: &DemOptions, format: &str) -> Result<f64, InputError> {
    opts.cell_size.ok_or_else(|| {
        ParamError::new(
            "cell_size",
            format!(
                "required for {format} input, which carries no georeferencing (metres per cell)"
            ),
        )
        .into()
    })
}
