//! Adaptive anti-aliasing over the rasteriser ([`super::raster`]): one loop for every renderer
//! that draws triangles (meshes through [`render_adaptive`], the terrain's raster path through
//! [`render_adaptive_with`] and its own refinement test).
//!
//! **Scheme** (the ray caster's, [`super::terrain`]): every pixel's centre sample is shaded; a
//! pixel whose centre [`Shaded::differs`] from a 4-neighbour's (another kind, a depth jump, a
//! visible colour step) also shades the [`sample_pattern`] samples (RGSS for 4) and averages them
//! with the centre in linear RGB, premultiplied by coverage. Rejected: shading every sample
//! (≈5× the shading cost for the same edges) and an analytic-coverage edge pass (does not match
//! the ray caster's picture).
//!
//! **Per band of [`BAND`] rows** (one loop per rayon thread takes the next band from a shared
//! counter, top to bottom; a band writes only its own rows, so the bytes do not depend on the
//! thread count or on which thread drew it):
//! 1. rasterise the *centre* sample of the band's rows plus one apron row above and below;
//! 2. shade the centres;
//! 3. mark the pixels to refine (a bit mask per row);
//! 4. rasterise the pattern samples *only at marked pixels* ([`RowMask`]: each triangle row's
//!    span is cut to its first and last marked pixel, rows without marks are skipped, and only
//!    marked pixels of the visibility buffer are cleared);
//! 5. shade the pattern samples of marked pixels and write the band.
//!
//! The band body (`band`: steps 2, 3 and 5 with the shader inlined; the coverage of steps 1
//! and 4 is [`Rasterizer`]'s) is compiled for AVX2 too and chosen at run time: no FMA target,
//! so the same bits (−2 % instructions and ≈ −2 % CPU on the paper case, `BENCHMARKS.md`).
//! Rejected: the same for the coverage loop (`Rasterizer::raster_rows`): +3 % CPU.
//!
//! Visibility at a sample does not depend on which other samples are rasterised, so the picture
//! is bit-identical to rasterising all `1 + samples` positions everywhere (what this loop did
//! before, at 5× the coverage work and buffer clears for 4 samples; measured in
//! `BENCHMARKS.md`, "Snow on terrain").
//!
//! **Allocation:** per worker thread, the band's visibility buffers (8 B per pixel for the
//! centre, 8 B per sample of the band for the pattern), the centre samples (`size_of::<P>()` per
//! pixel) and the mask (1 bit per pixel); nothing per pixel.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use multiversion::multiversion;
use rayon::prelude::*;

use super::image::{RgbaImage, Srgb8};
use super::raster::{Fragment, Rasterizer, RowMask, VisBuffer, BAND, NO_TRI};
use crate::control::{Canceled, Control};

/// Sub-pixel sample offsets in [0, 1)² for `n` samples (clamped to 1..=64): the centre for 1,
/// RGSS for 4, an n-rooks rotated grid otherwise. Returns the count written to `out`.
pub fn sample_pattern(n: u32, out: &mut [(f64, f64); 64]) -> usize {
    let n = n.clamp(1, 64) as usize;
    match n {
        1 => out[0] = (0.5, 0.5),
        4 => {
            out[..4].copy_from_slice(&[
                (0.375, 0.125),
                (0.875, 0.375),
                (0.125, 0.625),
                (0.625, 0.875),
            ]);
        }
        _ => {
            // Column k gets row (k·stride) mod n with a stride near n/φ coprime to n.
            let mut stride = ((n as f64 / 1.618) as usize).max(1);
            while gcd(stride, n) != 1 {
                stride += 1;
            }
            for (k, o) in out.iter_mut().take(n).enumerate() {
                *o = (
                    (k as f64 + 0.5) / n as f64,
                    (((k * stride) % n) as f64 + 0.5) / n as f64,
                );
            }
        }
    }
    n
}

fn gcd(a: usize, b: usize) -> usize {
    if b == 0 {
        a
    } else {
        gcd(b, a % b)
    }
}

/// One shaded sample: linear RGB, coverage (0 = transparent) and hit distance (+∞ = background,
/// −1 = transparent background).
#[derive(Debug, Clone, Copy, Default)]
pub struct Sample {
    pub c: [f32; 3],
    pub a: f32,
    pub t: f32,
}

impl Sample {
    /// True when this and a neighbouring centre sample differ enough that the pixel needs
    /// super-sampling: another kind (surface / background / transparent), a depth jump over 3 %,
    /// or a colour step over ~6/255 in a gamma-2 approximation of sRGB.
    #[inline]
    pub fn differs(&self, o: &Sample) -> bool {
        Keyed::of(*self).differs(&Keyed::of(*o))
    }
}

/// What the adaptive loop needs of a shaded sample: its colour and the refinement test between
/// neighbouring centre samples.
pub trait Shaded: Copy + Send {
    /// The sample's colour, coverage and distance.
    fn sample(&self) -> Sample;
    /// True when a pixel whose centre is `self` needs super-sampling because of its neighbour
    /// `o` (the test must be symmetric for the picture not to depend on scan order).
    fn differs(&self, o: &Self) -> bool;
}

/// A sample with the square roots of [`Sample::differs`] taken once per pixel instead of once
/// per comparison (same criterion).
#[derive(Debug, Clone, Copy, Default)]
struct Keyed {
    s: Sample,
    g: [f32; 3],
}

impl Keyed {
    #[inline]
    fn of(s: Sample) -> Self {
        Self {
            s,
            g: s.c.map(|v| v.max(0.0).sqrt()),
        }
    }
}

impl Shaded for Keyed {
    #[inline]
    fn sample(&self) -> Sample {
        self.s
    }

    #[inline]
    fn differs(&self, o: &Keyed) -> bool {
        let (p, q) = (&self.s, &o.s);
        if p.a != q.a || p.t.is_finite() != q.t.is_finite() {
            return true;
        }
        if p.t.is_finite() && (p.t - q.t).abs() > 0.03 * p.t.min(q.t) {
            return true;
        }
        (0..3).any(|ch| (self.g[ch] - o.g[ch]).abs() > 0.025)
    }
}

/// Write one pixel: average of `sum` (premultiplied) over `n` samples with total coverage
/// `cover`, sRGB with straight alpha.
#[inline]
pub(crate) fn write_pixel(px: &mut [u8], sum: [f32; 3], cover: f32, n: f32) {
    if cover > 0.0 {
        let inv = 1.0 / cover;
        let lut = Srgb8::table();
        px[0] = lut.encode(sum[0] * inv);
        px[1] = lut.encode(sum[1] * inv);
        px[2] = lut.encode(sum[2] * inv);
        px[3] = (cover / n * 255.0 + 0.5) as u8;
    } else {
        px.copy_from_slice(&[0; 4]);
    }
}

/// Receives finished rows: `(first row, rows)`, whole rows of straight sRGBA bytes.
pub type RowSink<'a> = dyn Fn(usize, &[u8]) + Sync + 'a;

/// A sample shader for [`render_adaptive`]: `(fragment or None for the background, x, y, row)`.
pub type ShadeFn<'a> = dyn Fn(Option<&Fragment>, f64, f64, usize) -> Sample + Sync + 'a;

/// Render a rasterised mesh with adaptive anti-aliasing (see the module doc).
///
/// `shade(fragment, x, y, row)` shades the sample at image point (`x`, `y`) of pixel row `row`,
/// with `None` for the background. `samples` extra samples for pixels that need anti-aliasing
/// (clamped 1..=64; 1 = centre only). `band_done` is called once per finished band (progress).
/// `checkpoint` per band. Output sRGB with straight alpha.
pub fn render_adaptive(
    raster: &Rasterizer,
    samples: u32,
    shade: &ShadeFn,
    ctl: &dyn Control,
    band_done: &(dyn Fn() + Sync),
) -> Result<RgbaImage, Canceled> {
    let keyed = |id: Option<u32>, x: f64, y: f64, row: usize| {
        let f = id.map(|id| raster.fragment(id, x, y));
        Keyed::of(shade(f.as_ref(), x, y, row))
    };
    render_adaptive_with(raster, samples, &keyed, false, Vec::new(), ctl, &|_, _| {
        band_done()
    })
}

/// [`render_adaptive`] for any shaded-sample type `P`: the refinement test is `P`'s
/// [`Shaded::differs`] (the terrain's skips colour steps within a cell's neighbourhood), and
/// `shade(id, x, y, row)` gets the visible screen triangle's id (`None` for the background),
/// which it resolves itself ([`Rasterizer::fragment`], or [`Rasterizer::source`] when it needs
/// only the mesh triangle).
///
/// `shade` is a type parameter rather than a `dyn Fn` so that it inlines into the sample loops:
/// through a vtable every sample paid an indirect call and returned its `P` through memory
/// (the paper case shades ~0.9 M samples per image).
///
/// `band_done(first_row, rows)` gets each finished band's rows (`4·width` bytes per row, final
/// sRGBA) as soon as it is drawn, in roughly top-to-bottom order and from the thread that drew
/// it (progress, and the streamed PNG of the terrain pipeline).
///
/// `row_background`: the caller promises that `shade(None, x, y, row)` depends on `row` only
/// (a sky that varies by image row, no holes to look through). Bands that no triangle touches
/// are then drawn by `uniform_band`: one background sample per row instead of one per pixel,
/// the same bytes (the paper case: 8 of its 19 bands are sky, ≈ 0.65 ms of CPU each before).
///
/// `buffer` becomes the image's bytes when it is `4·width·height` long (every byte is
/// overwritten); otherwise a zeroed buffer is allocated here. The terrain allocates it during
/// its set-up, which overlaps the descriptor: zeroing 2 MB took 0.2 ms with the other core
/// idle at the start of the band loop.
#[allow(clippy::too_many_arguments)]
pub fn render_adaptive_with<P: Shaded, F: Fn(Option<u32>, f64, f64, usize) -> P + Sync>(
    raster: &Rasterizer,
    samples: u32,
    shade: &F,
    row_background: bool,
    buffer: Vec<u8>,
    ctl: &dyn Control,
    band_done: &RowSink,
) -> Result<RgbaImage, Canceled> {
    let proj = raster.projection();
    let (w, h) = (proj.width as usize, proj.height as usize);
    let mut img = RgbaImage {
        width: proj.width,
        height: proj.height,
        data: if buffer.len() == w * h * 4 {
            buffer
        } else {
            vec![0u8; w * h * 4]
        },
    };
    let mut pattern = [(0.0, 0.0); 64];
    let ns = if samples.clamp(1, 64) > 1 {
        sample_pattern(samples, &mut pattern)
    } else {
        0
    };
    // Sample offsets snapped to the rasteriser's 1/256 pixel: the centre, then the pattern.
    let snap = |(x, y): (f64, f64)| (snap_offset(x), snap_offset(y));
    let pattern: Vec<(f64, f64)> = pattern[..ns].iter().map(|&o| snap(o)).collect();
    // Bands are handed out in image order from a shared counter to one loop per pool thread
    // (not split in halves as a parallel iterator would): rows then finish roughly top to bottom,
    // so `band_done` consumers that need row order (the streamed PNG) keep up, and the last
    // bands — the image's bottom, near terrain with few, large triangles, cheap — fill the time
    // one thread waits for the other's last expensive band. Each band is claimed once and
    // writes only its own rows: the bytes do not depend on which thread draws it.
    let slots: Vec<Mutex<Option<&mut [u8]>>> = img
        .data
        .chunks_mut(w * 4 * BAND)
        .map(|c| Mutex::new(Some(c)))
        .collect();
    let next = AtomicUsize::new(0);
    let loops = rayon::current_num_threads().clamp(1, slots.len().max(1));
    (0..loops).into_par_iter().try_for_each(|_| {
        let (mut vis, mut vis_aa) = (VisBuffer::default(), VisBuffer::default());
        let (mut centre, mut mask) = (Vec::<P>::new(), RowMask::default());
        loop {
            let b = next.fetch_add(1, Ordering::Relaxed);
            let Some(slot) = slots.get(b) else {
                return Ok(());
            };
            let Some(out) = slot.lock().ok().and_then(|mut o| o.take()) else {
                continue;
            };
            if let Err(e) = ctl.checkpoint() {
                // The other loops stop at their next band.
                next.store(slots.len(), Ordering::Relaxed);
                return Err(e);
            }
            if row_background && raster.band_is_empty(b) {
                uniform_band(w, h, shade, &pattern, b, out, &mut centre);
            } else {
                band(
                    raster,
                    shade,
                    &pattern,
                    b,
                    out,
                    &mut Bufs {
                        vis: &mut vis,
                        vis_aa: &mut vis_aa,
                        centre: &mut centre,
                        mask: &mut mask,
                    },
                );
            }
            band_done(b * BAND, out);
        }
    })?;
    drop(slots);
    Ok(img)
}

/// A worker's buffers for [`band`].
struct Bufs<'a, P> {
    vis: &'a mut VisBuffer,
    vis_aa: &'a mut VisBuffer,
    centre: &'a mut Vec<P>,
    mask: &'a mut RowMask,
}

/// Steps 1–5 of the module doc for band `b`, whose output rows are `out`. Compiled for AVX2 too
/// and chosen at run time (the same floating-point operations in wider registers, no FMA: the
/// same bits).
#[multiversion(targets("x86_64+avx2"))]
fn band<P: Shaded, F: Fn(Option<u32>, f64, f64, usize) -> P + Sync>(
    raster: &Rasterizer,
    shade: &F,
    pattern: &[(f64, f64)],
    b: usize,
    out: &mut [u8],
    bufs: &mut Bufs<'_, P>,
) {
    let Bufs {
        vis,
        vis_aa,
        centre,
        mask,
    } = bufs;
    let proj = raster.projection();
    let (w, h) = (proj.width as usize, proj.height as usize);
    let ns = pattern.len();
    let centre_at = [(snap_offset(0.5), snap_offset(0.5))];
    let (cx, cy) = centre_at[0];
    let (c0, c1) = (b * BAND, ((b + 1) * BAND).min(h));
    let (y0, y1) = (c0.saturating_sub(1), (c1 + 1).min(h));
    // 1–2. Centre samples of the band and its apron rows.
    raster.rasterize_band(b, y0, y1, &centre_at, vis);
    centre.clear();
    for y in y0..y1 {
        for x in 0..w {
            let (sx, sy) = (x as f64 + cx, y as f64 + cy);
            let id = vis.at(0, x, y);
            centre.push(shade((id != NO_TRI).then_some(id), sx, sy, y));
        }
    }
    let at = |x: usize, y: usize| &centre[(y - y0) * w + x];
    // 3. Pixels to refine: each pair of 4-neighbours is tested once (the test is
    // symmetric) and marks both of its pixels that lie in the band.
    mask.reset(c1 - c0, w);
    let mut any = false;
    if ns > 0 {
        for y in c0..c1 {
            for x in 1..w {
                if at(x - 1, y).differs(at(x, y)) {
                    mask.set(y - c0, x - 1);
                    mask.set(y - c0, x);
                    any = true;
                }
            }
        }
        for y in y0..y1 - 1 {
            for x in 0..w {
                if at(x, y).differs(at(x, y + 1)) {
                    if y >= c0 {
                        mask.set(y - c0, x);
                    }
                    if y + 1 < c1 {
                        mask.set(y + 1 - c0, x);
                    }
                    any = true;
                }
            }
        }
    }
    // 4. Pattern samples at the marked pixels only.
    if any {
        raster.rasterize_masked(b, c0, pattern, mask, vis_aa);
    }
    // 5. Shade and write.
    for (ry, row) in out.chunks_mut(w * 4).enumerate() {
        let y = c0 + ry;
        for (x, px) in row.chunks_exact_mut(4).enumerate() {
            let s0 = at(x, y).sample();
            let mut sum = [s0.c[0] * s0.a, s0.c[1] * s0.a, s0.c[2] * s0.a];
            let mut cover = s0.a;
            let mut n = 1.0f32;
            if any && mask.get(ry, x) {
                for (s, &(ox, oy)) in pattern.iter().enumerate() {
                    let (sx, sy) = (x as f64 + ox, y as f64 + oy);
                    let id = vis_aa.at(s, x, y);
                    let smp = shade((id != NO_TRI).then_some(id), sx, sy, y).sample();
                    for (acc, c) in sum.iter_mut().zip(smp.c) {
                        *acc += c * smp.a;
                    }
                    cover += smp.a;
                }
                n += ns as f32;
            }
            write_pixel(px, sum, cover, n);
        }
    }
}

/// [`band`] for a band that no triangle touches, when the background sample depends on the
/// row only (`row_background` of [`render_adaptive_with`]): every sample of a row is then the
/// same value, so the row is shaded once, its refinement test is the test of that value against
/// itself (horizontal pairs) and against the next row's (vertical pairs), and its pixel is
/// computed once — the same operations in the same order as [`band`] does per pixel — and
/// copied across the row. Same bytes as [`band`].
fn uniform_band<P: Shaded, F: Fn(Option<u32>, f64, f64, usize) -> P + Sync>(
    w: usize,
    h: usize,
    shade: &F,
    pattern: &[(f64, f64)],
    b: usize,
    out: &mut [u8],
    rows: &mut Vec<P>,
) {
    let ns = pattern.len();
    let (cx, cy) = (snap_offset(0.5), snap_offset(0.5));
    let (c0, c1) = (b * BAND, ((b + 1) * BAND).min(h));
    let (y0, y1) = (c0.saturating_sub(1), (c1 + 1).min(h));
    rows.clear();
    rows.extend((y0..y1).map(|y| shade(None, cx, y as f64 + cy, y)));
    let at = |y: usize| &rows[y - y0];
    for (ry, row) in out.chunks_mut(w * 4).enumerate() {
        let y = c0 + ry;
        let refine = ns > 0
            && ((w > 1 && at(y).differs(at(y)))
                || (y > y0 && at(y - 1).differs(at(y)))
                || (y + 1 < y1 && at(y).differs(at(y + 1))));
        let s0 = at(y).sample();
        let mut sum = [s0.c[0] * s0.a, s0.c[1] * s0.a, s0.c[2] * s0.a];
        let mut cover = s0.a;
        let mut n = 1.0f32;
        if refine {
            for &(ox, oy) in pattern {
                let smp = shade(None, ox, y as f64 + oy, y).sample();
                for (acc, c) in sum.iter_mut().zip(smp.c) {
                    *acc += c * smp.a;
                }
                cover += smp.a;
            }
            n += ns as f32;
        }
        let mut px = [0u8; 4];
        write_pixel(&mut px, sum, cover, n);
        for o in row.chunks_exact_mut(4) {
            o.copy_from_slice(&px);
        }
    }
}

/// A sample offset snapped to the rasteriser's 1/256 pixel (kept inside the pixel).
fn snap_offset(o: f64) -> f64 {
    (o * 256.0).round().clamp(0.0, 255.0) / 256.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::NoControl;
    use crate::geom::camera::Camera;
    use crate::render::raster::{Mesh, Projection};

    /// `uniform_band` draws the same bytes as `band` for bands without triangles, including
    /// rows whose background steps are large enough to be refined, an apron at the image edges
    /// and a last band shorter than [`BAND`].
    #[test]
    fn uniform_bands_match_the_general_band() {
        let cam = Camera {
            eye: [0.0; 3],
            target: [0.0, 0.0, -1.0],
            up: [0.0, 1.0, 0.0],
            fov_deg: 60.0,
        };
        // One triangle in the middle band only: the others are empty.
        let pos = [[-0.1, -0.05, -1.0], [0.1, -0.05, -1.0], [0.0, 0.05, -1.0]];
        let tris = [[0u32, 1, 2]];
        for (w, h) in [(37u32, 2 * BAND as u32 + 11), (1, 40)] {
            let rast = Rasterizer::new(
                &Mesh {
                    positions: &pos,
                    triangles: &tris,
                },
                &Projection::new(&cam, w, h, 1e-3),
            );
            // Background by row with steps every 5 rows (refined) and a smooth ramp between.
            let shade = |id: Option<u32>, _x: f64, _y: f64, row: usize| {
                let v = if id.is_some() {
                    0.9
                } else {
                    0.2 * (row / 5 % 3) as f32 + 0.001 * row as f32
                };
                Keyed::of(Sample {
                    c: [v, 0.5 * v, 0.25],
                    a: if row % 7 == 3 { 0.5 } else { 1.0 },
                    t: if id.is_some() { 1.0 } else { f32::INFINITY },
                })
            };
            for samples in [1, 4, 5] {
                let draw = |uniform: bool| {
                    // A dirty buffer of the right size: every byte must be overwritten.
                    let dirty = vec![0xA5; (w * h * 4) as usize];
                    render_adaptive_with(
                        &rast,
                        samples,
                        &shade,
                        uniform,
                        dirty,
                        &NoControl,
                        &|_, _| {},
                    )
                    .map(|i| i.data)
                    .unwrap_or_default()
                };
                let (general, uniform) = (draw(false), draw(true));
                assert_eq!(general.len(), (w * h * 4) as usize);
                assert!(general == uniform, "{w}×{h}, {samples} samples");
            }
        }
    }
}
