//! Float32 single-band GeoTIFF writer for raster outputs (`snow_cover.tif`, SPEC §1 *Outputs*):
//! same size, georeferencing, CRS and nodata as the input DEM, laid out as a **Cloud-Optimized
//! GeoTIFF** (COG) that GDAL's `validate_cloud_optimized_geotiff.py` accepts.
//!
//! The geo tags of the input ([`GeoTags`]) are copied verbatim, with GDAL's types: 33550, 33922,
//! 34264 and 34736 as DOUBLE, 34735 as SHORT, 34737 and GDAL_NODATA (42113) as ASCII. A
//! `GeoRef` that has a transform but no tags (built by hand) gets synthesised ones
//! ([`crate::formats::dem::synthesize_tags`]).
//!
//! Nodata: NaN cells are written as the input's nodata value (rounded to f32) and the tag
//! repeats that value (`"-32768"`, `"nan"`); without an input nodata value but with NaN cells,
//! NaN is written and tagged `"nan"`. Every IFD (overviews too) carries the tag, as GDAL writes.
//!
//! Layout (classic little-endian TIFF, what GDAL's COG driver writes without its optional ghost
//! header):
//! - header, then the IFD of the full-resolution image at offset 8, then the IFD of each
//!   overview (NewSubfileType = 1, halves of the previous level, until the level fits in one
//!   tile), chained in that order, each followed by its out-of-line tag values;
//! - then the tile data, smallest overview first and the full-resolution image last, each
//!   level's tiles in row-major order: a reader of a COG over HTTP ranges gets every IFD in the
//!   first request and the tiles of one level in one contiguous stretch.
//! - Tiles of [`TILE`] px square (fewer, rounded up to a multiple of 16, when the whole image is
//!   smaller), edge tiles padded with zeros; deflate (zlib, level 1) with the floating-point
//!   predictor (TIFF Technical Note 3, Predictor = 3: each tile row split into byte planes,
//!   most significant first, then differenced byte by byte), which GDAL, libtiff and the `tiff`
//!   crate's decoder read.
//! - Overviews: the mean of the valid (non-NaN) cells of each 2×2 block of the level above (a
//!   lone edge row or column averages what it has), NaN where all four are nodata — GDAL's
//!   `AVERAGE` resampling, which suits a continuous fraction like snow cover.
//!
//! Every tile of every level is compressed in parallel (rayon + flate2), and the result does not
//! depend on the thread count. The `tiff` crate's encoder (0.9) is not used: it writes each IFD
//! after its image data, strips only, and no predictor, while a COG needs every IFD before the
//! first tile. BigTIFF is not needed below 4 GiB, far above our cell limits (a larger output
//! would panic on the offset conversion: a caller bug).
//!
//! Cost: the overview pyramid (⅓ of the input's cells as f32), the compressed tiles (≈ 1–3
//! bytes per cell) and the output; one raw tile (1 MiB) per worker.

use std::io::Write;

use flate2::write::ZlibEncoder;
use rayon::prelude::*;

use crate::formats::dem::synthesize_tags;
use crate::geom::heightfield::{GeoRef, GeoTags};

/// Side of the square tiles (px), as GDAL's COG driver writes by default.
pub const TILE: usize = 512;

/// Float32 single-band Cloud-Optimized GeoTIFF of `values` (row-major, width×height) with the
/// georeferencing, CRS and nodata of `georef` copied from the input. NaN cells are written as the
/// input's nodata value (GDAL_NODATA tag 42113 as ASCII, e.g. "-32768" or "nan"); if the input
/// had no nodata value but there are NaN cells, write NaN and tag "nan".
///
/// # Panics
/// If `values.len() != width * height`, a side is 0 or larger than `u32::MAX`, or the file would
/// pass 4 GiB (caller bugs: far above the cell limits).
pub fn write_float32_geotiff(
    width: usize,
    height: usize,
    values: &[f32],
    georef: &GeoRef,
) -> Vec<u8> {
    assert!(
        width > 0
            && height > 0
            && u32::try_from(width.max(height)).is_ok()
            && values.len() == width.saturating_mul(height),
        "write_float32_geotiff: {width}×{height} grid with {} values",
        values.len()
    );
    let tags: GeoTags = if georef.tags == GeoTags::default() {
        synthesize_tags(georef.transform, georef.epsg, georef.geographic)
    } else {
        georef.tags.clone()
    };
    let nodata = nodata_of(values, georef);
    let fill = nodata.map(|n| n as f32).filter(|f| !f.is_nan());
    let tile = tile_side(width, height);

    // The pyramid: level 0 is the input, each next one half of the one above.
    let mut overviews: Vec<(usize, usize, Vec<f32>)> = Vec::new();
    let (mut w, mut h) = (width, height);
    while w.max(h) > tile {
        let prev = overviews.last().map_or(values, |(_, _, v)| v.as_slice());
        let next = halve(w, h, prev);
        w = w.div_ceil(2);
        h = h.div_ceil(2);
        overviews.push((w, h, next));
    }
    let levels: Vec<(usize, usize, &[f32])> = std::iter::once((width, height, values))
        .chain(overviews.iter().map(|(w, h, v)| (*w, *h, v.as_slice())))
        .collect();

    // Every tile of every level, compressed in parallel, in file order (smallest level first).
    let order: Vec<(usize, usize, usize)> = (0..levels.len())
        .rev()
        .flat_map(|l| {
            let (w, h, _) = levels[l];
            (0..h.div_ceil(tile))
                .flat_map(move |ty| (0..w.div_ceil(tile)).map(move |tx| (l, tx, ty)))
        })
        .collect();
    let tiles: Vec<Vec<u8>> = order
        .par_iter()
        .map(|&(l, tx, ty)| {
            let (w, h, v) = levels[l];
            compress_tile(w, h, v, tile, tx, ty, fill)
        })
        .collect();

    // The IFDs, with zero tile offsets first (their sizes do not depend on the values).
    let nodata_text = nodata.map(nodata_text);
    let mut ifds: Vec<Vec<Entry>> = levels
        .iter()
        .enumerate()
        .map(|(l, &(w, h, _))| {
            let n = w.div_ceil(tile) * h.div_ceil(tile);
            ifd_entries(l, w, h, tile, n, &tags, nodata_text.as_deref())
        })
        .collect();
    let ifd_sizes: Vec<usize> = ifds.iter().map(Vec::as_slice).map(ifd_size).collect();
    let data_start = 8 + ifd_sizes.iter().sum::<usize>();
    // Tile offsets and byte counts, level by level.
    let mut at = data_start;
    let mut per_level: Vec<(Vec<u32>, Vec<u32>)> = vec![(Vec::new(), Vec::new()); levels.len()];
    for (&(l, _, _), t) in order.iter().zip(&tiles) {
        per_level[l].0.push(to_u32(at));
        per_level[l].1.push(to_u32(t.len()));
        at += t.len();
    }
    for (entries, (offsets, counts)) in ifds.iter_mut().zip(&per_level) {
        for e in entries.iter_mut() {
            if e.tag == TAG_TILE_OFFSETS {
                e.data = longs(offsets);
            } else if e.tag == TAG_TILE_BYTE_COUNTS {
                e.data = longs(counts);
            }
        }
    }

    let mut out = Vec::with_capacity(at);
    out.extend_from_slice(b"II");
    out.extend_from_slice(&42u16.to_le_bytes());
    out.extend_from_slice(&8u32.to_le_bytes());
    let mut ifd_at = 8;
    for (i, entries) in ifds.iter().enumerate() {
        let next = if i + 1 < ifds.len() {
            ifd_at + ifd_sizes[i]
        } else {
            0
        };
        write_ifd(&mut out, ifd_at, entries, next);
        ifd_at += ifd_sizes[i];
    }
    debug_assert_eq!(out.len(), data_start);
    for t in &tiles {
        out.extend_from_slice(t);
    }
    out
}

/// The tile side: [`TILE`], or the image's larger side rounded up to a multiple of 16 (TIFF's
/// rule for tile sizes) when that is smaller, so a small raster is one small tile.
fn tile_side(width: usize, height: usize) -> usize {
    TILE.min(width.max(height).div_ceil(16) * 16)
}

/// The next overview: the mean of the valid cells of each 2×2 block (NaN if none is valid).
fn halve(w: usize, h: usize, v: &[f32]) -> Vec<f32> {
    let (w2, h2) = (w.div_ceil(2), h.div_ceil(2));
    let mut out = vec![0.0f32; w2 * h2];
    out.par_chunks_mut(w2).enumerate().for_each(|(r, row)| {
        // An edge block of one row or column has only those cells.
        let rows = 2 * r..(2 * r + 2).min(h);
        for (c, o) in row.iter_mut().enumerate() {
            let mut sum = 0.0f32;
            let mut n = 0u32;
            for rr in rows.clone() {
                for cc in 2 * c..(2 * c + 2).min(w) {
                    let x = v[rr * w + cc];
                    if !x.is_nan() {
                        sum += x;
                        n += 1;
                    }
                }
            }
            *o = if n == 0 { f32::NAN } else { sum / n as f32 };
        }
    });
    out
}

/// One tile (`tx`, `ty`) of a `w`×`h` level: NaN replaced by `fill`, padded with zeros, each row
/// through the floating-point predictor, the whole tile deflated as one zlib stream.
fn compress_tile(
    w: usize,
    h: usize,
    v: &[f32],
    tile: usize,
    tx: usize,
    ty: usize,
    fill: Option<f32>,
) -> Vec<u8> {
    let mut raw = vec![0u8; tile * tile * 4];
    let mut row = vec![0.0f32; tile];
    let (c0, r0) = (tx * tile, ty * tile);
    let cols = tile.min(w - c0);
    for (r, out) in raw.chunks_exact_mut(tile * 4).enumerate() {
        if r0 + r >= h {
            break; // rows below the image stay zero (all-zero bytes predict to zero)
        }
        let src = &v[(r0 + r) * w + c0..][..cols];
        for (d, &x) in row.iter_mut().zip(src) {
            *d = match fill {
                Some(f) if x.is_nan() => f,
                _ => x,
            };
        }
        row[cols..].fill(0.0);
        predict_row(&row, out);
    }
    // Level 1: with the predictor, higher levels shrink the file by a few per cent for several
    // times the time.
    let mut z = ZlibEncoder::new(
        Vec::with_capacity(raw.len() / 4 + 64),
        flate2::Compression::fast(),
    );
    // Writing into a Vec cannot fail.
    let _ = z.write_all(&raw);
    z.finish().unwrap_or_default()
}

/// TIFF's floating-point predictor (Predictor = 3) for one row of f32: the bytes of each value,
/// most significant first, gathered in four planes of `row.len()` bytes, then each byte minus
/// the one before it (wrapping).
fn predict_row(row: &[f32], out: &mut [u8]) {
    let n = row.len();
    let (p0, rest) = out.split_at_mut(n);
    let (p1, rest) = rest.split_at_mut(n);
    let (p2, p3) = rest.split_at_mut(n);
    for (i, x) in row.iter().enumerate() {
        let b = x.to_bits().to_be_bytes();
        p0[i] = b[0];
        p1[i] = b[1];
        p2[i] = b[2];
        p3[i] = b[3];
    }
    for j in (1..out.len()).rev() {
        out[j] = out[j].wrapping_sub(out[j - 1]);
    }
}

const TAG_TILE_OFFSETS: u16 = 324;
const TAG_TILE_BYTE_COUNTS: u16 = 325;
const ASCII: u16 = 2;
const SHORT: u16 = 3;
const LONG: u16 = 4;
const RATIONAL: u16 = 5;
const DOUBLE: u16 = 12;

/// One IFD entry: tag, field type, count and the value's little-endian bytes.
struct Entry {
    tag: u16,
    typ: u16,
    count: u32,
    data: Vec<u8>,
}

fn entry(tag: u16, typ: u16, count: usize, data: Vec<u8>) -> Entry {
    Entry {
        tag,
        typ,
        count: to_u32(count),
        data,
    }
}

fn short(tag: u16, v: u16) -> Entry {
    entry(tag, SHORT, 1, v.to_le_bytes().to_vec())
}

fn long(tag: u16, v: u32) -> Entry {
    entry(tag, LONG, 1, v.to_le_bytes().to_vec())
}

fn longs(v: &[u32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn doubles(tag: u16, v: &[f64]) -> Entry {
    entry(
        tag,
        DOUBLE,
        v.len(),
        v.iter().flat_map(|x| x.to_le_bytes()).collect(),
    )
}

fn ascii(tag: u16, s: &str) -> Entry {
    // NUL-terminated; characters a TIFF ASCII field cannot hold are dropped.
    let mut b: Vec<u8> = s.bytes().filter(|c| c.is_ascii() && *c != 0).collect();
    b.push(0);
    entry(tag, ASCII, b.len(), b)
}

fn to_u32(v: usize) -> u32 {
    u32::try_from(v)
        .unwrap_or_else(|_| panic!("write_float32_geotiff: {v} does not fit a classic TIFF"))
}

/// The tags of level `level` (0 = full resolution, with the geo tags), sorted by tag number;
/// the tile offsets and byte counts are `n` zeros, filled in once the layout is known.
fn ifd_entries(
    level: usize,
    w: usize,
    h: usize,
    tile: usize,
    n: usize,
    tags: &GeoTags,
    nodata: Option<&str>,
) -> Vec<Entry> {
    let tile16 = u16::try_from(tile).unwrap_or(512);
    let mut e = vec![
        long(254, u32::from(level > 0)), // NewSubfileType: 1 = reduced-resolution image
        long(256, to_u32(w)),
        long(257, to_u32(h)),
        short(258, 32), // BitsPerSample
        short(259, 8),  // Compression: deflate (Adobe)
        short(262, 1),  // PhotometricInterpretation: BlackIsZero
        short(277, 1),  // SamplesPerPixel
        short(284, 1),  // PlanarConfiguration: chunky
        short(317, 3),  // Predictor: floating point
        short(322, tile16),
        short(323, tile16),
        entry(TAG_TILE_OFFSETS, LONG, n, vec![0; 4 * n]),
        entry(TAG_TILE_BYTE_COUNTS, LONG, n, vec![0; 4 * n]),
        short(339, 3), // SampleFormat: IEEE float
    ];
    if level == 0 {
        // X/YResolution 1/1 without unit (TIFF baseline; GIS readers ignore them).
        let one: Vec<u8> = [1u32, 1].iter().flat_map(|x| x.to_le_bytes()).collect();
        e.push(entry(282, RATIONAL, 1, one.clone()));
        e.push(entry(283, RATIONAL, 1, one));
        e.push(short(296, 1));
        if let Some(v) = tags.pixel_scale.as_deref().filter(|v| !v.is_empty()) {
            e.push(doubles(33550, v));
        }
        if let Some(v) = tags.tiepoint.as_deref().filter(|v| !v.is_empty()) {
            e.push(doubles(33922, v));
        }
        if let Some(v) = tags.transformation.as_deref().filter(|v| !v.is_empty()) {
            e.push(doubles(34264, v));
        }
        if let Some(v) = tags.geo_key_directory.as_deref().filter(|v| !v.is_empty()) {
            let b = v.iter().flat_map(|x| x.to_le_bytes()).collect();
            e.push(entry(34735, SHORT, v.len(), b));
        }
        if let Some(v) = tags.geo_double_params.as_deref().filter(|v| !v.is_empty()) {
            e.push(doubles(34736, v));
        }
        if let Some(v) = &tags.geo_ascii_params {
            e.push(ascii(34737, v));
        }
    }
    if let Some(t) = nodata {
        e.push(ascii(42113, t));
    }
    e.sort_by_key(|x| x.tag);
    e
}

/// Bytes of an IFD with its out-of-line values (each at an even offset).
fn ifd_size(entries: &[Entry]) -> usize {
    2 + 12 * entries.len()
        + 4
        + entries
            .iter()
            .filter(|e| e.data.len() > 4)
            .map(|e| e.data.len().next_multiple_of(2))
            .sum::<usize>()
}

/// Appends the IFD that starts at file offset `at` (= `out.len()`), its values after it, and
/// `next` as the offset of the following IFD (0 for the last).
fn write_ifd(out: &mut Vec<u8>, at: usize, entries: &[Entry], next: usize) {
    debug_assert_eq!(out.len(), at);
    let mut extra_at = at + 2 + 12 * entries.len() + 4;
    let mut extra = Vec::new();
    out.extend_from_slice(&u16::try_from(entries.len()).unwrap_or(0).to_le_bytes());
    for e in entries {
        out.extend_from_slice(&e.tag.to_le_bytes());
        out.extend_from_slice(&e.typ.to_le_bytes());
        out.extend_from_slice(&e.count.to_le_bytes());
        if e.data.len() <= 4 {
            let mut v = [0u8; 4];
            v[..e.data.len()].copy_from_slice(&e.data);
            out.extend_from_slice(&v);
        } else {
            out.extend_from_slice(&to_u32(extra_at).to_le_bytes());
            extra.extend_from_slice(&e.data);
            if e.data.len() % 2 == 1 {
                extra.push(0);
            }
            extra_at += e.data.len().next_multiple_of(2);
        }
    }
    out.extend_from_slice(&to_u32(next).to_le_bytes());
    out.extend_from_slice(&extra);
}

/// Text of the GDAL_NODATA tag for `v`: integers without a fraction, `nan`, otherwise the
/// shortest round-trip decimal form.
fn nodata_text(v: f64) -> String {
    if v.is_nan() {
        "nan".to_string()
    } else if v.is_infinite() {
        if v > 0.0 { "inf" } else { "-inf" }.to_string()
    } else if v.fract() == 0.0 && v.abs() < 1e15 {
        format!("{v:.0}")
    } else if v.abs() >= 1e15 || v.abs() < 1e-4 {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

/// The nodata value written for NaN cells (see [`write_float32_geotiff`]).
fn nodata_of(values: &[f32], georef: &GeoRef) -> Option<f64> {
    match georef.nodata {
        Some(n) => Some(n),
        None if values.par_iter().any(|v| v.is_nan()) => Some(f64::NAN),
        None => None,
    }
}

#[cfg(test)]
mod tests {
    use super::{halve, nodata_text, predict_row, tile_side};

    #[test]
    fn nodata_texts_parse_back() {
        for v in [-32768.0, 0.0, -9999.0, -3.4028234663852886e38, 1.5, 1e-30] {
            let t = nodata_text(v);
            assert_eq!(t.parse::<f64>(), Ok(v), "{t}");
        }
        assert_eq!(nodata_text(-32768.0), "-32768");
        assert_eq!(nodata_text(f64::NAN), "nan");
    }

    #[test]
    fn tile_sides_are_multiples_of_16() {
        assert_eq!(tile_side(5, 4), 16);
        assert_eq!(tile_side(100, 17), 112);
        assert_eq!(tile_side(4096, 3), 512);
    }

    #[test]
    fn predictor_planes_and_differences() {
        // 1.0 = 3f 80 00 00, 2.0 = 40 00 00 00: planes [3f 40][80 00][00 00][00 00].
        let mut out = [0u8; 8];
        predict_row(&[1.0, 2.0], &mut out);
        let planes = [0x3fu8, 0x40, 0x80, 0x00, 0, 0, 0, 0];
        let mut want = planes;
        for j in (1..8).rev() {
            want[j] = planes[j].wrapping_sub(planes[j - 1]);
        }
        assert_eq!(out, want);
    }

    #[test]
    fn overview_means_skip_nodata() {
        let nan = f32::NAN;
        // 3×3: blocks [1 2;4 5], [3;6], [7 8], [9].
        let v = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, nan];
        let o = halve(3, 3, &v);
        assert_eq!(&o[..3], &[3.0, 4.5, 7.5]);
        assert!(o[3].is_nan());
    }
}
