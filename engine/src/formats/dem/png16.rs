//! Greyscale PNG height maps: height = stored value × `vertical_scale` (default 1 m per unit),
//! cell size from `cell_size` (required, [`ParamError`] on field `cell_size` when missing); no
//! georeferencing, no nodata (every value is a height; 0 is a valid elevation).
//!
//! 16-bit greyscale is the format the SPEC names. 8-bit greyscale is accepted too (values
//! 0–255 × `vertical_scale`), since many height-map tools export it and the meaning is the same;
//! with the alpha channel (grey + alpha), alpha 0 marks nodata. Colour and palette PNGs are
//! refused ([`InputError::UnsupportedFormat`]): there is no single right way to turn RGB into a
//! height (Mapbox/Terrarium encodings differ), and guessing silently would be worse than saying
//! so.
//!
//! The IHDR size is checked against `max_cells` before the image is decoded, and the `png`
//! crate's own memory limit is set to the decoded size of that many 16-bit grey + alpha pixels.

use png::{BitDepth, ColorType, Transformations};

use super::{check_cells, required_cell_size, DemOptions};
use crate::error::InputError;
use crate::geom::heightfield::{Dem, GeoRef};

const FORMAT: &str = "PNG";

fn corrupt(e: impl std::fmt::Display) -> InputError {
    InputError::Corrupt {
        format: FORMAT,
        detail: e.to_string(),
    }
}

pub(super) fn decode(bytes: &[u8], opts: &DemOptions) -> Result<Dem, InputError> {
    // IHDR is the first chunk (signature 8 bytes, length 4, type 4, then width and height):
    // refuse absurd sizes before the png crate reads any further.
    if let (Some(b"IHDR"), Some(w), Some(h)) =
        (bytes.get(12..16), bytes.get(16..20), bytes.get(20..24))
    {
        let w = u32::from_be_bytes([w[0], w[1], w[2], w[3]]);
        let h = u32::from_be_bytes([h[0], h[1], h[2], h[3]]);
        check_cells(u64::from(w), u64::from(h), opts.max_cells)?;
    }
    let limit = usize::try_from(opts.max_cells.saturating_mul(4)).unwrap_or(usize::MAX);
    let mut decoder = png::Decoder::new_with_limits(bytes, png::Limits { bytes: limit });
    decoder.set_transformations(Transformations::IDENTITY);
    let mut reader = decoder.read_info().map_err(|e| match e {
        png::DecodingError::LimitsExceeded => InputError::TooLarge {
            what: "PNG decoded size (bytes)",
            actual: 0,
            max: limit as u64,
        },
        other => corrupt(other),
    })?;
    let (w, h, color, depth) = {
        let info = reader.info();
        (info.width, info.height, info.color_type, info.bit_depth)
    };
    check_cells(u64::from(w), u64::from(h), opts.max_cells)?;
    let channels = match color {
        ColorType::Grayscale => 1,
        ColorType::GrayscaleAlpha => 2,
        other => {
            return Err(InputError::UnsupportedFormat(format!(
                "PNG colour type {other:?}; height maps must be greyscale (16-bit, or 8-bit)"
            )))
        }
    };
    let bytes_per_sample = match depth {
        BitDepth::Sixteen => 2,
        BitDepth::Eight => 1,
        other => {
            return Err(InputError::UnsupportedFormat(format!(
                "PNG bit depth {other:?}; height maps must be 16- or 8-bit greyscale"
            )))
        }
    };
    let cell = required_cell_size(opts, "PNG")?;
    let scale = opts.vertical_scale.unwrap_or(1.0);

    let mut buf = vec![0u8; reader.output_buffer_size()];
    let frame = reader.next_frame(&mut buf).map_err(corrupt)?;
    let (width, height) = (w as usize, h as usize);
    let line = frame.line_size;
    let mut heights = Vec::with_capacity(width * height);
    for row in 0..height {
        let start = row * line;
        let data = buf
            .get(start..start + width * channels * bytes_per_sample)
            .ok_or_else(|| corrupt("decoded image shorter than its header says"))?;
        for px in data.chunks_exact(channels * bytes_per_sample) {
            let (v, alpha) = if bytes_per_sample == 2 {
                let v = u16::from_be_bytes([px[0], px[1]]);
                let a = (channels == 2).then(|| u16::from_be_bytes([px[2], px[3]]));
                (f64::from(v), a.map(u32::from))
            } else {
                (f64::from(px[0]), (channels == 2).then(|| u32::from(px[1])))
            };
            heights.push(if alpha == Some(0) {
                f32::NAN
            } else {
                (v * scale) as f32
            });
        }
    }
    Ok(Dem {
        width,
        height,
        heights,
        dx: cell,
        dy: cell,
        georef: GeoRef::default(),
    })
}
