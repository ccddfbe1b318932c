//! Step 7, colour (paper §4.2): colour = t·rock + (1 − t)·snow per grid point, computed from the
//! descriptor of the smoothed field but drawn on the original heights by the renderer.
//!
//! The blend is done in linear RGB (the paper does not say; blending sRGB bytes darkens the
//! mid-tones of a snow/rock transition). With an orthophoto the rock colour varies per grid point
//! ([`albedo_with_rock`], placed by [`super::ortho`]).

use rayon::prelude::*;

use crate::render::image::srgb8_to_linear;

/// Grid points that are sea: those with `heights[k] <= level` (NaN heights are not) take the
/// linear `color` instead of the snow/rock blend.
#[derive(Debug, Clone, Copy)]
pub struct Sea<'a> {
    /// The DEM's heights (original, not exaggerated), one per grid point.
    pub heights: &'a [f32],
    pub level: f32,
    pub color: [f32; 3],
}

/// The blend `t·rock + (1 − t)·snow` of one grid point (NaN `t`, nodata, as rock).
#[inline]
fn blend(t: f32, rock: &[f32; 3], snow: &[f32; 3]) -> [f32; 3] {
    let t = if t.is_nan() { 1.0 } else { t.clamp(0.0, 1.0) };
    std::array::from_fn(|c| t * rock[c] + (1.0 - t) * snow[c])
}

/// Linear albedo per grid point. `t` is the descriptor (NaN where nodata, coloured as rock).
/// Allocates the output.
pub fn albedo(t: &[f32], rock_srgb: [u8; 3], snow_srgb: [u8; 3]) -> Vec<[f32; 3]> {
    albedo_with_sea(t, rock_srgb, snow_srgb, None)
}

/// [`albedo`] with the sea's colour where `sea` says (in the same pass: the same values as
/// overwriting [`albedo`]'s, without a second pass over the colours).
pub fn albedo_with_sea(
    t: &[f32],
    rock_srgb: [u8; 3],
    snow_srgb: [u8; 3],
    sea: Option<Sea>,
) -> Vec<[f32; 3]> {
    let rock = rock_srgb.map(srgb8_to_linear);
    let snow = snow_srgb.map(srgb8_to_linear);
    match sea {
        None => t.par_iter().map(|&t| blend(t, &rock, &snow)).collect(),
        Some(sea) => {
            assert_eq!(sea.heights.len(), t.len(), "one height per grid point");
            t.par_iter()
                .zip(sea.heights.par_iter())
                .map(|(&t, &h)| {
                    if h <= sea.level {
                        sea.color
                    } else {
                        blend(t, &rock, &snow)
                    }
                })
                .collect()
        }
    }
}

/// [`albedo`] with a rock colour per grid point (linear RGB, from an orthophoto).
pub fn albedo_with_rock(t: &[f32], rock: &[[f32; 3]], snow_srgb: [u8; 3]) -> Vec<[f32; 3]> {
    albedo_with_rock_and_sea(t, rock, snow_srgb, None)
}

/// [`albedo_with_rock`] with the sea's colour where `sea` says (see [`albedo_with_sea`]).
pub fn albedo_with_rock_and_sea(
    t: &[f32],
    rock: &[[f32; 3]],
    snow_srgb: [u8; 3],
    sea: Option<Sea>,
) -> Vec<[f32; 3]> {
    let snow = snow_srgb.map(srgb8_to_linear);
    match sea {
        None => t
            .par_iter()
            .zip(rock.par_iter())
            .map(|(&t, rock)| blend(t, rock, &snow))
            .collect(),
        Some(sea) => {
            assert_eq!(sea.heights.len(), t.len(), "one height per grid point");
            t.par_iter()
                .zip(rock.par_iter())
                .zip(sea.heights.par_iter())
                .map(|((&t, rock), &h)| {
                    if h <= sea.level {
                        sea.color
                    } else {
                        blend(t, rock, &snow)
                    }
                })
                .collect()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blend_ends_are_the_two_colors() {
        let a = albedo(&[0.0, 1.0, 0.5], [10, 20, 30], [250, 250, 250]);
        assert_eq!(a[0], [250u8; 3].map(srgb8_to_linear));
        assert_eq!(a[1], [10u8, 20, 30].map(srgb8_to_linear));
        let mid = (srgb8_to_linear(10) + srgb8_to_linear(250)) / 2.0;
        assert!((a[2][0] - mid).abs() < 1e-6);
    }

    #[test]
    fn the_sea_in_the_pass_is_the_overwritten_blend() {
        let t = [0.0, 0.3, f32::NAN, 1.0, 0.7];
        let heights = [5.0, -1.0, 0.0, f32::NAN, 0.0];
        let sea_color = [0.1, 0.2, 0.3];
        let sea = Sea {
            heights: &heights,
            level: 0.0,
            color: sea_color,
        };
        let mut want = albedo(&t, [10, 20, 30], [250, 250, 250]);
        for (c, &h) in want.iter_mut().zip(&heights) {
            if h <= 0.0 {
                *c = sea_color;
            }
        }
        let got = albedo_with_sea(&t, [10, 20, 30], [250, 250, 250], Some(sea));
        assert_eq!(got, want);
        let rock = vec![[0.4, 0.5, 0.6]; t.len()];
        let mut want = albedo_with_rock(&t, &rock, [250, 250, 250]);
        for (c, &h) in want.iter_mut().zip(&heights) {
            if h <= 0.0 {
                *c = sea_color;
            }
        }
        assert_eq!(
            albedo_with_rock_and_sea(&t, &rock, [250, 250, 250], Some(sea)),
            want
        );
    }
}
