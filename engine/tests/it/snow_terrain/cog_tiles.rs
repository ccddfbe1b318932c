//! Issue 22: a DEM read by ranges from a Cloud-Optimized GeoTIFF (`tiles::open_source` with a
//! tiled GeoTIFF above the caller's whole-DEM size). The COGs are real DEMs written by our own
//! COG writer (`formats::geotiff_write`, which GDAL's validator accepts): internal tiles of
//! 512², overviews by 2×2 means.
//!
//! - Seam-free: a 3×3 block of tiles equals the same pixels computed on the whole level, at a
//!   zoom drawn from the full resolution and one drawn from an overview, for every layer
//!   (cast shadows included: near and far field depend on the position only).
//! - Close to the whole-DEM map: the snow cover of a tiled map differs from the whole-DEM one
//!   only through its global values read on the overview.
//! - By ranges: one tile reads a small part of the object; opening reads the header and the
//!   bounded overview only.
//! - Bad files: absurd header sizes, a truncated file and corrupt tile bytes are input errors,
//!   never a panic or a large allocation.

use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use phenomena_engine::formats::dem::cog::ByteSource;
use phenomena_engine::formats::dem::{decode_dem, DemOptions};
use phenomena_engine::formats::geotiff_write::write_float32_geotiff;
use phenomena_engine::geom::heightfield::GeoTags;
use phenomena_engine::geom::mercator::{ground_resolution, lonlat_to_mercator, mercator_to_pixel};
use phenomena_engine::geom::Dem;
use phenomena_engine::params::Limits;
use phenomena_engine::render::RgbaImage;
use phenomena_engine::snow_terrain::tiles::{
    open_source, render_region, render_tile, Layer, MapError, MapSource, Region, Window,
};
use phenomena_engine::InputError;
use serde_json::json;

fn load(name: &str) -> Dem {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/dem")
        .join(name);
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    decode_dem(&bytes, Some(name), &DemOptions::default()).expect("decodes")
}

/// `dem` as a float32 COG (its own georeferencing re-synthesised from the transform).
fn cog_of(dem: &Dem) -> Vec<u8> {
    let mut g = dem.georef.clone();
    g.tags = GeoTags::default();
    write_float32_geotiff(dem.width, dem.height, &dem.heights, &g)
}

/// `dem` with `k`² cells per cell, bilinear between cell centres (a DEM large enough that a
/// tile is a small part of it).
fn upsample(dem: &Dem, k: usize) -> Dem {
    let (w, h) = (dem.width * k, dem.height * k);
    let mut heights = vec![0f32; w * h];
    for r in 0..h {
        let y = ((r as f64 + 0.5) / k as f64 - 0.5).clamp(0.0, (dem.height - 1) as f64);
        let (r0, fy) = (y.floor() as usize, (y - y.floor()) as f32);
        let r1 = (r0 + 1).min(dem.height - 1);
        for c in 0..w {
            let x = ((c as f64 + 0.5) / k as f64 - 0.5).clamp(0.0, (dem.width - 1) as f64);
            let (c0, fx) = (x.floor() as usize, (x - x.floor()) as f32);
            let c1 = (c0 + 1).min(dem.width - 1);
            let top = dem.at(c0, r0) * (1.0 - fx) + dem.at(c1, r0) * fx;
            let bottom = dem.at(c0, r1) * (1.0 - fx) + dem.at(c1, r1) * fx;
            heights[r * w + c] = top * (1.0 - fy) + bottom * fy;
        }
    }
    let mut georef = dem.georef.clone();
    if let Some(t) = georef.transform.as_mut() {
        t[1] /= k as f64;
        t[5] /= k as f64;
    }
    Dem {
        width: w,
        height: h,
        heights,
        dx: dem.dx / k as f64,
        dy: dem.dy / k as f64,
        georef,
    }
}

/// Bytes in memory, counting what is read.
struct Counted {
    bytes: Vec<u8>,
    read: AtomicU64,
}

impl Counted {
    fn new(bytes: Vec<u8>) -> Arc<Self> {
        Arc::new(Self {
            bytes,
            read: AtomicU64::new(0),
        })
    }
    fn read(&self) -> u64 {
        self.read.load(Ordering::Relaxed)
    }
}

impl ByteSource for Counted {
    fn size(&self) -> u64 {
        self.bytes.len() as u64
    }
    fn read_at(&self, offset: u64, buf: &mut [u8]) -> std::io::Result<()> {
        self.read.fetch_add(buf.len() as u64, Ordering::Relaxed);
        self.bytes.read_at(offset, buf)
    }
}

fn open(src: Arc<Counted>, params: serde_json::Value, whole_max: u64) -> MapSource {
    open_source(src, Some("dem.tif"), &params, &Limits::default(), whole_max).expect("opens")
}

fn centre_tile(src: &MapSource, z: u8) -> (u64, u64) {
    let c = src.info().center;
    let (mx, my) = lonlat_to_mercator(c[0], c[1]);
    let (px, py) = mercator_to_pixel(z, 256, mx, my);
    ((px / 256.0) as u64, (py / 256.0) as u64)
}

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

#[test]
fn a_cog_read_by_ranges_is_seam_free_on_its_full_resolution_and_its_overview() {
    let dem = load("tanzawa_sagami_aster_gdem2.tif");
    let bytes = Counted::new(cog_of(&dem));
    // 884 × 868 cells: levels 884×868 and 442×434; read by ranges above 200 000 cells, so the
    // overview is level 1.
    let src = open(bytes, json!({}), 200_000);
    assert!(src.is_tiled());
    let info = src.info().clone();
    let extent = (info.width as f64 * info.cell_m[0]).min(info.height as f64 * info.cell_m[1]);
    let mut z0 = info.maxzoom;
    while 3.0 * 256.0 * ground_resolution(z0, info.center[1]) > extent {
        z0 += 1;
    }
    let z1 = info.maxzoom - 2;
    assert_eq!(src.level_of_zoom(z0, 256, Layer::Snow), 0);
    assert_eq!(
        src.level_of_zoom(z1, 256, Layer::Snow),
        1,
        "z{z1} is drawn from the overview"
    );
    for z in [z0, z1] {
        let (cx, cy) = centre_tile(&src, z);
        let block = Region::tiles(z, cx - 1, cy - 1, 3, 3, 256).unwrap();
        for layer in [
            Layer::Snow,
            Layer::Relief,
            Layer::Hillshade,
            Layer::TerrainRgb,
        ] {
            let whole = render_region(&src, layer, &block, Window::Whole)
                .unwrap()
                .expect("on the DEM");
            let opaque = whole.data.chunks(4).filter(|p| p[3] > 0).count();
            assert!(opaque > 9 * 256, "z{z} {}: {opaque}", layer.name());
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
                    .unwrap_or_else(|| RgbaImage::new_filled(256, 256, [0; 4]));
                    let d = max_diff(&whole, &tile, i, j);
                    assert!(
                        d <= 1,
                        "z{z} {} tile ({i}, {j}): {d}/255 off the whole-level result",
                        layer.name()
                    );
                    seen.extend(tile.data.chunks(4).map(|p| [p[0], p[1], p[2], p[3]]));
                }
            }
            assert!(
                seen.len() > 20,
                "z{z} {}: {} colours",
                layer.name(),
                seen.len()
            );
        }
    }
}

/// The snow cover of the tiled map at its full resolution is the whole-DEM map's but for the
/// snowline band, read on the overview's elevations (2×2 means) instead of the DEM's: the
/// same snow within a few levels on average.
#[test]
fn a_tiled_map_draws_the_snow_of_the_whole_dem_map() {
    let dem = load("tanzawa_sagami_aster_gdem2.tif");
    let tiled = open(Counted::new(cog_of(&dem)), json!({}), 200_000);
    let whole = open(Counted::new(cog_of(&dem)), json!({}), 1 << 22);
    assert!(tiled.is_tiled() && !whole.is_tiled());
    let z = tiled.info().maxzoom;
    let (cx, cy) = centre_tile(&tiled, z);
    let a = render_tile(&tiled, Layer::Snow, z, cx, cy, 256)
        .unwrap()
        .unwrap();
    let b = render_tile(&whole, Layer::Snow, z, cx, cy, 256)
        .unwrap()
        .unwrap();
    let (mut sum, mut n) = (0u64, 0u64);
    for (p, q) in a.data.chunks(4).zip(b.data.chunks(4)) {
        sum += u64::from(p[3].abs_diff(q[3]));
        n += 1;
    }
    let mean = sum as f64 / n as f64;
    let snowy = b.data.chunks(4).filter(|p| p[3] > 64).count();
    assert!(snowy > 1000, "the whole map has snow here: {snowy} pixels");
    assert!(mean < 8.0, "mean |Δ alpha| {mean:.2}/255");
}

/// A tile of a 2652 × 2604-cell COG (Tanzawa, 3×3 cells per cell) reads a few of its internal
/// tiles, not the object: opening reads the header and the overview of at most 500 000 cells.
#[test]
fn a_tile_reads_a_small_part_of_a_large_cog() {
    let dem = upsample(&load("tanzawa_sagami_aster_gdem2.tif"), 3);
    let bytes = Counted::new(cog_of(&dem));
    let size = bytes.size();
    let src = open(bytes.clone(), json!({}), 500_000);
    assert!(src.is_tiled());
    let opened = bytes.read();
    assert!(
        opened * 8 < size,
        "opening read {opened} of {size} bytes (the header and a 663 × 651 overview)"
    );
    let z = src.info().maxzoom;
    let (cx, cy) = centre_tile(&src, z);
    for layer in [Layer::Snow, Layer::Relief] {
        let before = bytes.read();
        let tile = render_tile(&src, layer, z, cx, cy, 256).unwrap().unwrap();
        assert!(tile.data.chunks(4).filter(|p| p[3] > 0).count() > 256 * 200);
        let read = bytes.read() - before;
        // Snow: the internal tiles under the window (at most 2 × 2 of 6 × 6 at level 0);
        // relief: from the cache, with the near field's wider window.
        assert!(
            read * 6 < size,
            "{}: one tile read {read} of {size} bytes",
            layer.name()
        );
    }
    // All but the 4 bytes that told a TIFF went through the COG reader.
    assert_eq!(bytes.read(), src.bytes_fetched() + 4);
    assert!(src.held_bytes() < 100 << 20, "{}", src.held_bytes());
}

fn input_error(r: Result<MapSource, MapError>) -> InputError {
    match r {
        Err(MapError::Input(e)) => e,
        Err(e) => panic!("not an input error: {e}"),
        Ok(_) => panic!("opened"),
    }
}

#[test]
fn bad_cogs_are_input_errors() {
    let dem = load("tanzawa_sagami_aster_gdem2.tif");
    let good = cog_of(&dem);
    let open_bytes = |b: Vec<u8>| {
        open_source(
            Arc::new(b),
            Some("dem.tif"),
            &json!({}),
            &Limits::default(),
            200_000,
        )
    };
    // The header claims 65 535 × 65 535 cells (ImageWidth and ImageLength patched in the first
    // IFD, at offset 8: a count, then 12-byte entries): its 4 tile offsets do not cover that.
    let mut huge = good.clone();
    let n = u16::from_le_bytes([huge[8], huge[9]]) as usize;
    for e in 0..n {
        let at = 10 + 12 * e;
        let tag = u16::from_le_bytes([huge[at], huge[at + 1]]);
        if tag == 256 || tag == 257 {
            let kind = u16::from_le_bytes([huge[at + 2], huge[at + 3]]);
            let v: &[u8] = if kind == 3 {
                &[0xff, 0xff, 0, 0]
            } else {
                &[0xff, 0xff, 0xff, 0x7f]
            };
            huge[at + 8..at + 12].copy_from_slice(v);
        }
    }
    let e = input_error(open_bytes(huge));
    assert!(
        matches!(e, InputError::Corrupt { .. } | InputError::TooLarge { .. }),
        "{e}"
    );
    // Truncated: the full-resolution tiles (last in the file) lie past its end.
    let cut = good[..good.len() * 3 / 5].to_vec();
    let e = input_error(open_bytes(cut));
    assert!(matches!(e, InputError::Corrupt { .. }), "{e}");
    // Garbage over the last 40 % (full-resolution tiles): the map opens (header and overview
    // intact), and the tiles that read them are refused.
    let mut bad = good.clone();
    let from = bad.len() * 3 / 5;
    for (i, b) in bad[from..].iter_mut().enumerate() {
        *b = (i as u8).wrapping_mul(151).wrapping_add(7);
    }
    let src = open_bytes(bad).expect("the header and overview are intact");
    let z = src.info().maxzoom;
    let (cx, cy) = centre_tile(&src, z);
    let mut refused = 0;
    for j in 0..5u64 {
        for i in 0..5u64 {
            match render_tile(&src, Layer::Snow, z, cx + i - 2, cy + j - 2, 256) {
                Err(MapError::Input(InputError::Corrupt { .. })) => refused += 1,
                Ok(_) => {}
                Err(e) => panic!("{e}"),
            }
        }
    }
    assert!(refused > 0, "no tile read the corrupt bytes");
}
