//! Fibre textures drawn as the trails of moving points (SPEC §4 step 3; paper §2.3.1–2.3.3 and §3).
//!
//! Each fibre is a walk on the texel grid:
//!
//! 1. **Start point** (§2.3.1): a uniformly random texel, accepted with probability equal to the
//!    Perlin value there ([`super::noise::TileableNoise`]), so fibre density follows the noise.
//!    Rejected candidates are redrawn, at most [`MAX_START_ATTEMPTS`] times; a fibre whose every
//!    candidate was rejected is left out (only possible where the noise is ~0 almost everywhere).
//! 2. **Motion** (§2.3.2): each step moves to one of the 8 neighbouring texels, drawn from the
//!    *motion probability map* built around the current heading h. Micro-wiggle: only the 3
//!    neighbours nearest h are allowed — the nearest k₀ = round(h / 45°) and k₀ ± 1 — with
//!    probabilities that make the mean step point exactly along h (see [`motion_map`]; our
//!    reading: the paper gives no numbers). The other 5 have probability 0.
//! 3. **Bends** (§2.3.2): `bends` times per fibre, at distinct steps drawn uniformly from
//!    1..`fiber_length` (the paper's "any step count"), the heading turns by an angle drawn
//!    uniformly from [−`bend_angle_deg`, +`bend_angle_deg`] and the map is rebuilt around it. The
//!    initial heading is uniform in [0°, 360°).
//! 4. **Length**: exactly `fiber_length` steps; the trail covers the start texel and the
//!    `fiber_length` texels stepped onto (a texel visited twice is drawn twice).
//! 5. **Brightness** (§2.3.3): the start texel's Perlin value b₀, fading by `fiber_decay` per step:
//!    b_t = b₀ · (1 − `fiber_decay`)^t at step t (the start is t = 0) — the paper's depth cue
//!    within one texture.
//! 6. **Semi-transparent compositing** (§2.3.3): each trail texel is composited *over* the texture
//!    with opacity `fiber_opacity` and grey value b_t (premultiplied: L ← α·b + (1−α)·L,
//!    A ← α + (1−α)·A), fibres in index order.
//! 7. **Tiling**: walks wrap across the texture edges (toroidal grid), and the noise tiles, so the
//!    texture tiles seamlessly.
//! 8. **Shells** (§3): one texture per shell, shell i (0 = bottom) with
//!    ⌈`fibers` · (`shells` − i) / `shells`⌉ fibres — the count decreasing linearly upward (the
//!    paper: "decreasing the number of fibres, as many textures as layers, the densest on the
//!    lowest polygons"; linear is our reading).
//!
//! **Determinism and parallelism.** Fibre j of shell i draws from its own ChaCha8 stream (key from
//! the seed and the shell, stream number j), so a walk does not depend on any other walk. Walks
//! are traced in parallel (rayon over fibres, each writing its own slice of one preallocated
//! buffer); the trail texels are then bucketed by band of 64 rows with a stable counting sort
//! (fibre order kept within a band) and the bands composited in parallel, so each texel sees the
//! same sequence of "over" operations whatever the thread count — same seed, same bytes.
//!
//! Cost: O(fibres · fiber_length) for the walks, the bucketing and the compositing; allocates the
//! trail buffer twice (8 bytes per trail texel) and the texture.

use rand_chacha::ChaCha8Rng;
use rand_core::{RngCore, SeedableRng};
use rayon::prelude::*;

use super::noise::TileableNoise;

/// Start-point candidates per fibre before it is left out (module doc, step 1).
pub const MAX_START_ATTEMPTS: u32 = 1024;

/// Rows per compositing band (fixed, so the work split never depends on the thread count; the
/// result would not either).
const BAND_ROWS: usize = 64;

/// The 8 neighbour offsets, neighbour k at angle k·45° (x right, y down the texture rows).
pub const NEIGHBOURS: [(i32, i32); 8] = [
    (1, 0),
    (1, 1),
    (0, 1),
    (-1, 1),
    (-1, 0),
    (-1, -1),
    (0, -1),
    (1, -1),
];

/// Parameters of the fibre textures (SPEC §4 step 3).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FiberParams {
    /// `fibers`: fibres in the bottom shell's texture (the densest). Default: 5 000 (at 512²,
    /// the pipeline's default texture size: ~2 fibre texels per 10 texels).
    pub fibers: u32,
    /// `fiber_length`: steps per fibre, ≥ 1. Default: 48.
    pub fiber_length: u32,
    /// `bends`: heading changes per fibre, ≤ `fiber_length` − 1. Default: 2.
    pub bends: u32,
    /// `bend_angle_deg`: largest heading change at a bend, degrees, 0–180. Default: 60.
    pub bend_angle_deg: f32,
    /// `fiber_decay`: brightness lost per step, as a fraction, 0–1. Default: 0.02.
    pub fiber_decay: f32,
    /// `fiber_opacity`: opacity of one fibre texel, 0–1. Default: 0.35.
    pub fiber_opacity: f32,
}

impl Default for FiberParams {
    fn default() -> Self {
        Self {
            fibers: 5_000,
            fiber_length: 48,
            bends: 2,
            bend_angle_deg: 60.0,
            fiber_decay: 0.02,
            fiber_opacity: 0.35,
        }
    }
}

/// One shell's fibre texture: premultiplied grey `luminance` and `alpha`, row-major, in [0, 1].
#[derive(Debug, Clone, PartialEq)]
pub struct FiberTexture {
    pub width: u32,
    pub height: u32,
    /// Premultiplied grey value (brightness × coverage).
    pub luminance: Vec<f32>,
    /// Coverage.
    pub alpha: Vec<f32>,
}

impl FiberTexture {
    /// 8-bit RGBA, straight (not premultiplied) alpha, the fibre brightness times `color` (sRGB
    /// 8-bit, used as is). Allocates.
    pub fn to_rgba8(&self, color: [u8; 3]) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.alpha.len() * 4);
        for (l, a) in self.luminance.iter().zip(&self.alpha) {
            let grey = if *a > 0.0 {
                (l / a).clamp(0.0, 1.0)
            } else {
                0.0
            };
            for c in color {
                out.push((grey * c as f32).round() as u8);
            }
            out.push((a.clamp(0.0, 1.0) * 255.0).round() as u8);
        }
        out
    }
}

/// A bend: from step `step` on (the move into the step-th texel and later), the heading is
/// `heading` radians.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bend {
    pub step: u32,
    pub heading: f32,
}

/// A fibre's walk: start texel, its brightness b₀, the initial heading, the bends, and one
/// neighbour index (0–7, see [`NEIGHBOURS`]) per step.
#[derive(Debug, Clone, PartialEq)]
pub struct FiberWalk {
    pub start: (u32, u32),
    pub brightness: f32,
    pub heading: f32,
    pub bends: Vec<Bend>,
    pub moves: Vec<u8>,
}

impl FiberWalk {
    /// The heading in force at step `t` (0-based move index).
    pub fn heading_at(&self, t: u32) -> f32 {
        self.bends
            .iter()
            .rev()
            .find(|b| b.step <= t)
            .map_or(self.heading, |b| b.heading)
    }

    /// The texels of the trail (start first), wrapped into a `width` × `height` texture.
    pub fn texels(&self, width: u32, height: u32) -> Vec<(u32, u32)> {
        let (mut x, mut y) = (self.start.0 as i64, self.start.1 as i64);
        let mut out = Vec::with_capacity(self.moves.len() + 1);
        out.push(self.start);
        for &k in &self.moves {
            let (dx, dy) = NEIGHBOURS[k as usize & 7];
            x = (x + dx as i64).rem_euclid(width as i64);
            y = (y + dy as i64).rem_euclid(height as i64);
            out.push((x as u32, y as u32));
        }
        out
    }
}

/// The 3 neighbours allowed around heading `h` (radians) — k₀ − 1, k₀, k₀ + 1 with
/// k₀ = round(h / 45°), the 3 nearest h — and their probabilities: the motion probability map of
/// the module doc, with its 5 zero entries left out. The probabilities start from 1/3 each and
/// shift weight between the two side neighbours until the mean step Σ pₖ·vₖ points exactly along
/// h (vₖ the neighbour offset); all three stay > 0 for every h (the shift is at most
/// (2/3)·tan 22.5° ≈ 0.28 < 1/3). Rejected: weights ∝ cos(vₖ, h), whose mean step leans toward
/// the nearest of the 8 directions by up to ~10° (measured), so fibres drift onto the grid axes.
#[inline]
pub fn motion_map(h: f32) -> ([u8; 3], [f32; 3]) {
    let q = std::f32::consts::FRAC_PI_4;
    let k0 = (h / q).round() as i32;
    let ks = [
        (k0 - 1).rem_euclid(8) as u8,
        k0.rem_euclid(8) as u8,
        (k0 + 1).rem_euclid(8) as u8,
    ];
    let (hs, hc) = h.sin_cos();
    let v = |k: u8| {
        let (dx, dy) = NEIGHBOURS[k as usize];
        (dx as f32, dy as f32)
    };
    // Component of an offset across the heading.
    let across = |(x, y): (f32, f32)| x * hs - y * hc;
    let third = 1.0 / 3.0;
    let p = third * (across(v(ks[0])) + across(v(ks[1])) + across(v(ks[2])));
    let lever = across(v(ks[2])) - across(v(ks[0]));
    let x = if lever.abs() > 1e-6 {
        (-p / lever).clamp(-third, third)
    } else {
        0.0
    };
    (ks, [third - x, third, third + x])
}

/// Uniform f32 in [0, 1) from 24 random bits.
#[inline]
fn unit(rng: &mut ChaCha8Rng) -> f32 {
    (rng.next_u32() >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
}

/// Uniform integer in 0..n (n ≥ 1), by 64-bit multiply-shift (bias < 2⁻³², negligible here).
#[inline]
fn below(rng: &mut ChaCha8Rng, n: u32) -> u32 {
    ((rng.next_u32() as u64 * n as u64) >> 32) as u32
}

/// The RNG stream of fibre `fiber` in shell `shell` for `seed`.
pub fn fiber_rng(seed: u64, shell: u32, fiber: u32) -> ChaCha8Rng {
    let mut key = [0u8; 32];
    key[..8].copy_from_slice(&seed.to_le_bytes());
    key[8..12].copy_from_slice(&shell.to_le_bytes());
    key[12..16].copy_from_slice(b"dust");
    let mut rng = ChaCha8Rng::from_seed(key);
    rng.set_stream(fiber as u64);
    rng
}

/// Traces fibre `fiber` of shell `shell` on a `width` × `height` texture whose noise is `noise`
/// (row-major, as from [`TileableNoise::texture`]). `None` when no start point was accepted.
/// `bends_buf` and `moves` are reused buffers (cleared here) so that hot loops do not allocate.
#[allow(clippy::too_many_arguments)]
fn trace(
    params: &FiberParams,
    noise: &[f32],
    width: u32,
    height: u32,
    seed: u64,
    shell: u32,
    fiber: u32,
    bends_buf: &mut Vec<Bend>,
    moves: &mut Vec<u8>,
) -> Option<((u32, u32), f32, f32)> {
    let mut rng = fiber_rng(seed, shell, fiber);
    let texels = width.checked_mul(height)?;
    if texels == 0 {
        return None;
    }
    let mut start = None;
    for _ in 0..MAX_START_ATTEMPTS {
        let i = below(&mut rng, texels);
        let b = noise[i as usize];
        if unit(&mut rng) < b {
            start = Some(((i % width, i / width), b));
            break;
        }
    }
    let (start, b0) = start?;
    let h0 = unit(&mut rng) * std::f32::consts::TAU;
    // Bend steps: `bends` distinct steps in 1..fiber_length (sorted).
    bends_buf.clear();
    let n_bends = params.bends.min(params.fiber_length.saturating_sub(1));
    let max_turn = params.bend_angle_deg.to_radians();
    let mut placed = 0;
    while placed < n_bends {
        let s = 1 + below(&mut rng, params.fiber_length - 1);
        if bends_buf.iter().all(|b| b.step != s) {
            bends_buf.push(Bend {
                step: s,
                heading: 0.0,
            });
            placed += 1;
        }
    }
    bends_buf.sort_by_key(|b| b.step);
    let mut h = h0;
    for b in bends_buf.iter_mut() {
        h += (2.0 * unit(&mut rng) - 1.0) * max_turn;
        b.heading = h.rem_euclid(std::f32::consts::TAU);
    }
    moves.clear();
    let (mut ks, mut w) = motion_map(h0);
    let mut next_bend = 0;
    for t in 0..params.fiber_length {
        if next_bend < bends_buf.len() && bends_buf[next_bend].step == t {
            (ks, w) = motion_map(bends_buf[next_bend].heading);
            next_bend += 1;
        }
        let r = unit(&mut rng);
        let k = if r < w[0] {
            ks[0]
        } else if r < w[0] + w[1] {
            ks[1]
        } else {
            ks[2]
        };
        moves.push(k);
    }
    Some((start, b0, h0))
}

/// The walk of fibre `fiber` of shell `shell` (see the module doc), for tests and inspection.
/// Allocates.
pub fn fiber_walk(
    params: &FiberParams,
    noise: &[f32],
    width: u32,
    height: u32,
    seed: u64,
    shell: u32,
    fiber: u32,
) -> Option<FiberWalk> {
    let mut bends = Vec::new();
    let mut moves = Vec::new();
    let (start, brightness, heading) = trace(
        params, noise, width, height, seed, shell, fiber, &mut bends, &mut moves,
    )?;
    Some(FiberWalk {
        start,
        brightness,
        heading,
        bends,
        moves,
    })
}

/// Fibre count of shell `shell` (0 = bottom) of `shells`: ⌈fibers·(shells − shell)/shells⌉.
pub fn shell_fiber_count(fibers: u32, shell: u32, shells: u32) -> u32 {
    if shells == 0 || shell >= shells {
        return 0;
    }
    let n = fibers as u64 * (shells - shell) as u64;
    n.div_ceil(shells as u64) as u32
}

/// Generates shell `shell`'s fibre texture with `count` fibres (module doc). `noise` is the
/// tileable Perlin field at texel centres (length `width`·`height`). Parallel; the same bytes for
/// any thread count. Allocates the trail buffer and the texture.
pub fn fiber_texture(
    params: &FiberParams,
    noise: &[f32],
    width: u32,
    height: u32,
    seed: u64,
    shell: u32,
    count: u32,
) -> FiberTexture {
    let (w, h) = (width as usize, height as usize);
    let texels = w * h;
    let mut tex = FiberTexture {
        width,
        height,
        luminance: vec![0.0; texels],
        alpha: vec![0.0; texels],
    };
    if texels == 0 || count == 0 || noise.len() != texels {
        return tex;
    }
    // Trail texels per fibre: start + fiber_length steps; a left-out fibre keeps the texel index
    // u32::MAX in its slot, which no band contains.
    let per = params.fiber_length as usize + 1;
    let mut trail = vec![(u32::MAX, 0.0f32); count as usize * per];
    let keep = 1.0 - params.fiber_decay.clamp(0.0, 1.0);
    trail.par_chunks_mut(per).enumerate().for_each_init(
        || (Vec::new(), Vec::new()),
        |(bends, moves), (j, slot)| {
            let Some((start, b0, _)) = trace(
                params, noise, width, height, seed, shell, j as u32, bends, moves,
            ) else {
                return;
            };
            let (mut x, mut y) = (start.0 as i64, start.1 as i64);
            let mut b = b0;
            slot[0] = ((y as u32) * width + x as u32, b);
            for (s, &k) in slot[1..].iter_mut().zip(moves.iter()) {
                let (dx, dy) = NEIGHBOURS[k as usize];
                x = (x + dx as i64).rem_euclid(w as i64);
                y = (y + dy as i64).rem_euclid(h as i64);
                b *= keep;
                *s = ((y as u32) * width + x as u32, b);
            }
        },
    );
    let alpha = params.fiber_opacity.clamp(0.0, 1.0);
    let band = BAND_ROWS * w;
    let bands = texels.div_ceil(band);
    // Bucket the trail texels by band, keeping fibre order within a bucket (a stable counting
    // sort, serial: O(trail)), then composite the bands in parallel.
    let mut start = vec![0usize; bands + 1];
    for &(i, _) in &trail {
        if i != u32::MAX {
            start[i as usize / band + 1] += 1;
        }
    }
    let mut sum = 0;
    for s in start.iter_mut() {
        sum += *s;
        *s = sum;
    }
    let mut fill = start.clone();
    let mut sorted = vec![(0u32, 0.0f32); start[bands]];
    for &(i, b) in &trail {
        if i != u32::MAX {
            let k = i as usize / band;
            sorted[fill[k]] = (i, b);
            fill[k] += 1;
        }
    }
    tex.luminance
        .par_chunks_mut(band)
        .zip(tex.alpha.par_chunks_mut(band))
        .enumerate()
        .for_each(|(bi, (lum, alp))| {
            let lo = bi * band;
            for &(i, b) in &sorted[start[bi]..start[bi + 1]] {
                let o = i as usize - lo;
                lum[o] = alpha * b + (1.0 - alpha) * lum[o];
                alp[o] = alpha + (1.0 - alpha) * alp[o];
            }
        });
    tex
}

/// One texture per shell, shell 0 (bottom, densest) first, with
/// [`shell_fiber_count`]`(params.fibers, i, shells)` fibres each.
pub fn shell_textures(
    params: &FiberParams,
    noise: &[f32],
    width: u32,
    height: u32,
    seed: u64,
    shells: u32,
) -> Vec<FiberTexture> {
    (0..shells)
        .map(|i| {
            let n = shell_fiber_count(params.fibers, i, shells);
            fiber_texture(params, noise, width, height, seed, i, n)
        })
        .collect()
}

/// Convenience: the noise field for a texture of this size (see [`TileableNoise::texture`]).
pub fn noise_field(noise: &TileableNoise, width: u32, height: u32) -> Vec<f32> {
    noise.texture(width, height)
}
