//! PNG encoders for rendered images and 8-bit previews (png crate).
//!
//! Images go out with the sRGB chunk (they are sRGB-encoded) and the *fast* deflate setting with
//! the `Sub` filter: on a 1920×1080 render that costs a few tens of milliseconds and a file
//! ~1.3× the size of the default setting, which spent several times longer for the same pixels.
//! Encoding into a `Vec` cannot fail for valid dimensions; the `png` errors that remain (a buffer
//! whose length disagrees with the dimensions) are caller bugs and panic.

use crate::render::image::RgbaImage;

/// Encode an 8-bit sRGB RGBA image (straight alpha) as PNG. Allocates the output (~1–3 bytes per
/// pixel for renders). Panics when `img.data.len() != 4·width·height`.
pub fn encode_rgba(img: &RgbaImage) -> Vec<u8> {
    encode(img.width, img.height, png::ColorType::Rgba, &img.data)
}

/// Encode an 8-bit greyscale image (e.g. the descriptor preview). Panics when
/// `pixels.len() != width·height`.
pub fn encode_gray8(width: u32, height: u32, pixels: &[u8]) -> Vec<u8> {
    encode(width, height, png::ColorType::Grayscale, pixels)
}

/// Encode an 8-bit grey + alpha image (straight alpha; e.g. the dust's fibre textures), two
/// bytes per pixel. Panics when `pixels.len() != 2·width·height`.
pub fn encode_gray_alpha8(width: u32, height: u32, pixels: &[u8]) -> Vec<u8> {
    encode(width, height, png::ColorType::GrayscaleAlpha, pixels)
}

fn encode(width: u32, height: u32, color: png::ColorType, data: &[u8]) -> Vec<u8> {
    let samples = match color {
        png::ColorType::Rgba => 4,
        png::ColorType::GrayscaleAlpha => 2,
        _ => 1,
    };
    assert_eq!(
        data.len(),
        width as usize * height as usize * samples,
        "pixel buffer does not match the image size"
    );
    let mut out = Vec::with_capacity(data.len() / 2 + 1024);
    {
        let mut enc = png::Encoder::new(&mut out, width, height);
        enc.set_color(color);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_compression(png::Compression::Fast);
        enc.set_filter(png::FilterType::Sub);
        enc.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
        // Writing into a Vec only fails on inconsistent sizes, checked above.
        #[allow(clippy::expect_used)]
        let mut writer = enc.write_header().expect("png header into a Vec");
        #[allow(clippy::expect_used)]
        writer.write_image_data(data).expect("png data into a Vec");
        #[allow(clippy::expect_used)]
        writer.finish().expect("png end into a Vec");
    }
    out
}

/// Encode `frames` as an animated PNG (APNG) that loops forever, each frame shown `delay_ms`
/// milliseconds; the first frame is also the still image viewers without APNG support show.
/// Full frames (no sub-rectangles), blend op `Source`, dispose op `None`; same colour settings
/// and deflate level as [`encode_rgba`]. Allocates the output (~1–3 bytes per pixel per frame).
/// Panics when `frames` is empty or the frames differ in size (caller bugs).
pub fn encode_apng(frames: &[RgbaImage], delay_ms: u16) -> Vec<u8> {
    assert!(!frames.is_empty(), "an animated PNG needs a frame");
    let (width, height) = (frames[0].width, frames[0].height);
    for f in frames {
        assert!(
            f.width == width
                && f.height == height
                && f.data.len() == width as usize * height as usize * 4,
            "APNG frames must share one size"
        );
    }
    let mut out = Vec::with_capacity(frames.len() * (frames[0].data.len() / 2 + 64) + 1024);
    {
        let mut enc = png::Encoder::new(&mut out, width, height);
        enc.set_color(png::ColorType::Rgba);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_compression(png::Compression::Fast);
        enc.set_filter(png::FilterType::Sub);
        enc.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
        // These only fail for zero frames or a zero denominator, excluded above; writing into a
        // Vec only fails on inconsistent sizes, also checked above.
        #[allow(clippy::expect_used)]
        {
            enc.set_animated(frames.len() as u32, 0)
                .expect("at least one frame");
            enc.set_frame_delay(delay_ms, 1000)
                .expect("non-zero denominator");
            let mut writer = enc.write_header().expect("png header into a Vec");
            for f in frames {
                writer
                    .write_image_data(&f.data)
                    .expect("png frame into a Vec");
            }
            writer.finish().expect("png end into a Vec");
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_rgba_and_gray() {
        let mut img = RgbaImage::new_filled(5, 3, [10, 20, 30, 255]);
        img.set_pixel(4, 2, [1, 2, 3, 0]);
        let bytes = encode_rgba(&img);
        let dec = png::Decoder::new(std::io::Cursor::new(bytes));
        let mut r = dec.read_info().unwrap();
        let mut buf = vec![0; r.output_buffer_size()];
        let info = r.next_frame(&mut buf).unwrap();
        assert_eq!(
            (info.width, info.height, info.color_type),
            (5, 3, png::ColorType::Rgba)
        );
        assert_eq!(&buf[..info.buffer_size()], &img.data[..]);

        let g: Vec<u8> = (0..12).collect();
        let bytes = encode_gray8(4, 3, &g);
        let mut r = png::Decoder::new(std::io::Cursor::new(bytes))
            .read_info()
            .unwrap();
        let mut buf = vec![0; r.output_buffer_size()];
        let info = r.next_frame(&mut buf).unwrap();
        assert_eq!(info.color_type, png::ColorType::Grayscale);
        assert_eq!(&buf[..12], &g[..]);
    }
}
