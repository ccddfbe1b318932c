//! Base-colour textures as the mesh renderer samples them (see "Materials" in [`super`]).

use crate::geom::mesh::{Texture, TextureWrap};
use crate::render::image::{linear_to_srgb8, srgb8_to_linear};

/// A base-colour texture as the renderer samples it: the texture's sRGB texels and a mip
/// pyramid of box-filtered halves (averaged in linear light).
pub(super) struct MipTexture {
    /// (width, height, sRGB RGBA texels) from the full size down to 1 × 1.
    levels: Vec<(usize, usize, Vec<[u8; 4]>)>,
    wrap: [TextureWrap; 2],
}

impl MipTexture {
    pub(super) fn new(t: &Texture) -> Self {
        let (w, h) = (t.width as usize, t.height as usize);
        let mut levels = vec![(w, h, t.texels.clone())];
        if t.texels.len() != w * h || w == 0 || h == 0 {
            levels[0] = (1, 1, vec![[255; 4]]);
        }
        loop {
            let (w, h, px) = &levels[levels.len() - 1];
            let (w, h) = (*w, *h);
            if w == 1 && h == 1 {
                break;
            }
            let (nw, nh) = (w.div_ceil(2), h.div_ceil(2));
            let mut out = Vec::with_capacity(nw * nh);
            for y in 0..nh {
                for x in 0..nw {
                    let mut acc = [0.0f32; 4];
                    for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let p = px[(2 * y + dy).min(h - 1) * w + (2 * x + dx).min(w - 1)];
                        for k in 0..3 {
                            acc[k] += srgb8_to_linear(p[k]);
                        }
                        acc[3] += f32::from(p[3]);
                    }
                    out.push([
                        linear_to_srgb8(acc[0] * 0.25),
                        linear_to_srgb8(acc[1] * 0.25),
                        linear_to_srgb8(acc[2] * 0.25),
                        (acc[3] * 0.25 + 0.5) as u8,
                    ]);
                }
            }
            levels.push((nw, nh, out));
        }
        Self {
            levels,
            wrap: t.wrap,
        }
    }

    /// Linear RGB at texture coordinates `uv` (glTF convention) on mip level `level` (0 = full
    /// size; fractional levels blend the two nearest), bilinear within a level.
    pub(super) fn sample(&self, uv: [f32; 2], level: f32) -> [f32; 3] {
        let top = (self.levels.len() - 1) as f32;
        let level = if level.is_finite() {
            level.clamp(0.0, top)
        } else {
            0.0
        };
        let l0 = level.floor() as usize;
        let f = level - l0 as f32;
        let a = self.bilinear(l0, uv);
        if f > 1e-3 && l0 + 1 < self.levels.len() {
            let b = self.bilinear(l0 + 1, uv);
            [0, 1, 2].map(|k| a[k] + (b[k] - a[k]) * f)
        } else {
            a
        }
    }

    fn bilinear(&self, level: usize, uv: [f32; 2]) -> [f32; 3] {
        let (w, h, px) = &self.levels[level];
        let (w, h) = (*w, *h);
        let x = uv[0] * w as f32 - 0.5;
        let y = uv[1] * h as f32 - 0.5;
        if !(x.is_finite() && y.is_finite()) {
            return [1.0; 3];
        }
        let (fx, fy) = (x.floor(), y.floor());
        let (ax, ay) = (x - fx, y - fy);
        let index = |i: i64, n: usize, mode: TextureWrap| -> usize {
            let n = n as i64;
            let i = match mode {
                TextureWrap::Repeat => i.rem_euclid(n),
                TextureWrap::Clamp => i.clamp(0, n - 1),
                TextureWrap::Mirror => {
                    let m = i.rem_euclid(2 * n);
                    if m < n {
                        m
                    } else {
                        2 * n - 1 - m
                    }
                }
            };
            i as usize
        };
        let (x0, y0) = (fx as i64, fy as i64);
        let (i0, i1) = (index(x0, w, self.wrap[0]), index(x0 + 1, w, self.wrap[0]));
        let (j0, j1) = (index(y0, h, self.wrap[1]), index(y0 + 1, h, self.wrap[1]));
        let texel = |i: usize, j: usize| px[j * w + i].map(srgb8_to_linear);
        let (c00, c10, c01, c11) = (texel(i0, j0), texel(i1, j0), texel(i0, j1), texel(i1, j1));
        [0, 1, 2].map(|k| {
            let top = c00[k] + (c10[k] - c00[k]) * ax;
            let bottom = c01[k] + (c11[k] - c01[k]) * ax;
            top + (bottom - top) * ay
        })
    }
}
