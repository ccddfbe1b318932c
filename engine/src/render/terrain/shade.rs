//! Shading one sample of the terrain (see "Shadows", "Sky" and "Aerial perspective" in
//! [`super`]) and the anti-aliasing test of its pixels.

use super::accel::TerrainAccel;
use super::ao::AoMap;
use super::lod::ShadeLod;
use super::scene::{Hit, Lighting};
use crate::geom::vec::DVec3;
use crate::render::adaptive::{Sample, Shaded};

/// Shade one sample.
#[derive(Clone, Copy)]
pub(super) struct Shader<'s, 'a> {
    pub(super) accel: &'s TerrainAccel<'a>,
    pub(super) light: &'s Lighting,
    pub(super) eye: [f64; 3],
    pub(super) sun: [f64; 3],
    pub(super) near: f64,
    pub(super) inv_range: f64,
    pub(super) eps: f64,
    /// Per-grid-point sun visibility (small DEMs); `None` = a shadow ray per hit.
    pub(super) sun_map: Option<&'s [u8]>,
    /// The DEM has nodata points. Without them a miss is drawn as the sky without
    /// [`TerrainAccel::through_footprint`]: a ray that enters the footprint above the edge and
    /// sinks below the lowest height crosses the (continuous) surface, so it is a hit — up to
    /// rays that graze the DEM's edge within rounding (one pixel of the paper case changed).
    pub(super) holes: bool,
    /// The sky-view factor when `ambient_occlusion` > 0.
    pub(super) ao: Option<&'s AoMap>,
    /// [`Lighting::ambient_tint`].
    pub(super) amb_tint: [f32; 3],
    /// The shading pyramid when [`Lighting::texture_lod`] is on (ray caster only).
    pub(super) lod: Option<&'s ShadeLod>,
}

impl Shader<'_, '_> {
    #[inline]
    pub(super) fn shade(&self, dir: [f64; 3], y_frac: f32) -> Px {
        match self.accel.intersect(self.eye, dir, 0.0, f64::INFINITY) {
            Some(hit) => {
                let level = self.lod.map_or(0, |l| l.level(hit.t));
                if level == 0 {
                    Px::hit(self.shade_hit(&hit), &hit)
                } else {
                    let mut px = Px::hit(self.shade_filtered(&hit, level), &hit);
                    px.lod = level as u8;
                    px
                }
            }
            None => Px::background(self.miss(dir, y_frac)),
        }
    }

    /// A ray that hit nothing: transparent through a hole, else the sky.
    #[inline]
    pub(super) fn miss(&self, dir: [f64; 3], y_frac: f32) -> Sample {
        if self.holes && self.accel.through_footprint(self.eye, dir, 0.0) {
            return Sample {
                c: [0.0; 3],
                a: 0.0,
                t: -1.0,
            };
        }
        Sample {
            c: self.sky(y_frac),
            a: 1.0,
            t: f32::INFINITY,
        }
    }

    /// Shade a surface point.
    #[inline]
    pub(super) fn shade_hit(&self, hit: &Hit) -> Sample {
        let acc = self.accel;
        let albedo = acc.hit_albedo(hit);
        let light = self.light.shading.then(|| {
            let vis = || self.sun_map.map(|m| acc.hit_bilinear_u8(hit, m));
            self.direct_and_ambient(hit, acc.hit_normal(hit), vis)
        });
        self.finish_sample(albedo, light, hit.t)
    }

    /// [`Self::shade_hit`] from the shading pyramid's level `level` ≥ 1 (`lod.rs`): the filtered
    /// albedo, normal and sun visibility at the hit's grid position; the per-hit shadow ray when
    /// there is no sun map; the sky-view factor as at level 0 (already a smooth field).
    pub(super) fn shade_filtered(&self, hit: &Hit, level: usize) -> Sample {
        let Some(lod) = self.lod else {
            return self.shade_hit(hit);
        };
        let (albedo, n, sun_vis) =
            lod.shade_inputs(level, hit.col as f64 + hit.fx, hit.row as f64 + hit.fz);
        let light = self.light.shading.then(|| {
            let vis = || sun_vis.filter(|_| self.sun_map.is_some());
            self.direct_and_ambient(hit, n, vis)
        });
        self.finish_sample(albedo, light, hit.t)
    }

    /// The sun's Lambert term (× the sun map's visibility `map_vis()` when there is a map, else
    /// a shadow ray when shadows are on) and the sky light (× the sky-view factor) at `hit`
    /// with unit normal `n`.
    #[inline]
    fn direct_and_ambient(
        &self,
        hit: &Hit,
        n: [f64; 3],
        map_vis: impl FnOnce() -> Option<f32>,
    ) -> (f32, f32) {
        let (acc, l) = (self.accel, self.light);
        let ndl = DVec3::from(n).dot(DVec3::from(self.sun));
        let mut direct = 0.0f32;
        if ndl > 0.0 && self.sun[1] > -1.0 {
            direct = ndl as f32;
            match map_vis() {
                Some(v) => direct *= v,
                None => {
                    if l.shadows && !acc.sunlit(acc.hit_position(hit), self.sun, self.eps) {
                        direct = 0.0;
                    }
                }
            }
        }
        let mut amb = l.ambient * (0.5 + 0.5 * n[1] as f32);
        if let Some(ao) = self.ao {
            let w = l.ambient_occlusion;
            amb *= 1.0 - w + w * ao.at(hit.col, hit.row, hit.fx as f32, hit.fz as f32);
        }
        (direct, amb)
    }

    /// The tail every terrain shading path shares: `albedo` lit by the sun (`direct`: cos × sun
    /// visibility) and the tinted sky ambient (`amb`) when shading is on (`light`), then hazed at
    /// distance `t` (SPEC §1 steps 7–8).
    #[inline]
    pub(super) fn finish_sample(
        &self,
        albedo: [f32; 3],
        light: Option<(f32, f32)>,
        t: f64,
    ) -> Sample {
        let mut c = albedo;
        if let Some((direct, amb)) = light {
            let l = self.light;
            for ch in 0..3 {
                c[ch] = albedo[ch] * (l.sun_color[ch] * direct + amb * self.amb_tint[ch]);
            }
        }
        self.haze(&mut c, t);
        Sample {
            c,
            a: 1.0,
            t: t as f32,
        }
    }

    /// Aerial perspective (SPEC §1 step 8) on colour `c` of a point at distance `t`.
    #[inline]
    pub(super) fn haze(&self, c: &mut [f32; 3], t: f64) {
        let l = self.light;
        if l.haze > 0.0 && l.sky_tint > 0.0 {
            // In-scattered sky light: the colour fades toward the horizon sky with depth.
            let d = ((t - self.near) * self.inv_range).clamp(0.0, 1.0) as f32;
            let k = (l.haze * d).clamp(0.0, 1.0);
            let t = l.sky_tint.clamp(0.0, 1.0);
            let mean = (c[0] + c[1] + c[2]) / 3.0;
            for (ch, v) in c.iter_mut().enumerate() {
                let target = mean + t * (l.sky_horizon[ch] - mean);
                *v += (target - *v) * k;
            }
        } else if l.haze > 0.0 {
            let d = ((t - self.near) * self.inv_range).clamp(0.0, 1.0) as f32;
            let k = (l.haze * d).clamp(0.0, 1.0);
            let mean = (c[0] + c[1] + c[2]) / 3.0;
            for v in c.iter_mut() {
                *v += (mean - *v) * k;
            }
            c[0] *= 1.0 - 0.2 * k;
            c[1] *= 1.0 - 0.1 * k;
        }
    }

    #[inline]
    pub(super) fn sky(&self, y_frac: f32) -> [f32; 3] {
        self.light.sky(y_frac)
    }
}

/// A shaded sample and the cell it hit (`u32::MAX` for the background), for the
/// anti-aliasing test [`Px::differs`].
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Px {
    pub(super) s: Sample,
    pub(super) col: u32,
    pub(super) row: u32,
    /// The shading pyramid level it was shaded at (0 = full resolution).
    pub(super) lod: u8,
}

impl Px {
    #[inline]
    pub(super) fn hit(s: Sample, hit: &Hit) -> Self {
        Self {
            s,
            col: hit.col as u32,
            row: hit.row as u32,
            lod: 0,
        }
    }

    #[inline]
    pub(super) fn background(s: Sample) -> Self {
        Self {
            s,
            col: u32::MAX,
            row: u32::MAX,
            lod: 0,
        }
    }
}

impl Shaded for Px {
    #[inline]
    fn sample(&self) -> Sample {
        self.s
    }

    /// True when a pixel whose centre is `self` needs super-sampling because of its neighbour
    /// `o`: another kind (surface / background / transparent), a depth jump over 3 %, or —
    /// unless both centres lie in the same or adjacent cells — a colour step over ~6/255 in a
    /// gamma-2 approximation of sRGB ([`Sample::differs`]' thresholds).
    ///
    /// The cell exception: between centres in the same or adjacent cells the surface is smooth
    /// (bilinear albedo, normals and sun map, continuous across cell edges), so the pattern
    /// samples would average a nearly linear colour ramp and land within rounding of the
    /// centre value; colour steps there come from shading gradients, not from edges. Where
    /// centres are cells apart (sub-pixel terrain detail) the colour test still applies.
    /// Shaded from the texture level of detail's level `L` ([`super::lod`]), both centres read
    /// a field filtered over `2^L` cells, and the exception covers the same or adjacent cells
    /// of that level: centres up to `2^(L+1) − 1` grid cells apart (1 at level 0). Neighbouring
    /// centres there lie about one footprint, `2^L`–`2^(L+1)` cells, apart, so a reach of one
    /// filtered cell (`2^L`, session 13) refined most of them for the filtered field's own
    /// gradient: 2048² → 960×540 (`winter`), 104 k → 72 k refined pixels, 0.6 % of the pixels
    /// moved by more than 3/255 (at most 42/255, single silhouette pixels).
    /// Measured on the paper case (400×200 → 900×600): refined pixels … (see the module doc).
    #[inline]
    fn differs(&self, o: &Px) -> bool {
        let (p, q) = (&self.s, &o.s);
        if p.a != q.a || p.t.is_finite() != q.t.is_finite() {
            return true;
        }
        if p.t.is_finite() {
            if (p.t - q.t).abs() > 0.03 * p.t.min(q.t) {
                return true;
            }
            // In the same or adjacent cells of the coarser filtered level the two shadings
            // share (cells 2^L grid cells wide: centres up to 2^(L+1) − 1 apart; level 0: the
            // same or adjacent cells), the colour step is the filtered field's gradient.
            let reach = (2u32 << self.lod.min(o.lod)) - 1;
            if self.col.abs_diff(o.col) <= reach && self.row.abs_diff(o.row) <= reach {
                return false;
            }
        }
        // Square roots only here: most neighbours are decided above (and equal colours, e.g.
        // the sky along a row, need none).
        p.c != q.c
            && (0..3).any(|ch| (p.c[ch].max(0.0).sqrt() - q.c[ch].max(0.0).sqrt()).abs() > 0.025)
    }
}
