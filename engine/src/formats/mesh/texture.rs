//! Base-colour textures of the mesh readers: PNG through `png` (0.17) and JPEG through
//! `jpeg-decoder` (0.3, both image-rs crates the engine already builds for GeoTIFF and PNG output),
//! decoded to sRGB RGBA8 for rendering ([`crate::geom::mesh::Texture`]).
//!
//! - **Formats.** PNG of any colour type and depth (expanded to 8 bits; grey becomes RGB, a
//!   missing alpha 255) and baseline/progressive JPEG (grey, RGB; CMYK is converted naively).
//!   Other formats (KTX2, WebP, …) are not decoded: the reader keeps the part's base colour and
//!   adds a note, never an error.
//! - **Limits, before decoding.** The image header's size is checked against
//!   [`super::MeshOptions::max_texture_pixels`] (default 8192², ≈ 200 MB of RGB while decoding);
//!   larger is [`InputError::TooLarge`] (a 4xx for the service) — a decompression bomb stops
//!   there. Decoded images are box-filtered down by powers of two until their side is at most
//!   `store_side` (the reader shares a storage budget of [`STORE_TEXELS`] between a file's
//!   textures), so the textures of one mesh never hold more than ~128 MB however many there are.
//!   The encoded file is kept as it was for the GLB outputs.
//! - A corrupt image is `Corrupt` only where the mesh itself says it is a PNG/JPEG; a sidecar
//!   that fails to decode gets the same default-and-note treatment as a missing one (the caller
//!   decides, see [`super::obj`] and [`super::gltf`]).

use std::sync::Arc;

use crate::error::InputError;
use crate::geom::mesh::{Texture, TextureWrap};

/// Texels all the textures of one mesh may keep after decoding (32 Mi texels = 128 MiB RGBA8).
pub const STORE_TEXELS: u64 = 32 << 20;

/// Largest stored side of one texture.
pub const MAX_STORE_SIDE: u32 = 4096;

/// The stored side for each of `count` textures: the largest power of two ≤ [`MAX_STORE_SIDE`]
/// whose square, times `count`, fits [`STORE_TEXELS`] (at least 64).
pub fn store_side(count: usize) -> u32 {
    let mut side = MAX_STORE_SIDE;
    while side > 64 && u64::from(side) * u64::from(side) * count.max(1) as u64 > STORE_TEXELS {
        side /= 2;
    }
    side
}

/// Why an image was not decoded (the reader turns it into a note or an error).
#[derive(Debug)]
pub enum ImageError {
    /// Not PNG or JPEG.
    Unsupported(String),
    /// Bad bytes.
    Corrupt(String),
    /// Over the pixel limit.
    TooLarge(InputError),
}

impl std::fmt::Display for ImageError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ImageError::Unsupported(s) | ImageError::Corrupt(s) => f.write_str(s),
            ImageError::TooLarge(e) => write!(f, "{e}"),
        }
    }
}

/// The image type from magic bytes.
pub fn image_mime(bytes: &[u8]) -> Option<&'static str> {
    if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        Some("image/png")
    } else if bytes.starts_with(&[0xFF, 0xD8, 0xFF]) {
        Some("image/jpeg")
    } else {
        None
    }
}

/// Decodes `bytes` (PNG or JPEG) into a [`Texture`] named `name`, refusing images over
/// `max_pixels` before decoding and storing at most `store_side` texels on a side (module doc).
pub fn decode_image(
    bytes: Arc<[u8]>,
    name: &str,
    wrap: [TextureWrap; 2],
    max_pixels: u64,
    store_side: u32,
) -> Result<Texture, ImageError> {
    let Some(mime) = image_mime(&bytes) else {
        return Err(ImageError::Unsupported(format!(
            "texture '{name}' is neither PNG nor JPEG"
        )));
    };
    let too_large = |w: u32, h: u32| {
        let px = u64::from(w) * u64::from(h);
        (px > max_pixels).then_some(ImageError::TooLarge(InputError::TooLarge {
            what: "texture pixels",
            actual: px,
            max: max_pixels,
        }))
    };
    let corrupt = |e: String| ImageError::Corrupt(format!("texture '{name}': {e}"));
    let (w, h, rgba) = if mime == "image/png" {
        // The size from IHDR (the first chunk, right after the signature), before the decoder
        // reads further.
        let be = |i: usize| {
            bytes
                .get(i..i + 4)
                .map(|b| u32::from_be_bytes([b[0], b[1], b[2], b[3]]))
        };
        if bytes.get(12..16) == Some(b"IHDR") {
            if let (Some(w), Some(h)) = (be(16), be(20)) {
                if let Some(e) = too_large(w, h) {
                    return Err(e);
                }
            }
        }
        let mut dec = png::Decoder::new(std::io::Cursor::new(&bytes[..]));
        dec.set_transformations(png::Transformations::normalize_to_color8());
        let mut reader = dec.read_info().map_err(|e| corrupt(e.to_string()))?;
        let (w, h) = (reader.info().width, reader.info().height);
        if let Some(e) = too_large(w, h) {
            return Err(e);
        }
        let mut buf = vec![0u8; reader.output_buffer_size()];
        let info = reader
            .next_frame(&mut buf)
            .map_err(|e| corrupt(e.to_string()))?;
        let src = &buf[..info.buffer_size()];
        let rgba: Vec<[u8; 4]> = match info.color_type {
            png::ColorType::Rgba => src
                .chunks_exact(4)
                .map(|c| [c[0], c[1], c[2], c[3]])
                .collect(),
            png::ColorType::Rgb => src
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2], 255])
                .collect(),
            png::ColorType::GrayscaleAlpha => src
                .chunks_exact(2)
                .map(|c| [c[0], c[0], c[0], c[1]])
                .collect(),
            png::ColorType::Grayscale => src.iter().map(|&g| [g, g, g, 255]).collect(),
            png::ColorType::Indexed => {
                return Err(corrupt("indexed colour was not expanded".into()));
            }
        };
        (w, h, rgba)
    } else {
        let mut dec = jpeg_decoder::Decoder::new(std::io::Cursor::new(&bytes[..]));
        dec.read_info().map_err(|e| corrupt(e.to_string()))?;
        let info = dec
            .info()
            .ok_or_else(|| corrupt("no frame header".into()))?;
        let (w, h) = (u32::from(info.width), u32::from(info.height));
        if let Some(e) = too_large(w, h) {
            return Err(e);
        }
        let px = dec.decode().map_err(|e| corrupt(e.to_string()))?;
        let rgba: Vec<[u8; 4]> = match info.pixel_format {
            jpeg_decoder::PixelFormat::L8 => px.iter().map(|&g| [g, g, g, 255]).collect(),
            jpeg_decoder::PixelFormat::L16 => px
                .chunks_exact(2)
                .map(|c| [c[0], c[0], c[0], 255])
                .collect(),
            jpeg_decoder::PixelFormat::RGB24 => px
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2], 255])
                .collect(),
            jpeg_decoder::PixelFormat::CMYK32 => px
                .chunks_exact(4)
                .map(|c| {
                    let k = u16::from(c[3]);
                    let f = |v: u8| ((u16::from(v) * k) / 255) as u8;
                    [f(c[0]), f(c[1]), f(c[2]), 255]
                })
                .collect(),
        };
        (w, h, rgba)
    };
    if w == 0 || h == 0 || rgba.len() != w as usize * h as usize {
        return Err(corrupt(format!(
            "{w} × {h} image with {} texels",
            rgba.len()
        )));
    }
    let (w, h, texels) = shrink(w, h, rgba, store_side.max(1));
    Ok(Texture {
        name: name.to_string(),
        width: w,
        height: h,
        texels,
        encoded: bytes,
        mime,
        wrap,
    })
}

/// Halves the image (2 × 2 box filter in sRGB bytes, an odd last row/column folded into its
/// neighbour) until both sides are at most `side`.
fn shrink(mut w: u32, mut h: u32, mut px: Vec<[u8; 4]>, side: u32) -> (u32, u32, Vec<[u8; 4]>) {
    while w > side || h > side {
        let (nw, nh) = (w.div_ceil(2).max(1), h.div_ceil(2).max(1));
        let mut out = Vec::with_capacity(nw as usize * nh as usize);
        for y in 0..nh {
            for x in 0..nw {
                let mut acc = [0u32; 4];
                let mut n = 0u32;
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let (sx, sy) = ((2 * x + dx).min(w - 1), (2 * y + dy).min(h - 1));
                    let p = px[(sy * w + sx) as usize];
                    for k in 0..4 {
                        acc[k] += u32::from(p[k]);
                    }
                    n += 1;
                }
                out.push(acc.map(|a| ((a + n / 2) / n) as u8));
            }
        }
        (w, h, px) = (nw, nh, out);
    }
    (w, h, px)
}
