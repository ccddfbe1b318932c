//! Float32 single-band GeoTIFF writer for raster outputs (`snow_cover.tif`, SPEC §1 *Outputs*):
//! same size, georeferencing, CRS and nodata as the input DEM.
//!
//! The geo tags of the input ([`GeoTags`]) are copied verbatim, with GDAL's types: 33550, 33922,
//! 34264 and 34736 as DOUBLE, 34735 as SHORT, 34737 and GDAL_NODATA (42113) as ASCII. A
//! `GeoRef` that has a transform but no tags (built by hand) gets synthesised ones
//! ([`crate::formats::dem::synthesize_tags`]).
//!
//! Nodata: NaN cells are written as the input's nodata value (rounded to f32) and the tag
//! repeats that value (`"-32768"`, `"nan"`); without an input nodata value but with NaN cells,
//! NaN is written and tagged `"nan"`.
//!
//! Layout: one strip per 16 rows (or fewer), deflate (level 1), classic TIFF in the machine's
//! byte order (little-endian on x86). The strips are compressed in parallel (rayon + flate2)
//! and handed to the `tiff` crate's directory encoder as raw bytes with their offsets, since
//! its image encoder compresses strip after strip on one thread (4096²: ≈ 0.5 s of the job's
//! encode stage on one core). Rejected: the
//! floating-point predictor (TIFF 3) would shrink files further but the `tiff` 0.9 encoder does
//! not write it; BigTIFF is not needed below 4 GiB, far above our cell limits.
//!
//! Cost: allocates the compressed strips and the output (each ≈ 2–4 bytes per cell) and one raw
//! strip per worker.

use std::io::{Cursor, Write};

use flate2::write::ZlibEncoder;
use rayon::prelude::*;
use tiff::encoder::{Rational, TiffEncoder};
use tiff::tags::{CompressionMethod, PhotometricInterpretation, ResolutionUnit, SampleFormat, Tag};

use crate::formats::dem::synthesize_tags;
use crate::geom::heightfield::{GeoRef, GeoTags};

/// Float32 single-band GeoTIFF of `values` (row-major, width×height) with the georeferencing, CRS
/// and nodata of `georef` copied from the input. NaN cells are written as the input's nodata value
/// (GDAL_NODATA tag 42113 as ASCII, e.g. "-32768" or "nan"); if the input had no nodata value but
/// there are NaN cells, write NaN and tag "nan".
///
/// # Panics
/// If `values.len() != width * height`, a side is 0 or larger than `u32::MAX` (caller bugs);
/// encoding into memory cannot otherwise fail.
pub fn write_float32_geotiff(
    width: usize,
    height: usize,
    values: &[f32],
    georef: &GeoRef,
) -> Vec<u8> {
    assert!(
        width > 0 && height > 0 && values.len() == width.saturating_mul(height),
        "write_float32_geotiff: {width}×{height} grid with {} values",
        values.len()
    );
    // The geo tags come from the input file; should the encoder refuse them, fall back to tags
    // synthesised from the transform, then to none, rather than fail the job.
    let synthesized = GeoRef {
        tags: GeoTags::default(),
        ..georef.clone()
    };
    let bare = GeoRef {
        nodata: georef.nodata,
        ..GeoRef::default()
    };
    let nodata = nodata_of(values, georef);
    let strips = deflate_strips(width, height, values, nodata.map(|n| n as f32));
    let write = |g: &GeoRef| try_write(width, height, &strips, nodata, g);
    match write(georef)
        .or_else(|_| write(&synthesized))
        .or_else(|_| write(&bare))
    {
        Ok(bytes) => bytes,
        // A plain float32 TIFF of a checked size into memory cannot fail.
        Err(e) => panic!("write_float32_geotiff: in-memory TIFF encoding failed: {e}"),
    }
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

/// The image data: strips of 16 rows (or fewer), NaN replaced by `fill` when it is a number,
/// each deflated (its own zlib stream, as TIFF requires) in parallel. The result does not
/// depend on the thread count.
fn deflate_strips(width: usize, height: usize, values: &[f32], fill: Option<f32>) -> Vec<Vec<u8>> {
    let fill = fill.filter(|f| !f.is_nan());
    values
        .par_chunks(16.min(height) * width)
        .map(|strip| {
            let mut raw = Vec::with_capacity(strip.len() * 4);
            for &v in strip {
                let v = match fill {
                    Some(f) if v.is_nan() => f,
                    _ => v,
                };
                // The tiff crate writes the byte order of the machine ("II" on x86).
                raw.extend_from_slice(&v.to_ne_bytes());
            }
            // Fast: float heights barely compress at higher levels (no float predictor in
            // tiff 0.9); level 6 made the whole encode stage of a 4096² run take 1.4 s, level 1
            // about 0.5 s on one thread (CLI on a 4096² .npy, load 3.9).
            let mut z = ZlibEncoder::new(
                Vec::with_capacity(raw.len() / 2 + 64),
                flate2::Compression::fast(),
            );
            // Writing into a Vec cannot fail.
            let _ = z.write_all(&raw);
            z.finish().unwrap_or_default()
        })
        .collect()
}

/// The nodata value written for NaN cells (see [`write_float32_geotiff`]).
fn nodata_of(values: &[f32], georef: &GeoRef) -> Option<f64> {
    match georef.nodata {
        Some(n) => Some(n),
        None if values.par_iter().any(|v| v.is_nan()) => Some(f64::NAN),
        None => None,
    }
}

fn try_write(
    width: usize,
    height: usize,
    strips: &[Vec<u8>],
    nodata: Option<f64>,
    georef: &GeoRef,
) -> tiff::TiffResult<Vec<u8>> {
    let w = u32::try_from(width).map_err(|_| tiff::TiffError::LimitsExceeded)?;
    let h = u32::try_from(height).map_err(|_| tiff::TiffError::LimitsExceeded)?;
    let rows = 16.min(h);
    let tags: GeoTags = if georef.tags == GeoTags::default() {
        synthesize_tags(georef.transform, georef.epsg, georef.geographic)
    } else {
        georef.tags.clone()
    };
    let total: usize = strips.iter().map(Vec::len).sum();
    let mut out = Cursor::new(Vec::with_capacity(total + 4096));
    {
        let mut enc = TiffEncoder::new(&mut out)?;
        let mut dir = enc.new_directory()?;
        let mut offsets = Vec::with_capacity(strips.len());
        let mut counts = Vec::with_capacity(strips.len());
        for st in strips {
            let off = dir.write_data(st.as_slice())?;
            offsets.push(u32::try_from(off)?);
            counts.push(u32::try_from(st.len())?);
        }
        dir.write_tag(Tag::ImageWidth, w)?;
        dir.write_tag(Tag::ImageLength, h)?;
        dir.write_tag(Tag::Compression, CompressionMethod::Deflate.to_u16())?;
        dir.write_tag(Tag::BitsPerSample, &[32u16][..])?;
        dir.write_tag(Tag::SampleFormat, &[SampleFormat::IEEEFP.to_u16()][..])?;
        dir.write_tag(
            Tag::PhotometricInterpretation,
            PhotometricInterpretation::BlackIsZero.to_u16(),
        )?;
        dir.write_tag(Tag::RowsPerStrip, rows)?;
        dir.write_tag(Tag::SamplesPerPixel, 1u16)?;
        dir.write_tag(Tag::StripOffsets, offsets.as_slice())?;
        dir.write_tag(Tag::StripByteCounts, counts.as_slice())?;
        dir.write_tag(Tag::XResolution, Rational { n: 1, d: 1 })?;
        dir.write_tag(Tag::YResolution, Rational { n: 1, d: 1 })?;
        dir.write_tag(Tag::ResolutionUnit, ResolutionUnit::None.to_u16())?;
        if let Some(v) = &tags.pixel_scale {
            dir.write_tag(Tag::ModelPixelScaleTag, v.as_slice())?;
        }
        if let Some(v) = &tags.tiepoint {
            dir.write_tag(Tag::ModelTiepointTag, v.as_slice())?;
        }
        if let Some(v) = &tags.transformation {
            dir.write_tag(Tag::ModelTransformationTag, v.as_slice())?;
        }
        if let Some(v) = &tags.geo_key_directory {
            dir.write_tag(Tag::GeoKeyDirectoryTag, v.as_slice())?;
        }
        if let Some(v) = &tags.geo_double_params {
            dir.write_tag(Tag::GeoDoubleParamsTag, v.as_slice())?;
        }
        if let Some(v) = &tags.geo_ascii_params {
            // The tiff crate refuses non-ASCII or NUL bytes; drop such characters rather than
            // the whole tag.
            let clean: String = v.chars().filter(|c| c.is_ascii() && *c != '\0').collect();
            dir.write_tag(Tag::GeoAsciiParamsTag, clean.as_str())?;
        }
        if let Some(n) = nodata {
            dir.write_tag(Tag::GdalNodata, nodata_text(n).as_str())?;
        }
        dir.finish()?;
    }
    Ok(out.into_inner())
}

#[cfg(test)]
mod tests {
    use super::nodata_text;

    #[test]
    fn nodata_texts_parse_back() {
        for v in [-32768.0, 0.0, -9999.0, -3.4028234663852886e38, 1.5, 1e-30] {
            let t = nodata_text(v);
            assert_eq!(t.parse::<f64>(), Ok(v), "{t}");
        }
        assert_eq!(nodata_text(-32768.0), "-32768");
        assert_eq!(nodata_text(f64::NAN), "nan");
    }
}
