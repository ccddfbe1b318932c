//! What a catalogue needs to know of a finished `snow_cover.tif` (issue 22's STAC Item): where
//! the raster lies on the Earth, its grid in its own CRS, and its band's statistics. Read from
//! the Cloud-Optimized GeoTIFF itself (decoded as any GeoTIFF DEM is, [`decode_dem`]), so the
//! description is of the bytes a client downloads, not of a second computation.

use crate::error::InputError;
use crate::formats::dem::{decode_dem, DemOptions};
use crate::geom::mercator::{CrsError, CrsTransform};
use crate::params::Limits;

use super::tiles::lonlat_bbox;

/// Points per side of the footprint: a projected grid's edges are curves in WGS 84.
pub const OUTLINE_POINTS_PER_SIDE: usize = 8;

/// The georeferencing and band statistics of a single-band raster.
#[derive(Debug, Clone, PartialEq)]
pub struct RasterFootprint {
    /// Columns and rows.
    pub width: usize,
    pub height: usize,
    /// The CRS's EPSG code (`None`: geographic without a code, taken as WGS 84).
    pub epsg: Option<u32>,
    /// GDAL geotransform of cell corners: x = t0 + col·t1 + row·t2, y = t3 + col·t4 + row·t5.
    pub geotransform: [f64; 6],
    /// West, south, east, north in the raster's CRS units.
    pub crs_bbox: [f64; 4],
    /// The outline in WGS 84 longitude/latitude, counter-clockwise and closed (RFC 7946).
    pub outline: Vec<(f64, f64)>,
    /// West, south, east, north of [`RasterFootprint::outline`], degrees.
    pub bbox: [f64; 4],
    /// The nodata value the file declares (`GDAL_NODATA`).
    pub nodata: Option<f64>,
    /// Statistics of the valid cells; `None` when every cell is nodata.
    pub stats: Option<BandStats>,
}

/// Statistics of a band's valid cells.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BandStats {
    pub minimum: f64,
    pub maximum: f64,
    pub mean: f64,
    /// Population standard deviation.
    pub stddev: f64,
    /// Valid cells, per cent of all cells.
    pub valid_percent: f64,
}

/// Why a raster has no footprint.
#[derive(Debug, thiserror::Error)]
pub enum FootprintError {
    #[error(transparent)]
    Input(#[from] InputError),
    #[error(transparent)]
    Crs(#[from] CrsError),
}

/// The footprint and band statistics of the GeoTIFF `tif` (a `snow_cover.tif`), decoded within
/// `limits`. A raster without georeferencing, rotated, or in a CRS without an EPSG code has none.
pub fn footprint(tif: &[u8], limits: &Limits) -> Result<RasterFootprint, FootprintError> {
    let opts = DemOptions {
        max_cells: limits.max_input_cells,
        cell_size: None,
        vertical_scale: None,
    };
    let grid = decode_dem(tif, Some("snow_cover.tif"), &opts)?;
    let g = &grid.georef;
    let t = g.transform.ok_or(CrsError::NoGeoreference)?;
    if t[2] != 0.0 || t[4] != 0.0 {
        return Err(CrsError::Rotated.into());
    }
    let crs = CrsTransform::new(g.epsg, g.geographic)?;
    let (w, h) = (grid.width, grid.height);
    let outline = crs
        .outline_lonlat([t[0], t[1], t[3], t[5]], w, h, OUTLINE_POINTS_PER_SIDE)
        .ok_or(CrsError::Unsupported(g.epsg.unwrap_or(0)))?;
    let (xa, xb) = (t[0], t[0] + w as f64 * t[1]);
    let (ya, yb) = (t[3], t[3] + h as f64 * t[5]);
    let crs_bbox = [xa.min(xb), ya.min(yb), xa.max(xb), ya.max(yb)];
    Ok(RasterFootprint {
        width: w,
        height: h,
        epsg: g.epsg.or(g.geographic.then_some(4326)),
        geotransform: t,
        crs_bbox,
        bbox: lonlat_bbox(&outline),
        outline,
        nodata: g.nodata,
        stats: band_stats(&grid.heights),
    })
}

/// Statistics of the non-NaN values (nodata decodes to NaN).
fn band_stats(values: &[f32]) -> Option<BandStats> {
    let (mut n, mut sum, mut sum2) = (0usize, 0.0f64, 0.0f64);
    let (mut min, mut max) = (f64::INFINITY, f64::NEG_INFINITY);
    for &v in values.iter().filter(|v| !v.is_nan()) {
        let v = f64::from(v);
        n += 1;
        sum += v;
        sum2 += v * v;
        min = min.min(v);
        max = max.max(v);
    }
    if n == 0 {
        return None;
    }
    let mean = sum / n as f64;
    Some(BandStats {
        minimum: min,
        maximum: max,
        mean,
        stddev: (sum2 / n as f64 - mean * mean).max(0.0).sqrt(),
        valid_percent: 100.0 * n as f64 / values.len() as f64,
    })
}

#[cfg(test)]
mod tests {
    use super::band_stats;

    #[test]
    fn stats_skip_nodata() {
        let s = band_stats(&[0.0, 1.0, f32::NAN, 0.5]).unwrap();
        assert_eq!((s.minimum, s.maximum), (0.0, 1.0));
        assert!((s.mean - 0.5).abs() < 1e-12);
        assert!((s.stddev - (1.0f64 / 6.0).sqrt()).abs() < 1e-9);
        assert!((s.valid_percent - 75.0).abs() < 1e-12);
        assert!(band_stats(&[f32::NAN]).is_none());
    }
}
