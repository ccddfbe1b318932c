//! Issue 22's map tiles: seam-free by construction. A 3×3 block of tiles, each computed on its
//! own window of the DEM grown by the descriptor's reach, equals the same pixels resampled from
//! the whole-DEM result within 1/255 per channel, at two zooms, on a projected DEM (Olinda, UTM
//! 25S) and a geographic one (Jacksboro, EPSG:4326); and the whole-DEM result the tiles are held
//! to is the pipeline's own descriptor. Cast shadows longer than a tile and its halo continue
//! across tile edges (a sun-visibility field over the whole map).

use std::path::PathBuf;

use phenomena_engine::formats::dem::{decode_dem, DemOptions};
use phenomena_engine::geom::heightfield::GeoRef;
use phenomena_engine::geom::mercator::{ground_resolution, lonlat_to_mercator, mercator_to_pixel};
use phenomena_engine::geom::Dem;
use phenomena_engine::params::Limits;
use phenomena_engine::render::RgbaImage;
use phenomena_engine::snow_terrain::descriptor::compute;
use phenomena_engine::snow_terrain::tiles::{
    decode_terrain_rgb, decode_terrarium, render_region, render_tile, sun_visibility, Layer,
    MapSource, Region, Window,
};
use phenomena_engine::snow_terrain::SnowTerrainParams;
use phenomena_engine::NoControl;
use serde_json::json;

fn load(name: &str) -> Dem {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/dem")
        .join(name);
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    decode_dem(&bytes, Some(name), &DemOptions::default()).expect("decodes")
}

fn source(name: &str, params: serde_json::Value) -> MapSource {
    let p = SnowTerrainParams::from_json(&params, &Limits::default()).unwrap();
    MapSource::new(load(name), &p).unwrap()
}

/// The tile (x, y) at zoom z holding the centre of the map.
fn centre_tile(src: &MapSource, z: u8) -> (u64, u64) {
    let c = src.info().center;
    let (mx, my) = lonlat_to_mercator(c[0], c[1]);
    let (px, py) = mercator_to_pixel(z, 256, mx, my);
    ((px / 256.0) as u64, (py / 256.0) as u64)
}

/// Largest per-channel difference of tile (i, j) of the block against the block's pixels.
fn max_diff(block: &RgbaImage, tile: &RgbaImage, i: u32, j: u32) -> u8 {
    let mut worst = 0u8;
    for y in 0..tile.height {
        for x in 0..tile.width {
            let a = tile.pixel(x, y);
            let b = block.pixel(i * tile.width + x, j * tile.height + y);
            for k in 0..4 {
                worst = worst.max(a[k].abs_diff(b[k]));
            }
        }
    }
    worst
}

fn opaque(img: &RgbaImage) -> usize {
    img.data.chunks(4).filter(|p| p[3] > 0).count()
}

fn check_seams(name: &str, params: serde_json::Value, layers: &[Layer]) {
    let src = source(name, params);
    let info = src.info().clone();
    assert!(info.maxzoom >= info.minzoom, "{info:?}");
    // The first zoom from the DEM's own at which a 3×3 block fits in the DEM, and the next.
    let extent = (info.width as f64 * info.cell_m[0]).min(info.height as f64 * info.cell_m[1]);
    let mut z0 = info.maxzoom;
    while 3.0 * 256.0 * ground_resolution(z0, info.center[1]) > extent {
        z0 += 1;
    }
    for z in [z0, z0 + 1] {
        let (cx, cy) = centre_tile(&src, z);
        let block = Region::tiles(z, cx - 1, cy - 1, 3, 3, 256).unwrap();
        for &layer in layers {
            let whole = render_region(&src, layer, &block, Window::Whole)
                .unwrap()
                .expect("on the DEM");
            // The block is inside the DEM for the most part: the test compares real pixels
            // (snow is transparent where there is none: on the sea and the lowlands).
            let min = if layer == Layer::Snow {
                9 * 256
            } else {
                9 * 256 * 256 / 4
            };
            assert!(
                opaque(&whole) > min,
                "{name} z{z} {}: {} opaque pixels",
                layer.name(),
                opaque(&whole)
            );
            let mut seen = std::collections::HashSet::new();
            for j in 0..3u32 {
                for i in 0..3u32 {
                    let tile = render_tile(
                        &src,
                        layer,
                        z,
                        cx - 1 + u64::from(i),
                        cy - 1 + u64::from(j),
                        256,
                    )
                    .unwrap()
                    // A tile off the DEM (204) is transparent in the whole-DEM result too.
                    .unwrap_or_else(|| RgbaImage::new_filled(256, 256, [0; 4]));
                    let d = max_diff(&whole, &tile, i, j);
                    assert!(
                        d <= 1,
                        "{name} z{z} {} tile ({i}, {j}): {d}/255 off the whole-DEM result",
                        layer.name()
                    );
                    seen.extend(tile.data.chunks(4).map(|p| [p[0], p[1], p[2], p[3]]));
                }
            }
            // Not a constant picture: the comparison can fail.
            assert!(
                seen.len() > 20,
                "{name} z{z} {}: {} colours",
                layer.name(),
                seen.len()
            );
        }
    }
}

#[test]
fn tiles_equal_the_whole_dem_result_on_a_projected_dem() {
    check_seams(
        "olinda_dem_utm25s.tif",
        json!({}),
        &[
            Layer::Snow,
            Layer::Relief,
            Layer::Hillshade,
            Layer::TerrainRgb,
        ],
    );
}

#[test]
fn tiles_equal_the_whole_dem_result_on_a_geographic_dem() {
    check_seams(
        "jacksboro_fault_dem_f32.tif",
        json!({}),
        &[
            Layer::Snow,
            Layer::Relief,
            Layer::Hillshade,
            Layer::Terrarium,
        ],
    );
}

/// The paper preset's cell-based smoothing (radius 3, 5 + 1 passes) gives the widest reach.
#[test]
fn tiles_equal_the_whole_dem_result_with_the_widest_reach() {
    let src = source("jacksboro_fault_dem_f32.tif", json!({"preset": "paper"}));
    assert!(src.halo() >= 20, "halo {}", src.halo());
    check_seams(
        "jacksboro_fault_dem_f32.tif",
        json!({"preset": "paper", "tsa_window": 2}),
        &[Layer::Snow, Layer::Relief],
    );
}

/// The whole-DEM result of the tiles is the pipeline's descriptor (parameters resolved once per
/// map change nothing).
#[test]
fn resolved_parameters_give_the_pipelines_descriptor() {
    for name in ["olinda_dem_utm25s.tif", "jacksboro_fault_dem_f32.tif"] {
        let p = SnowTerrainParams::from_json(&json!({}), &Limits::default()).unwrap();
        let dem = load(name);
        let src = MapSource::new(dem.clone(), &p).unwrap();
        let a = compute(&dem, &p.descriptor, &NoControl, (0.0, 1.0))
            .unwrap()
            .t;
        let b = compute(&dem, src.descriptor_params(), &NoControl, (0.0, 1.0))
            .unwrap()
            .t;
        let worst = a
            .iter()
            .zip(&b)
            .filter(|(x, _)| !x.is_nan())
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-4, "{name}: {worst}");
    }
}

/// `terrain-rgb` and `terrarium` decode to the same elevations within their quantisation
/// (0.1 m and 1/256 m), and to elevations the DEM holds.
#[test]
fn elevation_encodings_decode_back() {
    let src = source("jacksboro_fault_dem_f32.tif", json!({}));
    let (lo, hi) = (236.0 - 1.0, 1076.0 + 1.0);
    let z = src.info().maxzoom;
    let (cx, cy) = centre_tile(&src, z);
    let rgb = render_tile(&src, Layer::TerrainRgb, z, cx, cy, 256)
        .unwrap()
        .unwrap();
    let ter = render_tile(&src, Layer::Terrarium, z, cx, cy, 256)
        .unwrap()
        .unwrap();
    let mut n = 0;
    for (a, b) in rgb.data.chunks(4).zip(ter.data.chunks(4)) {
        assert_eq!(a[3], b[3]);
        if a[3] == 0 {
            continue;
        }
        let ha = decode_terrain_rgb([a[0], a[1], a[2]]);
        let hb = decode_terrarium([b[0], b[1], b[2]]);
        assert!((ha - hb).abs() <= 0.05 + 0.5 / 256.0 + 1e-3, "{ha} {hb}");
        assert!((lo..=hi).contains(&ha), "{ha}");
        n += 1;
    }
    assert!(n > 256 * 256 / 2, "{n} opaque pixels");
}

/// Tiles away from the DEM are not drawn; tiles half on it are transparent off it.
#[test]
fn tiles_off_the_dem_are_empty() {
    let src = source("olinda_dem_utm25s.tif", json!({}));
    let z = src.info().maxzoom + 2;
    let (cx, cy) = centre_tile(&src, z);
    assert!(render_tile(&src, Layer::Snow, z, cx + 40, cy, 256)
        .unwrap()
        .is_none());
    // At the smallest zoom the DEM spans at most one tile's width: part of a tile is drawn.
    let z = src.info().minzoom;
    let (cx, cy) = centre_tile(&src, z);
    let tile = render_tile(&src, Layer::Hillshade, z, cx, cy, 256)
        .unwrap()
        .unwrap();
    let n = opaque(&tile);
    assert!(n > 100 && n < 256 * 256, "{n} opaque pixels at z{z}");
}

// ---------- cast shadows across tiles ----------

/// Geographic grid: 0.0003° cells from (10° E, 47° N), a plane rising 0.5 m per column to the
/// east, with `block` (rows, columns) raised by 600 m.
fn ridge_dem(n: usize, rows: std::ops::Range<usize>, cols: std::ops::Range<usize>) -> Dem {
    let step = 0.0003;
    let mut heights = Vec::with_capacity(n * n);
    for r in 0..n {
        for c in 0..n {
            let wall = if rows.contains(&r) && cols.contains(&c) {
                600.0
            } else {
                0.0
            };
            heights.push(1000.0 + 0.5 * c as f32 + wall);
        }
    }
    let lat = 47.0 - step * n as f64 / 2.0;
    Dem {
        width: n,
        height: n,
        heights,
        dx: step * 111_320.0 * lat.to_radians().cos(),
        dy: step * 111_320.0,
        georef: GeoRef {
            transform: Some([10.0, step, 0.0, 47.0, 0.0, -step]),
            epsg: Some(4326),
            geographic: true,
            ..Default::default()
        },
    }
}

/// The field itself: a 600 m wall with the sun at 15° casts a shadow 600 / tan 15° ≈ 2,239 m
/// long away from the sun, on the flat and nowhere else; an oblique sun casts it along its
/// azimuth.
#[test]
fn sun_visibility_casts_shadows_of_the_right_length() {
    let dem = ridge_dem(240, 180..190, 40..200);
    let len_cells = 600.0 / 15f64.to_radians().tan() / dem.dy; // ≈ 67 rows
    let v = sun_visibility(&dem, 180.0, 15.0);
    let at = |r: usize, c: usize| v[r * 240 + c];
    // Sun in the south: the shadow lies north of the wall (rows above 180).
    let tip = 180.0 - len_cells;
    assert_eq!(at((tip + 4.0) as usize, 120), 0.0);
    assert_eq!(at(150, 120), 0.0);
    assert_eq!(at((tip - 4.0) as usize, 120), 1.0);
    assert_eq!(at(150, 20), 1.0, "beside the wall");
    assert_eq!(at(200, 120), 1.0, "on the sun's side");
    assert_eq!(at(185, 120), 1.0, "on the wall");
    // Sun in the south-east (135°): a pillar's shadow runs north-west, d metres long.
    let dem = ridge_dem(240, 150..156, 150..156);
    let v = sun_visibility(&dem, 135.0, 15.0);
    // 1,500 m from the pillar toward the north-west is shadow, the same distance north-east is
    // lit (the pillar's top is 600 m up; its shadow reaches ≈ 2,239 m).
    let (dc, dr) = (
        (1500.0 / 2f64.sqrt() / dem.dx).round() as usize,
        (1500.0 / 2f64.sqrt() / dem.dy).round() as usize,
    );
    assert_eq!(v[(152 - dr) * 240 + (152 - dc)], 0.0, "north-west");
    assert_eq!(v[(152 - dr) * 240 + (152 + dc)], 1.0, "north-east");
}

/// A shadow much longer than a tile and its halo: the tiles over its far end (which do not
/// contain the wall, nor does their window) are dark, equal the whole-DEM result within 1/255
/// across every seam of a 3×3 block straddling the shadow's tip, and are darker than the same
/// tiles without cast shadows.
#[test]
fn cast_shadows_continue_across_tile_edges() {
    let params = json!({"sun_azimuth_deg": 180, "sun_elevation_deg": 15});
    let p = SnowTerrainParams::from_json(&params, &Limits::default()).unwrap();
    let dem = ridge_dem(240, 180..190, 40..200);
    let src = MapSource::new(dem.clone(), &p).unwrap();
    let p_off = SnowTerrainParams::from_json(
        &json!({"sun_azimuth_deg": 180, "sun_elevation_deg": 15, "shadows": false}),
        &Limits::default(),
    )
    .unwrap();
    let flat = MapSource::new(dem.clone(), &p_off).unwrap();
    let tip = 180.0 - 600.0 / 15f64.to_radians().tan() / dem.dy;
    // The tile holding the shadow's tip at zoom 16 (tiles ≈ 400 m, 12 rows).
    let z = 16;
    let (lon, lat) = (10.0 + 120.5 * 0.0003, 47.0 - (tip + 0.5) * 0.0003);
    let (mx, my) = lonlat_to_mercator(lon, lat);
    let (px, py) = mercator_to_pixel(z, 256, mx, my);
    let (cx, cy) = ((px / 256.0) as u64, (py / 256.0) as u64);
    let block = Region::tiles(z, cx - 1, cy - 1, 3, 3, 256).unwrap();
    let whole = render_region(&src, Layer::Relief, &block, Window::Whole)
        .unwrap()
        .unwrap();
    let unshadowed = render_region(&flat, Layer::Relief, &block, Window::Whole)
        .unwrap()
        .unwrap();
    // The block lies far from the wall: more than its halo away from every tile's window.
    let block_south_row = tip + 1.5 * 256.0 * ground_resolution(z, lat) / dem.dy;
    assert!(
        180.0 - block_south_row > 2.0 * src.halo() as f64,
        "block rows to {block_south_row}, halo {}",
        src.halo()
    );
    let mut darker = 0;
    for j in 0..3u32 {
        for i in 0..3u32 {
            let tile = render_tile(
                &src,
                Layer::Relief,
                z,
                cx - 1 + u64::from(i),
                cy - 1 + u64::from(j),
                256,
            )
            .unwrap()
            .unwrap();
            let d = max_diff(&whole, &tile, i, j);
            assert!(
                d <= 1,
                "relief tile ({i}, {j}): {d}/255 off the whole-DEM result"
            );
        }
    }
    // South of the tip (bottom row of tiles) is in shadow, north of it (top row) is lit.
    let mean_red = |img: &RgbaImage, y0: u32, y1: u32| -> f64 {
        let mut s = 0.0;
        for y in y0..y1 {
            for x in 0..img.width {
                s += f64::from(img.pixel(x, y)[0]);
            }
        }
        s / f64::from((y1 - y0) * img.width)
    };
    let (top, bottom) = (mean_red(&whole, 0, 256), mean_red(&whole, 512, 768));
    let (top_off, bottom_off) = (
        mean_red(&unshadowed, 0, 256),
        mean_red(&unshadowed, 512, 768),
    );
    assert!(
        (top - top_off).abs() < 1.0,
        "lit north of the tip: {top} vs {top_off}"
    );
    assert!(
        bottom < bottom_off - 20.0,
        "shadow south of the tip: {bottom} vs {bottom_off}"
    );
    for (a, b) in whole.data.chunks(4).zip(unshadowed.data.chunks(4)) {
        if u16::from(a[0]) + 10 < u16::from(b[0]) {
            darker += 1;
        }
    }
    assert!(darker > 256 * 256, "{darker} pixels in cast shadow");
    std::fs::create_dir_all(env!("CARGO_TARGET_TMPDIR")).unwrap();
    let _ = std::fs::write(
        format!("{}/cast_shadow_block.png", env!("CARGO_TARGET_TMPDIR")),
        phenomena_engine::formats::png_write::encode_rgba(&whole),
    );
}
