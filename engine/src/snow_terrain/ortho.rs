//! Step 7 with an orthophoto (SPEC §1 step 7; the paper's §6 future work: "the colour of the
//! rock … from aerial photographs"): the rock colour of each grid point is the ortho's colour
//! there instead of the single `rock_color`.
//!
//! **Placement.** When both the DEM and the ortho are georeferenced, each grid point (the centre
//! of its cell in the DEM's transform) goes through the DEM's transform to CRS coordinates and
//! through the inverse of the ortho's transform to ortho pixel coordinates, sampled bilinearly
//! (pixel centres at `+0.5`). When a cell spans more than one ortho pixel (a 90 m DEM under a
//! 30 m image) its colour is the mean over the cell's footprint — n × m bilinear samples on a
//! regular grid inside the cell, n and m the footprint's extent in ortho pixels rounded up (at
//! most 8 each) — so the rock colour is the cell's area colour, not one aliased point of it. Both must be in the same CRS: equal EPSG codes, or the same UTM zone
//! on WGS 84, ETRS89, SIRGAS 2000 or GDA94 (datums tied to ITRF that agree within about a metre,
//! far below a DEM cell); a file without an EPSG code is taken to be in the other's CRS.
//! Otherwise the request is refused naming both CRSs (no reprojection). Otherwise (a plain PNG or
//! JPEG, or a DEM without georeferencing) the image is stretched over the DEM's extent: the
//! image's outer pixel edges on the DEM's outer cell edges. Grid points outside the ortho, and its
//! transparent pixels (alpha, blended), keep `rock_color`. An ortho that covers no grid point at
//! all is refused (it is almost surely the wrong file).
//!
//! The colours are converted to linear RGB before blending, like `rock_color` ([`super::color`]).

use rayon::prelude::*;

use super::params::SnowTerrainParams;
use crate::error::InputError;
use crate::formats::ortho::{decode_ortho, Ortho};
use crate::geom::Dem;
use crate::render::image::srgb8_to_linear;

/// A rock colour per grid point (linear RGB), from an ortho placed on the DEM.
#[derive(Debug, Clone, PartialEq)]
pub struct RockColors {
    /// `dem.width × dem.height` linear RGB, or per point the fallback where the ortho is absent.
    pub rgb: Vec<[f32; 3]>,
    /// Share of grid points the ortho covers (0–1].
    pub coverage: f64,
    /// `"georeferenced"` or `"stretched"`.
    pub placement: &'static str,
}

/// The UTM zone and hemisphere of an EPSG code on a datum within a metre of WGS 84, or `None`.
fn utm_zone(epsg: u32) -> Option<(u32, bool)> {
    match epsg {
        32601..=32660 => Some((epsg - 32600, true)), // WGS 84 / UTM north
        32701..=32760 => Some((epsg - 32700, false)), // WGS 84 / UTM south
        25828..=25838 => Some((epsg - 25800, true)), // ETRS89 / UTM
        31965..=31976 => Some((epsg - 31954, true)), // SIRGAS 2000 / UTM 11N–22N
        31977..=31985 => Some((epsg - 31960, false)), // SIRGAS 2000 / UTM 17S–25S
        28348..=28358 => Some((epsg - 28300, false)), // GDA94 / MGA
        _ => None,
    }
}

/// Same CRS for this module's purpose (see the module doc).
fn same_crs(a: u32, b: u32) -> bool {
    a == b || utm_zone(a).is_some_and(|z| utm_zone(b) == Some(z))
}

fn crs_name(epsg: Option<u32>) -> String {
    epsg.map_or("an unknown CRS".into(), |e| format!("EPSG:{e}"))
}

/// The rock colours of `dem`'s grid from the orthophoto file `bytes` (decoded within
/// `max_cells` pixels), `p`'s `rock_color` where it has none. Errors: the file does not decode,
/// or [`rock_colours`]'.
pub fn decode_rock(
    dem: &Dem,
    bytes: &[u8],
    p: &SnowTerrainParams,
    max_cells: u64,
) -> Result<RockColors, InputError> {
    let ortho = decode_ortho(bytes, max_cells)?;
    rock_colors(dem, &ortho, p.rock_linear())
}

/// The rock colours of `dem`'s grid from `ortho`, `fallback` (linear) where it has none.
/// Errors: the CRSs differ, or the ortho covers no grid point (422).
pub fn rock_colors(dem: &Dem, ortho: &Ortho, fallback: [f32; 3]) -> Result<RockColors, InputError> {
    let (w, h) = (dem.width, dem.height);
    // Grid point (col, row) → ortho pixel coordinates (u, v), pixel centres at +0.5.
    let georef = match (&ortho.georef, &dem.georef.transform) {
        (Some(o), Some(t)) => {
            if let (Some(a), Some(b)) = (dem.georef.epsg, o.epsg) {
                if !same_crs(a, b) {
                    return Err(InputError::Unusable(format!(
                        "the orthophoto is in {} and the DEM in {}: send the orthophoto in the \
                         DEM's CRS (no reprojection is done)",
                        crs_name(Some(b)),
                        crs_name(Some(a)),
                    )));
                }
            }
            let ot = o.transform;
            let det = ot[1] * ot[5] - ot[2] * ot[4];
            if det == 0.0 || !det.is_finite() {
                return Err(InputError::Unusable(
                    "the orthophoto's georeferencing is degenerate (zero pixel size)".into(),
                ));
            }
            Some((*t, ot, det))
        }
        _ => None,
    };
    let (ow, oh) = (ortho.width as f64, ortho.height as f64);
    // A point of the DEM's grid, in cell units (cell centres at +0.5), → ortho pixel coordinates.
    let to_pixel = |c: f64, r: f64| -> (f64, f64) {
        match georef {
            Some((t, o, det)) => {
                let x = t[0] + c * t[1] + r * t[2];
                let y = t[3] + c * t[4] + r * t[5];
                let (px, py) = (x - o[0], y - o[3]);
                ((o[5] * px - o[2] * py) / det, (o[1] * py - o[4] * px) / det)
            }
            None => (c * ow / w as f64, r * oh / h as f64),
        }
    };
    let lin: Vec<[f32; 4]> = ortho
        .rgba
        .par_iter()
        .map(|p| {
            [
                srgb8_to_linear(p[0]),
                srgb8_to_linear(p[1]),
                srgb8_to_linear(p[2]),
                f32::from(p[3]) / 255.0,
            ]
        })
        .collect();
    let (iw, ih) = (ortho.width, ortho.height);
    let sample = |u: f64, v: f64| -> Option<[f32; 4]> {
        if !(u >= 0.0 && v >= 0.0 && u <= ow && v <= oh) {
            return None;
        }
        // Bilinear between pixel centres, clamped at the image's edge pixels.
        let (x, y) = (
            (u - 0.5).clamp(0.0, ow - 1.0),
            (v - 0.5).clamp(0.0, oh - 1.0),
        );
        let (i, j) = (x as usize, y as usize);
        let (i1, j1) = ((i + 1).min(iw - 1), (j + 1).min(ih - 1));
        let (a, b) = ((x - i as f64) as f32, (y - j as f64) as f32);
        let p = |i: usize, j: usize| lin[j * iw + i];
        let (p00, p10, p01, p11) = (p(i, j), p(i1, j), p(i, j1), p(i1, j1));
        Some(std::array::from_fn(|c| {
            (1.0 - a) * (1.0 - b) * p00[c]
                + a * (1.0 - b) * p10[c]
                + (1.0 - a) * b * p01[c]
                + a * b * p11[c]
        }))
    };
    // The footprint of one cell in ortho pixels, along the DEM's columns and rows.
    let (u0, v0) = to_pixel(0.0, 0.0);
    let (uc, vc) = to_pixel(1.0, 0.0);
    let (ur, vr) = to_pixel(0.0, 1.0);
    let extent = |a: f64, b: f64| (a.hypot(b).ceil() as usize).clamp(1, 8);
    let (nc, nr) = (extent(uc - u0, vc - v0), extent(ur - u0, vr - v0));
    let mut rgb = vec![fallback; w * h];
    let covered: usize = rgb
        .par_chunks_mut(w.max(1))
        .enumerate()
        .map(|(row, out)| {
            let mut n = 0;
            for (col, o) in out.iter_mut().enumerate() {
                // The mean (alpha-weighted colour, alpha) over the samples inside the ortho.
                let (mut sum, mut k) = ([0.0f32; 4], 0u32);
                for a in 0..nc {
                    for b in 0..nr {
                        let c = col as f64 + (a as f64 + 0.5) / nc as f64;
                        let r = row as f64 + (b as f64 + 0.5) / nr as f64;
                        let (u, v) = to_pixel(c, r);
                        if let Some(s) = sample(u, v) {
                            for i in 0..3 {
                                sum[i] += s[3] * s[i];
                            }
                            sum[3] += s[3];
                            k += 1;
                        }
                    }
                }
                if k > 0 {
                    n += 1;
                    let k = k as f32;
                    let alpha = sum[3] / k;
                    *o = std::array::from_fn(|c| sum[c] / k + (1.0 - alpha) * fallback[c]);
                }
            }
            n
        })
        .sum();
    if covered == 0 {
        return Err(InputError::Unusable(
            "the orthophoto does not overlap the DEM (no grid point lies inside it)".into(),
        ));
    }
    Ok(RockColors {
        rgb,
        coverage: covered as f64 / (w * h).max(1) as f64,
        placement: if georef.is_some() {
            "georeferenced"
        } else {
            "stretched"
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formats::ortho::OrthoGeoref;
    use crate::geom::heightfield::GeoRef;

    fn dem(transform: Option<[f64; 6]>, epsg: Option<u32>) -> Dem {
        Dem {
            width: 4,
            height: 2,
            heights: vec![0.0; 8],
            dx: 10.0,
            dy: 10.0,
            georef: GeoRef {
                transform,
                epsg,
                ..GeoRef::default()
            },
        }
    }

    fn ortho(w: usize, h: usize, georef: Option<OrthoGeoref>) -> Ortho {
        Ortho {
            width: w,
            height: h,
            rgba: (0..w * h).map(|k| [(k * 10) as u8, 0, 0, 255]).collect(),
            georef,
            format: "test",
        }
    }

    #[test]
    fn plain_images_are_stretched_pixel_for_cell() {
        // 4 × 2 image on a 4 × 2 DEM: each grid point takes its own pixel exactly.
        let r = rock_colors(&dem(None, None), &ortho(4, 2, None), [0.0; 3]).unwrap();
        assert_eq!(r.placement, "stretched");
        for k in 0..8 {
            assert_eq!(r.rgb[k][0], srgb8_to_linear((k * 10) as u8));
        }
        assert_eq!(r.coverage, 1.0);
    }

    #[test]
    fn georeferenced_images_go_through_both_transforms() {
        // DEM cells 10 m from (1000, 2000); ortho pixels 5 m from (1010, 2000): grid point
        // (1, 0) (centre x 1015, y 1995) is ortho pixel centre (0.5+0.5, 0.5) → between pixels
        // 0 and 1 of row 0... exactly pixel coordinates (1.0, 1.0): the mean of 4 pixels.
        let t = [1000.0, 10.0, 0.0, 2000.0, 0.0, -10.0];
        let o = OrthoGeoref {
            transform: [1010.0, 5.0, 0.0, 2000.0, 0.0, -5.0],
            epsg: Some(32633),
            geographic: false,
        };
        let r = rock_colors(&dem(Some(t), Some(32633)), &ortho(6, 4, Some(o)), [0.5; 3]).unwrap();
        assert_eq!(r.placement, "georeferenced");
        // Grid point (0, 0) at x 1005 is west of the ortho: fallback.
        assert_eq!(r.rgb[0], [0.5; 3]);
        let want =
            (srgb8_to_linear(0) + srgb8_to_linear(10) + srgb8_to_linear(60) + srgb8_to_linear(70))
                / 4.0;
        assert!((r.rgb[1][0] - want).abs() < 1e-6, "{} {want}", r.rgb[1][0]);
        assert!(r.coverage < 1.0 && r.coverage > 0.5);
    }

    #[test]
    fn crs_mismatch_names_both() {
        let t = [1000.0, 10.0, 0.0, 2000.0, 0.0, -10.0];
        let o = OrthoGeoref {
            transform: t,
            epsg: Some(4326),
            geographic: true,
        };
        let e = rock_colors(&dem(Some(t), Some(32633)), &ortho(4, 2, Some(o)), [0.0; 3])
            .unwrap_err()
            .to_string();
        assert!(e.contains("EPSG:4326") && e.contains("EPSG:32633"), "{e}");
        // SIRGAS 2000 / UTM 25S and WGS 84 / UTM 25S are one zone.
        let o = OrthoGeoref {
            epsg: Some(31985),
            ..o
        };
        assert!(rock_colors(&dem(Some(t), Some(32725)), &ortho(4, 2, Some(o)), [0.0; 3]).is_ok());
    }

    #[test]
    fn an_ortho_elsewhere_is_refused() {
        let t = [1000.0, 10.0, 0.0, 2000.0, 0.0, -10.0];
        let o = OrthoGeoref {
            transform: [9000.0, 10.0, 0.0, 2000.0, 0.0, -10.0],
            epsg: None,
            geographic: false,
        };
        assert!(matches!(
            rock_colors(&dem(Some(t), None), &ortho(4, 2, Some(o)), [0.0; 3]),
            Err(InputError::Unusable(_))
        ));
    }
}
