//! `snow_cover.tif` as a Cloud-Optimized GeoTIFF (issue 22): the layout checked byte by byte with
//! a TIFF parser written here (IFDs first and chained full resolution → smallest overview, tile
//! data after every IFD, smallest overview first, overview sizes, deflate + floating-point
//! predictor, nodata on every level), the pixels read back exactly with the `tiff` crate, and —
//! when GDAL's Python bindings are installed (`.ci/run` installs them) — GDAL's own COG
//! validator and GDAL reading back the pixels, georeferencing and nodata.

use std::collections::BTreeMap;
use std::process::Command;

use phenomena_engine::formats::dem::{decode_dem, DemOptions};
use phenomena_engine::formats::geotiff_write::{write_float32_geotiff, TILE};
use phenomena_engine::geom::heightfield::GeoRef;

/// A `w`×`h` field of smooth values in [0, 1] with a nodata (NaN) disc and a NaN corner block.
fn field(w: usize, h: usize) -> Vec<f32> {
    let mut v = Vec::with_capacity(w * h);
    for r in 0..h {
        for c in 0..w {
            let (x, y) = (c as f32 / w as f32, r as f32 / h as f32);
            let s = 0.5 + 0.5 * (7.0 * x).sin() * (5.0 * y + 0.3).cos();
            let hole = (x - 0.3).powi(2) + (y - 0.6).powi(2) < 0.01 || (r < 3 && c < 5);
            v.push(if hole { f32::NAN } else { s });
        }
    }
    v
}

fn utm_georef(nodata: Option<f64>) -> GeoRef {
    GeoRef {
        transform: Some([500_000.0, 30.0, 0.0, 4_100_000.0, 0.0, -30.0]),
        epsg: Some(32613),
        nodata,
        ..Default::default()
    }
}

/// One parsed IFD: its offset, its tags (type, raw little-endian value bytes), and the end of
/// its entries and out-of-line values.
struct Ifd {
    offset: usize,
    tags: BTreeMap<u16, (u16, Vec<u8>)>,
    end: usize,
}

impl Ifd {
    fn ints(&self, tag: u16) -> Vec<u64> {
        let (typ, b) = &self.tags[&tag];
        match typ {
            3 => b
                .chunks_exact(2)
                .map(|c| u64::from(u16::from_le_bytes([c[0], c[1]])))
                .collect(),
            4 => b
                .chunks_exact(4)
                .map(|c| u64::from(u32::from_le_bytes([c[0], c[1], c[2], c[3]])))
                .collect(),
            t => panic!("tag {tag}: type {t} is not an integer"),
        }
    }
    fn int(&self, tag: u16) -> u64 {
        let v = self.ints(tag);
        assert_eq!(v.len(), 1, "tag {tag}");
        v[0]
    }
    fn ascii(&self, tag: u16) -> String {
        let (typ, b) = &self.tags[&tag];
        assert_eq!(*typ, 2);
        assert_eq!(b.last(), Some(&0), "ASCII tag {tag} is NUL-terminated");
        String::from_utf8(b[..b.len() - 1].to_vec()).unwrap()
    }
}

/// Every IFD of a classic little-endian TIFF, in chain order.
fn parse(bytes: &[u8]) -> Vec<Ifd> {
    let u16_at = |o: usize| u16::from_le_bytes([bytes[o], bytes[o + 1]]);
    let u32_at = |o: usize| u32::from_le_bytes(bytes[o..o + 4].try_into().unwrap()) as usize;
    assert_eq!(&bytes[..4], b"II*\0", "classic little-endian TIFF");
    let mut out = Vec::new();
    let mut at = u32_at(4);
    while at != 0 {
        let n = usize::from(u16_at(at));
        let mut tags = BTreeMap::new();
        let mut end = at + 2 + 12 * n + 4;
        let mut last_tag = 0;
        for i in 0..n {
            let e = at + 2 + 12 * i;
            let (tag, typ, count) = (u16_at(e), u16_at(e + 2), u32_at(e + 4));
            assert!(tag > last_tag, "tags sorted ascending");
            last_tag = tag;
            let size = match typ {
                2 => 1,
                3 => 2,
                4 => 4,
                5 | 12 => 8,
                t => panic!("unexpected type {t}"),
            } * count;
            let data = if size <= 4 {
                bytes[e + 8..e + 8 + size].to_vec()
            } else {
                let o = u32_at(e + 8);
                assert_eq!(o % 2, 0, "values on a word boundary");
                end = end.max(o + size);
                bytes[o..o + size].to_vec()
            };
            tags.insert(tag, (typ, data));
        }
        let next = u32_at(at + 2 + 12 * n);
        out.push(Ifd {
            offset: at,
            tags,
            end,
        });
        at = next;
    }
    out
}

/// The mean of the valid cells of each 2×2 block, computed here independently of the writer.
fn means(w: usize, h: usize, v: &[f32]) -> Vec<f32> {
    let (w2, h2) = (w.div_ceil(2), h.div_ceil(2));
    let mut out = Vec::with_capacity(w2 * h2);
    for r in 0..h2 {
        for c in 0..w2 {
            let mut cells = Vec::new();
            for rr in 2 * r..(2 * r + 2).min(h) {
                for cc in 2 * c..(2 * c + 2).min(w) {
                    cells.push(v[rr * w + cc]);
                }
            }
            let ok: Vec<f32> = cells.into_iter().filter(|x| !x.is_nan()).collect();
            out.push(if ok.is_empty() {
                f32::NAN
            } else {
                ok.iter().sum::<f32>() / ok.len() as f32
            });
        }
    }
    out
}

fn read_level(dec: &mut tiff::decoder::Decoder<std::io::Cursor<&Vec<u8>>>) -> Vec<f32> {
    match dec.read_image().unwrap() {
        tiff::decoder::DecodingResult::F32(v) => v,
        other => panic!("not f32: {:?}", std::mem::discriminant(&other)),
    }
}

/// The COG layout of a 1300×900 raster with nodata −9999: three levels (1300×900, 650×450 and,
/// since 650 > 512, 325×225), every structural rule of a COG, and the pixels of every level read
/// back with the `tiff` crate.
#[test]
fn cog_layout_and_pixels() {
    let (w, h) = (1300, 900);
    let vals = field(w, h);
    let bytes = write_float32_geotiff(w, h, &vals, &utm_georef(Some(-9999.0)));
    let ifds = parse(&bytes);

    // Levels: full resolution, then halves until the level fits one tile.
    let sizes: Vec<(u64, u64)> = ifds.iter().map(|d| (d.int(256), d.int(257))).collect();
    assert_eq!(sizes, [(1300, 900), (650, 450), (325, 225)]);
    assert_eq!(TILE, 512);
    assert_eq!(ifds[0].offset, 8, "main IFD right after the header");
    for (i, d) in ifds.iter().enumerate() {
        assert_eq!(d.int(254), u64::from(i > 0), "NewSubfileType of level {i}");
        assert_eq!((d.int(322), d.int(323)), (512, 512), "tiled, 512 px");
        assert_eq!(d.int(259), 8, "deflate");
        assert_eq!(d.int(317), 3, "floating-point predictor");
        assert_eq!(
            (d.int(258), d.int(339), d.int(277)),
            (32, 3, 1),
            "one float32 band"
        );
        assert_eq!(d.ascii(42113), "-9999", "nodata on level {i}");
        if i > 0 {
            assert!(d.offset > ifds[i - 1].offset, "IFDs by decreasing size");
            assert!(!d.tags.contains_key(&34735), "geokeys on the main IFD only");
        }
    }
    assert!(ifds[0].tags.contains_key(&34735) && ifds[0].tags.contains_key(&33550));

    // Tile data after every IFD, smallest level first, each level's tiles contiguous in
    // row-major order, the main image last and ending the file.
    let headers_end = ifds.iter().map(|d| d.end).max().unwrap();
    let mut at = headers_end.next_multiple_of(2);
    for d in ifds.iter().rev() {
        let (offsets, counts) = (d.ints(324), d.ints(325));
        let (tw, th) = (d.int(256).div_ceil(512), d.int(257).div_ceil(512));
        assert_eq!(offsets.len() as u64, tw * th);
        for (o, n) in offsets.iter().zip(&counts) {
            assert_eq!(*o as usize, at, "tiles follow each other");
            assert!(*n > 0);
            at += *n as usize;
        }
    }
    assert_eq!(at, bytes.len(), "the main image's last tile ends the file");

    // Pixels: level 0 exactly (NaN written as −9999), overviews the means of the level above.
    let mut dec = tiff::decoder::Decoder::new(std::io::Cursor::new(&bytes)).unwrap();
    let mut expect = vals.clone();
    let (mut lw, mut lh) = (w, h);
    for level in 0..ifds.len() {
        if level > 0 {
            dec.next_image().unwrap();
            expect = means(lw, lh, &expect);
            lw = lw.div_ceil(2);
            lh = lh.div_ceil(2);
        }
        let got = read_level(&mut dec);
        assert_eq!(got.len(), lw * lh, "level {level}");
        for (i, (g, e)) in got.iter().zip(&expect).enumerate() {
            if e.is_nan() {
                assert_eq!(*g, -9999.0, "level {level} cell {i}: nodata");
            } else if level == 0 {
                assert_eq!(g.to_bits(), e.to_bits(), "level 0 cell {i}: exact");
            } else {
                assert!((g - e).abs() <= 1e-6, "level {level} cell {i}: {g} vs {e}");
            }
        }
        // The next level averages what was written (with nodata as NaN again).
        expect = got
            .iter()
            .map(|&x| if x == -9999.0 { f32::NAN } else { x })
            .collect();
    }
    assert!(!dec.more_images(), "no more IFDs than levels");

    // And the DEM reader reads it back with its georeferencing.
    let back = decode_dem(&bytes, Some("snow_cover.tif"), &DemOptions::default()).unwrap();
    assert_eq!((back.width, back.height), (w, h));
    assert_eq!(back.georef.transform, utm_georef(None).transform);
    assert_eq!(back.georef.epsg, Some(32613));
    assert_eq!(back.georef.nodata, Some(-9999.0));
    assert_eq!(
        back.valid_cells(),
        vals.iter().filter(|v| !v.is_nan()).count()
    );
}

/// A raster smaller than a tile is one tile rounded up to a multiple of 16, without overviews;
/// NaN nodata stays NaN; no nodata, no tag.
#[test]
fn cog_small_rasters() {
    let vals = field(37, 23);
    let bytes = write_float32_geotiff(37, 23, &vals, &utm_georef(None));
    let ifds = parse(&bytes);
    assert_eq!(ifds.len(), 1);
    assert_eq!((ifds[0].int(322), ifds[0].int(323)), (48, 48));
    assert_eq!(ifds[0].ascii(42113), "nan");
    let mut dec = tiff::decoder::Decoder::new(std::io::Cursor::new(&bytes)).unwrap();
    let got = read_level(&mut dec);
    assert!(got
        .iter()
        .zip(&vals)
        .all(|(g, e)| g.to_bits() == e.to_bits() || (g.is_nan() && e.is_nan())));

    let clean: Vec<f32> = (0..600 * 7).map(|i| i as f32 * 0.25).collect();
    let bytes = write_float32_geotiff(600, 7, &clean, &utm_georef(None));
    let ifds = parse(&bytes);
    assert!(!ifds[0].tags.contains_key(&42113));
    // 600 px wide: one overview of 300×4.
    let sizes: Vec<(u64, u64)> = ifds.iter().map(|d| (d.int(256), d.int(257))).collect();
    assert_eq!(sizes, [(600, 7), (300, 4)]);
    let mut dec = tiff::decoder::Decoder::new(std::io::Cursor::new(&bytes)).unwrap();
    assert_eq!(read_level(&mut dec), clean);
}

const VALIDATOR: &str =
    "/usr/lib/python3/dist-packages/osgeo_utils/samples/validate_cloud_optimized_geotiff.py";

/// GDAL's COG validator accepts the file with neither error nor warning, and GDAL (libtiff)
/// reads back the same pixels, overviews, geotransform, EPSG code and nodata. Skipped (with a
/// message) where GDAL's Python bindings are not installed.
#[test]
fn cog_passes_gdal_validator() {
    // Debian's python3-gdal is for the system interpreter (a pyenv `python3` first on the PATH
    // does not see it).
    let python = ["/usr/bin/python3", "python3"].into_iter().find(|py| {
        Command::new(py)
            .args(["-c", "from osgeo import gdal"])
            .output()
            .is_ok_and(|o| o.status.success())
    });
    let (true, Some(python)) = (std::path::Path::new(VALIDATOR).exists(), python) else {
        eprintln!("skipped: GDAL's Python bindings (python3-gdal) are not installed");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (1300, 900);
    let vals = field(w, h);
    for (name, nodata) in [("m9999.tif", Some(-9999.0)), ("nan.tif", None)] {
        let path = dir.path().join(name);
        std::fs::write(
            &path,
            write_float32_geotiff(w, h, &vals, &utm_georef(nodata)),
        )
        .unwrap();
        let out = Command::new(python)
            .arg(VALIDATOR)
            .arg(&path)
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(out.status.success(), "validator refused {name}: {text}");
        assert!(
            text.contains("is a valid cloud optimized GeoTIFF"),
            "{text}"
        );
        assert!(!text.contains("warning"), "{text}");

        // GDAL reads it: pixels of the main image and first overview as raw float32.
        let raw = dir.path().join(format!("{name}.raw"));
        let ovr = dir.path().join(format!("{name}.ovr.raw"));
        let script = format!(
            "from osgeo import gdal\n\
             gdal.UseExceptions()\n\
             ds = gdal.Open({path:?})\n\
             b = ds.GetRasterBand(1)\n\
             open({raw:?}, 'wb').write(b.ReadRaster(buf_type=gdal.GDT_Float32))\n\
             o = b.GetOverview(0)\n\
             open({ovr:?}, 'wb').write(o.ReadRaster(buf_type=gdal.GDT_Float32))\n\
             print(b.GetOverviewCount(), o.XSize, o.YSize, repr(b.GetNoDataValue()))\n\
             print(*ds.GetGeoTransform())\n\
             print(ds.GetSpatialRef().GetAuthorityCode(None))\n",
            path = path.to_str().unwrap(),
            raw = raw.to_str().unwrap(),
            ovr = ovr.to_str().unwrap(),
        );
        let out = Command::new(python).args(["-c", &script]).output().unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let text = String::from_utf8_lossy(&out.stdout).to_string();
        let lines: Vec<&str> = text.lines().collect();
        let nd = if nodata.is_some() { "-9999.0" } else { "nan" };
        assert_eq!(lines[0], format!("2 650 450 {nd}"), "{text}");
        assert_eq!(lines[1], "500000.0 30.0 0.0 4100000.0 0.0 -30.0", "{text}");
        assert_eq!(lines[2], "32613", "{text}");
        let floats = |p: &std::path::Path| -> Vec<f32> {
            std::fs::read(p)
                .unwrap()
                .chunks_exact(4)
                .map(|c| f32::from_ne_bytes(c.try_into().unwrap()))
                .collect()
        };
        let fill = nodata.map_or(f32::NAN, |n| n as f32);
        let want: Vec<f32> = vals
            .iter()
            .map(|&v| if v.is_nan() { fill } else { v })
            .collect();
        let got = floats(&raw);
        assert_eq!(got.len(), want.len());
        assert!(
            got.iter()
                .zip(&want)
                .all(|(g, e)| g.to_bits() == e.to_bits() || (g.is_nan() && e.is_nan())),
            "{name}: GDAL reads other pixels"
        );
        let want_ovr = means(w, h, &vals);
        let got_ovr = floats(&ovr);
        assert_eq!(got_ovr.len(), want_ovr.len());
        for (g, e) in got_ovr.iter().zip(&want_ovr) {
            if e.is_nan() {
                assert!(g.to_bits() == fill.to_bits() || (g.is_nan() && fill.is_nan()));
            } else {
                assert!((g - e).abs() <= 1e-6, "{name} overview: {g} vs {e}");
            }
        }
    }
}
