//! Labelled contact sheets: a grid of tiles with a caption under each, like the paper's parameter
//! sweeps (Figs. 11–12). Captions use the `font8x8` bitmap font (printable ASCII; other characters
//! draw as `?`) scaled 2× to 16 px glyphs, dark on a neutral grey background.

use super::image::RgbaImage;

/// Background, sRGB.
const BG: [u8; 3] = [0xE4, 0xE4, 0xE2];
/// Caption colour, sRGB.
const INK: [u8; 3] = [0x22, 0x22, 0x22];
/// Gap around and between tiles, pixels.
const PAD: usize = 12;
/// Font scale: 8 px glyphs drawn at 16 px.
const SCALE: usize = 2;
const GLYPH: usize = 8 * SCALE;
/// Caption strip below each tile: glyph height plus 6 px above and below.
const CAPTION: usize = GLYPH + 12;

/// Lay `tiles` out in `columns` columns (≥ 1; the rows follow), each tile with its caption
/// centred below it (at 1× when too wide at 2×, truncated to end in `..` beyond that). Cells are the size of the
/// largest tile; smaller tiles are centred. Tiles are composited over the background (straight
/// alpha, blended in sRGB bytes, which is adequate for a preview sheet). The result is opaque.
///
/// Size: `columns·(W + PAD) + PAD` by `rows·(H + CAPTION + PAD) + PAD` with W × H the largest tile
/// (PAD = 12, CAPTION = 28). Allocates the sheet only.
pub fn contact_sheet(tiles: &[(RgbaImage, String)], columns: usize) -> RgbaImage {
    let columns = columns.clamp(1, tiles.len().max(1));
    let rows = tiles.len().div_ceil(columns);
    let cw = tiles.iter().map(|t| t.0.width as usize).max().unwrap_or(0);
    let ch = tiles.iter().map(|t| t.0.height as usize).max().unwrap_or(0);
    let sw = columns * (cw + PAD) + PAD;
    let sh = rows * (ch + CAPTION + PAD) + PAD;
    let mut sheet = RgbaImage::new_filled(sw as u32, sh as u32, [BG[0], BG[1], BG[2], 255]);
    for (k, (tile, label)) in tiles.iter().enumerate() {
        let (col, row) = (k % columns, k / columns);
        let x0 = PAD + col * (cw + PAD);
        let y0 = PAD + row * (ch + CAPTION + PAD);
        let tx = x0 + (cw - tile.width as usize) / 2;
        let ty = y0 + (ch - tile.height as usize) / 2;
        blit_over(&mut sheet, tile, tx, ty);
        draw_label(&mut sheet, label, x0, y0 + ch + (CAPTION - GLYPH) / 2, cw);
    }
    sheet
}

fn blit_over(dst: &mut RgbaImage, src: &RgbaImage, x0: usize, y0: usize) {
    let dw = dst.width as usize;
    let sw = src.width as usize;
    for y in 0..src.height as usize {
        for x in 0..sw {
            let s = &src.data[(y * sw + x) * 4..(y * sw + x) * 4 + 4];
            let d = ((y0 + y) * dw + x0 + x) * 4;
            let a = u32::from(s[3]);
            for (o, &v) in dst.data[d..d + 3].iter_mut().zip(&s[..3]) {
                let mix = u32::from(v) * a + u32::from(*o) * (255 - a);
                *o = ((mix + 127) / 255) as u8;
            }
        }
    }
}

/// Draw `text` centred in the `width` pixels starting at `x0`, top at `y0`: at 2× when it fits,
/// else at 1× (vertically centred in the same strip), else truncated to end in `..`.
fn draw_label(img: &mut RgbaImage, text: &str, x0: usize, y0: usize, width: usize) {
    let mut chars: Vec<char> = text.chars().collect();
    let (scale, y0) = if chars.len() * GLYPH <= width {
        (SCALE, y0)
    } else {
        (1, y0 + (GLYPH - 8) / 2)
    };
    let glyph_w = 8 * scale;
    let max_chars = width / glyph_w;
    if chars.len() > max_chars {
        chars.truncate(max_chars.saturating_sub(2));
        chars.resize(max_chars, '.');
    }
    let tw = chars.len() * glyph_w;
    let mut x = x0 + (width.saturating_sub(tw)) / 2;
    let iw = img.width as usize;
    for ch in chars {
        let code = if ch.is_ascii() && !ch.is_ascii_control() {
            ch as usize
        } else {
            '?' as usize
        };
        let glyph = font8x8::legacy::BASIC_LEGACY[code];
        for (gy, bits) in glyph.iter().enumerate() {
            for gx in 0..8 {
                if bits >> gx & 1 == 1 {
                    for sy in 0..scale {
                        for sx in 0..scale {
                            let px = x + gx * scale + sx;
                            let py = y0 + gy * scale + sy;
                            let i = (py * iw + px) * 4;
                            img.data[i..i + 3].copy_from_slice(&INK);
                        }
                    }
                }
            }
        }
        x += glyph_w;
    }
}
