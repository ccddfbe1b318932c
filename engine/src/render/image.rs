//! 8-bit sRGB images with straight (non-premultiplied) alpha, and linear ↔ sRGB conversions.
//!
//! Shading happens in linear RGB (`f32`, nominally 0..1); only the final write converts to sRGB
//! bytes. The conversion uses a 16,384-entry table built once (16 KiB) because `powf` per channel
//! per pixel cost ~100 ms on a 1920×1080 image; the table's quantisation step is below half an
//! sRGB code value everywhere except the very darkest codes, where it is below one.

use std::sync::OnceLock;

/// An 8-bit RGBA image, row-major, row 0 at the top, 4 bytes per pixel: sRGB-encoded R, G, B and
/// straight (not premultiplied) linear alpha.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RgbaImage {
    pub width: u32,
    pub height: u32,
    /// `width × height × 4` bytes.
    pub data: Vec<u8>,
}

impl crate::formats::png_write::RgbaPixels for RgbaImage {
    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }
    fn rgba(&self) -> &[u8] {
        &self.data
    }
}

impl RgbaImage {
    /// A `width × height` image filled with `rgba` (sRGB bytes). Allocates `4·w·h` bytes.
    pub fn new_filled(width: u32, height: u32, rgba: [u8; 4]) -> Self {
        let n = width as usize * height as usize;
        let mut data = Vec::with_capacity(n * 4);
        for _ in 0..n {
            data.extend_from_slice(&rgba);
        }
        Self {
            width,
            height,
            data,
        }
    }

    /// The pixel at (`x`, `y`). Panics when out of range.
    #[inline]
    pub fn pixel(&self, x: u32, y: u32) -> [u8; 4] {
        let i = (y as usize * self.width as usize + x as usize) * 4;
        [
            self.data[i],
            self.data[i + 1],
            self.data[i + 2],
            self.data[i + 3],
        ]
    }

    /// Set the pixel at (`x`, `y`). Panics when out of range.
    #[inline]
    pub fn set_pixel(&mut self, x: u32, y: u32, rgba: [u8; 4]) {
        let i = (y as usize * self.width as usize + x as usize) * 4;
        self.data[i..i + 4].copy_from_slice(&rgba);
    }
}

/// Exact sRGB transfer function: linear `[0, 1]` → encoded `[0, 1]` (input clamped).
#[inline]
pub fn linear_to_srgb(v: f32) -> f32 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.003_130_8 {
        v * 12.92
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// Exact inverse sRGB transfer function: encoded `[0, 1]` → linear `[0, 1]` (input clamped).
#[inline]
pub fn srgb_to_linear(v: f32) -> f32 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.040_45 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

const LUT_SIZE: usize = 16_384;

fn encode_lut() -> &'static [u8; LUT_SIZE] {
    static LUT: OnceLock<Box<[u8; LUT_SIZE]>> = OnceLock::new();
    LUT.get_or_init(|| {
        let mut t = Box::new([0u8; LUT_SIZE]);
        for (i, v) in t.iter_mut().enumerate() {
            let lin = i as f32 / (LUT_SIZE - 1) as f32;
            *v = (linear_to_srgb(lin) * 255.0 + 0.5) as u8;
        }
        t
    })
}

/// Linear `[0, 1]` → sRGB byte through the table (clamped; NaN gives 0). Cheap: one table read.
#[inline]
pub fn linear_to_srgb8(v: f32) -> u8 {
    Srgb8::table().encode(v)
}

/// The table of [`linear_to_srgb8`], fetched once for many pixels.
#[derive(Clone, Copy)]
pub struct Srgb8(&'static [u8; LUT_SIZE]);

impl Srgb8 {
    #[inline]
    pub fn table() -> Self {
        Self(encode_lut())
    }

    /// [`linear_to_srgb8`].
    #[inline]
    pub fn encode(self, v: f32) -> u8 {
        // `as i32` saturates and maps NaN to 0 (cheaper than `as usize`, which has no SSE2
        // instruction); the clamp keeps the index in the table.
        let i = (v * (LUT_SIZE - 1) as f32 + 0.5) as i32;
        self.0[i.clamp(0, LUT_SIZE as i32 - 1) as usize]
    }
}

/// sRGB byte → linear `[0, 1]` through a 256-entry table.
#[inline]
pub fn srgb8_to_linear(v: u8) -> f32 {
    static LUT: OnceLock<[f32; 256]> = OnceLock::new();
    LUT.get_or_init(|| {
        let mut t = [0.0f32; 256];
        for (i, v) in t.iter_mut().enumerate() {
            *v = srgb_to_linear(i as f32 / 255.0);
        }
        t
    })[v as usize]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_round_trip_every_code() {
        for c in 0..=255u8 {
            assert_eq!(linear_to_srgb8(srgb8_to_linear(c)), c, "code {c}");
        }
    }

    #[test]
    fn srgb_clamps() {
        assert_eq!(linear_to_srgb8(-1.0), 0);
        assert_eq!(linear_to_srgb8(f32::NAN), 0);
        assert_eq!(linear_to_srgb8(7.0), 255);
        assert!((linear_to_srgb(0.5) - 0.7354).abs() < 1e-3);
    }
}
