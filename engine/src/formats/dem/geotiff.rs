//! GeoTIFF (and plain TIFF) DEMs through the `tiff` crate: 8/16/32/64-bit integer and 32/64-bit
//! float samples, stripped or tiled, uncompressed/deflate/LZW/PackBits, with or without a
//! predictor, classic TIFF or BigTIFF.
//!
//! - Nodata: GDAL_NODATA (tag 42113, ASCII, e.g. `"-32768"`, `"nan"`) → NaN in the heights. The
//!   comparison is made in the stored type (float32 data against the value rounded to f32, which
//!   is how GDAL matches `-3.4028234663852886e+38`).
//! - Georeferencing: ModelTransformation, else ModelTiepoint + ModelPixelScale → GDAL transform
//!   (PixelIsPoint shifted half a cell, as GDAL does). The GeoKeyDirectory gives the EPSG code
//!   and whether the CRS is geographic. All six raw geo tags are kept in [`GeoTags`] so that the
//!   writer copies them verbatim.
//! - A TIFF without georeferencing needs `cell_size`, like a PNG.
//! - Multi-band images: band 1 is the DEM (interleaved samples only).
//!
//! The declared width × height is checked against `max_cells` from the first IFD, before any
//! pixel data is decoded, and the decoder's own `Limits` cap its buffer at `max_cells` samples
//! of 8 bytes.

use std::io::Cursor;

use tiff::decoder::{Decoder, DecodingResult, Limits};
use tiff::tags::Tag;
use tiff::ColorType;

use super::geo::{cell_size_metres, crs_info, transform_from_tags};
use super::{check_cells, required_cell_size, DemOptions};
use crate::error::InputError;
use crate::geom::heightfield::{Dem, GeoRef, GeoTags};

const FORMAT: &str = "GeoTIFF";

fn corrupt(e: impl std::fmt::Display) -> InputError {
    InputError::Corrupt {
        format: FORMAT,
        detail: e.to_string(),
    }
}

pub(crate) fn map_tiff_err(e: tiff::TiffError) -> InputError {
    match e {
        tiff::TiffError::UnsupportedError(u) => {
            InputError::UnsupportedFormat(format!("TIFF variant not supported: {u}"))
        }
        tiff::TiffError::LimitsExceeded => {
            corrupt("a tag, strip or tile is larger than the image it belongs to allows")
        }
        other => corrupt(other),
    }
}

pub(super) fn decode(bytes: &[u8], opts: &DemOptions) -> Result<Dem, InputError> {
    let mut limits = Limits::default();
    // Room for max_cells samples of the widest type (f64/i64), so a legitimately large DEM under
    // the cell limit decodes, and nothing larger is ever allocated by the decoder.
    let limit = usize::try_from(opts.max_cells.saturating_mul(8)).unwrap_or(usize::MAX);
    limits.decoding_buffer_size = limit;
    limits.intermediate_buffer_size = limit;
    let mut dec = Decoder::new(Cursor::new(bytes))
        .map_err(map_tiff_err)?
        .with_limits(limits);
    let (w, h) = dec.dimensions().map_err(map_tiff_err)?;
    check_cells(u64::from(w), u64::from(h), opts.max_cells)?;
    let (width, height) = (w as usize, h as usize);

    let (samples, bits) = match dec.colortype().map_err(map_tiff_err)? {
        ColorType::Gray(b) => (1, b),
        ColorType::GrayA(b) => (2, b),
        ColorType::RGB(b) => (3, b),
        ColorType::RGBA(b) | ColorType::CMYK(b) => (4, b),
        other => {
            return Err(InputError::UnsupportedFormat(format!(
                "TIFF colour type {other:?} is not an elevation band"
            )))
        }
    };

    let tags = read_geo_tags(&mut dec)?;
    let nodata = match dec.find_tag(Tag::GdalNodata).map_err(map_tiff_err)? {
        Some(v) => parse_nodata(&v.into_string().map_err(map_tiff_err)?),
        None => None,
    };

    // The whole decoded image (all bands) must fit in the decoder's buffer limit.
    let decoded_bytes = u64::from(w) * u64::from(h) * samples as u64 * u64::from(bits).div_ceil(8);
    if decoded_bytes > limit as u64 {
        return Err(InputError::TooLarge {
            what: "decoded TIFF bytes (all bands)",
            actual: decoded_bytes,
            max: limit as u64,
        });
    }
    let image = dec.read_image().map_err(map_tiff_err)?;
    let heights = to_heights(image, width * height, samples, nodata)?;

    let crs = crs_info(&tags);
    let transform = transform_from_tags(&tags, crs.pixel_is_point);
    let (dx, dy) = match transform {
        Some(t) => cell_size_metres(&t, width, height, crs.geographic, crs.linear_unit),
        None => {
            let c = required_cell_size(opts, "a TIFF without georeferencing")?;
            (c, c)
        }
    };
    Ok(Dem {
        width,
        height,
        heights,
        dx,
        dy,
        georef: GeoRef {
            transform,
            epsg: crs.epsg,
            geographic: crs.geographic,
            nodata,
            tags,
        },
    })
}

/// Parse a GDAL_NODATA string; `None` if it is not a number (GDAL ignores such values too).
pub(crate) fn parse_nodata(s: &str) -> Option<f64> {
    let s = s.trim_matches(|c: char| c == '\0' || c.is_whitespace());
    s.parse::<f64>().ok()
}

pub(crate) fn read_geo_tags<R: std::io::Read + std::io::Seek>(
    dec: &mut Decoder<R>,
) -> Result<GeoTags, InputError> {
    let mut f64s = |tag: Tag| -> Result<Option<Vec<f64>>, InputError> {
        match dec.find_tag(tag).map_err(map_tiff_err)? {
            Some(v) => Ok(Some(v.into_f64_vec().map_err(map_tiff_err)?)),
            None => Ok(None),
        }
    };
    let pixel_scale = f64s(Tag::ModelPixelScaleTag)?;
    let tiepoint = f64s(Tag::ModelTiepointTag)?;
    let transformation = f64s(Tag::ModelTransformationTag)?;
    let geo_double_params = f64s(Tag::GeoDoubleParamsTag)?;
    let geo_key_directory = match dec
        .find_tag(Tag::GeoKeyDirectoryTag)
        .map_err(map_tiff_err)?
    {
        Some(v) => Some(v.into_u16_vec().map_err(map_tiff_err)?),
        None => None,
    };
    let geo_ascii_params = match dec.find_tag(Tag::GeoAsciiParamsTag).map_err(map_tiff_err)? {
        Some(v) => Some(
            v.into_string()
                .map_err(map_tiff_err)?
                .trim_end_matches('\0')
                .to_string(),
        ),
        None => None,
    };
    Ok(GeoTags {
        pixel_scale,
        tiepoint,
        transformation,
        geo_key_directory,
        geo_double_params,
        geo_ascii_params,
    })
}

/// Band 1 of the decoded samples as f32 heights, nodata → NaN.
pub(crate) fn to_heights(
    image: DecodingResult,
    cells: usize,
    samples: usize,
    nodata: Option<f64>,
) -> Result<Vec<f32>, InputError> {
    fn enough(len: usize, needed: usize) -> Result<(), InputError> {
        if len < needed {
            return Err(corrupt(format!("decoded {len} samples, expected {needed}")));
        }
        Ok(())
    }
    fn band<T: Copy>(
        v: &[T],
        cells: usize,
        samples: usize,
        f: impl Fn(T) -> f32,
    ) -> Result<Vec<f32>, InputError> {
        enough(v.len(), cells.saturating_mul(samples))?;
        Ok(v.iter()
            .step_by(samples)
            .take(cells)
            .map(|&x| f(x))
            .collect())
    }
    // Integer data: compare in f64 (exact for every integer type up to 2^53).
    let nd = nodata;
    let int = move |x: f64| -> f32 {
        if nd == Some(x) {
            f32::NAN
        } else {
            x as f32
        }
    };
    let nd32 = nodata.map(|n| n as f32);
    let float = |x: f32| match nd32 {
        Some(n) if x == n || (n.is_nan() && x.is_nan()) => f32::NAN,
        _ => x,
    };
    match image {
        DecodingResult::U8(v) => band(&v, cells, samples, |x| int(f64::from(x))),
        DecodingResult::I8(v) => band(&v, cells, samples, |x| int(f64::from(x))),
        DecodingResult::U16(v) => band(&v, cells, samples, |x| int(f64::from(x))),
        DecodingResult::I16(v) => band(&v, cells, samples, |x| int(f64::from(x))),
        DecodingResult::U32(v) => band(&v, cells, samples, |x| int(f64::from(x))),
        DecodingResult::I32(v) => band(&v, cells, samples, |x| int(f64::from(x))),
        DecodingResult::U64(v) => band(&v, cells, samples, |x| int(x as f64)),
        DecodingResult::I64(v) => band(&v, cells, samples, |x| int(x as f64)),
        // One f32 band (the usual float DEM): the decoder's buffer becomes the heights, nodata
        // replaced in place, instead of a copy into a second grid of the same size.
        DecodingResult::F32(mut v) if samples == 1 => {
            enough(v.len(), cells)?;
            v.truncate(cells);
            if nd32.is_some() {
                v.iter_mut().for_each(|x| *x = float(*x));
            }
            Ok(v)
        }
        DecodingResult::F32(v) => band(&v, cells, samples, float),
        DecodingResult::F64(v) => band(&v, cells, samples, |x| match nodata {
            Some(n) if x == n || (n.is_nan() && x.is_nan()) => f32::NAN,
            _ => x as f32,
        }),
    }
}
