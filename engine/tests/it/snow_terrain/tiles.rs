//! Issue 22's map tiles: seam-free by construction. A 3×3 block of tiles, each computed on its
//! own window of the DEM grown by the descriptor's reach, equals the same pixels resampled from
//! the whole-DEM result within 1/255 per channel, at two zooms, on a projected DEM (Olinda, UTM
//! 25S) and a geographic one (Jacksboro, EPSG:4326); and the whole-DEM result the tiles are held
//! to is the pipeline's own descriptor.

use std::path::PathBuf;

use phenomena_engine::formats::dem::{decode_dem, DemOptions};
use phenomena_engine::geom::mercator::{ground_resolution, lonlat_to_mercator, mercator_to_pixel};
use phenomena_engine::geom::Dem;
use phenomena_engine::params::Limits;
use phenomena_engine::render::RgbaImage;
use phenomena_engine::snow_terrain::descriptor::compute;
use phenomena_engine::snow_terrain::tiles::{
    decode_terrain_rgb, decode_terrarium, render_region, render_tile, Layer, MapSource, Region,
    Window,
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
            let whole = render_region(&src, layer, &block, Window::Whole).expect("on the DEM");
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
    let rgb = render_tile(&src, Layer::TerrainRgb, z, cx, cy, 256).unwrap();
    let ter = render_tile(&src, Layer::Terrarium, z, cx, cy, 256).unwrap();
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
    assert!(render_tile(&src, Layer::Snow, z, cx + 40, cy, 256).is_none());
    // At the smallest zoom the DEM spans at most one tile's width: part of a tile is drawn.
    let z = src.info().minzoom;
    let (cx, cy) = centre_tile(&src, z);
    let tile = render_tile(&src, Layer::Hillshade, z, cx, cy, 256).unwrap();
    let n = opaque(&tile);
    assert!(n > 100 && n < 256 * 256, "{n} opaque pixels at z{z}");
}
