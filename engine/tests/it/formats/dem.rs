//! DEM readers on the real DEMs of `shared/data/dem` (statistics from its README, read with
//! GDAL), on files the tests write themselves (HGT, PNG, NPY, other GeoTIFF layouts), the float32
//! GeoTIFF writer's round trip, and fuzz-style robustness (truncation, flipped bytes, absurd
//! headers → an error, never a panic).

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests may unwrap (STYLE habit 4)

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

// ---------- real ESRI ASCII grids ----------

#[test]
fn tanzawa_asc_matches_geotiff() {
    let asc = read(dem_path!("tanzawa_sagami_aster_gdem2_f32.asc"));
    let tif = read(dem_path!("tanzawa_sagami_aster_gdem2.tif"));
    check_stats(&asc, 884, 868, 0.0, 1668.0, 244.542);
    assert_eq!(asc.heights, tif.heights);
    // The geographic heuristic: cellsize < 1 and the extent within lon/lat range.
    assert!(asc.georef.geographic);
    assert_eq!(asc.georef.epsg, Some(4326));
    assert!(close(asc.dx, tif.dx, 1e-3) && close(asc.dy, tif.dy, 1e-3));
    let (a, b) = (asc.georef.transform.unwrap(), tif.georef.transform.unwrap());
    for i in 0..6 {
        assert!(close(a[i], b[i], 1e-7), "{a:?} vs {b:?}");
    }
}

#[test]
fn colorado_asc_unused_nodata() {
    let dem = read(dem_path!("colorado_front_range_srtmgl3.asc"));
    check_stats(&dem, 758, 758, 1547.0, 4320.0, 2639.999);
    assert_eq!(dem.valid_cells(), 758 * 758);
    assert_eq!(dem.georef.nodata, Some(0.0));
    assert_eq!(dem.georef.epsg, Some(4326));
    let tif = read(dem_path!("colorado_front_range_srtmgl3_f32.tif"));
    assert_eq!(dem.heights, tif.heights);
    // 3″ at ≈ 40.15°N: ≈ 71 m east, ≈ 92.5 m north.
    let (m_lat, m_lon) = metres_per_degree(40.150417);
    assert!(close(dem.dx, m_lon / 1200.0, 0.01) && close(dem.dy, m_lat / 1200.0, 0.01));
    assert!(
        close(dem.dx, 71.0, 0.5) && close(dem.dy, 92.5, 0.5),
        "{} {}",
        dem.dx,
        dem.dy
    );
}

#[test]
fn jacksboro_asc() {
    let dem = read(dem_path!("jacksboro_fault_dem_f32.asc"));
    check_stats(&dem, 403, 344, 236.0, 1076.0, 531.031);
    assert_eq!(dem.georef.epsg, Some(4326));
}

#[test]
fn volcano_asc_is_projected_10m() {
    let dem = read(dem_path!("maunga_whau_volcano.asc"));
    check_stats(&dem, 87, 61, 94.0, 195.0, 130.188);
    assert!(!dem.georef.geographic);
    assert_eq!(dem.georef.epsg, None);
    assert_eq!((dem.dx, dem.dy), (10.0, 10.0));
    assert_eq!(
        dem.georef.transform,
        Some([0.0, 10.0, 0.0, 610.0, 0.0, -10.0])
    );
    // Synthesised tags so the writer can georeference ASC outputs.
    assert_eq!(dem.georef.tags.pixel_scale, Some(vec![10.0, 10.0, 0.0]));
    assert_eq!(
        dem.georef.tags.tiepoint,
        Some(vec![0.0, 0.0, 0.0, 0.0, 610.0, 0.0])
    );
    assert!(dem.georef.tags.geo_key_directory.is_some());
}

fn asc_err(text: &str) -> InputError {
    decode_dem(text.as_bytes(), Some("x.asc"), &opts()).unwrap_err()
}

#[test]
fn asc_header_variants() {
    let text = "NCOLS 3\nNrows 3\nXLLCENTER 105\nyllcenter 5\nDX 2\nDY 4\nnodata_value -9999\n\
                1 2 3\n4 -9999 6\n7 8 9\n";
    let dem = decode_dem(text.as_bytes(), None, &opts()).unwrap();
    assert_eq!(dem.valid_cells(), 8);
    assert!(dem.at(1, 1).is_nan());
    assert_eq!(dem.at(2, 2), 9.0);
    assert_eq!(
        dem.georef.transform,
        Some([104.0, 2.0, 0.0, 15.0, 0.0, -4.0])
    );
    assert_eq!((dem.dx, dem.dy), (2.0, 4.0));
    assert!(!dem.georef.geographic);
    // cell_size overrides the header (metres).
    let o = DemOptions {
        cell_size: Some(30.0),
        ..opts()
    };
    let dem = decode_dem(text.as_bytes(), Some("a.asc"), &o).unwrap();
    assert_eq!((dem.dx, dem.dy), (30.0, 30.0));
}

#[test]
fn asc_refuses_bad_bodies() {
    let head = "ncols 3\nnrows 3\nxllcorner 0\nyllcorner 0\ncellsize 1\n";
    for body in [
        "1 2 3 4 5 6 7 8",
        "1 2 3 4 5 6 7 8 9 10",
        "1 2 3 4 x 6 7 8 9",
    ] {
        let e = asc_err(&format!("{head}{body}\n"));
        assert!(matches!(e, InputError::Corrupt { .. }), "{body}: {e:?}");
    }
    assert!(matches!(
        asc_err("ncols 3\nnrows 3\n1 2 3"),
        InputError::Corrupt { .. }
    ));
    // Absurd sizes: over the limit → TooLarge; under it but no data → Corrupt (no allocation).
    let e =
        asc_err("ncols 1000000000\nnrows 1000000000\nxllcorner 0\nyllcorner 0\ncellsize 1\n1\n");
    assert!(matches!(e, InputError::TooLarge { .. }), "{e:?}");
    let e = asc_err("ncols 8000\nnrows 8000\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2\n");
    assert!(matches!(e, InputError::Corrupt { .. }), "{e:?}");
    let e = asc_err("ncols -3\nnrows 3\nxllcorner 0\nyllcorner 0\ncellsize 1\n1\n");
    assert!(matches!(e, InputError::Corrupt { .. }), "{e:?}");
}

#[test]
fn tiny_and_empty_grids_are_unusable() {
    let e = asc_err("ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2 3 4\n");
    assert!(matches!(e, InputError::Unusable(_)), "{e:?}");
    let e = asc_err(
        "ncols 3\nnrows 3\nxllcorner 0\nyllcorner 0\ncellsize 1\nNODATA_value 5\n5 5 5 5 5 5 5 5 5\n",
    );
    assert!(matches!(e, InputError::Unusable(_)), "{e:?}");
}

// ---------- GeoTIFF variants written here ----------

/// GeoTIFF tags for a north-up EPSG:4326 grid at (lon, lat) with 1/1200° cells.
fn write_geo_tags<W: std::io::Write + std::io::Seek, K: tiff::encoder::TiffKind>(
    dir: &mut tiff::encoder::DirectoryEncoder<W, K>,
    nodata: Option<&str>,
) {
    use tiff::tags::Tag;
    let res = 1.0 / 1200.0;
    dir.write_tag(Tag::ModelPixelScaleTag, &[res, res, 0.0][..])
        .unwrap();
    dir.write_tag(Tag::ModelTiepointTag, &[0.0, 0.0, 0.0, 10.0, 47.0, 0.0][..])
        .unwrap();
    dir.write_tag(
        Tag::GeoKeyDirectoryTag,
        &[
            1u16, 1, 0, 3, 1024, 0, 1, 2, 1025, 0, 1, 1, 2048, 0, 1, 4326,
        ][..],
    )
    .unwrap();
    if let Some(n) = nodata {
        dir.write_tag(Tag::GdalNodata, n).unwrap();
    }
}

fn grid_values(w: usize, h: usize) -> Vec<f64> {
    (0..w * h)
        .map(|i| ((i % w) * 3 + (i / w) * 7) as f64 + 100.0)
        .collect()
}

macro_rules! typed_tiff {
    ($color:ty, $t:ty, $w:expr, $h:expr, $nodata:expr, $comp:expr) => {{
        let (w, h) = ($w, $h);
        let mut data: Vec<$t> = grid_values(w, h).iter().map(|&v| v as $t).collect();
        if let Some(nd) = $nodata {
            data[0] = nd;
        }
        let mut cur = std::io::Cursor::new(Vec::new());
        let mut enc = tiff::encoder::TiffEncoder::new(&mut cur).unwrap();
        let mut img = enc
            .new_image_with_compression::<$color, _>(w as u32, h as u32, $comp)
            .unwrap();
        let nd_text = $nodata.map(|n: $t| format!("{}", n));
        write_geo_tags(img.encoder(), nd_text.as_deref());
        img.write_data(&data).unwrap();
        cur.into_inner()
    }};
}

fn check_generated(bytes: &[u8], w: usize, h: usize, nodata_first: bool) {
    let dem = decode_dem(bytes, Some("gen.tif"), &opts()).unwrap();
    assert_eq!((dem.width, dem.height), (w, h));
    let expect = grid_values(w, h);
    for (i, (&got, &want)) in dem.heights.iter().zip(&expect).enumerate() {
        if i == 0 && nodata_first {
            assert!(got.is_nan());
        } else {
            assert_eq!(f64::from(got), want, "cell {i}");
        }
    }
    assert_eq!(dem.georef.epsg, Some(4326));
    assert!(dem.georef.geographic);
    assert_eq!(dem.georef.transform.unwrap()[0], 10.0);
    let (m_lat, m_lon) = metres_per_degree(47.0 - h as f64 / 2400.0);
    assert!(close(dem.dx, m_lon / 1200.0, 1e-6) && close(dem.dy, m_lat / 1200.0, 1e-6));
}

#[test]
fn geotiff_sample_types_and_compressions() {
    use tiff::encoder::colortype::{Gray16, Gray32Float, Gray64Float, GrayI16, GrayI32};
    use tiff::encoder::compression::{Deflate, Lzw, Packbits, Uncompressed};
    let (w, h) = (37, 23);
    check_generated(
        &typed_tiff!(GrayI16, i16, w, h, Some(-32768i16), Lzw),
        w,
        h,
        true,
    );
    check_generated(
        &typed_tiff!(Gray16, u16, w, h, Some(0u16), Deflate::default()),
        w,
        h,
        true,
    );
    check_generated(
        &typed_tiff!(GrayI32, i32, w, h, Some(-9999i32), Uncompressed),
        w,
        h,
        true,
    );
    check_generated(
        &typed_tiff!(GrayI32, i32, w, h, None::<i32>, Packbits),
        w,
        h,
        false,
    );
    check_generated(
        &typed_tiff!(Gray32Float, f32, w, h, Some(f32::NAN), Lzw),
        w,
        h,
        true,
    );
    check_generated(
        &typed_tiff!(Gray64Float, f64, w, h, Some(-3.4e38f64), Deflate::default()),
        w,
        h,
        true,
    );
}

/// A minimal little-endian TIFF writer for layouts the `tiff` encoder cannot produce (tiles,
/// absurd sizes). `entries` are (tag, type, count, little-endian value bytes); `chunks` are the
/// strips or tiles, whose offsets and byte counts are added (`offsets_tag` 273 strips, 324 tiles).
fn raw_tiff(
    mut entries: Vec<(u16, u16, u32, Vec<u8>)>,
    chunks: &[Vec<u8>],
    offsets_tag: u16,
) -> Vec<u8> {
    let mut out = b"II*\0\0\0\0\0".to_vec();
    let mut offsets = Vec::new();
    for c in chunks {
        offsets.extend((out.len() as u32).to_le_bytes());
        out.extend(c);
    }
    let counts: Vec<u8> = chunks
        .iter()
        .flat_map(|c| (c.len() as u32).to_le_bytes())
        .collect();
    entries.push((offsets_tag, 4, chunks.len() as u32, offsets));
    let counts_tag = if offsets_tag == 273 { 279 } else { 325 };
    entries.push((counts_tag, 4, chunks.len() as u32, counts));
    entries.sort_by_key(|e| e.0);
    let mut fixed = Vec::new();
    for (tag, ty, count, mut bytes) in entries {
        let value = if bytes.len() <= 4 {
            bytes.resize(4, 0);
            bytes
        } else {
            if out.len() % 2 == 1 {
                out.push(0);
            }
            let off = out.len() as u32;
            out.extend(&bytes);
            off.to_le_bytes().to_vec()
        };
        fixed.push((tag, ty, count, value));
    }
    if out.len() % 2 == 1 {
        out.push(0);
    }
    let ifd = out.len() as u32;
    out[4..8].copy_from_slice(&ifd.to_le_bytes());
    out.extend((fixed.len() as u16).to_le_bytes());
    for (tag, ty, count, value) in fixed {
        out.extend(tag.to_le_bytes());
        out.extend(ty.to_le_bytes());
        out.extend(count.to_le_bytes());
        out.extend(value);
    }
    out.extend(0u32.to_le_bytes());
    out
}

fn short(tag: u16, v: u16) -> (u16, u16, u32, Vec<u8>) {
    (tag, 3, 1, v.to_le_bytes().to_vec())
}
fn long(tag: u16, v: u32) -> (u16, u16, u32, Vec<u8>) {
    (tag, 4, 1, v.to_le_bytes().to_vec())
}
fn doubles(tag: u16, v: &[f64]) -> (u16, u16, u32, Vec<u8>) {
    (
        tag,
        12,
        v.len() as u32,
        v.iter().flat_map(|x| x.to_le_bytes()).collect(),
    )
}
fn shorts(tag: u16, v: &[u16]) -> (u16, u16, u32, Vec<u8>) {
    (
        tag,
        3,
        v.len() as u32,
        v.iter().flat_map(|x| x.to_le_bytes()).collect(),
    )
}

/// Tiled int16 GeoTIFF (16×16 tiles, partial edge tiles), uncompressed or deflate.
fn tiled_tiff(w: usize, h: usize, deflate: bool) -> Vec<u8> {
    let t = 16;
    let vals = grid_values(w, h);
    let mut tiles = Vec::new();
    for ty in 0..h.div_ceil(t) {
        for tx in 0..w.div_ceil(t) {
            let mut tile = Vec::new();
            for r in 0..t {
                for c in 0..t {
                    let (row, col) = (ty * t + r, tx * t + c);
                    let v = if row < h && col < w {
                        vals[row * w + col] as i16
                    } else {
                        0
                    };
                    tile.extend(v.to_le_bytes());
                }
            }
            if deflate {
                use std::io::Write;
                let mut z =
                    flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
                z.write_all(&tile).unwrap();
                tile = z.finish().unwrap();
            }
            tiles.push(tile);
        }
    }
    let entries = vec![
        long(256, w as u32),
        long(257, h as u32),
        short(258, 16),
        short(259, if deflate { 8 } else { 1 }),
        short(262, 1),
        short(277, 1),
        short(284, 1),
        short(322, t as u16),
        short(323, t as u16),
        short(339, 2),
        doubles(33550, &[1.0 / 1200.0, 1.0 / 1200.0, 0.0]),
        doubles(33922, &[0.0, 0.0, 0.0, 10.0, 47.0, 0.0]),
        shorts(
            34735,
            &[1, 1, 0, 3, 1024, 0, 1, 2, 1025, 0, 1, 1, 2048, 0, 1, 4326],
        ),
    ];
    raw_tiff(entries, &tiles, 324)
}

#[test]
fn geotiff_tiled_uncompressed_and_deflate() {
    check_generated(&tiled_tiff(37, 23, false), 37, 23, false);
    check_generated(&tiled_tiff(40, 33, true), 40, 33, false);
}

#[test]
fn geotiff_absurd_dimensions_refused_before_decoding() {
    let entries = vec![
        long(256, 4_000_000_000),
        long(257, 4_000_000_000),
        short(258, 16),
        short(259, 1),
        short(262, 1),
        short(277, 1),
        long(278, 4_000_000_000),
        short(339, 2),
    ];
    let bytes = raw_tiff(entries, &[vec![0u8; 8]], 273);
    let e = decode_dem(&bytes, None, &opts()).unwrap_err();
    assert!(matches!(e, InputError::TooLarge { .. }), "{e:?}");
}

#[test]
fn plain_tiff_needs_cell_size() {
    let mut cur = std::io::Cursor::new(Vec::new());
    tiff::encoder::TiffEncoder::new(&mut cur)
        .unwrap()
        .write_image::<tiff::encoder::colortype::Gray16>(4, 4, &[7u16; 16])
        .unwrap();
    let bytes = cur.into_inner();
    match decode_dem(&bytes, None, &opts()).unwrap_err() {
        InputError::Param(p) => assert_eq!(p.field, "cell_size"),
        e => panic!("{e:?}"),
    }
    let o = DemOptions {
        cell_size: Some(2.5),
        ..opts()
    };
    let dem = decode_dem(&bytes, None, &o).unwrap();
    assert_eq!((dem.dx, dem.dy, dem.georef.transform), (2.5, 2.5, None));
}

#[test]
fn geotiff_pixel_is_point_and_transformation() {
    let vals: Vec<u8> = (0..16i16).flat_map(|v| v.to_le_bytes()).collect();
    let base = || {
        vec![
            long(256, 4),
            long(257, 4),
            short(258, 16),
            short(259, 1),
            short(262, 1),
            short(277, 1),
            long(278, 4),
            short(339, 2),
        ]
    };
    // PixelIsPoint: the tiepoint names the first cell's centre.
    let mut e = base();
    e.push(doubles(33550, &[30.0, 30.0, 0.0]));
    e.push(doubles(33922, &[0.0, 0.0, 0.0, 1000.0, 2000.0, 0.0]));
    e.push(shorts(
        34735,
        &[1, 1, 0, 3, 1024, 0, 1, 1, 1025, 0, 1, 2, 3072, 0, 1, 32633],
    ));
    let dem = decode_dem(
        &raw_tiff(e, std::slice::from_ref(&vals), 273),
        None,
        &opts(),
    )
    .unwrap();
    assert_eq!(
        dem.georef.transform,
        Some([985.0, 30.0, 0.0, 2015.0, 0.0, -30.0])
    );
    assert_eq!(dem.georef.epsg, Some(32633));
    // ModelTransformation with US survey feet.
    let mut e = base();
    let m = [
        3.0, 0.0, 0.0, 500.0, 0.0, -3.0, 0.0, 800.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0,
    ];
    e.push(doubles(34264, &m));
    e.push(shorts(
        34735,
        &[1, 1, 0, 2, 1024, 0, 1, 1, 3076, 0, 1, 9003],
    ));
    let dem = decode_dem(&raw_tiff(e, &[vals], 273), None, &opts()).unwrap();
    assert_eq!(
        dem.georef.transform,
        Some([500.0, 3.0, 0.0, 800.0, 0.0, -3.0])
    );
    assert!(close(dem.dx, 3.0 * 1200.0 / 3937.0, 1e-12));
}

// ---------- HGT ----------

fn hgt_bytes(side: usize) -> Vec<u8> {
    (0..side * side)
        .flat_map(|i| {
            let v: i16 = if i % 1000 == 7 {
                -32768
            } else {
                ((i % side) + (i / side)) as i16 - 50
            };
            v.to_be_bytes()
        })
        .collect()
}

#[test]
fn hgt_3_arcsecond_tile() {
    let bytes = hgt_bytes(1201);
    assert_eq!(sniff(&bytes, Some("N35E139.hgt")), Some(DemFormat::Hgt));
    assert_eq!(sniff(&bytes, None), Some(DemFormat::Hgt));
    let dem = decode_dem(&bytes, Some("N35E139.hgt"), &opts()).unwrap();
    assert_eq!((dem.width, dem.height), (1201, 1201));
    let voids = (0..1201 * 1201).filter(|i| i % 1000 == 7).count();
    assert_eq!(dem.width * dem.height - dem.valid_cells(), voids);
    assert_eq!(dem.at(3, 2), 3.0 + 2.0 - 50.0);
    assert_eq!(dem.georef.epsg, Some(4326));
    let t = dem.georef.transform.unwrap();
    let res = 1.0 / 1200.0;
    // Cell centres on whole degrees: corners half a cell outside.
    assert!(close(t[0], 139.0 - res / 2.0, 1e-12) && close(t[3], 36.0 + res / 2.0, 1e-12));
    assert!(close(t[1], res, 1e-15) && close(t[5], -res, 1e-15));
    let (m_lat, m_lon) = metres_per_degree(35.5);
    assert!(close(dem.dx, m_lon * res, 1e-6) && close(dem.dy, m_lat * res, 1e-6));
    let south = decode_dem(&bytes, Some("s12w077.hgt"), &opts()).unwrap();
    assert_eq!(south.georef.transform.unwrap()[3], -11.0 + res / 2.0);
}

#[test]
fn hgt_1_arcsecond_and_bad_sizes() {
    let dem = decode_dem(&hgt_bytes(3601), Some("N00E000.hgt"), &opts()).unwrap();
    assert_eq!((dem.width, dem.height), (3601, 3601));
    assert!(close(dem.georef.transform.unwrap()[1], 1.0 / 3600.0, 1e-15));
    let e = decode_dem(&[0u8; 1000], Some("N35E139.hgt"), &opts()).unwrap_err();
    assert!(matches!(e, InputError::Corrupt { .. }), "{e:?}");
    let small = DemOptions {
        max_cells: 1_000_000,
        ..opts()
    };
    let e = decode_dem(&hgt_bytes(1201), Some("N35E139.hgt"), &small).unwrap_err();
    assert!(matches!(e, InputError::TooLarge { .. }), "{e:?}");
    // A name that is not a tile name: no georeferencing, so cell_size is needed.
    match decode_dem(&hgt_bytes(1201), Some("tile.hgt"), &opts()).unwrap_err() {
        InputError::Param(p) => assert_eq!(p.field, "cell_size"),
        e => panic!("{e:?}"),
    }
}

// ---------- PNG ----------

fn png_bytes(w: u32, h: u32, color: png::ColorType, depth: png::BitDepth, data: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, w, h);
    enc.set_color(color);
    enc.set_depth(depth);
    enc.write_header().unwrap().write_image_data(data).unwrap();
    out
}

#[test]
fn png16_heights_and_scale() {
    let (w, h) = (5u32, 4u32);
    let data: Vec<u8> = (0..w * h)
        .flat_map(|i| (i as u16 * 1000).to_be_bytes())
        .collect();
    let bytes = png_bytes(
        w,
        h,
        png::ColorType::Grayscale,
        png::BitDepth::Sixteen,
        &data,
    );
    assert_eq!(sniff(&bytes, Some("x.png")), Some(DemFormat::Png16));
    match decode_dem(&bytes, None, &opts()).unwrap_err() {
        InputError::Param(p) => assert_eq!(p.field, "cell_size"),
        e => panic!("{e:?}"),
    }
    let o = DemOptions {
        cell_size: Some(5.0),
        vertical_scale: Some(0.1),
        ..opts()
    };
    let dem = decode_dem(&bytes, None, &o).unwrap();
    assert_eq!((dem.width, dem.height, dem.dx, dem.dy), (5, 4, 5.0, 5.0));
    assert_eq!(dem.at(2, 3), 1700.0);
    assert_eq!(dem.georef.transform, None);
    // 8-bit greyscale is accepted; colour is not.
    let o = DemOptions {
        cell_size: Some(1.0),
        ..opts()
    };
    let g8 = png_bytes(
        3,
        3,
        png::ColorType::Grayscale,
        png::BitDepth::Eight,
        &[9; 9],
    );
    assert_eq!(decode_dem(&g8, None, &o).unwrap().at(1, 1), 9.0);
    let rgb = png_bytes(3, 3, png::ColorType::Rgb, png::BitDepth::Eight, &[9; 27]);
    let e = decode_dem(&rgb, None, &o).unwrap_err();
    assert!(matches!(e, InputError::UnsupportedFormat(_)), "{e:?}");
}

fn crc32(bytes: &[u8]) -> u32 {
    let mut c = 0xffff_ffffu32;
    for &b in bytes {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xedb8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

#[test]
fn png_absurd_header_is_too_large() {
    let mut ihdr = b"IHDR".to_vec();
    ihdr.extend(2_000_000_000u32.to_be_bytes());
    ihdr.extend(2_000_000_000u32.to_be_bytes());
    ihdr.extend([16, 0, 0, 0, 0]);
    let mut bytes = b"\x89PNG\r\n\x1a\n".to_vec();
    bytes.extend(13u32.to_be_bytes());
    bytes.extend(&ihdr);
    bytes.extend(crc32(&ihdr).to_be_bytes());
    let o = DemOptions {
        cell_size: Some(1.0),
        ..opts()
    };
    let e = decode_dem(&bytes, None, &o).unwrap_err();
    assert!(matches!(e, InputError::TooLarge { .. }), "{e:?}");
}

// ---------- NPY ----------

fn npy_bytes<T: npyz::AutoSerialize + Copy>(shape: &[u64], data: &[T]) -> Vec<u8> {
    use npyz::WriterBuilder;
    let mut out = Vec::new();
    let mut w = npyz::WriteOptions::new()
        .default_dtype()
        .shape(shape)
        .writer(&mut out)
        .begin_nd()
        .unwrap();
    w.extend(data.iter().copied()).unwrap();
    w.finish().unwrap();
    out
}

#[test]
fn npy_dtypes() {
    let vals = grid_values(6, 4);
    let o = opts();
    let check = |bytes: Vec<u8>| {
        assert_eq!(sniff(&bytes, None), Some(DemFormat::Npy));
        let dem = decode_dem(&bytes, Some("a.npy"), &o).unwrap();
        assert_eq!((dem.width, dem.height, dem.dx), (6, 4, 1.0));
        for (g, w) in dem.heights.iter().zip(&vals) {
            assert_eq!(f64::from(*g), *w);
        }
    };
    let s = [4u64, 6];
    check(npy_bytes(
        &s,
        &vals.iter().map(|&v| v as f32).collect::<Vec<_>>(),
    ));
    check(npy_bytes(&s, &vals));
    check(npy_bytes(
        &s,
        &vals.iter().map(|&v| v as i16).collect::<Vec<_>>(),
    ));
    check(npy_bytes(
        &s,
        &vals.iter().map(|&v| v as u16).collect::<Vec<_>>(),
    ));
    check(npy_bytes(
        &s,
        &vals.iter().map(|&v| v as i32).collect::<Vec<_>>(),
    ));
    check(npy_bytes(
        &s,
        &vals.iter().map(|&v| v as u8).collect::<Vec<_>>(),
    ));
}

#[test]
fn npy_nan_scale_and_errors() {
    let mut v = vec![1.0f32; 16];
    v[5] = f32::NAN;
    let o = DemOptions {
        cell_size: Some(2.0),
        vertical_scale: Some(3.0),
        ..opts()
    };
    let dem = decode_dem(&npy_bytes(&[4, 4], &v), None, &o).unwrap();
    assert_eq!((dem.valid_cells(), dem.at(0, 0), dem.dx), (15, 3.0, 2.0));
    assert!(dem.at(1, 1).is_nan());
    let e = decode_dem(&npy_bytes(&[2, 2, 4], &v), None, &opts()).unwrap_err();
    assert!(matches!(e, InputError::Unusable(_)), "{e:?}");
    let full = npy_bytes(&[4, 4], &v);
    let e = decode_dem(&full[..full.len() - 3], None, &opts()).unwrap_err();
    assert!(matches!(e, InputError::Corrupt { .. }), "{e:?}");
    // Absurd shapes: over the limit, and overflowing u64.
    for shape in [
        "(100000000, 100000000)",
        "(4294967296, 4294967296, 4294967296)",
    ] {
        let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}");
        while (header.len() + 11) % 64 != 0 {
            header.push(' ');
        }
        header.push('\n');
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        bytes.extend((header.len() as u16).to_le_bytes());
        bytes.extend(header.as_bytes());
        bytes.extend([0u8; 64]);
        let e = decode_dem(&bytes, None, &opts()).unwrap_err();
        assert!(matches!(e, InputError::TooLarge { .. }), "{shape}: {e:?}");
    }
}

// ---------- writer round trip ----------

fn same_heights(a: &[f32], b: &[f32]) -> bool {
    a.len() == b.len()
        && a.iter()
            .zip(b)
            .all(|(x, y)| x == y || (x.is_nan() && y.is_nan()))
}

fn round_trip(dem: &Dem) -> Dem {
    let bytes = write_float32_geotiff(dem.width, dem.height, &dem.heights, &dem.georef);
    decode_dem(&bytes, Some("out.tif"), &opts()).unwrap()
}

#[test]
fn writer_round_trips_real_dems() {
    for path in [
        dem_path!("tanzawa_sagami_aster_gdem2.tif"),
        dem_path!("luxembourg_elev.tif"),
        dem_path!("olinda_dem_utm25s.tif"),
        dem_path!("colorado_front_range_srtmgl3_f32.tif"),
        dem_path!("jacksboro_fault_dem_f32.tif"),
        dem_path!("maunga_whau_volcano.asc"),
        dem_path!("colorado_front_range_srtmgl3.asc"),
    ] {
        let dem = read(path);
        let back = round_trip(&dem);
        assert_eq!((back.width, back.height), (dem.width, dem.height), "{path}");
        assert!(same_heights(&back.heights, &dem.heights), "{path}");
        assert_eq!(back.georef.transform, dem.georef.transform, "{path}");
        assert_eq!(back.georef.epsg, dem.georef.epsg, "{path}");
        assert_eq!(back.georef.geographic, dem.georef.geographic, "{path}");
        assert_eq!(back.georef.tags, dem.georef.tags, "{path}");
        match (back.georef.nodata, dem.georef.nodata) {
            (Some(a), Some(b)) => assert!(a == b || (a.is_nan() && b.is_nan()), "{path}"),
            (a, b) => assert_eq!(a, b, "{path}"),
        }
        assert_eq!((back.dx, back.dy), (dem.dx, dem.dy), "{path}");
    }
}

#[test]
fn writer_nodata_rules() {
    let dem = read(dem_path!("luxembourg_elev.tif"));
    let bytes = write_float32_geotiff(dem.width, dem.height, &dem.heights, &dem.georef);
    // NaN cells are stored as the input's nodata value, tagged "-32768".
    let mut d = tiff::decoder::Decoder::new(std::io::Cursor::new(&bytes)).unwrap();
    assert_eq!(
        d.get_tag_ascii_string(tiff::tags::Tag::GdalNodata).unwrap(),
        "-32768"
    );
    let tiff::decoder::DecodingResult::F32(raw) = d.read_image().unwrap() else {
        panic!()
    };
    assert_eq!(raw.iter().filter(|&&v| v == -32768.0).count(), 3942);
    // No input nodata but NaN cells: NaN, tagged "nan".
    let mut dem = read(dem_path!("jacksboro_fault_dem_f32.tif"));
    dem.heights[10] = f32::NAN;
    let bytes = write_float32_geotiff(dem.width, dem.height, &dem.heights, &dem.georef);
    let mut d = tiff::decoder::Decoder::new(std::io::Cursor::new(&bytes)).unwrap();
    assert_eq!(
        d.get_tag_ascii_string(tiff::tags::Tag::GdalNodata).unwrap(),
        "nan"
    );
    let back = decode_dem(&bytes, None, &opts()).unwrap();
    assert_eq!(back.valid_cells(), dem.width * dem.height - 1);
    // No nodata and no NaN: no tag.
    let clean = read(dem_path!("jacksboro_fault_dem_f32.tif"));
    let bytes = write_float32_geotiff(clean.width, clean.height, &clean.heights, &clean.georef);
    let mut d = tiff::decoder::Decoder::new(std::io::Cursor::new(&bytes)).unwrap();
    assert!(d.find_tag(tiff::tags::Tag::GdalNodata).unwrap().is_none());
}

#[test]
fn writer_synthesises_tags_for_hand_built_georef() {
    let georef = phenomena_engine::geom::heightfield::GeoRef {
        transform: Some([500000.0, 20.0, 0.0, 4000000.0, 0.0, -20.0]),
        epsg: Some(32633),
        ..Default::default()
    };
    let vals: Vec<f32> = (0..20).map(|i| i as f32).collect();
    let back = decode_dem(&write_float32_geotiff(5, 4, &vals, &georef), None, &opts()).unwrap();
    assert_eq!(back.georef.transform, georef.transform);
    assert_eq!(back.georef.epsg, Some(32633));
    assert_eq!((back.dx, back.dy), (20.0, 20.0));
    assert_eq!(back.heights, vals);
}

// ---------- robustness ----------

/// Decoding must return (Ok or a clean error), never panic — including inside the third-party
/// decoders, whose panics `decode_dem` turns into an error with this detail.
fn no_panic(bytes: &[u8], name: Option<&str>, o: &DemOptions) -> Result<Dem, InputError> {
    let r = decode_dem(bytes, name, o);
    if let Err(InputError::Corrupt { detail, .. }) = &r {
        assert!(!detail.contains("panicked"), "decoder panicked on {name:?}");
    }
    r
}

fn fuzz_inputs() -> Vec<(Vec<u8>, &'static str)> {
    let mut v = Vec::new();
    for path in [
        dem_path!("luxembourg_elev.tif"),
        dem_path!("olinda_dem_utm25s.tif"),
        dem_path!("maunga_whau_volcano.asc"),
    ] {
        v.push((
            std::fs::read(path).unwrap(),
            path.rsplit('/').next().unwrap(),
        ));
    }
    let vals: Vec<f32> = (0..400).map(|i| i as f32).collect();
    v.push((npy_bytes(&[20, 20], &vals), "a.npy"));
    let data: Vec<u8> = (0..400u16).flat_map(|i| i.to_be_bytes()).collect();
    v.push((
        png_bytes(
            20,
            20,
            png::ColorType::Grayscale,
            png::BitDepth::Sixteen,
            &data,
        ),
        "a.png",
    ));
    v.push((tiled_tiff(37, 23, true), "tiled.tif"));
    let lux = read(dem_path!("luxembourg_elev.tif"));
    v.push((
        write_float32_geotiff(lux.width, lux.height, &lux.heights, &lux.georef),
        "w.tif",
    ));
    v
}

#[test]
fn truncated_files_are_errors() {
    let o = DemOptions {
        cell_size: Some(1.0),
        ..opts()
    };
    for (bytes, name) in fuzz_inputs() {
        for k in [0, 1, 2, 3, 5, 8, 16, 64] {
            let n = bytes.len() * k / 100;
            assert!(
                no_panic(&bytes[..n], Some(name), &o).is_err(),
                "{name} cut at {n}"
            );
            assert!(no_panic(&bytes[..k.min(bytes.len())], None, &o).is_err());
        }
        for k in 1..10 {
            let n = bytes.len() * k / 10;
            assert!(
                no_panic(&bytes[..n], Some(name), &o).is_err(),
                "{name} cut at {n}"
            );
        }
    }
    let hgt = hgt_bytes(1201);
    for n in [0, 2, 1000, hgt.len() / 2, hgt.len() - 2] {
        assert!(no_panic(&hgt[..n], Some("N35E139.hgt"), &o).is_err());
    }
}

#[test]
fn flipped_bytes_never_panic() {
    let o = DemOptions {
        cell_size: Some(1.0),
        max_cells: 1 << 22,
        ..opts()
    };
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    };
    for (bytes, name) in fuzz_inputs() {
        for _ in 0..300 {
            let mut b = bytes.clone();
            // Mostly hit headers and directories, where a flip changes sizes and offsets.
            let span = if next() % 2 == 0 {
                b.len().min(512)
            } else {
                b.len()
            };
            for _ in 0..1 + next() % 4 {
                let i = (next() as usize) % span;
                b[i] ^= 1 << (next() % 8);
            }
            let _ = no_panic(&b, Some(name), &o);
        }
    }
}

#[test]
fn sniffing() {
    assert_eq!(sniff(b"II*\0rest", None), Some(DemFormat::GeoTiff));
    assert_eq!(sniff(b"MM\0*rest", Some("a.asc")), Some(DemFormat::GeoTiff));
    assert_eq!(sniff(b"  NCOLS 3\n", None), Some(DemFormat::EsriAscii));
    assert_eq!(
        sniff(b"whatever", Some("dem.ASC")),
        Some(DemFormat::EsriAscii)
    );
    assert_eq!(
        sniff(b"whatever", Some("N35E139.HGT")),
        Some(DemFormat::Hgt)
    );
    assert_eq!(sniff(b"\x93NUMPY\x01\x00", None), Some(DemFormat::Npy));
    assert_eq!(sniff(b"hello", Some("a.txt")), None);
    let e = decode_dem(b"hello", Some("a.txt"), &opts()).unwrap_err();
    assert!(matches!(e, InputError::UnsupportedFormat(_)));
}

#[test]
fn wgs84_metres_per_degree() {
    // Standard values: 110 574 m per degree of latitude and 111 320 m of longitude at the
    // equator; 111 694 m of latitude near the pole.
    let (lat0, lon0) = metres_per_degree(0.0);
    assert!(
        close(lat0, 110_574.3, 0.5) && close(lon0, 111_319.5, 0.5),
        "{lat0} {lon0}"
    );
    let (lat89, _) = metres_per_degree(89.9);
    assert!(close(lat89, 111_693.9, 1.0), "{lat89}");
}

#[test]
fn geotiff_horizontal_predictor() {
    // int16 strips with the horizontal-differencing predictor (TIFF Predictor = 2), as GDAL
    // writes with PREDICTOR=2.
    let (w, h) = (9usize, 5usize);
    let vals = grid_values(w, h);
    let mut strip = Vec::new();
    for r in 0..h {
        let mut prev = 0i16;
        for c in 0..w {
            let v = vals[r * w + c] as i16;
            strip.extend(v.wrapping_sub(prev).to_le_bytes());
            prev = v;
        }
    }
    let entries = vec![
        long(256, w as u32),
        long(257, h as u32),
        short(258, 16),
        short(259, 1),
        short(262, 1),
        short(277, 1),
        long(278, h as u32),
        short(317, 2),
        short(339, 2),
        doubles(33550, &[1.0 / 1200.0, 1.0 / 1200.0, 0.0]),
        doubles(33922, &[0.0, 0.0, 0.0, 10.0, 47.0, 0.0]),
        shorts(
            34735,
            &[1, 1, 0, 3, 1024, 0, 1, 2, 1025, 0, 1, 1, 2048, 0, 1, 4326],
        ),
    ];
    check_generated(&raw_tiff(entries, &[strip], 273), w, h, false);
}

#[test]
fn max_cells_applies_to_every_real_format() {
    let small = DemOptions {
        max_cells: 10_000,
        ..opts()
    };
    for path in [
        dem_path!("tanzawa_sagami_aster_gdem2.tif"),
        dem_path!("olinda_dem_utm25s.tif"),
        dem_path!("colorado_front_range_srtmgl3.asc"),
    ] {
        let bytes = std::fs::read(path).unwrap();
        let e = decode_dem(&bytes, path.rsplit('/').next(), &small).unwrap_err();
        assert!(matches!(e, InputError::TooLarge { .. }), "{path}: {e:?}");
    }
}

/// Fuzz finding (`fuzz/run.sh`, target `dem_npy`): a header with 21 nested `{` made npyz's
/// header parser backtrack for over 10 s. Such headers are refused up front, for DEMs and
/// volumes alike (both read the shape through `npy_header`); the error naming the nesting shows
/// npyz never ran.
#[test]
fn npy_headers_with_deep_nesting_are_refused_at_once() {
    let header = format!(
        "{{'descr': '<f4', 'fortran_order': False, 'shape': (8, 8), {}{}",
        "{".repeat(21),
        "}"
    );
    let mut h = header.into_bytes();
    while (10 + h.len() + 1) % 64 != 0 {
        h.push(b' ');
    }
    h.push(b'\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend_from_slice(&(h.len() as u16).to_le_bytes());
    bytes.extend_from_slice(&h);
    bytes.extend_from_slice(&[0u8; 256]);
    let e = decode_dem(&bytes, Some("x.npy"), &opts()).unwrap_err();
    assert!(matches!(e, InputError::Corrupt { .. }), "{e:?}");
    assert!(e.to_string().contains("nests brackets"), "{e}");
    let v = phenomena_engine::formats::volume::decode_volume(
        &bytes,
        Some("x.npy"),
        &Default::default(),
    )
    .unwrap_err();
    assert!(v.to_string().contains("nests brackets"), "{v}");
}
