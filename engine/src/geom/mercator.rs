//! Web Mercator (EPSG:3857) and the OGC WebMercatorQuad tile matrix set, and the reprojection of
//! a DEM's CRS to and from WGS 84 longitude/latitude for map tiles.
//!
//! **Tiles.** Zoom `z` splits the square `[-πR, πR]²` (R = 6 378 137 m, the WGS 84 semi-major
//! axis; EPSG:3857's spherical formulas) into `2^z × 2^z` tiles, x east from the antimeridian,
//! y south from 85.05113° N (the XYZ / "slippy map" scheme MapLibre, Leaflet and OpenLayers use).
//! Global pixel coordinates at zoom z with `size`-pixel tiles run from 0 to `size·2^z`.
//!
//! **Reprojection.** The DEM's CRS is what its reader found: an EPSG code, or "geographic" for
//! ESRI ASCII grids without a `.prj`. A geographic CRS on WGS 84 (EPSG:4326, or none given) needs
//! no transformation (degrees are used as they are); any other EPSG code goes through
//! [`proj4rs`] with the Proj4 definition that `crs-definitions` holds for it (datum shifts
//! included where the definition has `+towgs84`). Chosen over PROJ's C library through the `proj`
//! crate: pure Rust, nothing to install on the machines or in the image, and the projections DEMs
//! come in (UTM, transverse Mercator, Lambert, Albers, polar stereographic) are there; WKT-only
//! CRSs are not supported (the readers keep EPSG codes only).

use proj4rs::proj::Proj;

/// WGS 84 semi-major axis, metres: the sphere of EPSG:3857.
pub const EARTH_RADIUS: f64 = 6_378_137.0;
/// Half the width of the Web Mercator square, metres (π·R).
pub const HALF_WORLD: f64 = std::f64::consts::PI * EARTH_RADIUS;
/// Latitude of the square's northern edge, degrees.
pub const MAX_LATITUDE: f64 = 85.051_128_779_806_6;

/// Web Mercator (x, y) metres of a longitude/latitude in degrees (latitude clamped to the
/// square).
pub fn lonlat_to_mercator(lon: f64, lat: f64) -> (f64, f64) {
    let lat = lat.clamp(-MAX_LATITUDE, MAX_LATITUDE).to_radians();
    let x = EARTH_RADIUS * lon.to_radians();
    let y = EARTH_RADIUS * (std::f64::consts::FRAC_PI_4 + lat / 2.0).tan().ln();
    (x, y)
}

/// Longitude/latitude in degrees of Web Mercator (x, y) metres.
pub fn mercator_to_lonlat(x: f64, y: f64) -> (f64, f64) {
    let lon = (x / EARTH_RADIUS).to_degrees();
    let lat = (2.0 * (y / EARTH_RADIUS).exp().atan() - std::f64::consts::FRAC_PI_2).to_degrees();
    (lon, lat)
}

/// Web Mercator (x, y) metres of the global pixel position (`px`, `py`) (pixel corners at
/// integers) at zoom `z` with `size`-pixel tiles.
pub fn pixel_to_mercator(z: u8, size: u32, px: f64, py: f64) -> (f64, f64) {
    let world = f64::from(size) * 2f64.powi(i32::from(z));
    let m = 2.0 * HALF_WORLD / world;
    (-HALF_WORLD + px * m, HALF_WORLD - py * m)
}

/// Global pixel position at zoom `z` with `size`-pixel tiles of Web Mercator (x, y) metres.
pub fn mercator_to_pixel(z: u8, size: u32, x: f64, y: f64) -> (f64, f64) {
    let world = f64::from(size) * 2f64.powi(i32::from(z));
    let m = world / (2.0 * HALF_WORLD);
    ((x + HALF_WORLD) * m, (HALF_WORLD - y) * m)
}

/// Ground size of one pixel at zoom `z` and latitude `lat` (degrees) with 256-pixel tiles,
/// metres (Web Mercator's scale 1/cos φ taken out).
pub fn ground_resolution(z: u8, lat: f64) -> f64 {
    2.0 * HALF_WORLD * lat.to_radians().cos() / (256.0 * 2f64.powi(i32::from(z)))
}

/// Why a DEM cannot be put on a web map.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CrsError {
    #[error("the DEM has no georeferencing (no geotransform): a map needs to know where it lies")]
    NoGeoreference,
    #[error("the DEM is rotated or sheared (its geotransform has rotation terms); only north-up grids are supported")]
    Rotated,
    #[error("the DEM's CRS is projected but names no EPSG code; only EPSG-coded CRSs can be reprojected")]
    UnknownCrs,
    #[error("EPSG:{0} is not a CRS this service can reproject (no Proj4 definition for it)")]
    Unsupported(u32),
}

/// A DEM CRS ⇄ WGS 84 longitude/latitude (degrees) transformation.
#[derive(Debug)]
pub struct CrsTransform {
    /// `None`: the CRS is WGS 84 longitude/latitude itself.
    proj: Option<(Proj, Proj)>,
}

impl CrsTransform {
    /// The transformation for a CRS known by its EPSG code (`None` for a geographic CRS without
    /// one, taken as WGS 84).
    pub fn new(epsg: Option<u32>, geographic: bool) -> Result<Self, CrsError> {
        match (epsg, geographic) {
            (None | Some(4326), true) | (Some(4326), false) => Ok(Self { proj: None }),
            (None, false) => Err(CrsError::UnknownCrs),
            (Some(code), _) => {
                let c = u16::try_from(code).map_err(|_| CrsError::Unsupported(code))?;
                let dem = Proj::from_epsg_code(c).map_err(|_| CrsError::Unsupported(code))?;
                let wgs =
                    Proj::from_proj_string("+proj=longlat +ellps=WGS84 +datum=WGS84 +no_defs")
                        .map_err(|_| CrsError::Unsupported(code))?;
                Ok(Self {
                    proj: Some((dem, wgs)),
                })
            }
        }
    }

    /// Whether the CRS is WGS 84 longitude/latitude (no transformation).
    pub fn is_identity(&self) -> bool {
        self.proj.is_none()
    }

    /// DEM CRS coordinates of a longitude/latitude in degrees; `None` where the projection has
    /// no value (far outside its zone).
    pub fn from_lonlat(&self, lon: f64, lat: f64) -> Option<(f64, f64)> {
        let Some((dem, wgs)) = &self.proj else {
            return Some((lon, lat));
        };
        let mut p = (lon.to_radians(), lat.to_radians(), 0.0);
        proj4rs::transform::transform(wgs, dem, &mut p).ok()?;
        let (x, y) = if dem.is_latlong() {
            (p.0.to_degrees(), p.1.to_degrees())
        } else {
            (p.0, p.1)
        };
        (x.is_finite() && y.is_finite()).then_some((x, y))
    }

    /// The outline of a north-up grid of `width × height` cells whose corner (column, row) lies
    /// at `(x0 + column·a, y0 + row·e)` in the CRS (`t = [x0, a, y0, e]`), as longitude/latitude
    /// in degrees: `k` points a side (a projected grid's edges are curves in WGS 84),
    /// counter-clockwise from the north-west corner (down the west edge first) and closed
    /// (the last point repeats the first), the ring order of RFC 7946 §3.1.6. `None` where the
    /// CRS has no value at a point.
    pub fn outline_lonlat(
        &self,
        t: [f64; 4],
        width: usize,
        height: usize,
        k: usize,
    ) -> Option<Vec<(f64, f64)>> {
        let [x0, a, y0, e] = t;
        let (w, h) = (width as f64, height as f64);
        let k = k.max(1);
        let mut ring = Vec::with_capacity(4 * k + 1);
        // Grid corners in the order NW → SW → SE → NE (counter-clockwise on the map).
        let corners = [(0.0, 0.0), (0.0, h), (w, h), (w, 0.0)];
        for side in 0..4 {
            let (c0, r0) = corners[side];
            let (c1, r1) = corners[(side + 1) % 4];
            for i in 0..k {
                let f = i as f64 / k as f64;
                let (c, r) = (c0 + f * (c1 - c0), r0 + f * (r1 - r0));
                ring.push(self.to_lonlat(x0 + c * a, y0 + r * e)?);
            }
        }
        ring.push(ring[0]);
        Some(ring)
    }

    /// Longitude/latitude in degrees of DEM CRS coordinates.
    pub fn to_lonlat(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        let Some((dem, wgs)) = &self.proj else {
            return Some((x, y));
        };
        let mut p = if dem.is_latlong() {
            (x.to_radians(), y.to_radians(), 0.0)
        } else {
            (x, y, 0.0)
        };
        proj4rs::transform::transform(dem, wgs, &mut p).ok()?;
        let (lon, lat) = (p.0.to_degrees(), p.1.to_degrees());
        (lon.is_finite() && lat.is_finite()).then_some((lon, lat))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mercator_round_trips_and_hits_the_square() {
        let (x, y) = lonlat_to_mercator(180.0, MAX_LATITUDE);
        assert!((x - HALF_WORLD).abs() < 1e-6 && (y - HALF_WORLD).abs() < 1e-3);
        let (lon, lat) = mercator_to_lonlat(lonlat_to_mercator(139.1, 35.4).0, 4_218_000.0);
        let (x, y) = lonlat_to_mercator(lon, lat);
        assert!((x - lonlat_to_mercator(139.1, 35.4).0).abs() < 1e-6);
        assert!((y - 4_218_000.0).abs() < 1e-6);
        let (px, py) = mercator_to_pixel(3, 256, 0.0, 0.0);
        assert!((px - 1024.0).abs() < 1e-6 && (py - 1024.0).abs() < 1e-6);
        let (x, y) = pixel_to_mercator(3, 256, 1024.0, 1024.0);
        assert!(x.abs() < 1e-6 && y.abs() < 1e-6, "{x} {y}");
    }

    #[test]
    fn utm_south_reaches_the_known_point() {
        // Olinda (shared/data: olinda_dem_utm25s.tif, west 288776.25, north 9120760.75), UTM 25S.
        let t = CrsTransform::new(Some(32725), false).unwrap();
        let (lon, lat) = t.to_lonlat(288_776.25, 9_120_760.75).unwrap();
        assert!(
            (lon + 34.9).abs() < 0.1 && (lat + 7.95).abs() < 0.1,
            "{lon} {lat}"
        );
        let (x, y) = t.from_lonlat(lon, lat).unwrap();
        assert!((x - 288_776.25).abs() < 1e-3 && (y - 9_120_760.75).abs() < 1e-3);
    }

    #[test]
    fn refuses_what_it_cannot_place() {
        assert_eq!(
            CrsTransform::new(None, false).err(),
            Some(CrsError::UnknownCrs)
        );
        assert!(CrsTransform::new(None, true).unwrap().is_identity());
        assert_eq!(
            CrsTransform::new(Some(99_999_999), false).err(),
            Some(CrsError::Unsupported(99_999_999))
        );
    }
}
