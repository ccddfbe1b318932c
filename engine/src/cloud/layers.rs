//! The linear layers of a render (SPEC §3.1): per pixel Ī (the direct light for a unit sun
//! colour), M (the multiple-scattering light for a unit sun, [`super::multiple`]; empty in
//! single mode), A (the ambient part, linear RGB) and α. The image is `I = I_l·(Ī + M) + A`
//! composited with α, so a render at a camera answers every sun colour: the sun-colour edit
//! solves for I_l from the painted pixels' Ī + M and A, and the new version's image is the same
//! layers recoloured.
//!
//! `layers.bin` stores them beside a render so that a later sun-colour edit at the same camera
//! reads them instead of marching (the "when the render at that camera exists"). The
//! blob carries the identity of what it depends on ([`identity`]: the view and the state
//! fields other than the sun colour and background, the density floor included); a reader uses it only when the identity
//! equals the edit's. The volume and the ambient field are not in the identity: the caller
//! pairs a blob only with the scene version it was rendered from.
//!
//! Format (little-endian): the magic `PHLAY1\0\0`; u32 length and UTF-8 JSON of the identity;
//! u32 width and height; per row u32 `x0 ≤ x1 ≤ width`, the span of stored pixels (outside it Ī,
//! A and α are 0: sky); then the rows' spans of records of five f32 (Ī, A.r, A.g, A.b, α). Sky
//! rows and margins cost 8 bytes a row, a covered pixel 20 bytes; lossless, so a cached edit
//! gives the same bytes as a marched one. Layers with a multiple-scattering part are written as
//! `PHLAY2\0\0`, the same with records of six f32 (Ī, M, A.r, A.g, A.b, α).

use rayon::prelude::*;
use serde::Serialize;

use super::multiple::Scattering;
use super::params::View;
use super::state::CloudState;
use crate::params::CameraSpec;
use crate::render::image::{linear_to_srgb8, srgb8_to_linear, RgbaImage};
use crate::InputError;

/// The linear layers of a render, row-major, row 0 at the top.
#[derive(Debug, Clone, PartialEq)]
pub struct Layers {
    pub width: u32,
    pub height: u32,
    /// Ī per pixel.
    pub direct: Vec<f32>,
    /// M per pixel (multiple scattering for a unit sun); empty in single mode (M = 0).
    pub multiple: Vec<f32>,
    /// A per pixel, linear RGB.
    pub ambient: Vec<[f32; 3]>,
    /// 1 − g(T) per pixel.
    pub alpha: Vec<f32>,
}

/// Which terms of the layers an image shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Show {
    /// I_l·Ī + A: the render.
    All,
    /// I_l·Ī only (single scattering).
    Direct,
    /// I_l·M only (multiple scattering).
    Multiple,
    /// A only.
    Ambient,
}

impl Layers {
    /// Linear radiance I of pixel `i` (premultiplied by alpha: the cloud's own light).
    #[inline]
    pub fn radiance(&self, i: usize, sun: [f32; 3], show: Show) -> [f32; 3] {
        let d = self.direct[i];
        let a = self.ambient[i];
        let m = self.multiple.get(i).copied();
        std::array::from_fn(|q| match (show, m) {
            (Show::All, None) => sun[q] * d + a[q],
            (Show::All, Some(m)) => sun[q] * (d + m) + a[q],
            (Show::Direct, _) => sun[q] * d,
            (Show::Multiple, m) => sun[q] * m.unwrap_or(0.0),
            (Show::Ambient, _) => a[q],
        })
    }

    /// The sRGB RGBA image: over `background` (opaque: `I + (1 − α)·bg`) when given, else
    /// straight colour `I/α` with alpha α so that compositing over any sky gives `I + (1 − α)·sky`.
    pub fn to_image(&self, sun: [f32; 3], background: Option<[u8; 3]>, show: Show) -> RgbaImage {
        let bg = background.map(|b| b.map(srgb8_to_linear));
        let mut data = vec![0u8; self.direct.len() * 4];
        data.par_chunks_mut(4 * self.width as usize)
            .enumerate()
            .for_each(|(y, row)| {
                for (x, px) in row.chunks_exact_mut(4).enumerate() {
                    let i = y * self.width as usize + x;
                    let c = self.radiance(i, sun, show);
                    let a = self.alpha[i].clamp(0.0, 1.0);
                    let out = match bg {
                        Some(bg) => {
                            let v: [f32; 3] = std::array::from_fn(|q| c[q] + (1.0 - a) * bg[q]);
                            [
                                linear_to_srgb8(v[0]),
                                linear_to_srgb8(v[1]),
                                linear_to_srgb8(v[2]),
                                255,
                            ]
                        }
                        None => {
                            let alpha8 = (a * 255.0 + 0.5) as u8;
                            if alpha8 == 0 {
                                [0, 0, 0, 0]
                            } else {
                                let inv = 1.0 / a;
                                [
                                    linear_to_srgb8(c[0] * inv),
                                    linear_to_srgb8(c[1] * inv),
                                    linear_to_srgb8(c[2] * inv),
                                    alpha8,
                                ]
                            }
                        }
                    };
                    px.copy_from_slice(&out);
                }
            });
        RgbaImage {
            width: self.width,
            height: self.height,
            data,
        }
    }
}

/// The name of the output (and of a cloud edit job's auxiliary input) that holds the layers.
pub const LAYERS_FILE: &str = "layers.bin";

/// The `layers.bin` output (a render's or an edit's).
pub(crate) fn layers_bin(bytes: Vec<u8>) -> crate::Output {
    crate::Output::new(LAYERS_FILE, "application/octet-stream", bytes)
}

/// The blob's magic.
const MAGIC: &[u8; 8] = b"PHLAY1\0\0";
/// The magic of layers with a multiple-scattering part.
const MAGIC_MS: &[u8; 8] = b"PHLAY2\0\0";

/// What a render's layers depend on besides the volume and ambient field.
#[derive(Serialize)]
struct Identity<'a> {
    width: u32,
    height: u32,
    camera: &'a CameraSpec,
    kappa: Option<f64>,
    /// The density floor taken out of the volume before the render ([`super::floor`]): the
    /// same volume with another floor gives other layers. Left out when the state leaves it
    /// open (then the identity is what it was before the floor existed, and never equals that
    /// of a render, whose state always has the floor resolved).
    #[serde(skip_serializing_if = "Option::is_none")]
    density_floor: Option<f64>,
    sun_direction: [f64; 3],
    ambient: [f64; 3],
    ambient_scale: f64,
    anisotropy: f64,
    step: f64,
    /// Left out in single mode with albedo 1, so that the identity of such layers is what it
    /// was before the multiple mode existed.
    #[serde(skip_serializing_if = "Scattering::is_single")]
    scattering: Scattering,
    #[serde(skip_serializing_if = "is_one")]
    albedo: f64,
}

fn is_one(v: &f64) -> bool {
    *v == 1.0
}

/// The identity of the layers of `state` rendered at `view`: compact JSON (the same values
/// give the same string).
pub fn identity(view: &View, state: &CloudState) -> String {
    let id = Identity {
        width: view.width,
        height: view.height,
        camera: &view.camera,
        kappa: state.kappa,
        density_floor: state.density_floor,
        sun_direction: state.sun_direction,
        ambient: state.ambient,
        ambient_scale: state.ambient_scale,
        anisotropy: state.anisotropy,
        step: state.step,
        scattering: state.scattering,
        albedo: state.albedo,
    };
    // Plain numbers and a camera spec: serialisation cannot fail.
    serde_json::to_string(&id).unwrap_or_default()
}

impl Layers {
    /// Pixel `i`'s record: Ī, A, α (and M after Ī when the layers have it).
    #[inline]
    fn record(&self, i: usize) -> ([f32; 6], usize) {
        let a = self.ambient[i];
        match self.multiple.get(i) {
            Some(m) => ([self.direct[i], *m, a[0], a[1], a[2], self.alpha[i]], 6),
            None => ([self.direct[i], a[0], a[1], a[2], self.alpha[i], 0.0], 5),
        }
    }

    /// `layers.bin` (see the module doc) with the identity `id`. Allocates the blob: 8 bytes a
    /// row plus 20 a stored pixel.
    pub fn to_bytes(&self, id: &str) -> Vec<u8> {
        let (w, h) = (self.width as usize, self.height as usize);
        let ms = !self.multiple.is_empty();
        let rec = if ms { 24 } else { 20 };
        let spans: Vec<(usize, usize)> = (0..h)
            .map(|y| {
                let row = |x: usize| self.record(y * w + x).0;
                let lit = |x: &usize| row(*x) != [0.0; 6];
                match (0..w).find(lit) {
                    Some(x0) => (x0, (0..w).rev().find(lit).map_or(x0, |x| x + 1)),
                    None => (0, 0),
                }
            })
            .collect();
        let stored: usize = spans.iter().map(|(a, b)| b - a).sum();
        let mut out = Vec::with_capacity(20 + id.len() + 8 * h + rec * stored);
        out.extend_from_slice(if ms { MAGIC_MS } else { MAGIC });
        out.extend_from_slice(&(id.len() as u32).to_le_bytes());
        out.extend_from_slice(id.as_bytes());
        out.extend_from_slice(&self.width.to_le_bytes());
        out.extend_from_slice(&self.height.to_le_bytes());
        for (a, b) in &spans {
            out.extend_from_slice(&(*a as u32).to_le_bytes());
            out.extend_from_slice(&(*b as u32).to_le_bytes());
        }
        for (y, (a, b)) in spans.iter().enumerate() {
            for x in *a..*b {
                let (r, n) = self.record(y * w + x);
                for v in &r[..n] {
                    out.extend_from_slice(&v.to_le_bytes());
                }
            }
        }
        out
    }

    /// Reads `layers.bin`: the identity it was written with and the layers. Refuses a wrong
    /// magic, spans outside the image, a length that does not match and non-finite values;
    /// images larger than `max_pixels` are refused before allocating.
    pub fn from_bytes(bytes: &[u8], max_pixels: u64) -> Result<(String, Self), InputError> {
        let corrupt = |detail: String| InputError::Corrupt {
            format: "render layers",
            detail,
        };
        let mut at = 0usize;
        let mut take = |n: usize| -> Result<&[u8], InputError> {
            let end = at
                .checked_add(n)
                .filter(|&e| e <= bytes.len())
                .ok_or_else(|| corrupt(format!("truncated at byte {at}")))?;
            let s = &bytes[at..end];
            at = end;
            Ok(s)
        };
        let ms = match take(8)? {
            m if m == MAGIC => false,
            m if m == MAGIC_MS => true,
            _ => return Err(corrupt("missing the PHLAY1/PHLAY2 header".into())),
        };
        let rec = if ms { 24 } else { 20 };
        let u32_at = |b: &[u8]| u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        let n = u32_at(take(4)?) as usize;
        let id = std::str::from_utf8(take(n)?)
            .map_err(|_| corrupt("the identity is not UTF-8".into()))?
            .to_string();
        let width = u32_at(take(4)?);
        let height = u32_at(take(4)?);
        let pixels = u64::from(width) * u64::from(height);
        if pixels > max_pixels {
            return Err(InputError::TooLarge {
                what: "render layers (pixels)",
                actual: pixels,
                max: max_pixels,
            });
        }
        let (w, h) = (width as usize, height as usize);
        let mut spans = Vec::with_capacity(h);
        for y in 0..h {
            let s = take(8)?;
            let (a, b) = (u32_at(&s[..4]) as usize, u32_at(&s[4..]) as usize);
            if a > b || b > w {
                return Err(corrupt(format!("row {y} spans {a}..{b} of {w} pixels")));
            }
            spans.push((a, b));
        }
        let mut layers = Self {
            width,
            height,
            direct: vec![0.0; w * h],
            multiple: if ms { vec![0.0; w * h] } else { vec![] },
            ambient: vec![[0.0; 3]; w * h],
            alpha: vec![0.0; w * h],
        };
        for (y, (a, b)) in spans.into_iter().enumerate() {
            let recs = take(rec * (b - a))?;
            for (x, r) in (a..b).zip(recs.chunks_exact(rec)) {
                let mut v = [0f32; 6];
                for (k, o) in v.iter_mut().enumerate().take(rec / 4) {
                    *o = f32::from_le_bytes([r[4 * k], r[4 * k + 1], r[4 * k + 2], r[4 * k + 3]]);
                }
                let v = &v[..rec / 4];
                if v.iter().any(|x| !x.is_finite()) {
                    return Err(corrupt(format!("pixel ({x}, {y}) holds {v:?}")));
                }
                let i = y * w + x;
                let v = if ms {
                    layers.multiple[i] = v[1];
                    [v[0], v[2], v[3], v[4], v[5]]
                } else {
                    [v[0], v[1], v[2], v[3], v[4]]
                };
                layers.direct[i] = v[0];
                layers.ambient[i] = [v[1], v[2], v[3]];
                layers.alpha[i] = v[4];
            }
        }
        if at != bytes.len() {
            return Err(corrupt(format!(
                "{} bytes after the last row",
                bytes.len() - at
            )));
        }
        Ok((id, layers))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blob_round_trip_and_refusals() {
        let (w, h) = (5u32, 3u32);
        let n = (w * h) as usize;
        let mut l = Layers {
            width: w,
            height: h,
            direct: vec![0.0; n],
            multiple: vec![],
            ambient: vec![[0.0; 3]; n],
            alpha: vec![0.0; n],
        };
        // Row 0 sky, row 1 pixels 1 and 3 (a gap inside the span), row 2 the last pixel.
        for (i, v) in [(6usize, 0.5f32), (8, 0.25), (14, 1.0)] {
            l.direct[i] = v;
            l.ambient[i] = [v, 0.1, 0.2];
            l.alpha[i] = v;
        }
        let b = l.to_bytes("{\"id\":1}");
        assert_eq!(b.len(), 8 + 4 + 8 + 8 + 8 * 3 + 20 * 4);
        let (id, back) = Layers::from_bytes(&b, 1000).unwrap();
        assert_eq!(id, "{\"id\":1}");
        assert_eq!(back, l);
        assert!(Layers::from_bytes(&b[..b.len() - 1], 1000).is_err());
        assert!(Layers::from_bytes(&b, 10).is_err());
        assert!(Layers::from_bytes(b"PHLAY2\0\0", 1000).is_err());
        let mut bad = b.clone();
        bad.push(0);
        assert!(Layers::from_bytes(&bad, 1000).is_err());
        // A span past the width.
        let mut bad = b.clone();
        let row1 = 8 + 4 + 8 + 8 + 8 + 4;
        bad[row1..row1 + 4].copy_from_slice(&9u32.to_le_bytes());
        assert!(Layers::from_bytes(&bad, 1000).is_err());
        // With a multiple-scattering layer: PHLAY2, six floats a pixel, same round trip.
        l.multiple = vec![0.0; n];
        l.multiple[8] = 0.75;
        l.multiple[7] = 0.5; // a pixel lit by multiple scattering only
        let b = l.to_bytes("{}");
        assert_eq!(&b[..8], b"PHLAY2\0\0");
        assert_eq!(b.len(), 8 + 4 + 2 + 8 + 8 * 3 + 24 * 4);
        assert_eq!(Layers::from_bytes(&b, 1000).unwrap().1, l);
        assert!(Layers::from_bytes(&b[..b.len() - 4], 1000).is_err());
    }
}
