//! The surface descriptor t (paper §4.1; SPEC §1 steps 1–6): 0 = fully snow-covered, 1 = bare rock.
//!
//! Snow lies in hollows, on high ground and on slopes turned away from the sun; rock shows on
//! ridges, on convex and flat wind-swept ground below the snow line and on sunny faces. The stages,
//! one module each:
//!
//! 1. [`smooth`](super::smooth): smooth the heights with the L1 diamond (`smooth_radius`,
//!    `smooth_iterations`);
//! 2. [`tsa`](super::tsa): Tangent Sphere Accessibility of the smoothed field × exaggeration;
//! 3. [`transfer`](super::transfer): Eq. 4 with the probe radius;
//! 4. [`altitude`](super::altitude): more snow higher up (SPEC's reading of §3.4.1);
//! 5. smooth t with the same diamond (`descriptor_smooth_iterations`);
//! 6. [`sun`](super::sun): slopes facing the sun melt.
//!
//! Every stage is deterministic and independent of the rayon pool size.

use std::time::Instant;

use rayon::prelude::*;

use super::altitude::{altitude, max_height};
use super::smooth::Smoother;
use super::sun::{apply_sun, Sun};
use super::transfer::transfer;
use super::tsa::{tsa_rows, TsaGrid};
use crate::control::{Canceled, Control};
use crate::geom::Dem;

/// Validated descriptor parameters. The caller validates the ranges given here.
///
/// **Scale.** Lengths are metres, so one parameter set behaves alike on DEMs with different cell
/// sizes as far as the probe is concerned: TSA (step 2) is, to first order, the radius of curvature
/// of the smoothed terrain in its most concave direction, a physical length. The smoothing radius is
/// in cells (as in the paper), so on a finer DEM it removes smaller features; the defaults were
/// checked on 10 m, ~25 m and ~70 m × 90 m DEMs.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DescriptorParams {
    /// n of the smoothing diamond 1 ≤ |di| + |dj| ≤ n (paper Fig. 8, "smoothing region"), cells,
    /// 0..=16 (0 = no smoothing). The paper shows 1, 2, 3, 7 and uses 3 for its Hotaka picture
    /// (Fig. 13b, 50 m mesh). Default: 3.
    pub smooth_radius: usize,
    /// Smoothing passes of step 1, 0..=50. Paper §5.1: 5. Default: 5.
    pub smooth_iterations: usize,
    /// TSA neighbourhood half-width in cells (Chebyshev), 1..=8: neighbouring grid points within it
    /// bound the tangent sphere. 1 reaches every vertex of the paper's 12 triangles (§4.1 line 5).
    /// Cost grows as (2w + 1)². Default: 1.
    pub tsa_window: usize,
    /// Clamp for unbounded TSA (planes, ridges, convex ground), metres, > 0. Only matters for the
    /// `tsa` output: anything ≥ `probe_radius` maps to bare rock. Default: 100 000 m.
    pub tsa_max: f32,
    /// Probe (brush) radius r of Eq. 4 in metres of the exaggerated terrain, > 0. A point whose
    /// tangent sphere is smaller than the probe keeps snow in proportion. Default: 5000 m (see
    /// [`DescriptorParams::default`]).
    pub probe_radius: f32,
    /// b of Eq. 4: how much rock shows where TSA = 0, [0, 1]. Paper: 0. Default: 0.
    pub b: f32,
    /// Factor on elevations before TSA (step 2), (0, 100]. Default: 1.
    pub vertical_exaggeration: f32,
    /// Elevation (metres, original heights) below which no snow lies (step 4). Default: 0 m.
    pub snowline: f32,
    /// Exponent of the altitude factor (step 4), (0, 10]. Paper: 2 (a quadratic). Default: 2.
    pub altitude_exponent: f32,
    /// Smoothing passes over t (step 5, paper §4.1 line 9), same diamond, 0..=50. Default: 1.
    pub descriptor_smooth_iterations: usize,
    /// Compass azimuth of the sun, degrees [0, 360): 0 = north, 90 = east, 180 = south (northern
    /// hemisphere; use 0 in the southern one). Paper: south. Default: 180°.
    pub sun_azimuth_deg: f32,
    /// θ1, the half-width of the range of slope azimuths around the sun that melt, degrees [0, 90]
    /// (0 disables the correction). Paper §5.1: 60°. Default: 60°.
    pub sun_spread_deg: f32,
    /// Triangles flatter than this are ignored by the sun correction, degrees [0, 90). Default: 5°.
    pub sun_min_slope_deg: f32,
}

impl Default for DescriptorParams {
    /// Defaults follow the paper where it gives a value (smoothing 5 passes, θ1 = 60°, b = 0,
    /// quadratic altitude) and were calibrated on the DEMs in `shared/data/dem` otherwise:
    ///
    /// * `smooth_radius` 3: the paper's choice for its real-terrain figure; with 5 passes it blurs
    ///   over ≈ 5 cells, enough to turn 25–90 m DEM noise into valleys and ridges.
    /// * `tsa_window` 1: the paper's neighbourhood, and the fast one; after smoothing, wider windows
    ///   changed the picture little (TSA measures curvature of an already smooth field).
    /// * `probe_radius` 5000 m. TSA measures, to first order, the radius of curvature of the
    ///   smoothed terrain in its most concave direction, a physical length, which is why the probe is
    ///   in metres. The paper's radii are of this size: its grid spacing is 0.1 unit for a 50 m mesh,
    ///   so Fig. 13b's 5.5 is 2.75 km and Fig. 12's 7.5 is 3.75 km. Measured TSA medians after the
    ///   default smoothing: ~3.4 km on Tanzawa (25–31 m cells), ~4.9 km on the Colorado Front Range
    ///   and ~5.1 km on Jacksboro (70–93 m cells), 0.55 km on the 10 m Maunga Whau. At 5 km about
    ///   half of a mountain DEM's cells (the concave half) keep some snow: the valley network and
    ///   cirques read white, ridges and spurs dark. At 3 km only valley floors kept snow (thin
    ///   lines); at 10 km the snow joined across most slopes. Caveat: the smoothing radius is in
    ///   cells (paper), so a finer DEM resolves smaller hollows at the same probe; raise
    ///   `smooth_radius` on DEMs finer than ~20 m for the same look.
    fn default() -> Self {
        Self {
            smooth_radius: 3,
            smooth_iterations: 5,
            tsa_window: 1,
            tsa_max: 100_000.0,
            probe_radius: 5000.0,
            b: 0.0,
            vertical_exaggeration: 1.0,
            snowline: 0.0,
            altitude_exponent: 2.0,
            descriptor_smooth_iterations: 1,
            sun_azimuth_deg: 180.0,
            sun_spread_deg: 60.0,
            sun_min_slope_deg: 5.0,
        }
    }
}

/// The descriptor and its intermediate grids (all `width × height`, NaN at nodata).
#[derive(Debug, Clone)]
pub struct Descriptor {
    /// Step 1: smoothed heights, metres (not exaggerated).
    pub smoothed: Vec<f32>,
    /// Step 2: TSA of the smoothed, exaggerated field, metres, clamped at `tsa_max`.
    pub tsa: Vec<f32>,
    /// Steps 3–6: t in [0, 1] (0 = snow, 1 = rock).
    pub t: Vec<f32>,
    /// (stage name, milliseconds) in execution order.
    pub timings: Vec<(&'static str, f64)>,
}

/// Share of the descriptor's time each stage takes (for progress), in stage order.
const STAGES: [(&str, f32); 6] = [
    ("smooth", 0.25),
    ("tsa", 0.40),
    ("transfer", 0.02),
    ("altitude", 0.03),
    ("smooth_t", 0.10),
    ("sun", 0.20),
];

/// Rows of TSA between progress reports and cancellation checks.
const TSA_BLOCK_ROWS: usize = 256;

/// Stages 1–6. Reports progress through `ctl` with stage names "smooth", "tsa", "transfer",
/// "altitude", "smooth_t", "sun" and fractions scaled into [`frac.0`, `frac.1`] of the whole job;
/// checks for cancellation between stages, smoothing passes and blocks of TSA rows.
///
/// Allocates about eight `width × height` `f32` grids at peak. Cost for 4096² on 2 cores with the
/// defaults: a few hundred milliseconds (see the `descriptor_4096` test).
pub fn compute(
    dem: &Dem,
    p: &DescriptorParams,
    ctl: &dyn Control,
    frac: (f32, f32),
) -> Result<Descriptor, Canceled> {
    let (w, h) = (dem.width, dem.height);
    let mut timings = Vec::with_capacity(STAGES.len());
    let mut prog = Progress::new(ctl, frac);

    // 1. Smooth the heights.
    ctl.checkpoint()?;
    let t0 = Instant::now();
    let mut sm = Smoother::new(&dem.heights, w, h, p.smooth_radius);
    for i in 0..p.smooth_iterations {
        prog.report(0, i as f32 / p.smooth_iterations as f32);
        ctl.checkpoint()?;
        sm.step();
    }
    let smoothed = sm.current();
    timings.push(("smooth", ms(t0)));

    // 2. TSA on the smoothed field × exaggeration.
    ctl.checkpoint()?;
    let t0 = Instant::now();
    let exaggerated: Vec<f32>;
    let field = if p.vertical_exaggeration == 1.0 {
        &smoothed
    } else {
        exaggerated = smoothed
            .iter()
            .map(|v| v * p.vertical_exaggeration)
            .collect();
        &exaggerated
    };
    let grid = TsaGrid {
        heights: field,
        width: w,
        height: h,
        dx: dem.dx as f32,
        dy: dem.dy as f32,
    };
    let mut tsa = vec![0.0f32; w * h];
    if w > 0 {
        for (k, block) in tsa.chunks_mut(w * TSA_BLOCK_ROWS).enumerate() {
            prog.report(1, (k * TSA_BLOCK_ROWS) as f32 / h as f32);
            ctl.checkpoint()?;
            let r0 = k * TSA_BLOCK_ROWS;
            let r1 = r0 + block.len() / w;
            tsa_rows(grid, p.tsa_window, p.tsa_max, r0..r1, block);
        }
    }
    timings.push(("tsa", ms(t0)));

    // 3–4. Transfer function and altitude (on the original heights), fused into the reload of
    // the smoother for step 5: one pass, no temporary grid. t is NaN exactly where the heights
    // are, so step 5 reuses the buffers and neighbour counts of step 1. "altitude" times the
    // h_max scan, "transfer" the fused pass.
    prog.report(2, 0.0);
    ctl.checkpoint()?;
    let t0 = Instant::now();
    let h_max = max_height(&dem.heights);
    let altitude_ms = ms(t0);
    prog.report(3, 0.0);
    ctl.checkpoint()?;
    let t0 = Instant::now();
    let (r, b, line, exp) = (p.probe_radius, p.b, p.snowline, p.altitude_exponent);
    sm.reload_with(&tsa, &dem.heights, |v, h| {
        let t = transfer(v, r, b);
        match h_max {
            Some(h_max) => altitude(t, h, line, h_max, exp),
            None => t,
        }
    });
    timings.push(("transfer", ms(t0)));
    timings.push(("altitude", altitude_ms));

    // 5. Smooth t.
    ctl.checkpoint()?;
    let t0 = Instant::now();
    for i in 0..p.descriptor_smooth_iterations {
        prog.report(4, i as f32 / p.descriptor_smooth_iterations as f32);
        ctl.checkpoint()?;
        sm.step();
    }
    let mut t = sm.finish();
    timings.push(("smooth_t", ms(t0)));

    // 6. Sun correction, on the smoothed (not exaggerated) heights.
    prog.report(5, 0.0);
    ctl.checkpoint()?;
    let t0 = Instant::now();
    let sun = Sun {
        azimuth_deg: p.sun_azimuth_deg,
        spread_deg: p.sun_spread_deg,
        min_slope_deg: p.sun_min_slope_deg,
    };
    apply_sun(&mut t, &smoothed, w, h, dem.dx as f32, dem.dy as f32, sun);
    t.par_iter_mut().for_each(|v| {
        if !v.is_nan() {
            *v = v.clamp(0.0, 1.0);
        }
    });
    timings.push(("sun", ms(t0)));
    prog.report(STAGES.len(), 0.0);

    Ok(Descriptor {
        smoothed,
        tsa,
        t,
        timings,
    })
}

fn ms(t0: Instant) -> f64 {
    t0.elapsed().as_secs_f64() * 1e3
}

/// Maps (stage, fraction within stage) to the job's fraction.
struct Progress<'a> {
    ctl: &'a dyn Control,
    start: f32,
    span: f32,
}

impl<'a> Progress<'a> {
    fn new(ctl: &'a dyn Control, (a, b): (f32, f32)) -> Self {
        Self {
            ctl,
            start: a,
            span: b - a,
        }
    }

    /// Stage `i` is `within` done; `i == STAGES.len()` reports the end.
    fn report(&mut self, i: usize, within: f32) {
        let before: f32 = STAGES[..i.min(STAGES.len())].iter().map(|s| s.1).sum();
        let (name, share) = STAGES.get(i).copied().unwrap_or(("sun", 0.0));
        let f = (before + share * within.clamp(0.0, 1.0)).min(1.0);
        self.ctl.progress(name, self.start + self.span * f);
    }
}
