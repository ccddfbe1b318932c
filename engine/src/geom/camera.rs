//! A perspective pin-hole camera and per-pixel ray generation.
//!
//! Frame: X = east, Y = up, Z = south (right-handed, glTF's Y-up frame). Angles are in degrees at
//! the API and radians inside. Everything is `f64`: a 4096-cell DEM at 30 m spans 120 km, and
//! `f32` ray origins lose centimetres there. The maths is glam's `DVec3`; the public fields stay
//! `[f64; 3]` (what parameters and the renderers hold).

use super::vec::{normalized as normalize, sun_direction, DVec3};

/// A perspective camera looking from `eye` at `target`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Eye position in world units (metres).
    pub eye: [f64; 3],
    /// The point the view centres on (metres).
    pub target: [f64; 3],
    /// Approximate up direction; need not be unit or orthogonal to the view. Default: `[0, 1, 0]`.
    pub up: [f64; 3],
    /// Vertical field of view, degrees, (0, 180). Default: 40.
    pub fov_deg: f64,
}

impl Camera {
    /// A camera on a sphere of radius `distance` around `center`, looking at it.
    ///
    /// `azimuth_deg` is the compass direction *from the centre to the camera*: 0 puts the camera
    /// north of the centre looking south, 90 east looking west, 180 south looking north.
    /// `elevation_deg` is the angle above the horizon (90 = straight down, clamped to ±89.9 so the
    /// up vector stays defined).
    pub fn orbit(
        center: [f64; 3],
        azimuth_deg: f64,
        elevation_deg: f64,
        distance: f64,
        fov_deg: f64,
    ) -> Self {
        // The camera stands where a sun at these angles would be seen from the centre.
        let dir = DVec3::from(sun_direction(azimuth_deg, elevation_deg.clamp(-89.9, 89.9)));
        Self {
            eye: (DVec3::from(center) + dir * distance).to_array(),
            target: center,
            up: [0.0, 1.0, 0.0],
            fov_deg,
        }
    }

    /// Distance at which a sphere of `bounding_radius` fits the vertical field of view `fov_deg`
    /// (the tighter one for landscape images), with a 5 % margin.
    pub fn auto_distance(bounding_radius: f64, fov_deg: f64) -> f64 {
        let half = (fov_deg.clamp(1.0, 179.0) * 0.5).to_radians();
        1.05 * bounding_radius / half.sin()
    }

    /// Image-plane coordinates of `p` for an image of aspect `width / height`: `[-1, 1]²` is the
    /// frame (x right, y up); `None` when `p` is behind the eye. For many points, build the
    /// [`Projector`] once ([`Camera::projector`]): the same numbers without the per-point basis.
    pub fn project_ndc(&self, p: [f64; 3], aspect: f64) -> Option<[f64; 2]> {
        self.projector(aspect).project(p)
    }

    /// The camera's basis and field of view, set up once for [`Projector::project`].
    pub fn projector(&self, aspect: f64) -> Projector {
        let (f, r, u) = self.basis();
        Projector {
            eye: DVec3::from(self.eye),
            f,
            r,
            u,
            tan_half: self.tan_half_fov(),
            aspect,
        }
    }

    /// An orbit camera (see [`Camera::orbit`]) at the smallest distance from which every point of
    /// `points` lies inside `margin` (e.g. 0.92) of the frame of an image with this `aspect`.
    /// Frames a wide, flat DEM far tighter than a bounding sphere does. Bisection on the distance
    /// between 1 % and 100 % of the bounding-sphere distance; 48 steps, no allocation.
    #[allow(clippy::too_many_arguments)]
    pub fn orbit_framing(
        center: [f64; 3],
        azimuth_deg: f64,
        elevation_deg: f64,
        fov_deg: f64,
        aspect: f64,
        points: &[[f64; 3]],
        margin: f64,
    ) -> Self {
        let radius = points
            .iter()
            .map(|p| DVec3::from(*p).distance(DVec3::from(center)))
            .fold(0.0f64, f64::max)
            .max(1e-9);
        // The sphere fits the narrower of the two fields of view at this distance.
        let vfov = fov_deg.clamp(1.0, 179.0);
        let hfov = (2.0 * ((vfov * 0.5).to_radians().tan() * aspect).atan()).to_degrees();
        let far = Self::auto_distance(radius, vfov.min(hfov)) / margin.clamp(0.1, 1.0);
        let fits = |d: f64| {
            let cam = Self::orbit(center, azimuth_deg, elevation_deg, d, fov_deg).projector(aspect);
            points.iter().all(|p| {
                cam.project(*p)
                    .is_some_and(|[x, y]| x.abs() <= margin && y.abs() <= margin)
            })
        };
        let (mut lo, mut hi) = (0.01 * far, far);
        if fits(lo) {
            hi = lo;
        }
        for _ in 0..48 {
            let mid = 0.5 * (lo + hi);
            if fits(mid) {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        Self::orbit(center, azimuth_deg, elevation_deg, hi, fov_deg)
    }

    /// [`Camera::orbit_framing`] solved in closed form instead of by bisection: along the orbit's
    /// fixed direction only the eye moves, so with `q = p − centre` and the view's basis
    /// (`f`, `r`, `u`) a point's depth at distance `d` is `q·f + d` and it lies in the frame
    /// when `|q·r| ≤ margin·tan(fov/2)·aspect·(q·f + d)` and `|q·u| ≤ margin·tan(fov/2)·(q·f + d)`:
    /// the smallest `d` is a maximum over the points, one pass (the bisection projected every
    /// point at 49 trial distances). Same bracket as the bisection (1 %–100 % of the
    /// bounding-sphere distance); the distance found agrees with the bisection's to its
    /// tolerance (2⁻⁴⁸ of the bracket), raised by 10⁻⁹ relative so that rounding keeps every
    /// point inside.
    #[allow(clippy::too_many_arguments)]
    pub fn orbit_fit(
        center: [f64; 3],
        azimuth_deg: f64,
        elevation_deg: f64,
        fov_deg: f64,
        aspect: f64,
        points: &[[f64; 3]],
        margin: f64,
    ) -> Self {
        let c = DVec3::from(center);
        let radius = points
            .iter()
            .map(|p| DVec3::from(*p).distance(c))
            .fold(0.0f64, f64::max)
            .max(1e-9);
        let vfov = fov_deg.clamp(1.0, 179.0);
        let hfov = (2.0 * ((vfov * 0.5).to_radians().tan() * aspect).atan()).to_degrees();
        let far = Self::auto_distance(radius, vfov.min(hfov)) / margin.clamp(0.1, 1.0);
        let unit = Self::orbit(center, azimuth_deg, elevation_deg, 1.0, fov_deg);
        let (f, r, u) = unit.basis();
        let th = unit.tan_half_fov();
        let (kx, ky) = (margin * th * aspect, margin * th);
        let need = points.iter().fold(f64::NEG_INFINITY, |d, p| {
            let q = DVec3::from(*p) - c;
            let z = q.dot(f);
            let reach = (q.dot(r).abs() / kx).max(q.dot(u).abs() / ky);
            // Depth must stay positive too (`project`'s 1e-9).
            d.max(reach - z).max(2e-9 - z)
        });
        let d = if need.is_nan() {
            far
        } else {
            (need + 1e-9 * need.abs()).clamp(0.01 * far, far)
        };
        Self::orbit(center, azimuth_deg, elevation_deg, d, fov_deg)
    }

    /// An orbit around the centre of the box `lo..hi` that frames its 8 corners within 92 % of
    /// an image of this `aspect` (see [`Camera::orbit_framing`]).
    pub fn frame_box(
        lo: [f64; 3],
        hi: [f64; 3],
        azimuth_deg: f64,
        elevation_deg: f64,
        fov_deg: f64,
        aspect: f64,
    ) -> Self {
        let center = [0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k]));
        let corners: [[f64; 3]; 8] = std::array::from_fn(|i| {
            [
                if i & 1 == 0 { lo[0] } else { hi[0] },
                if i & 2 == 0 { lo[1] } else { hi[1] },
                if i & 4 == 0 { lo[2] } else { hi[2] },
            ]
        });
        Self::orbit_framing(
            center,
            azimuth_deg,
            elevation_deg,
            fov_deg,
            aspect,
            &corners,
            0.92,
        )
    }

    /// The view's unit forward, right and up vectors (the rasteriser's projection shares them).
    pub fn basis(&self) -> (DVec3, DVec3, DVec3) {
        let f = normalize(DVec3::from(self.target) - DVec3::from(self.eye));
        let mut r = f.cross(DVec3::from(self.up));
        if r.length_squared() < 1e-18 {
            // Looking along `up`: pick any perpendicular.
            r = f.cross(DVec3::NEG_Z);
        }
        let r = normalize(r);
        (f, r, r.cross(f))
    }

    /// Tangent of half the vertical field of view.
    pub fn tan_half_fov(&self) -> f64 {
        (self.fov_deg.clamp(1e-3, 179.0) * 0.5).to_radians().tan()
    }

    /// Ray generator for an `width × height` image. Cheap; no allocation.
    pub fn ray_gen(&self, width: u32, height: u32) -> RayGen {
        let (f, r, u) = self.basis();
        let tan_half = self.tan_half_fov();
        let w = f64::from(width.max(1));
        let h = f64::from(height.max(1));
        RayGen {
            eye: self.eye,
            forward: f,
            right: r * (tan_half * w / h),
            up: u * tan_half,
            inv_w: 1.0 / w,
            inv_h: 1.0 / h,
        }
    }
}

/// A [`Camera`]'s projection to image-plane coordinates, with the basis computed once
/// ([`Camera::projector`]); the snow-terrain framing search projects every silhouette point of a
/// DEM for each of its 49 trial distances.
#[derive(Debug, Clone, Copy)]
pub struct Projector {
    eye: DVec3,
    f: DVec3,
    r: DVec3,
    u: DVec3,
    tan_half: f64,
    aspect: f64,
}

impl Projector {
    /// Image-plane coordinates of `p` (see [`Camera::project_ndc`]).
    #[inline]
    pub fn project(&self, p: [f64; 3]) -> Option<[f64; 2]> {
        let v = DVec3::from(p) - self.eye;
        let z = v.dot(self.f);
        if z <= 1e-9 {
            return None;
        }
        Some([
            v.dot(self.r) / (z * self.tan_half * self.aspect),
            v.dot(self.u) / (z * self.tan_half),
        ])
    }
}

/// Generates primary rays for image coordinates (pixel (0,0) is the top-left; (x + 0.5, y + 0.5)
/// is that pixel's centre).
#[derive(Debug, Clone, Copy)]
pub struct RayGen {
    pub eye: [f64; 3],
    forward: DVec3,
    right: DVec3,
    up: DVec3,
    inv_w: f64,
    inv_h: f64,
}

impl RayGen {
    /// Unit direction of the ray through image point (`x`, `y`) in pixels.
    #[inline]
    pub fn dir(&self, x: f64, y: f64) -> [f64; 3] {
        let sx = 2.0 * x * self.inv_w - 1.0;
        let sy = 1.0 - 2.0 * y * self.inv_h;
        normalize(self.forward + sx * self.right + sy * self.up).to_array()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn framing_puts_every_point_inside_and_touches_the_margin() {
        // A wide flat box seen from 30° up: tighter than the bounding sphere.
        let pts: Vec<[f64; 3]> = [-1.0f64, 1.0]
            .iter()
            .flat_map(|&x| [-1.0f64, 1.0].map(move |z| [x * 1000.0, 0.0, z * 800.0]))
            .collect();
        let cam = Camera::orbit_framing([0.0; 3], 200.0, 30.0, 40.0, 1.5, &pts, 0.9);
        let ndc: Vec<[f64; 2]> = pts
            .iter()
            .map(|p| cam.project_ndc(*p, 1.5).unwrap())
            .collect();
        let extent = ndc
            .iter()
            .flat_map(|p| [p[0].abs(), p[1].abs()])
            .fold(0.0, f64::max);
        assert!(extent <= 0.9 + 1e-9 && extent > 0.899, "{extent}");
        let sphere = Camera::auto_distance(1280.6, 40.0);
        let d = (0..3).map(|i| cam.eye[i] * cam.eye[i]).sum::<f64>().sqrt();
        assert!(d < sphere, "{d} vs {sphere}");
    }

    /// The closed form finds the bisection's distance, every point inside the margin and one
    /// on it, for scattered points around an off-origin centre, in several views.
    #[test]
    fn closed_form_framing_matches_the_bisection() {
        let pts: Vec<[f64; 3]> = (0..200)
            .map(|i| {
                let a = f64::from(i) * 0.7;
                [
                    500.0 + 3000.0 * a.sin(),
                    200.0 * (1.3 * a).cos(),
                    -200.0 + 2000.0 * (0.9 * a).cos(),
                ]
            })
            .collect();
        let c = [500.0, 0.0, -200.0];
        for (az, el, fov, aspect, m) in [
            (200.0, 30.0, 40.0, 1.5, 0.95),
            (10.0, 60.0, 25.0, 0.8, 0.9),
            (135.0, 5.0, 50.0, 16.0 / 9.0, 0.95),
        ] {
            let a = Camera::orbit_framing(c, az, el, fov, aspect, &pts, m);
            let b = Camera::orbit_fit(c, az, el, fov, aspect, &pts, m);
            let dist = |k: &Camera| {
                (0..3)
                    .map(|i| (k.eye[i] - c[i]).powi(2))
                    .sum::<f64>()
                    .sqrt()
            };
            let (da, db) = (dist(&a), dist(&b));
            assert!((da - db).abs() <= 1e-8 * da, "{da} vs {db}");
            let extent = pts
                .iter()
                .flat_map(|p| b.project_ndc(*p, aspect).unwrap())
                .map(f64::abs)
                .fold(0.0, f64::max);
            assert!(extent <= m && extent > m - 1e-6, "{extent}");
        }
    }

    #[test]
    fn orbit_compass() {
        let c = [10.0, 5.0, -3.0];
        let north = Camera::orbit(c, 0.0, 0.0, 100.0, 40.0);
        assert!((north.eye[2] - (c[2] - 100.0)).abs() < 1e-9);
        let east = Camera::orbit(c, 90.0, 0.0, 100.0, 40.0);
        assert!((east.eye[0] - (c[0] + 100.0)).abs() < 1e-9);
        let south = Camera::orbit(c, 180.0, 30.0, 100.0, 40.0);
        assert!(south.eye[2] > c[2]);
        assert!((south.eye[1] - (c[1] + 50.0)).abs() < 1e-9);
    }

    #[test]
    fn centre_ray_points_at_target_and_right_is_right() {
        let cam = Camera::orbit([0.0; 3], 180.0, 0.0, 10.0, 60.0);
        let g = cam.ray_gen(200, 100);
        let d = g.dir(100.0, 50.0);
        assert!((d[2] + 1.0).abs() < 1e-12, "{d:?}");
        // Camera south looking north: image right is east (+X), image top is up.
        assert!(g.dir(199.0, 50.0)[0] > 0.0);
        assert!(g.dir(100.0, 0.0)[1] > 0.0);
        // Vertical fov: the top edge ray is 30° above the axis.
        let top = g.dir(100.0, 0.0);
        assert!((top[1].atan2(-top[2]).to_degrees() - 30.0).abs() < 1e-9);
    }
}
