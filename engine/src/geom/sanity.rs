//! Coordinate sanity: the range of world coordinates the engine computes with, checked when an
//! input is decoded (mesh positions) or a parameter is validated (a volume's `bounds`), so that
//! an absurd file is a clear error before any pipeline runs.
//!
//! **Why a bound, and why 10⁹.** Mesh positions are `f32` and the mesh pipelines square and
//! multiply them: edge lengths², triangle areas, the surface-area heuristic of the ray-casting
//! BVH (`obvhs`), dot products of positions with directions. `f32::MAX` ≈ 3.4·10³⁸, so a square
//! overflows to ∞ beyond |x| ≈ 1.8·10¹⁹ and a product of three beyond ≈ 7·10¹²; the ∞ then
//! becomes NaN in the next subtraction. That is how a mesh with finite coordinates ≥ 10²⁰ made
//! the BVH builder panic. Bounding |x| ≤ 10⁹ keeps cubes (10²⁷) and even their sum over the
//! largest accepted mesh (4·10⁶ triangles → 4·10³³) finite in `f32`. 10⁹ m is 2.6 times the
//! distance to the Moon: no scene of these pipelines (terrain, objects, clouds) comes near it,
//! while geo-referenced meshes (UTM, ≈ 10⁷ m; Earth-centred, ≈ 6.4·10⁶ m) stay accepted.
//!
//! **Volume boxes** are `f64` but the march steps through them in `f32` too, so the same bound
//! applies to their corners; in addition each side must span at least [`MIN_RELATIVE_EXTENT`] of
//! its axis' largest |coordinate| (else, in `f32`, both faces round to the same number and the
//! voxel size is 0) and at least [`MIN_EXTENT`] absolutely (squared voxel sizes of a
//! 4096-voxel axis then stay above `f32`'s smallest normal number).
//!
//! Rejected: rescaling absurd inputs silently (the units would be a guess), and checking in
//! each pipeline (the same rule three times, and after the input was accepted).

/// Largest |coordinate| accepted in world space (metres for meshes, world units for volume
/// boxes): 10⁹. See the module doc for why.
pub const MAX_COORDINATE: f64 = 1e9;

/// Smallest side of a volume box relative to the largest |coordinate| on its axis: 10⁻⁶ (about
/// 8 `f32` steps at that coordinate).
pub const MIN_RELATIVE_EXTENT: f64 = 1e-6;

/// Smallest side of a volume box in world units: 10⁻⁶.
pub const MIN_EXTENT: f64 = 1e-6;

/// The first position (index, description) that is not finite or lies beyond
/// ±[`MAX_COORDINATE`]. Allocates only for the message.
pub fn first_bad_position(positions: &[[f32; 3]]) -> Option<(usize, String)> {
    let i = positions.iter().position(|p| {
        p.iter()
            .any(|c| !c.is_finite() || f64::from(c.abs()) > MAX_COORDINATE)
    })?;
    let p = positions[i];
    let what = if p.iter().all(|c| c.is_finite()) {
        format!("coordinates within ±{MAX_COORDINATE:e} (the engine's range, see the docs)")
    } else {
        "finite coordinates".to_string()
    };
    Some((
        i,
        format!("vertex {i} is at {p:?}; positions must have {what}"),
    ))
}

/// Checks a volume box `(min, max)`: finite corners within ±[`MAX_COORDINATE`], `min < max` on
/// every axis, each side at least [`MIN_EXTENT`] and [`MIN_RELATIVE_EXTENT`] of its axis'
/// largest |coordinate|. The error names the axis and the rule.
pub fn check_box(lo: [f64; 3], hi: [f64; 3]) -> Result<(), String> {
    const AXES: [&str; 3] = ["x", "y", "z"];
    // Range first on every axis, so an out-of-range corner is named as such.
    for k in 0..3 {
        let (a, b) = (lo[k], hi[k]);
        let axis = AXES[k];
        if !(a.is_finite() && b.is_finite()) {
            return Err(format!(
                "{axis}: the corners must be finite, got {a} and {b}"
            ));
        }
        if a.abs() > MAX_COORDINATE || b.abs() > MAX_COORDINATE {
            return Err(format!(
                "{axis}: {a}..{b} reaches beyond ±{MAX_COORDINATE:e}, the engine's coordinate range"
            ));
        }
    }
    for k in 0..3 {
        let (a, b) = (lo[k], hi[k]);
        let axis = AXES[k];
        if a >= b {
            return Err(format!("{axis}: min {a} must be less than max {b}"));
        }
        let need = MIN_EXTENT.max(a.abs().max(b.abs()) * MIN_RELATIVE_EXTENT);
        if b - a < need {
            return Err(format!(
                "{axis}: the side {} is thinner than {need:e} (at least {MIN_EXTENT:e} and \
                 {MIN_RELATIVE_EXTENT:e} of the axis' largest |coordinate|)",
                b - a
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn positions_within_the_range_pass_and_the_first_outlier_is_named() {
        assert_eq!(first_bad_position(&[[0.0; 3], [-1e9, 1e9, 6.4e6]]), None);
        let (i, msg) = first_bad_position(&[[0.0; 3], [1.0, 1e20, 0.0], [f32::NAN; 3]]).unwrap();
        assert_eq!(i, 1);
        assert!(msg.contains("vertex 1") && msg.contains("1e9"), "{msg}");
        let (i, msg) = first_bad_position(&[[0.0; 3], [f32::INFINITY, 0.0, 0.0]]).unwrap();
        assert_eq!(i, 1);
        assert!(msg.contains("finite"), "{msg}");
    }

    #[test]
    fn boxes_must_be_finite_in_range_ordered_and_thick_enough() {
        assert!(check_box([0.0; 3], [1.0, 2.0, 1.0]).is_ok());
        assert!(check_box([-1e9; 3], [1e9; 3]).is_ok());
        let e = check_box([0.0; 3], [1.0, 1e12, 1.0]).unwrap_err();
        assert!(e.starts_with("y:") && e.contains("1e9"), "{e}");
        assert!(check_box([0.0, f64::NAN, 0.0], [1.0; 3])
            .unwrap_err()
            .contains("finite"));
        assert!(check_box([0.0; 3], [1.0, 0.0, 1.0])
            .unwrap_err()
            .contains("less than"));
        // Thinner than 10⁻⁶ absolutely, or relative to where the box sits.
        assert!(check_box([0.0; 3], [1e-9, 1.0, 1.0]).is_err());
        let e = check_box([1e8, 0.0, 0.0], [1e8 + 1.0, 1.0, 1.0]).unwrap_err();
        assert!(e.starts_with("x:"), "{e}");
        assert!(check_box([1e8, 0.0, 0.0], [1e8 + 1e3, 1.0, 1.0]).is_ok());
    }
}
