//! DEM readers on the real DEMs of `shared/data/dem` (statistics from its README, read with
//! GDAL), on files the tests write themselves (HGT, PNG, NPY, other GeoTIFF layouts), the float32
//! GeoTIFF writer's round trip, and fuzz-style robustness (truncation, flipped bytes, absurd
//! headers → an error, never a panic).

use phenomena_engine::formats::dem::{decode_dem, metres_per_degree, sniff, DemFormat, DemOptions};
use phenomena_engine::formats::geotiff_write::write_float32_geotiff;
use phenomena_engine::geom::heightfield::Dem;
use phenomena_engine::InputError;

macro_rules! dem_path {
    ($name:literal) => {
        concat!(env!("CARGO_MANIFEST_DIR"), "/../../shared/data/dem/", $name)
    };
}

fn opts() -> DemOptions {
    DemOptions::default()
}

fn read(path: &str) -> Dem {
    let bytes = std::fs::read(path).unwrap();
    let name = path.rsplit('/').next();
    decode_dem(&bytes, name, &opts()).unwrap()
}

/// Dimensions, min/max exactly, mean within 1e-3 relative.
fn check_stats(dem: &Dem, w: usize, h: usize, min: f32, max: f32, mean: f64) {
    assert_eq!((dem.width, dem.height), (w, h));
    let (lo, hi, m) = dem.stats().unwrap();
    assert_eq!(lo, min, "min");
    assert_eq!(hi, max, "max");
    assert!(((m - mean) / mean).abs() < 1e-3, "mean {m} vs {mean}");
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol
}

// ---------- real GeoTIFFs ----------

#[test]
fn tanzawa_int16_geotiff() {
    let dem = read(dem_path!("tanzawa_sagami_aster_gdem2.tif"));
    check_stats(&dem, 884, 868, 0.0, 1668.0, 244.542);
    assert_eq!(dem.georef.epsg, Some(4326));
    assert!(dem.georef.geographic);
    let t = dem.georef.transform.unwrap();
    assert!(
        close(t[0], 139.105694, 1e-5) && close(t[3], 35.488194, 1e-5),
        "{t:?}"
    );
    assert!(close(t[1], 1.0 / 3600.0, 1e-9) && close(t[5], -1.0 / 3600.0, 1e-9));
    // 1″ at 35.3°N, computed here independently of the reader (WGS84 radii of curvature).
    let lat = (35.488194 - 868.0 / 3600.0 / 2.0f64).to_radians();
    let (a, e2) = (6_378_137.0f64, 0.006_694_379_990_14f64);
    let w = 1.0 - e2 * lat.sin().powi(2);
    let east = a / w.sqrt() * lat.cos() * (1.0f64 / 3600.0).to_radians();
    let north = a * (1.0 - e2) / w.powf(1.5) * (1.0f64 / 3600.0).to_radians();
    assert!(close(dem.dx, east, 1e-3), "dx {} vs {east}", dem.dx);
    assert!(close(dem.dy, north, 1e-3), "dy {} vs {north}", dem.dy);
    assert!(close(dem.dx, 25.2, 0.1) && close(dem.dy, 30.8, 0.1));
}

#[test]
fn tanzawa_float32_geotiff_matches_int16() {
    let a = read(dem_path!("tanzawa_sagami_aster_gdem2.tif"));
    let b = read(dem_path!("tanzawa_sagami_aster_gdem2_f32.tif"));
    check_stats(&b, 884, 868, 0.0, 1668.0, 244.542);
    assert_eq!(a.heights, b.heights);
    assert_eq!(b.georef.epsg, Some(4326));
}

#[test]
fn colorado_float32_geotiff_with_nan_nodata() {
    let dem = read(dem_path!("colorado_front_range_srtmgl3_f32.tif"));
    check_stats(&dem, 758, 758, 1547.0, 4320.0, 2639.999);
    assert_eq!(dem.georef.epsg, Some(4326));
    assert!(dem.georef.nodata.unwrap().is_nan());
    assert_eq!(dem.valid_cells(), 758 * 758);
    let t = dem.georef.transform.unwrap();
    assert!(
        close(t[0], -105.81625, 1e-5) && close(t[3], 40.46625, 1e-5),
        "{t:?}"
    );
}

#[test]
fn jacksboro_float32_geotiff() {
    let dem = read(dem_path!("jacksboro_fault_dem_f32.tif"));
    check_stats(&dem, 403, 344, 236.0, 1076.0, 531.031);
    assert_eq!(dem.georef.epsg, Some(4326));
    assert_eq!(dem.georef.nodata, None);
}

#[test]
fn luxembourg_int16_nodata() {
    let dem = read(dem_path!("luxembourg_elev.tif"));
    check_stats(&dem, 95, 90, 141.0, 547.0, 348.337);
    assert_eq!(dem.georef.nodata, Some(-32768.0));
    assert_eq!(dem.width * dem.height - dem.valid_cells(), 3942);
    assert_eq!(dem.georef.epsg, Some(4326));
    let t = dem.georef.transform.unwrap();
    assert!(
        close(t[0], 5.741667, 1e-5) && close(t[3], 50.191667, 1e-5),
        "{t:?}"
    );
}

#[test]
fn olinda_projected_utm() {
    let dem = read(dem_path!("olinda_dem_utm25s.tif"));
    check_stats(&dem, 111, 111, -1.0, 88.0, 21.665);
    assert_eq!(dem.georef.epsg, Some(32725));
    assert!(!dem.georef.geographic);
    assert!(
        close(dem.dx, 89.994, 1e-3) && close(dem.dy, 89.994, 1e-3),
        "{} {}",
        dem.dx,
        dem.dy
    );
    let t = dem.georef.transform.unwrap();
    assert!(
        close(t[0], 288776.25, 1e-2) && close(t[3], 9120760.75, 1e-2),
        "{t:?}"
    );
}
