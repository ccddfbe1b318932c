//! Orthophotos (SPEC §1 step 7, the rock colour from an image): RGB or RGBA GeoTIFF, PNG or
//! JPEG, 8 or 16 bits per sample (16-bit samples keep their high byte; grey is expanded to RGB).
//! The format is told by the file's magic bytes (the name is not needed: an asset named by id
//! has none).
//!
//! - **GeoTIFF** through the `tiff` crate, with the DEM reader's georeferencing (ModelTransformation
//!   or ModelTiepoint + ModelPixelScale; the GeoKeys' EPSG code): an ortho that has it is placed
//!   by it. A TIFF without georeferencing is a plain image.
//! - **PNG** through the `png` crate and **JPEG** through `jpeg-decoder` (the baseline and
//!   progressive decoder the `tiff` crate already uses for JPEG-compressed TIFFs): plain
//!   images, stretched over the DEM's extent by the pipeline.
//!
//! Every decoder reads the header first and refuses an image of more than `max_pixels` pixels
//! with [`InputError::TooLarge`] (413) before any pixel buffer is allocated.

use std::io::Cursor;

use tiff::decoder::{Decoder, DecodingResult, Limits};
use tiff::ColorType;

use super::dem::geo::{crs_info, transform_from_tags};
use super::dem::geotiff::{map_tiff_err, read_geo_tags};
use crate::error::InputError;

/// A decoded orthophoto: straight-alpha sRGB bytes, row 0 at the top (north).
#[derive(Debug, Clone, PartialEq)]
pub struct Ortho {
    pub width: usize,
    pub height: usize,
    /// `width × height` RGBA (alpha 255 for RGB images).
    pub rgba: Vec<[u8; 4]>,
    /// Where the image lies, when the file says (GeoTIFF).
    pub georef: Option<OrthoGeoref>,
    /// `"GeoTIFF"`, `"TIFF"`, `"PNG"` or `"JPEG"`.
    pub format: &'static str,
}

/// An ortho's georeferencing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrthoGeoref {
    /// GDAL-style affine transform of pixel corners (see [`crate::geom::heightfield::GeoRef`]).
    pub transform: [f64; 6],
    /// EPSG code of the CRS when the GeoKeys give one.
    pub epsg: Option<u32>,
    pub geographic: bool,
}

fn corrupt(format: &'static str, e: impl std::fmt::Display) -> InputError {
    InputError::Corrupt {
        format,
        detail: e.to_string(),
    }
}

fn check_pixels(w: u64, h: u64, max_pixels: u64) -> Result<(), InputError> {
    if w == 0 || h == 0 {
        return Err(InputError::Unusable(format!(
            "the orthophoto is {w} × {h} pixels; it needs at least one"
        )));
    }
    let n = w.saturating_mul(h);
    if n > max_pixels {
        return Err(InputError::TooLarge {
            what: "orthophoto pixels",
            actual: n,
            max: max_pixels,
        });
    }
    Ok(())
}

/// Decodes an orthophoto (see the module doc).
pub fn decode_ortho(bytes: &[u8], max_pixels: u64) -> Result<Ortho, InputError> {
    if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        decode_png(bytes, max_pixels)
    } else if bytes.starts_with(&[0xFF, 0xD8, 0xFF]) {
        decode_jpeg(bytes, max_pixels)
    } else if bytes.starts_with(b"II*\0")
        || bytes.starts_with(b"MM\0*")
        || bytes.starts_with(b"II+\0")
        || bytes.starts_with(b"MM\0+")
    {
        decode_tiff(bytes, max_pixels)
    } else {
        Err(InputError::UnsupportedFormat(
            "the orthophoto must be a GeoTIFF/TIFF, PNG or JPEG image".into(),
        ))
    }
}

/// Interleaved samples (`channels` per pixel, 1–4) → RGBA.
fn to_rgba(samples: &[u8], channels: usize) -> Vec<[u8; 4]> {
    samples
        .chunks_exact(channels)
        .map(|p| match channels {
            1 => [p[0], p[0], p[0], 255],
            2 => [p[0], p[0], p[0], p[1]],
            3 => [p[0], p[1], p[2], 255],
            _ => [p[0], p[1], p[2], p[3]],
        })
        .collect()
}

fn decode_png(bytes: &[u8], max_pixels: u64) -> Result<Ortho, InputError> {
    const F: &str = "PNG";
    let mut dec = png::Decoder::new(Cursor::new(bytes));
    dec.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    // The header alone (read_header_info) is enough for the size check.
    let (w, h) = {
        let info = dec.read_header_info().map_err(|e| corrupt(F, e))?;
        (info.width, info.height)
    };
    check_pixels(u64::from(w), u64::from(h), max_pixels)?;
    let mut reader = dec.read_info().map_err(|e| corrupt(F, e))?;
    let (ct, _) = reader.output_color_type();
    let channels = match ct {
        png::ColorType::Grayscale => 1,
        png::ColorType::GrayscaleAlpha => 2,
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        png::ColorType::Indexed => {
            return Err(corrupt(F, "palette not expanded"));
        }
    };
    let mut buf = vec![0u8; reader.output_buffer_size()];
    let frame = reader.next_frame(&mut buf).map_err(|e| corrupt(F, e))?;
    buf.truncate(frame.buffer_size());
    let (width, height) = (w as usize, h as usize);
    let line = frame.line_size;
    let mut rgba = Vec::with_capacity(width * height);
    for row in buf.chunks_exact(line).take(height) {
        rgba.extend(to_rgba(&row[..width * channels], channels));
    }
    if rgba.len() != width * height {
        return Err(corrupt(F, "truncated image data"));
    }
    Ok(Ortho {
        width,
        height,
        rgba,
        georef: None,
        format: F,
    })
}

fn decode_jpeg(bytes: &[u8], max_pixels: u64) -> Result<Ortho, InputError> {
    const F: &str = "JPEG";
    let mut dec = jpeg_decoder::Decoder::new(Cursor::new(bytes));
    dec.read_info().map_err(|e| corrupt(F, e))?;
    let info = dec.info().ok_or_else(|| corrupt(F, "no frame header"))?;
    check_pixels(u64::from(info.width), u64::from(info.height), max_pixels)?;
    dec.set_max_decoding_buffer_size(
        usize::try_from(max_pixels.saturating_mul(4)).unwrap_or(usize::MAX),
    );
    let pixels = dec.decode().map_err(|e| corrupt(F, e))?;
    let rgba = match info.pixel_format {
        jpeg_decoder::PixelFormat::L8 => to_rgba(&pixels, 1),
        jpeg_decoder::PixelFormat::L16 => {
            // Big-endian 16-bit grey: keep the high byte.
            let hi: Vec<u8> = pixels.chunks_exact(2).map(|p| p[0]).collect();
            to_rgba(&hi, 1)
        }
        jpeg_decoder::PixelFormat::RGB24 => to_rgba(&pixels, 3),
        jpeg_decoder::PixelFormat::CMYK32 => {
            return Err(InputError::UnsupportedFormat(
                "CMYK JPEG orthophotos are not supported; send RGB".into(),
            ))
        }
    };
    let (width, height) = (usize::from(info.width), usize::from(info.height));
    if rgba.len() != width * height {
        return Err(corrupt(F, "truncated image data"));
    }
    Ok(Ortho {
        width,
        height,
        rgba,
        georef: None,
        format: F,
    })
}

fn decode_tiff(bytes: &[u8], max_pixels: u64) -> Result<Ortho, InputError> {
    let mut limits = Limits::default();
    // Room for max_pixels pixels of 4 samples of 16 bits.
    let limit = usize::try_from(max_pixels.saturating_mul(8)).unwrap_or(usize::MAX);
    limits.decoding_buffer_size = limit;
    limits.intermediate_buffer_size = limit;
    let mut dec = Decoder::new(Cursor::new(bytes))
        .map_err(map_tiff_err)?
        .with_limits(limits);
    let (w, h) = dec.dimensions().map_err(map_tiff_err)?;
    check_pixels(u64::from(w), u64::from(h), max_pixels)?;
    let (channels, bits) = match dec.colortype().map_err(map_tiff_err)? {
        ColorType::Gray(b) => (1, b),
        ColorType::GrayA(b) => (2, b),
        ColorType::RGB(b) => (3, b),
        ColorType::RGBA(b) => (4, b),
        other => {
            return Err(InputError::UnsupportedFormat(format!(
                "TIFF colour type {other:?}: the orthophoto must be RGB, RGBA or grey"
            )))
        }
    };
    if bits != 8 && bits != 16 {
        return Err(InputError::UnsupportedFormat(format!(
            "{bits}-bit TIFF samples: the orthophoto must have 8 or 16 bits per sample"
        )));
    }
    let tags = read_geo_tags(&mut dec)?;
    let samples: Vec<u8> = match dec.read_image().map_err(map_tiff_err)? {
        DecodingResult::U8(v) => v,
        DecodingResult::U16(v) => v.iter().map(|s| (s >> 8) as u8).collect(),
        _ => {
            return Err(InputError::UnsupportedFormat(
                "the orthophoto's TIFF samples must be unsigned integers".into(),
            ))
        }
    };
    let (width, height) = (w as usize, h as usize);
    if samples.len() < width * height * channels {
        return Err(corrupt("TIFF", "truncated image data"));
    }
    let rgba = to_rgba(&samples[..width * height * channels], channels);
    let crs = crs_info(&tags);
    let georef = transform_from_tags(&tags, crs.pixel_is_point).map(|transform| OrthoGeoref {
        transform,
        epsg: crs.epsg,
        geographic: crs.geographic,
    });
    Ok(Ortho {
        width,
        height,
        rgba,
        format: if georef.is_some() { "GeoTIFF" } else { "TIFF" },
        georef,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn png_rgb(w: u32, h: u32) -> Vec<u8> {
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, w, h);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            let mut wr = enc.write_header().unwrap();
            let data: Vec<u8> = (0..w * h * 3).map(|i| (i % 251) as u8).collect();
            wr.write_image_data(&data).unwrap();
        }
        out
    }

    #[test]
    fn png_decodes_and_the_limit_is_checked_first() {
        let bytes = png_rgb(7, 5);
        let o = decode_ortho(&bytes, 1000).unwrap();
        assert_eq!((o.width, o.height, o.format), (7, 5, "PNG"));
        assert_eq!(o.rgba[1], [3, 4, 5, 255]);
        assert!(o.georef.is_none());
        assert!(matches!(
            decode_ortho(&bytes, 34),
            Err(InputError::TooLarge { actual: 35, .. })
        ));
    }

    #[test]
    fn garbage_is_refused() {
        assert!(matches!(
            decode_ortho(b"hello", 100),
            Err(InputError::UnsupportedFormat(_))
        ));
        let mut bytes = png_rgb(7, 5);
        bytes.truncate(40);
        assert!(decode_ortho(&bytes, 1000).is_err());
        assert!(decode_ortho(&[0xFF, 0xD8, 0xFF, 0xE0, 0, 1], 1000).is_err());
        assert!(decode_ortho(b"II*\0\x08\0\0\0\0\0", 1000).is_err());
    }
}
