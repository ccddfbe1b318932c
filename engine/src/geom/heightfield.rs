//! A DEM as the pipelines see it: a row-major grid of heights with nodata as NaN, plus the
//! georeferencing needed to write rasters that line up with the input.
//!
//! World frame used by every consumer (descriptor, renderer, glTF): X = east (column × `dx`),
//! Y = up (elevation, metres), Z = south (row × `dy`); right-handed, the same as glTF's Y-up frame.
//! Row 0 is the northern edge (north-up rasters).

/// GeoTIFF tag values carried from input to output so that rasters we write line up with the
/// input in any GIS. For inputs without GeoTIFF tags the decoders synthesise equivalent ones.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GeoTags {
    /// ModelPixelScaleTag (33550).
    pub pixel_scale: Option<Vec<f64>>,
    /// ModelTiepointTag (33922).
    pub tiepoint: Option<Vec<f64>>,
    /// ModelTransformationTag (34264).
    pub transformation: Option<Vec<f64>>,
    /// GeoKeyDirectoryTag (34735).
    pub geo_key_directory: Option<Vec<u16>>,
    /// GeoDoubleParamsTag (34736).
    pub geo_double_params: Option<Vec<f64>>,
    /// GeoAsciiParamsTag (34737).
    pub geo_ascii_params: Option<String>,
}

/// Where the grid lies on Earth.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GeoRef {
    /// GDAL-style affine transform of cell *corners*: x = t[0] + col·t[1] + row·t[2],
    /// y = t[3] + col·t[4] + row·t[5], in CRS units. `None` when the file has no georeferencing.
    pub transform: Option<[f64; 6]>,
    /// EPSG code of the CRS when known (4326, 32725, …).
    pub epsg: Option<u32>,
    /// True when CRS units are degrees (geographic CRS).
    pub geographic: bool,
    /// The nodata value as written in the file (e.g. -32768, NaN); heights hold NaN for it.
    pub nodata: Option<f64>,
    /// Raw GeoTIFF tags to copy to raster outputs.
    pub tags: GeoTags,
}

/// A decoded DEM.
#[derive(Debug, Clone, PartialEq)]
pub struct Dem {
    pub width: usize,
    pub height: usize,
    /// `width × height` heights in metres, row-major, row 0 north; NaN marks nodata.
    pub heights: Vec<f32>,
    /// Cell size in metres along X (east) and Z (south). For geographic CRSs converted at the
    /// DEM's centre latitude.
    pub dx: f64,
    pub dy: f64,
    pub georef: GeoRef,
}

impl Dem {
    /// Height at (`col`, `row`); NaN for nodata. Panics on out-of-range indices (callers iterate
    /// within bounds).
    #[inline]
    pub fn at(&self, col: usize, row: usize) -> f32 {
        self.heights[row * self.width + col]
    }

    /// Number of cells that hold data.
    pub fn valid_cells(&self) -> usize {
        self.heights.iter().filter(|h| !h.is_nan()).count()
    }

    /// (min, max, mean) of valid heights, `None` when every cell is nodata. See
    /// [`Self::valid_stats`].
    pub fn stats(&self) -> Option<(f32, f32, f64)> {
        self.valid_stats().map(|(lo, hi, mean, _)| (lo, hi, mean))
    }

    /// (min, max, mean, count) of the valid heights, `None` when every cell is nodata. Parallel
    /// over chunks of 2¹⁶ cells; each chunk's sum runs in cell order (`f64`) and the chunks'
    /// sums are added in chunk order, so the figures do not depend on the thread count (the
    /// mean is the serial sum's whenever the sums are exact, e.g. integer heights).
    pub fn valid_stats(&self) -> Option<(f32, f32, f64, usize)> {
        self.valid_stats_above(None).0
    }

    /// [`Self::valid_stats`] and, in the same pass, (min, max, count) of the valid heights
    /// above `floor` (`None` when `floor` is `None` or no cell is above it): the range a
    /// histogram of the land cells needs (`snow_terrain::altitude::ElevationHistogram`), without
    /// a pass of its own. The first figures are the same bits as [`Self::valid_stats`]'.
    #[allow(clippy::type_complexity)]
    pub fn valid_stats_above(
        &self,
        floor: Option<f32>,
    ) -> (Option<(f32, f32, f64, usize)>, Option<(f32, f32, usize)>) {
        use rayon::prelude::*;
        type Part = (f32, f32, f64, usize, f32, f32, usize);
        let parts: Vec<Part> = self
            .heights
            .par_chunks(1 << 16)
            .map(|c| {
                let mut min = f32::INFINITY;
                let mut max = f32::NEG_INFINITY;
                let mut sum = 0.0f64;
                let mut n = 0usize;
                let (mut lmin, mut lmax, mut ln) = (f32::INFINITY, f32::NEG_INFINITY, 0usize);
                // No floor: nothing is above +∞.
                let f = floor.unwrap_or(f32::INFINITY);
                for &h in c {
                    if !h.is_nan() {
                        min = min.min(h);
                        max = max.max(h);
                        sum += f64::from(h);
                        n += 1;
                        if h > f {
                            lmin = lmin.min(h);
                            lmax = lmax.max(h);
                            ln += 1;
                        }
                    }
                }
                (min, max, sum, n, lmin, lmax, ln)
            })
            .collect();
        let (min, max, sum, n, lmin, lmax, ln) = parts.iter().fold(
            (
                f32::INFINITY,
                f32::NEG_INFINITY,
                0.0f64,
                0usize,
                f32::INFINITY,
                f32::NEG_INFINITY,
                0usize,
            ),
            |(a, b, s, n, la, lb, ln), p| {
                (
                    a.min(p.0),
                    b.max(p.1),
                    s + p.2,
                    n + p.3,
                    la.min(p.4),
                    lb.max(p.5),
                    ln + p.6,
                )
            },
        );
        (
            (n > 0).then(|| (min, max, sum / n as f64, n)),
            (floor.is_some() && ln > 0).then_some((lmin, lmax, ln)),
        )
    }
}
