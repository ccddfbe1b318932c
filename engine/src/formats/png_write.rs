//! PNG encoders for rendered images and 8-bit previews (png crate).
//!
//! Images go out with the sRGB chunk (they are sRGB-encoded) and the *fast* deflate setting with
//! the `Sub` filter: on a 1920×1080 render that costs a few tens of milliseconds and a file
//! ~1.3× the size of the default setting, which spent several times longer for the same pixels.
//! Encoding into a `Vec` cannot fail for valid dimensions; the `png` errors that remain (a buffer
//! whose length disagrees with the dimensions) are caller bugs and panic.

/// What the RGBA encoders read: an 8-bit image, row-major, row 0 at the top, 4 bytes per pixel
/// (sRGB-encoded R, G, B and straight alpha). The renderer's image type implements it; the
/// encoders need nothing else of it.
pub trait RgbaPixels {
    /// Width and height, pixels.
    fn size(&self) -> (u32, u32);
    /// `4 · width · height` bytes.
    fn rgba(&self) -> &[u8];
}

/// Encode an 8-bit sRGB RGBA image (straight alpha) as PNG. Allocates the output (~1–3 bytes per
/// pixel for renders). Panics when the pixels are not `4·width·height` bytes.
pub fn encode_rgba(img: &impl RgbaPixels) -> Vec<u8> {
    let (width, height) = img.size();
    encode(width, height, png::ColorType::Rgba, img.rgba())
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
        let enc = encoder(&mut out, width, height, color);
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

/// An RGBA PNG encoded while the image is still being drawn: row bands arrive in any order from
/// any thread ([`Self::rows`]), each is filtered by the thread that offers it, and the deflate
/// stream is fed in row order by whichever thread finds the next band ready (the others do not
/// wait: they queue their band and return). [`Self::finish`] drains what is left and writes the
/// file. The bytes are those of [`encode_rgba`] on the finished image: the same header (the png
/// crate's), the same `Sub` filter, the same compressor (`fdeflate`, which the png crate uses
/// for `Compression::Fast`) fed the same sequence of rows (one `write_data` per filtered row,
/// filter byte first), one IDAT chunk, and the same fallback to stored blocks when deflate does
/// not pay. Test: `stream_matches_encode_rgba`.
///
/// Why: the renders hand their bands over as they finish, so most of the deflate (serial by
/// nature: one stream) runs while the other core still renders, instead of after the render on
/// one core.
pub struct RgbaPngStream {
    width: u32,
    height: u32,
    /// Bands filtered but not yet compressed (first row → filtered rows), and the next row the
    /// compressor expects.
    queue: std::sync::Mutex<Queue>,
    /// The compressor; `None` after a write error (then [`Self::finish`] encodes from scratch).
    deflate: std::sync::Mutex<Option<fdeflate::Compressor<std::io::Cursor<Vec<u8>>>>>,
}

#[derive(Default)]
struct Queue {
    next_row: usize,
    bands: std::collections::BTreeMap<usize, Vec<u8>>,
}

impl RgbaPngStream {
    /// A stream for a `width × height` RGBA image.
    pub fn new(width: u32, height: u32) -> Self {
        let raw = (width as usize * 4 + 1) * height as usize;
        Self {
            width,
            height,
            queue: std::sync::Mutex::new(Queue::default()),
            deflate: std::sync::Mutex::new(
                fdeflate::Compressor::new(std::io::Cursor::new(Vec::with_capacity(raw / 2 + 64)))
                    .ok(),
            ),
        }
    }

    /// Rows `first_row..` of the image, `data` being whole rows of `4·width` bytes (straight
    /// RGBA). Each row must be offered exactly once; bands may come in any order and from any
    /// thread. Filters `data` (on this thread), then compresses every band that is next in row
    /// order unless another thread is compressing (that thread, or [`Self::finish`], takes
    /// them).
    pub fn rows(&self, first_row: usize, data: &[u8]) {
        let row_len = self.width as usize * 4;
        if row_len == 0 || data.is_empty() {
            return;
        }
        let mut filtered = Vec::with_capacity(data.len() + data.len() / row_len);
        for line in data.chunks(row_len) {
            filtered.push(1); // FilterType::Sub
            filter_sub_rgba(line, &mut filtered);
        }
        if let Ok(mut q) = self.queue.lock() {
            q.bands.insert(first_row, filtered);
        }
        self.drain(false);
    }

    /// Compress the queued bands that are next in row order. With `wait`, waits for the
    /// compressor; otherwise gives up when another thread holds it, and re-checks after
    /// releasing it (a band queued meanwhile by a thread that gave up is not left behind).
    fn drain(&self, wait: bool) {
        let row_len = self.width as usize * 4 + 1;
        loop {
            let guard = if wait {
                self.deflate.lock().ok()
            } else {
                self.deflate.try_lock().ok()
            };
            let Some(mut deflate) = guard else { return };
            loop {
                let band = self.queue.lock().ok().and_then(|mut q| {
                    let next = q.next_row;
                    let band = q.bands.remove(&next)?;
                    q.next_row += band.len() / row_len;
                    Some(band)
                });
                let Some(band) = band else { break };
                if let Some(c) = deflate.as_mut() {
                    if band
                        .chunks(row_len)
                        .try_for_each(|r| c.write_data(r))
                        .is_err()
                    {
                        *deflate = None;
                    }
                }
            }
            drop(deflate);
            let more = self
                .queue
                .lock()
                .is_ok_and(|q| q.bands.contains_key(&q.next_row));
            if !more {
                return;
            }
        }
    }

    /// The PNG of `img` (the image whose rows were offered): [`encode_rgba`]'s bytes. Falls
    /// back to [`encode_rgba`] when not every row was offered or the compressor failed. Panics
    /// when the pixels are not `4·width·height` bytes (a caller bug).
    pub fn finish(self, img: &impl RgbaPixels) -> Vec<u8> {
        assert!(
            img.size() == (self.width, self.height)
                && img.rgba().len() == self.width as usize * self.height as usize * 4,
            "image does not match the stream"
        );
        self.drain(true);
        let complete = self
            .queue
            .lock()
            .is_ok_and(|q| q.next_row == self.height as usize && q.bands.is_empty());
        let zlib = self
            .deflate
            .into_inner()
            .ok()
            .flatten()
            .filter(|_| complete)
            .and_then(|c| c.finish().ok())
            .map(std::io::Cursor::into_inner);
        let raw = (self.width as usize * 4 + 1) * self.height as usize;
        match zlib {
            // The png crate's rule: stored blocks (unfiltered) when deflate makes it bigger.
            Some(z) if z.len() <= fdeflate::StoredOnlyCompressor::<()>::compressed_size(raw) => {
                let mut out = Vec::with_capacity(z.len() + 1024);
                {
                    let enc = encoder(&mut out, self.width, self.height, png::ColorType::Rgba);
                    // Writing into a Vec only fails on inconsistent sizes, checked above.
                    #[allow(clippy::expect_used)]
                    let mut writer = enc.write_header().expect("png header into a Vec");
                    // One IDAT per 2^31 − 1 bytes, as the png crate splits them.
                    for chunk in z.chunks((u32::MAX >> 1) as usize) {
                        #[allow(clippy::expect_used)]
                        writer
                            .write_chunk(png::chunk::IDAT, chunk)
                            .expect("png data into a Vec");
                    }
                    #[allow(clippy::expect_used)]
                    writer.finish().expect("png end into a Vec");
                }
                out
            }
            _ => encode_rgba(img),
        }
    }
}

/// A PNG encoder with the settings every writer here shares: 8 bits, `Fast` deflate, the `Sub`
/// filter, sRGB (perceptual). [`RgbaPngStream`] depends on these being the same as
/// [`encode_rgba`]'s.
fn encoder<W: std::io::Write>(
    out: W,
    width: u32,
    height: u32,
    color: png::ColorType,
) -> png::Encoder<'static, W> {
    let mut enc = png::Encoder::new(out, width, height);
    enc.set_color(color);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Fast);
    enc.set_filter(png::FilterType::Sub);
    enc.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
    enc
}

/// The PNG `Sub` filter of one RGBA row (4 bytes per pixel), appended to `out`.
fn filter_sub_rgba(line: &[u8], out: &mut Vec<u8>) {
    out.extend_from_slice(&line[..line.len().min(4)]);
    if line.len() > 4 {
        out.extend(
            line[4..]
                .iter()
                .zip(&line[..line.len() - 4])
                .map(|(c, p)| c.wrapping_sub(*p)),
        );
    }
}

/// Encode `frames` as an animated PNG (APNG) that loops forever, each frame shown `delay_ms`
/// milliseconds; the first frame is also the still image viewers without APNG support show.
/// Full frames (no sub-rectangles), blend op `Source`, dispose op `None`; same colour settings
/// and deflate level as [`encode_rgba`]. Allocates the output (~1–3 bytes per pixel per frame).
/// Panics when `frames` is empty or the frames differ in size (caller bugs).
pub fn encode_apng<F: RgbaPixels>(frames: &[F], delay_ms: u16) -> Vec<u8> {
    assert!(!frames.is_empty(), "an animated PNG needs a frame");
    let (width, height) = frames[0].size();
    for f in frames {
        assert!(
            f.size() == (width, height) && f.rgba().len() == width as usize * height as usize * 4,
            "APNG frames must share one size"
        );
    }
    let mut out = Vec::with_capacity(frames.len() * (frames[0].rgba().len() / 2 + 64) + 1024);
    {
        let mut enc = encoder(&mut out, width, height, png::ColorType::Rgba);
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
                    .write_image_data(f.rgba())
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

    /// A bare RGBA buffer (the encoders' tests need no renderer).
    struct RgbaImage {
        width: u32,
        height: u32,
        data: Vec<u8>,
    }

    impl RgbaImage {
        fn new_filled(width: u32, height: u32, rgba: [u8; 4]) -> Self {
            let n = width as usize * height as usize;
            Self {
                width,
                height,
                data: rgba.repeat(n),
            }
        }
    }

    impl RgbaPixels for RgbaImage {
        fn size(&self) -> (u32, u32) {
            (self.width, self.height)
        }
        fn rgba(&self) -> &[u8] {
            &self.data
        }
    }

    #[test]
    fn stream_matches_encode_rgba() {
        // Bands out of order from several threads, a noisy image (deflate pays) and a flat one.
        for (w, h, seed) in [(37u32, 29u32, 7u32), (64, 40, 0)] {
            let mut img = RgbaImage::new_filled(w, h, [200, 210, 220, 255]);
            let mut x = seed;
            for (i, v) in img.data.iter_mut().enumerate() {
                if seed != 0 {
                    x = x.wrapping_mul(1_103_515_245).wrapping_add(12_345);
                    *v = (x >> 16) as u8 & if i % 3 == 0 { 0xFF } else { 0x0F };
                }
            }
            let stream = RgbaPngStream::new(w, h);
            let band = 4 * w as usize * 5;
            let bands: Vec<(usize, &[u8])> = img.data.chunks(band).enumerate().collect();
            let order: Vec<usize> = (0..bands.len()).rev().collect();
            std::thread::scope(|s| {
                for part in order.chunks(2) {
                    let (stream, bands) = (&stream, &bands);
                    s.spawn(move || {
                        for &b in part {
                            stream.rows(b * 5, bands[b].1);
                        }
                    });
                }
            });
            assert_eq!(stream.finish(&img), encode_rgba(&img));
            // Rows missing: falls back to the whole-image encoder.
            let partial = RgbaPngStream::new(w, h);
            partial.rows(0, bands[0].1);
            assert_eq!(partial.finish(&img), encode_rgba(&img));
        }
    }

    #[test]
    fn round_trip_rgba_and_gray() {
        let mut img = RgbaImage::new_filled(5, 3, [10, 20, 30, 255]);
        img.data[4 * 14..].copy_from_slice(&[1, 2, 3, 0]);
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
