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
//! Layout: one strip per 16 rows (or fewer), deflate, little-endian classic TIFF. Rejected: the
//! floating-point predictor (TIFF 3) would shrink files further but the `tiff` 0.9 encoder does
//! not write it; BigTIFF is not needed below 4 GiB, far above our cell limits.
//!
//! Cost: allocates the output (≈ 4 bytes per cell before compression) and one strip buffer.

use std::io::Cursor;

use tiff::encoder::{
    colortype::Gray32Float,
    compression::{Deflate, DeflateLevel},
    TiffEncoder,
};
use tiff::tags::Tag;

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
    match try_write(width, height, values, georef)
        .or_else(|_| try_write(width, height, values, &synthesized))
        .or_else(|_| try_write(width, height, values, &bare))
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

fn try_write(
    width: usize,
    height: usize,
    values: &[f32],
    georef: &GeoRef,
) -> tiff::TiffResult<Vec<u8>> {
    let w = u32::try_from(width).map_err(|_| tiff::TiffError::LimitsExceeded)?;
    let h = u32::try_from(height).map_err(|_| tiff::TiffError::LimitsExceeded)?;
    let has_nan = values.iter().any(|v| v.is_nan());
    let nodata = match georef.nodata {
        Some(n) => Some(n),
        None if has_nan => Some(f64::NAN),
        None => None,
    };
    let fill = nodata.map(|n| n as f32);
    let data: std::borrow::Cow<[f32]> = match fill {
        Some(f) if has_nan && !f.is_nan() => values
            .iter()
            .map(|&v| if v.is_nan() { f } else { v })
            .collect::<Vec<_>>()
            .into(),
        _ => values.into(),
    };

    let tags: GeoTags = if georef.tags == GeoTags::default() {
        synthesize_tags(georef.transform, georef.epsg, georef.geographic)
    } else {
        georef.tags.clone()
    };

    let mut out = Cursor::new(Vec::with_capacity(values.len() * 4 / 2 + 1024));
    {
        let mut enc = TiffEncoder::new(&mut out)?;
        let mut image = enc.new_image_with_compression::<Gray32Float, _>(
            w,
            h,
            // Fast: float heights barely compress at higher levels (no float predictor in
            // tiff 0.9); level 6 made the whole encode stage of a 4096² run take 1.4 s,
            // level 1 about 0.5 s (CLI on a 4096² .npy, load 3.9).
            Deflate::with_level(DeflateLevel::Fast),
        )?;
        image.rows_per_strip(16.min(h))?;
        let dir = image.encoder();
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
        image.write_data(&data)?;
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
