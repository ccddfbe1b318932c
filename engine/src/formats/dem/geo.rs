//! Georeferencing shared by the DEM readers and the GeoTIFF writer: GeoKey directory parsing,
//! the affine transform from GeoTIFF tags, synthesised tags for formats without them, and the
//! conversion of geographic cell sizes (degrees) to metres.
//!
//! Metres per degree use the WGS84 ellipsoid (a = 6 378 137 m, f = 1/298.257223563) at the
//! DEM's centre latitude φ:
//! - along a meridian (north–south): M(φ)·π/180 with the meridional radius of curvature
//!   M = a(1 − e²)/(1 − e² sin²φ)^{3/2};
//! - along a parallel (east–west): N(φ)·cos φ·π/180 with the prime-vertical radius
//!   N = a/√(1 − e² sin²φ).
//!
//! Rejected: a spherical Earth (111 195 m per degree everywhere) is off by up to 1 % in latitude,
//! and Vincenty distances across the whole DEM add nothing for cells of a few arc-seconds.

use crate::geom::heightfield::{GeoRef, GeoTags};

const WGS84_A: f64 = 6_378_137.0;
const WGS84_F: f64 = 1.0 / 298.257_223_563;

// GeoKey IDs (GeoTIFF 1.1, §7).
pub(crate) const GT_MODEL_TYPE: u16 = 1024;
pub(crate) const GT_RASTER_TYPE: u16 = 1025;
pub(crate) const GEOGRAPHIC_TYPE: u16 = 2048;
pub(crate) const PROJECTED_CS_TYPE: u16 = 3072;
pub(crate) const PROJECTION: u16 = 3074;
pub(crate) const PROJ_LINEAR_UNITS: u16 = 3076;
pub(crate) const PROJ_LINEAR_UNIT_SIZE: u16 = 3077;

/// GeoTIFF tag numbers.
pub(crate) const TAG_GEO_DOUBLE_PARAMS: u16 = 34736;

/// Metres per degree of (latitude, longitude) on the WGS84 ellipsoid at latitude `lat_deg`.
pub fn metres_per_degree(lat_deg: f64) -> (f64, f64) {
    let e2 = WGS84_F * (2.0 - WGS84_F);
    let phi = lat_deg.clamp(-90.0, 90.0).to_radians();
    let s2 = phi.sin() * phi.sin();
    let w = 1.0 - e2 * s2;
    let m = WGS84_A * (1.0 - e2) / (w * w.sqrt());
    let n = WGS84_A / w.sqrt();
    let rad = std::f64::consts::PI / 180.0;
    (m * rad, n * phi.cos() * rad)
}

/// A GeoKey value: a short stored in the directory, doubles, or ASCII.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum KeyValue {
    Short(u16),
    Doubles(Vec<f64>),
    Ascii(String),
}

/// Parse a GeoKeyDirectory into (key id, value) pairs. Malformed entries (out-of-range offsets,
/// an unknown tag location) are skipped rather than failing the whole file: georeferencing is
/// best effort, the heights are what matters.
pub(crate) fn parse_geo_keys(tags: &GeoTags) -> Vec<(u16, KeyValue)> {
    let Some(dir) = tags.geo_key_directory.as_deref() else {
        return Vec::new();
    };
    let Some(&n) = dir.get(3) else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for k in 0..usize::from(n) {
        let Some(entry) = dir.get(4 + 4 * k..8 + 4 * k) else {
            break;
        };
        let (id, loc, count, off) = (
            entry[0],
            entry[1],
            usize::from(entry[2]),
            usize::from(entry[3]),
        );
        let value = match loc {
            0 => Some(KeyValue::Short(entry[3])),
            TAG_GEO_DOUBLE_PARAMS => tags
                .geo_double_params
                .as_deref()
                .and_then(|d| d.get(off..off.checked_add(count)?))
                .map(|d| KeyValue::Doubles(d.to_vec())),
            34737 => tags
                .geo_ascii_params
                .as_deref()
                .and_then(|s| s.get(off..off.checked_add(count)?))
                .map(|s| KeyValue::Ascii(s.trim_end_matches(['|', '\0']).to_string())),
            34735 => dir.get(off).copied().map(KeyValue::Short),
            _ => None,
        };
        if let Some(v) = value {
            out.push((id, v));
        }
    }
    out
}

fn key_short(keys: &[(u16, KeyValue)], id: u16) -> Option<u16> {
    keys.iter().find_map(|(k, v)| match v {
        KeyValue::Short(s) if *k == id => Some(*s),
        _ => None,
    })
}

fn key_double(keys: &[(u16, KeyValue)], id: u16) -> Option<f64> {
    keys.iter().find_map(|(k, v)| match v {
        KeyValue::Doubles(d) if *k == id => d.first().copied(),
        _ => None,
    })
}

/// What the GeoKeys say about the CRS.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct CrsInfo {
    pub epsg: Option<u32>,
    pub geographic: bool,
    /// Raster type PixelIsPoint (tiepoints name cell centres).
    pub pixel_is_point: bool,
    /// Metres per CRS unit for projected CRSs (1 for metres, 0.3048 for feet).
    pub linear_unit: f64,
}

/// EPSG code of WGS84 / UTM for a ProjectionGeoKey naming a UTM zone (16001–16060 north,
/// 16101–16160 south): 326zz / 327zz.
fn utm_epsg(projection: u16) -> Option<u32> {
    match projection {
        16001..=16060 => Some(32600 + u32::from(projection - 16000)),
        16101..=16160 => Some(32700 + u32::from(projection - 16100)),
        _ => None,
    }
}

/// Interpret the GeoKey directory: EPSG code (ProjectedCSTypeGeoKey, else GeographicTypeGeoKey;
/// 32767 "user-defined" and 0 are not codes), geographic vs projected (GTModelTypeGeoKey 2 =
/// geographic; without it, a geographic key and no projected key), raster type and linear unit.
///
/// A user-defined projected CRS whose ProjectionGeoKey is a UTM zone (GDAL writes this for UTM on
/// a GRS80 or unnamed datum, e.g. `olinda_dem_utm25s.tif`) is reported as WGS84 / UTM of that
/// zone (EPSG 326zz/327zz): GRS80 and WGS84 differ by less than a millimetre, and the datum is
/// only a label for our outputs, whose raw GeoKeys are copied verbatim anyway.
pub(crate) fn crs_info(tags: &GeoTags) -> CrsInfo {
    let keys = parse_geo_keys(tags);
    let valid = |c: u16| (c != 0 && c != 32767).then_some(u32::from(c));
    let projected = key_short(&keys, PROJECTED_CS_TYPE)
        .and_then(valid)
        .or_else(|| key_short(&keys, PROJECTION).and_then(utm_epsg));
    let geog = key_short(&keys, GEOGRAPHIC_TYPE).and_then(valid);
    let geographic = match key_short(&keys, GT_MODEL_TYPE) {
        Some(t) => t == 2,
        None => projected.is_none() && geog.is_some(),
    };
    let epsg = if geographic {
        geog.or(projected)
    } else {
        projected.or(geog)
    };
    let linear_unit = match key_short(&keys, PROJ_LINEAR_UNITS) {
        Some(9002) => 0.3048,
        Some(9003) => 1200.0 / 3937.0,
        Some(32767) => key_double(&keys, PROJ_LINEAR_UNIT_SIZE)
            .filter(|s| s.is_finite() && *s > 0.0)
            .unwrap_or(1.0),
        _ => 1.0,
    };
    CrsInfo {
        epsg,
        geographic,
        pixel_is_point: key_short(&keys, GT_RASTER_TYPE) == Some(2),
        linear_unit,
    }
}

/// GDAL geotransform (cell corners) from ModelTransformation, or ModelTiepoint + ModelPixelScale.
/// With PixelIsPoint the model coordinates name cell centres and, as GDAL does, the transform is
/// moved half a cell up-left. `None` when the tags do not give one or give non-finite values.
pub(crate) fn transform_from_tags(tags: &GeoTags, pixel_is_point: bool) -> Option<[f64; 6]> {
    let mut t = if let Some(m) = tags.transformation.as_deref().filter(|m| m.len() >= 16) {
        [m[3], m[0], m[1], m[7], m[4], m[5]]
    } else {
        let tp = tags.tiepoint.as_deref().filter(|t| t.len() >= 6)?;
        let ps = tags.pixel_scale.as_deref().filter(|p| p.len() >= 2)?;
        let (i, j, x, y) = (tp[0], tp[1], tp[3], tp[4]);
        let (sx, sy) = (ps[0], ps[1]);
        [x - i * sx, sx, 0.0, y + j * sy, 0.0, -sy]
    };
    if pixel_is_point {
        t[0] -= 0.5 * (t[1] + t[2]);
        t[3] -= 0.5 * (t[4] + t[5]);
    }
    t.iter().all(|v| v.is_finite()).then_some(t)
}

/// Cell size in metres (east, south) from a transform. Geographic transforms are in degrees and
/// converted at the centre latitude of a `width × height` grid; projected ones are multiplied by
/// `linear_unit` (metres per CRS unit).
pub(crate) fn cell_size_metres(
    t: &[f64; 6],
    width: usize,
    height: usize,
    geographic: bool,
    linear_unit: f64,
) -> (f64, f64) {
    if geographic {
        let lat = t[3] + t[4] * width as f64 / 2.0 + t[5] * height as f64 / 2.0;
        let (m_lat, m_lon) = metres_per_degree(lat);
        (
            (t[1] * m_lon).hypot(t[4] * m_lat),
            (t[2] * m_lon).hypot(t[5] * m_lat),
        )
    } else {
        (
            t[1].hypot(t[4]) * linear_unit,
            t[2].hypot(t[5]) * linear_unit,
        )
    }
}

/// GeoTIFF tags equivalent to a transform and CRS, for inputs that have no tags of their own
/// (ESRI ASCII, HGT) or a `GeoRef` built by hand.
///
/// North-up transforms become ModelPixelScale + ModelTiepoint (what GDAL writes), rotated ones a
/// ModelTransformation. The GeoKeyDirectory says RasterPixelIsArea and, with an EPSG code,
/// GTModelType (2 geographic / 1 projected) plus GeographicType or ProjectedCSType. Without a
/// code only the raster type is written, which GIS software reads as "CRS unknown" — the honest
/// answer for an `.asc` in metres without a `.prj`.
pub fn synthesize_tags(
    transform: Option<[f64; 6]>,
    epsg: Option<u32>,
    geographic: bool,
) -> GeoTags {
    let Some(t) = transform else {
        return GeoTags::default();
    };
    let mut tags = GeoTags::default();
    if t[2] == 0.0 && t[4] == 0.0 {
        tags.pixel_scale = Some(vec![t[1], -t[5], 0.0]);
        tags.tiepoint = Some(vec![0.0, 0.0, 0.0, t[0], t[3], 0.0]);
    } else {
        tags.transformation = Some(vec![
            t[1], t[2], 0.0, t[0], t[4], t[5], 0.0, t[3], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0,
        ]);
    }
    let mut keys: Vec<[u16; 4]> = Vec::new();
    let code = epsg.and_then(|e| u16::try_from(e).ok());
    if code.is_some() {
        keys.push([GT_MODEL_TYPE, 0, 1, if geographic { 2 } else { 1 }]);
    }
    keys.push([GT_RASTER_TYPE, 0, 1, 1]);
    if let Some(code) = code {
        let key = if geographic {
            GEOGRAPHIC_TYPE
        } else {
            PROJECTED_CS_TYPE
        };
        keys.push([key, 0, 1, code]);
    }
    let mut dir = vec![1, 1, 0, keys.len() as u16];
    for k in keys {
        dir.extend_from_slice(&k);
    }
    tags.geo_key_directory = Some(dir);
    tags
}

/// A `GeoRef` for a north-up grid with known transform and CRS, with synthesised tags.
pub(crate) fn georef_from(
    transform: [f64; 6],
    epsg: Option<u32>,
    geographic: bool,
    nodata: Option<f64>,
) -> GeoRef {
    GeoRef {
        transform: Some(transform),
        epsg,
        geographic,
        nodata,
        tags: synthesize_tags(Some(transform), epsg, geographic),
    }
}
