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

use super::altitude::{altitude, max_height, ElevationHistogram};
use super::smooth::Smoother;
use super::sun::{apply_sun, Sun};
use super::transfer::transfer;
use super::tsa::{tsa_rows, TsaGrid};
use crate::control::{Canceled, Control};
use crate::geom::Dem;

/// Validated descriptor parameters. The caller validates the ranges given here.
///
/// Two sets of values: [`DescriptorParams::default`], the *winter* look that shows snow on the
/// upper part of any DEM with no parameters (issue 17), and [`DescriptorParams::paper`], the
/// paper's literal settings (`"preset": "paper"` on the wire). Fields that are `Option`s are
/// resolved from the DEM when `None` (see [`Resolved`]).
///
/// **Scale.** Every length of the default is in metres, so the same terrain gives the same
/// pattern at 30 m and 120 m cells: the probe radius and the snow band are metres; the smoothing
/// is chosen per DEM to blur over `smooth_length` metres (see [`smoothing_for`]); TSA uses the
/// paper's 1-cell window on that smoothed field, where it measures the field's radius of
/// curvature whatever the cell size (the field has no detail finer than the smoothing); the
/// slope term reads slopes of the same smoothed field. The `paper` preset keeps the paper's
/// cell-based smoothing (radius 3, 5 passes).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DescriptorParams {
    /// n of the smoothing diamond 1 ≤ |di| + |dj| ≤ n (paper Fig. 8, "smoothing region"), cells,
    /// 1..=16. The paper shows 1, 2, 3, 7 and uses 3 for its Hotaka picture (Fig. 13b, 50 m
    /// mesh). Default: `None`, chosen from `smooth_length` and the cell size; `paper`: 3.
    pub smooth_radius: Option<usize>,
    /// Smoothing passes of step 1, 0..=50. Paper §5.1: 5. Default: `None`, 5 passes unless the
    /// cells are so coarse that fewer passes of the smallest diamond reach `smooth_length`;
    /// `paper`: 5.
    pub smooth_iterations: Option<usize>,
    /// Target blur of step 1 when `smooth_radius`/`smooth_iterations` are not given: the
    /// standard deviation, metres, of the smoothing kernel (the passes' combined spread),
    /// (0, 100 000]. Default: 70 m, what the paper's radius 3 × 5 passes gives on 30 m cells
    /// (σ = 2.33 cells), so the speed targets measured on 25–31 m Tanzawa are unchanged.
    pub smooth_length: f32,
    /// TSA neighbourhood half-width in cells (Chebyshev), 1..=16: neighbouring grid points within it
    /// bound the tangent sphere. 1 reaches every vertex of the paper's 12 triangles (§4.1 line 5).
    /// Cost grows as (2w + 1)². Default: 1.
    pub tsa_window: usize,
    /// Clamp for unbounded TSA (planes, ridges, convex ground), metres, > 0. Only matters for the
    /// `tsa` output: anything ≥ `probe_radius` maps to bare rock. Default: 100 000 m.
    pub tsa_max: f32,
    /// Probe (brush) radius r of Eq. 4 in metres of the exaggerated terrain, > 0. A point whose
    /// tangent sphere is smaller than the probe keeps snow in proportion. Default: 5000 m (see
    /// [`DescriptorParams::paper`]).
    pub probe_radius: f32,
    /// b of Eq. 4: how much rock shows where TSA = 0, [0, 1]. Paper: 0. Default: 0.
    pub b: f32,
    /// Snow the wind's brush leaves where it reaches (TSA ≥ r: convex and open ground), [0, 1]:
    /// the transfer becomes g'(t) = (1 − swept_snow)·g(t), so snow s ∈ [swept_snow, 1] before
    /// the altitude, sun and slope terms. *Not* Eq. 4's b: b is the rock left at TSA = 0 (in
    /// hollows), and b > 0 takes snow *from* hollows; the floor on open ground that issue 17
    /// asks of "b > 0" is this term. Paper: 0 (open ground bare). Default: 0.75 — above the
    /// band, ridges and open slopes read white with a grey tinge and hollows fully white; at
    /// 0.6 the top decile of the DEMs in `shared/data` fell below 0.6 mean snow on ridgy tops.
    pub swept_snow: f32,
    /// Factor on elevations before TSA (step 2), (0, 100]. Default: 1.
    pub vertical_exaggeration: f32,
    /// z₀, elevation (metres, original heights) below which no snow lies (step 4). Default:
    /// `None`, the `snowline_quantile` of the land cells' elevations; `paper`: 0 m.
    pub snowline: Option<f32>,
    /// Quantile of the land elevations (cells above `sea_level`) that is the snowline when
    /// `snowline` is not given, [0, 1]. Default: 0.3 (the lowest 30 % of the land, the valley
    /// floors and plains, stays bare).
    pub snowline_quantile: f32,
    /// z₁ − z₀, height of the transition band above the snowline over which the altitude factor
    /// rises from 0 to 1, metres, > 0. Default: `None`, up to the `full_snow_quantile` elevation
    /// (if that is not above the snowline, half-way from the snowline to the top).
    pub snow_band: Option<f32>,
    /// Quantile of the land elevations above which the full snow lies when `snow_band` is not
    /// given, [0, 1]. Default 0.7 (the top 30 % of the land is above the band); `paper`: 1,
    /// the highest point (the paper's ramp from the snowline to the summit).
    pub full_snow_quantile: f32,
    /// Exponent of the altitude factor (step 4), (0, 10]. Paper: 2 (a quadratic). Default: 1
    /// (a linear ramp across the band).
    pub altitude_exponent: f32,
    /// Cells at or below this elevation (metres) are sea: no snow, and left out of the
    /// quantiles. Default: 0 m (a DEM reaching the sea, bathymetry included, has no snow on the
    /// water); `None` (`paper`): no sea. For an inland depression below sea level (Dead Sea,
    /// Death Valley) give a lower value.
    pub sea_level: Option<f32>,
    /// Smoothing passes over t (step 5, paper §4.1 line 9), same diamond, 0..=50. Default:
    /// `None`, as many passes as blur t by `smooth_length`/√5 metres (the paper's one pass
    /// against five for the heights): 1 on 30 m cells, 0 on cells coarser than ≈ 45 m;
    /// `paper`: 1.
    pub descriptor_smooth_iterations: Option<usize>,
    /// Compass azimuth of the sun, degrees [0, 360]: 0 = north, 90 = east, 180 = south. Paper:
    /// south. Default: `None`, from the hemisphere: 0° (north) when the DEM's centre is south of
    /// the equator (a geographic CRS, or a WGS 84 / UTM south zone, EPSG 32701–32760), else
    /// 180°; `paper`: 180°.
    pub sun_azimuth_deg: Option<f32>,
    /// θ1, the half-width of the range of slope azimuths around the sun that melt, degrees [0, 90]
    /// (0 disables the correction). Paper §5.1: 60°. Default: 60°.
    pub sun_spread_deg: f32,
    /// Triangles flatter than this are ignored by the sun correction, degrees [0, 90). Default: 5°.
    pub sun_min_slope_deg: f32,
    /// How much of its snow a slope facing the sun straight on loses, [0, 1]: the sun factor
    /// becomes 1 − k·(1 − A). Paper: 1 (a south face steeper than 5° is bare whatever its
    /// height). Default: 0.5 — south faces above the band keep half their snow, north faces all.
    pub sun_strength: f32,
    /// Slope term: snow s is multiplied by 1 on slopes up to `slope_start_deg`, 0 from
    /// `slope_end_deg`, and a smoothstep between, degrees [0, 90], end ≥ start; 90 disables it
    /// (`paper`). Slopes of the original DEM (not smoothed, not exaggerated): the faces the DEM
    /// resolves and the render draws. (Read on the smoothed field, a 60° face of a 25 m DEM
    /// kept 0.8 snow.) A coarser DEM resolves fewer steep faces, and has fewer bare ones.
    /// Default: 35° → 60°: snow sloughs off in avalanches from about 35°, and faces steeper than
    /// 50–55° hold little (at 50° the factor is 0.35, at 55° 0.10).
    pub slope_start_deg: f32,
    /// See `slope_start_deg`. Default: 60°.
    pub slope_end_deg: f32,
}

impl Default for DescriptorParams {
    /// The winter look (issue 17): with no parameters, the upper part of any DEM is mostly white,
    /// valley floors and plains are bare, and in between the paper's descriptor decides. The
    /// reasoning per term:
    ///
    /// * altitude: a band from the 30 % to the 70 % quantile of the land elevations. Quantiles
    ///   follow the DEM's own relief, whatever its absolute height (a 200 m hill country and the
    ///   Alps both get bare lowlands and white tops), do not move when the DEM is resampled, and
    ///   are not fooled by a single spike. An absolute `snowline` still wins.
    /// * transfer: the paper's probe (5 km) decides where snow is deepest; `swept_snow` 0.75 keeps
    ///   open ground above the band snowy (the paper's g = 1 there makes every ridge bare).
    /// * sun: half strength, so sunny faces are greyer than shady ones but high south faces
    ///   keep snow; azimuth from the hemisphere.
    /// * slope: 35° → 60° (avalanche terrain: slopes beyond ~50° rarely hold snow).
    /// * smoothing: over 70 m whatever the cell size (paper: 3 cells × 5 passes).
    fn default() -> Self {
        Self {
            smooth_radius: None,
            smooth_iterations: None,
            smooth_length: 70.0,
            tsa_window: 1,
            tsa_max: 100_000.0,
            probe_radius: 5000.0,
            b: 0.0,
            swept_snow: 0.75,
            vertical_exaggeration: 1.0,
            snowline: None,
            snowline_quantile: 0.3,
            snow_band: None,
            full_snow_quantile: 0.7,
            altitude_exponent: 1.0,
            sea_level: Some(0.0),
            descriptor_smooth_iterations: None,
            sun_azimuth_deg: None,
            sun_spread_deg: 60.0,
            sun_min_slope_deg: 5.0,
            sun_strength: 0.5,
            slope_start_deg: 35.0,
            slope_end_deg: 60.0,
        }
    }
}

impl DescriptorParams {
    /// The paper's own look (`"preset": "paper"`): its values where it gives one (smoothing 5
    /// passes, θ1 = 60°, b = 0, quadratic altitude from 0 m to the summit, no sea, no slope term,
    /// full sun correction) and the values calibrated on the DEMs in `shared/data/dem` before
    /// issue 17 otherwise:
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
    ///   cells (paper), so a finer DEM resolves smaller hollows at the same probe.
    ///
    /// Outputs with this preset are byte-identical to those before the winter default existed.
    pub fn paper() -> Self {
        Self {
            smooth_radius: Some(3),
            smooth_iterations: Some(5),
            swept_snow: 0.0,
            snowline: Some(0.0),
            full_snow_quantile: 1.0,
            altitude_exponent: 2.0,
            sea_level: None,
            descriptor_smooth_iterations: Some(1),
            sun_azimuth_deg: Some(180.0),
            sun_strength: 1.0,
            slope_start_deg: 90.0,
            slope_end_deg: 90.0,
            ..Self::default()
        }
    }
}

/// Mean of di² over the diamond of radius `n` (the per-axis variance of one neighbour offset).
fn diamond_m2(n: usize) -> f64 {
    let (s, k) = super::smooth::diamond_offsets(n).fold((0.0, 0.0), |(s, k), (di, _)| {
        (s + (di * di) as f64, k + 1.0)
    });
    if k > 0.0 {
        s / k
    } else {
        0.0
    }
}

/// (diamond radius n, passes) that blur a DEM with `cell` metre cells by `length` metres. One pass
/// `(own + mean of the diamond)/2` spreads a value with per-axis variance m₂(n)/2 cells², and
/// passes add variances, so k passes give σ² = k·m₂(n)/2 cells². With 5 passes (the paper's) we
/// take the n in 1..=16 whose σ is nearest `length`; where even n = 1 over-smooths (cells coarser
/// than ≈ 0.9·`length`), n = 1 with fewer passes (0 when the cells are as coarse as the blur).
/// `radius`/`passes` given by the caller are kept.
pub fn smoothing_for(
    length: f32,
    cell: f64,
    radius: Option<usize>,
    passes: Option<usize>,
) -> (usize, usize) {
    let v = (f64::from(length) / cell.max(1e-9)).powi(2);
    let nearest_n = |k: usize| {
        (1..=16usize)
            .min_by(|&a, &b| {
                let da = (k as f64 * diamond_m2(a) / 2.0 - v).abs();
                let db = (k as f64 * diamond_m2(b) / 2.0 - v).abs();
                da.total_cmp(&db)
            })
            .unwrap_or(1)
    };
    match (radius, passes) {
        (Some(n), Some(k)) => (n, k),
        (Some(n), None) => (n, 5),
        (None, Some(k)) => (nearest_n(k.max(1)), k),
        (None, None) => {
            let one = diamond_m2(1) / 2.0; // 0.25 cells² per pass of the smallest diamond
            if v < 5.0 * one {
                (1, (v / one).round().clamp(0.0, 5.0) as usize)
            } else {
                (nearest_n(5), 5)
            }
        }
    }
}

/// The values the descriptor resolved from the DEM for the parameters left `None`, and the terms'
/// inputs, for `report.json`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Resolved {
    /// Diamond radius and passes of step 1 (the radius is step 5's too).
    pub smooth_radius: usize,
    pub smooth_iterations: usize,
    /// Passes of step 5.
    pub descriptor_smooth_iterations: usize,
    /// z₀, metres; `None` when the DEM has no land cell.
    pub snowline_m: Option<f32>,
    /// "given" or "quantile 0.3 of the land elevations".
    pub snowline_source: String,
    /// z₁, the elevation above which the altitude factor is 1, metres.
    pub full_snow_elevation_m: Option<f32>,
    /// Sun azimuth used by step 6 and the render, degrees.
    pub sun_azimuth_deg: f32,
    /// "given", "northern hemisphere (…)", "southern hemisphere (…)" or "no georeferencing".
    pub sun_azimuth_source: String,
    /// Cells at or below `sea_level`.
    pub sea_cells: usize,
}

/// The sun's azimuth for `dem`: the given one, else 0° (north) when the DEM's centre is south of
/// the equator — known from a geographic CRS's transform or a WGS 84 / UTM south zone
/// (EPSG 32701–32760) — else 180°. Also says how it was chosen.
pub fn sun_azimuth_for(dem: &Dem, given: Option<f32>) -> (f32, String) {
    if let Some(a) = given {
        return (a, "given".into());
    }
    let g = &dem.georef;
    let lat = match (g.geographic, g.transform) {
        (true, Some(t)) => {
            let (c, r) = (dem.width as f64 / 2.0, dem.height as f64 / 2.0);
            Some(t[3] + c * t[4] + r * t[5])
        }
        _ => None,
    };
    match (lat, g.epsg) {
        (Some(lat), _) if lat < 0.0 => (
            0.0,
            format!("southern hemisphere (centre latitude {lat:.2}°)"),
        ),
        (Some(lat), _) => (
            180.0,
            format!("northern hemisphere (centre latitude {lat:.2}°)"),
        ),
        (None, Some(e)) if (32701..=32760).contains(&e) => {
            (0.0, format!("southern hemisphere (EPSG:{e}, UTM south)"))
        }
        (None, Some(e)) if (32601..=32660).contains(&e) => {
            (180.0, format!("northern hemisphere (EPSG:{e}, UTM north)"))
        }
        _ => (
            180.0,
            "hemisphere unknown from the CRS: northern assumed".into(),
        ),
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
    /// What the parameters left open resolved to on this DEM.
    pub resolved: Resolved,
}

/// Share of the descriptor's time each stage takes (for progress), in stage order.
const STAGES: [(&str, f32); 7] = [
    ("smooth", 0.25),
    ("tsa", 0.38),
    ("transfer", 0.02),
    ("altitude", 0.03),
    ("smooth_t", 0.10),
    ("sun", 0.18),
    ("slope", 0.04),
];

/// Rows of TSA between progress reports and cancellation checks.
const TSA_BLOCK_ROWS: usize = 256;

/// Stages 1–6 and the slope term. Reports progress through `ctl` with stage names "smooth",
/// "tsa", "transfer", "altitude", "smooth_t", "sun", "slope" and fractions scaled into [`progress_span.0`, `progress_span.1`] of the whole job;
/// checks for cancellation between stages, smoothing passes and blocks of TSA rows.
///
/// Allocates about eight `width × height` `f32` grids at peak. Cost for 4096² on 2 cores with the
/// defaults: a few hundred milliseconds (`cargo bench --bench snow_terrain -- descriptor`).
pub fn compute(
    dem: &Dem,
    p: &DescriptorParams,
    ctl: &dyn Control,
    progress_span: (f32, f32),
) -> Result<Descriptor, Canceled> {
    compute_with(dem, p, ctl, progress_span, None)
}

/// [`compute`] with the histogram of the DEM's elevations already built (`elevations`; the
/// pipeline builds it once for the altitude band and the report's deciles). Used by step 4
/// when it counts the cells the band's quantiles need ([`ElevationHistogram::is_of`] the
/// `sea_level`), else step 4 builds its own: the same result either way.
pub fn compute_with(
    dem: &Dem,
    p: &DescriptorParams,
    ctl: &dyn Control,
    progress_span: (f32, f32),
    elevations: Option<&ElevationHistogram>,
) -> Result<Descriptor, Canceled> {
    let (w, h) = (dem.width, dem.height);
    let mut timings = Vec::with_capacity(STAGES.len());
    let mut prog = Progress::new(ctl, progress_span);
    let cell = (dem.dx * dem.dy).abs().sqrt();
    let (radius, passes) =
        smoothing_for(p.smooth_length, cell, p.smooth_radius, p.smooth_iterations);
    let (sun_azimuth_deg, sun_azimuth_source) = sun_azimuth_for(dem, p.sun_azimuth_deg);

    // 1. Smooth the heights.
    ctl.checkpoint()?;
    let t0 = Instant::now();
    let mut sm = Smoother::new(&dem.heights, w, h, radius);
    for i in 0..passes {
        prog.report(0, i as f32 / passes as f32);
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
    // snowline's resolution (the h_max scan, or the elevation quantiles), "transfer" the fused
    // pass.
    prog.report(2, 0.0);
    ctl.checkpoint()?;
    let t0 = Instant::now();
    let band = altitude_band(&dem.heights, p, elevations);
    let altitude_ms = ms(t0);
    prog.report(3, 0.0);
    ctl.checkpoint()?;
    let t0 = Instant::now();
    let (r, b, exp, keep) = (p.probe_radius, p.b, p.altitude_exponent, 1.0 - p.swept_snow);
    let sea = p.sea_level;
    sm.reload_with(&tsa, &dem.heights, |v, h| {
        if sea.is_some_and(|s| h <= s) {
            return 1.0;
        }
        let mut t = transfer(v, r, b);
        if keep != 1.0 {
            t *= keep;
        }
        match band {
            Some((z0, z1)) => altitude(t, h, z0, z1, exp),
            None => t,
        }
    });
    timings.push(("transfer", ms(t0)));
    timings.push(("altitude", altitude_ms));

    // 5. Smooth t.
    ctl.checkpoint()?;
    let t0 = Instant::now();
    let t_passes = t_passes_for(p, cell, radius);
    for i in 0..t_passes {
        prog.report(4, i as f32 / t_passes as f32);
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
        azimuth_deg: sun_azimuth_deg,
        spread_deg: p.sun_spread_deg,
        min_slope_deg: p.sun_min_slope_deg,
        strength: p.sun_strength,
    };
    apply_sun(&mut t, &smoothed, w, h, dem.dx as f32, dem.dy as f32, sun);
    timings.push(("sun", ms(t0)));

    // 6b. Slope term (issue 17) and the sea fused with the final clamp: one pass. The sea is
    // set bare again here because step 5 smoothed snow from the shore onto it.
    prog.report(6, 0.0);
    ctl.checkpoint()?;
    let t0 = Instant::now();
    let slope =
        (p.slope_start_deg < 90.0).then(|| SlopeTerm::new(p.slope_start_deg, p.slope_end_deg));
    let mut sea_cells = 0;
    if slope.is_some() || sea.is_some() {
        let (dx, dy) = (dem.dx as f32, dem.dy as f32);
        let heights = &dem.heights;
        // Rows in parallel; the sea cells counted on the way (integer sums: any order).
        sea_cells = t
            .par_chunks_mut(w.max(1))
            .enumerate()
            .map_init(Vec::new, |tan2, (r, row)| {
                slope_row(row, r, heights, w, h, dx, dy, slope.as_ref(), sea, tan2)
            })
            .sum();
    } else {
        t.par_iter_mut().for_each(|v| {
            if !v.is_nan() {
                *v = v.clamp(0.0, 1.0);
            }
        });
    }
    timings.push(("slope", ms(t0)));
    prog.report(STAGES.len(), 0.0);

    let resolved = Resolved {
        smooth_radius: radius,
        smooth_iterations: passes,
        descriptor_smooth_iterations: t_passes,
        snowline_m: band.map(|b| b.0),
        snowline_source: if p.snowline.is_some() {
            "given".into()
        } else {
            format!(
                "quantile {} of the land elevations (cells above sea_level)",
                p.snowline_quantile
            )
        },
        full_snow_elevation_m: band.map(|b| b.1),
        sun_azimuth_deg,
        sun_azimuth_source,
        sea_cells,
    };
    Ok(Descriptor {
        smoothed,
        tsa,
        t,
        timings,
        resolved,
    })
}

/// Passes of step 5: the given `descriptor_smooth_iterations`, else as many as blur t by
/// `smooth_length`/√5 metres with the diamond of `radius` on `cell`-metre cells.
fn t_passes_for(p: &DescriptorParams, cell: f64, radius: usize) -> usize {
    p.descriptor_smooth_iterations.unwrap_or_else(|| {
        let v = (f64::from(p.smooth_length) / 5f64.sqrt() / cell).powi(2);
        let per_pass = diamond_m2(radius) / 2.0;
        (v / per_pass).round().clamp(0.0, 50.0) as usize
    })
}

/// `p` with every value that [`compute`] would resolve from the whole of `dem` fixed: the
/// smoothing diamond and passes (steps 1 and 5), the snowline and band of step 4 (elevation
/// quantiles of the whole DEM) and the sun's azimuth (the hemisphere of the DEM's centre).
/// [`compute`] with the result on any window of `dem` (cropped, same `dx`, `dy`) gives, away
/// from the window's cut edges, what it gives with `p` on the whole DEM: what map tiles need
/// (`super::tiles`). `None` fields stay `None` only where nothing is left to resolve (a DEM
/// without land has no altitude band).
pub fn resolve(dem: &Dem, p: &DescriptorParams) -> DescriptorParams {
    let cell = (dem.dx * dem.dy).abs().sqrt();
    let mut r = resolve_smoothing(p, cell);
    r.sun_azimuth_deg = Some(sun_azimuth_for(dem, p.sun_azimuth_deg).0);
    if let Some((z0, z1)) = altitude_band(&dem.heights, p, None) {
        r.snowline = Some(z0);
        r.snow_band = Some(z1 - z0);
    }
    r
}

/// `p` with the smoothing of steps 1 and 5 fixed for cells of `cell` metres (the part of
/// [`resolve`] that depends on the grid's resolution, not its heights): what a map resolves
/// once per level of a DEM read by levels (`super::tiles`, a COG's overviews).
pub fn resolve_smoothing(p: &DescriptorParams, cell: f64) -> DescriptorParams {
    let (radius, passes) =
        smoothing_for(p.smooth_length, cell, p.smooth_radius, p.smooth_iterations);
    let mut r = p.clone();
    r.smooth_radius = Some(radius);
    r.smooth_iterations = Some(passes);
    r.descriptor_smooth_iterations = Some(t_passes_for(p, cell, radius));
    r
}

/// How far, in cells, the descriptor [`compute`] gives at a grid point reaches into the heights
/// with resolved parameters (see [`resolve`]): step 1's diamond × passes, TSA's window plus the
/// two cells its one-sided normals read (step 2), step 5's diamond × passes, and the one cell of
/// the sun correction's quads and the slope term's differences (step 6). A window of the DEM
/// grown by this many cells on each side holds every height a point inside it depends on.
pub fn reach(p: &DescriptorParams) -> usize {
    let radius = p.smooth_radius.unwrap_or(16);
    let passes = p.smooth_iterations.unwrap_or(50);
    let t_passes = p.descriptor_smooth_iterations.unwrap_or(50);
    radius * (passes + t_passes) + p.tsa_window + 2 + 1
}

/// Whether step 4's band comes from the land elevations' quantiles (a histogram of the cells
/// above `sea_level`: [`compute_with`]'s `elevations` when it is of those cells), not from
/// given values and the highest cell.
pub fn needs_quantiles(p: &DescriptorParams) -> bool {
    p.snowline.is_none() || (p.snow_band.is_none() && p.full_snow_quantile < 1.0)
}

/// (z₀, z₁) of the altitude term for these parameters (see [`super::altitude`]), `None` when no
/// cell is land. The `paper` preset (a given snowline, `full_snow_quantile` 1) needs only the
/// highest cell; otherwise one histogram gives both quantiles.
fn altitude_band(
    heights: &[f32],
    p: &DescriptorParams,
    elevations: Option<&ElevationHistogram>,
) -> Option<(f32, f32)> {
    if !needs_quantiles(p) {
        let z0 = p.snowline?;
        return match p.snow_band {
            Some(d) => Some((z0, z0 + d)),
            None => max_height(heights).map(|m| (z0, m)),
        };
    }
    let qs = [
        f64::from(p.snowline_quantile),
        f64::from(p.full_snow_quantile),
        1.0,
    ];
    let q = match elevations.filter(|e| e.is_of(p.sea_level)) {
        Some(e) => e.quantiles(&qs),
        None => ElevationHistogram::new(heights, p.sea_level)?.quantiles(&qs),
    };
    let z0 = p.snowline.unwrap_or(q[0]);
    let z1 = match p.snow_band {
        Some(d) => z0 + d,
        None if q[1] > z0 => q[1],
        None => z0 + 0.5 * (q[2] - z0).max(0.0),
    };
    Some((z0, z1))
}

/// The slope term's smoothstep from `start` to `end` degrees, evaluated on tan²(slope).
struct SlopeTerm {
    tan2_start: f32,
    tan2_end: f32,
    start: f32,
    inv_span: f32,
}

impl SlopeTerm {
    fn new(start_deg: f32, end_deg: f32) -> Self {
        let t2 = |d: f32| {
            let t = d.clamp(0.0, 89.99).to_radians().tan();
            t * t
        };
        let start = start_deg.to_radians();
        let span = (end_deg.to_radians() - start).max(1e-6);
        Self {
            tan2_start: t2(start_deg),
            tan2_end: t2(end_deg),
            start,
            inv_span: 1.0 / span,
        }
    }

    /// 1 up to the start slope, 0 from the end slope, smoothstep in the angle between.
    #[inline]
    fn factor(&self, tan2: f32) -> f32 {
        if tan2.is_nan() || tan2 <= self.tan2_start {
            1.0
        } else if tan2 >= self.tan2_end {
            0.0
        } else {
            let x = ((tan2.sqrt().atan() - self.start) * self.inv_span).clamp(0.0, 1.0);
            1.0 - x * x * (3.0 - 2.0 * x)
        }
    }
}

/// Step 6b on row `r` of t (`row`): the sea bare, the slope term on land, the clamp to [0, 1];
/// returns the row's sea cells. Away from the grid's edge and from nodata the gradient is the
/// central difference of [`gradient2`], computed with the same operations (the same bits) for
/// the whole row first, in a loop the compiler vectorises, into the scratch row `tan2`; where
/// that is NaN (a nodata neighbour) and at the grid's edge, [`gradient2`] itself.
#[allow(clippy::too_many_arguments)]
#[inline]
fn slope_row(
    row: &mut [f32],
    r: usize,
    heights: &[f32],
    w: usize,
    h: usize,
    dx: f32,
    dy: f32,
    slope: Option<&SlopeTerm>,
    sea: Option<f32>,
    tan2: &mut Vec<f32>,
) -> usize {
    let hrow = &heights[r * w..(r + 1) * w];
    tan2.clear();
    tan2.resize(w, f32::NAN);
    if r > 0 && r + 1 < h && w >= 3 && slope.is_some() {
        let (up, dn) = (
            &heights[(r - 1) * w + 1..r * w - 1],
            &heights[(r + 1) * w + 1..(r + 2) * w - 1],
        );
        for ((((t, &a), &b), &u), &d) in tan2[1..w - 1]
            .iter_mut()
            .zip(&hrow[..w - 2])
            .zip(&hrow[2..])
            .zip(up)
            .zip(dn)
        {
            let gx = (b - a) / (2.0 * dx);
            let gy = (d - u) / (2.0 * dy);
            *t = gx * gx + gy * gy;
        }
    }
    let mut sea_cells = 0;
    for (c, v) in row.iter_mut().enumerate() {
        if v.is_nan() {
            continue;
        }
        if sea.is_some_and(|s| hrow[c] <= s) {
            *v = 1.0;
            sea_cells += 1;
            continue;
        }
        let f = match slope {
            None => 1.0,
            Some(k) => {
                let g = tan2[c];
                k.factor(if g.is_nan() {
                    gradient2(heights, w, h, c, r, dx, dy)
                } else {
                    g
                })
            }
        };
        let s = (1.0 - *v) * f;
        *v = (1.0 - s).clamp(0.0, 1.0);
    }
    sea_cells
}

/// tan² of the slope of `f` at (c, r): central differences, one-sided at the grid's edge and next
/// to nodata; NaN when no neighbour along either axis holds data (the slope term then leaves the
/// cell alone).
#[inline]
fn gradient2(f: &[f32], w: usize, h: usize, c: usize, r: usize, dx: f32, dy: f32) -> f32 {
    let at = |c: usize, r: usize| f[r * w + c];
    let here = at(c, r);
    let diff = |a: Option<f32>, b: Option<f32>, step: f32| -> f32 {
        let a = a.filter(|v| !v.is_nan());
        let b = b.filter(|v| !v.is_nan());
        match (a, b) {
            (Some(a), Some(b)) => (b - a) / (2.0 * step),
            (Some(a), None) => (here - a) / step,
            (None, Some(b)) => (b - here) / step,
            (None, None) => f32::NAN,
        }
    };
    let gx = diff(
        c.checked_sub(1).map(|c| at(c, r)),
        (c + 1 < w).then(|| at(c + 1, r)),
        dx,
    );
    let gy = diff(
        r.checked_sub(1).map(|r| at(c, r)),
        (r + 1 < h).then(|| at(c, r + 1)),
        dy,
    );
    match (gx.is_nan(), gy.is_nan()) {
        (true, true) => f32::NAN,
        (true, false) => gy * gy,
        (false, true) => gx * gx,
        (false, false) => gx * gx + gy * gy,
    }
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
        let (name, share) = STAGES.get(i).copied().unwrap_or(("slope", 0.0));
        let f = (before + share * within.clamp(0.0, 1.0)).min(1.0);
        self.ctl.progress(name, self.start + self.span * f);
    }
}
