//! Vector maths: glam's `Vec3` (f32, meshes) and `DVec3` (f64, cameras and terrain), plus the
//! few helpers glam does not have in the form the engine relies on.
//!
//! Bit-exactness: every helper here computes exactly what the hand-written array code before it
//! did (the outputs are checked byte for byte, `scripts/checksums.sh`): [`unit`] *divides* by the
//! length, while glam's `normalize` multiplies by its reciprocal (one rounding more), so the two
//! are not interchangeable.

pub use glam::{DVec3, Vec3};

/// `v` scaled to unit length by division; the zero vector when `v` is zero or not finite
/// (degenerate normals stay harmless instead of turning into NaNs).
#[inline]
pub fn unit(v: [f32; 3]) -> [f32; 3] {
    let v = Vec3::from(v);
    let l = v.length();
    if l > 0.0 && l.is_finite() {
        (v / l).to_array()
    } else {
        [0.0; 3]
    }
}

/// Unit vector along `v`, multiplied by the reciprocal length (glam's `normalize`); `v`
/// unchanged when its length is zero (or its reciprocal not finite). The cameras' and the mesh
/// renderer's shadow-map frame.
#[inline]
pub fn normalized(v: DVec3) -> DVec3 {
    v.normalize_or(v)
}

/// [`unit`] in f64.
#[inline]
pub fn unit_f64(v: DVec3) -> DVec3 {
    let l = v.length();
    if l > 0.0 && l.is_finite() {
        v / l
    } else {
        DVec3::ZERO
    }
}

/// The unit direction at compass `azimuth_deg` (0 = north, 90 = east) and `elevation_deg` above
/// the horizon, in the world frame (X east, Y up, Z south): where the sun is seen from the scene
/// (SPEC §1 step 6, §2, §3), or where an orbiting camera stands seen from its centre.
#[inline]
pub fn sun_direction(azimuth_deg: f64, elevation_deg: f64) -> [f64; 3] {
    let (az, el) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
    // North is -Z, east is +X.
    [el.cos() * az.sin(), el.sin(), -el.cos() * az.cos()]
}

/// Box (tri-planar) projection of triangle `(a, b, c)`: the axis its face normal is most aligned
/// with (0 = X, 1 = Y, 2 = Z; ties go to the lower index, so the choice is deterministic) and the
/// two coordinates that project onto that axis plane, as `(u, v)`: X → (Z, Y), Y → (X, Z),
/// Z → (X, Y). Shared by the dust export's UVs and the snow cover's flake overlay.
pub fn box_projection(a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> (usize, [usize; 2]) {
    let (a, b, c) = (Vec3::from(a), Vec3::from(b), Vec3::from(c));
    let n = (b - a).cross(c - a).abs();
    if n.x >= n.y && n.x >= n.z {
        (0, [2, 1])
    } else if n.y >= n.z {
        (1, [0, 2])
    } else {
        (2, [0, 1])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unit_divides_and_zero_stays_zero() {
        let v = [3.0f32, 4.0, 12.0];
        assert_eq!(unit(v), [3.0 / 13.0, 4.0 / 13.0, 12.0 / 13.0]);
        assert_eq!(unit([0.0; 3]), [0.0; 3]);
        assert_eq!(unit([f32::NAN, 0.0, 1.0]), [0.0; 3]);
    }

    #[test]
    fn sun_direction_compass() {
        let n = sun_direction(0.0, 0.0);
        assert!((n[2] + 1.0).abs() < 1e-12, "north is -Z: {n:?}");
        let e = sun_direction(90.0, 0.0);
        assert!((e[0] - 1.0).abs() < 1e-12, "east is +X: {e:?}");
        assert!((sun_direction(10.0, 90.0)[1] - 1.0).abs() < 1e-12);
    }
}
