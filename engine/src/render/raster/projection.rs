//! The camera's projection onto the image, shared by the rasteriser's set-up and its callers.

use crate::geom::camera::Camera;
use crate::geom::vec::DVec3;

/// Guard band beyond each image edge, pixels. Triangles are clipped to it so fixed-point
/// coordinates stay below 2^24 (i32) and edge-function products below 2^50 (i64).
const GUARD: f64 = 16_384.0;
/// Largest image side accepted by the fixed-point coverage (larger images are clamped).
pub const MAX_SIDE: u32 = 32_768;

/// The camera's projection for a `width × height` image: the model of [`Camera::ray_gen`]
/// (pixel (0, 0) top-left, y down), plus a near plane at view depth `near` (world units, > 0).
#[derive(Debug, Clone, Copy)]
pub struct Projection {
    pub eye: [f64; 3],
    pub(super) right: DVec3,
    pub(super) up: DVec3,
    pub(super) forward: DVec3,
    /// Screen-x per unit of x/z and screen-y per unit of y/z (in NDC).
    pub(super) kx: f64,
    pub(super) ky: f64,
    pub(super) half_w: f64,
    pub(super) half_h: f64,
    pub width: u32,
    pub height: u32,
    pub near: f64,
}

impl Projection {
    /// Projection of `camera` onto a `width × height` image (each side clamped to 1..=32 768)
    /// with near plane `near` (clamped to ≥ 1e-9).
    pub fn new(camera: &Camera, width: u32, height: u32, near: f64) -> Self {
        let (f, r, u) = camera.basis();
        let tan_half = camera.tan_half_fov();
        let width = width.clamp(1, MAX_SIDE);
        let height = height.clamp(1, MAX_SIDE);
        let (w, h) = (f64::from(width), f64::from(height));
        Self {
            eye: camera.eye,
            right: r,
            up: u,
            forward: f,
            kx: h / (tan_half * w),
            ky: 1.0 / tan_half,
            half_w: 0.5 * w,
            half_h: 0.5 * h,
            width,
            height,
            near: near.max(1e-9),
        }
    }

    /// Camera-space coordinates of world point `p`: x right, y up, z forward (view depth).
    #[inline]
    pub fn to_camera(&self, p: [f64; 3]) -> [f64; 3] {
        let v = DVec3::from(p) - DVec3::from(self.eye);
        [v.dot(self.right), v.dot(self.up), v.dot(self.forward)]
    }

    /// Image position (pixels, y down) of a camera-space point with `c[2] > 0`.
    #[inline]
    pub fn screen(&self, c: [f64; 3]) -> (f64, f64) {
        let iz = 1.0 / c[2];
        (
            (c[0] * iz * self.kx + 1.0) * self.half_w,
            (1.0 - c[1] * iz * self.ky) * self.half_h,
        )
    }

    /// Clip planes `a·x + b·y + c·z + d ≥ 0` in camera space: near, then the guard band.
    pub(super) fn planes(&self) -> [[f64; 4]; 5] {
        let mx = 1.0 + GUARD / self.half_w;
        let my = 1.0 + GUARD / self.half_h;
        [
            [0.0, 0.0, 1.0, -self.near],
            [-self.kx, 0.0, mx, 0.0],
            [self.kx, 0.0, mx, 0.0],
            [0.0, -self.ky, my, 0.0],
            [0.0, self.ky, my, 0.0],
        ]
    }
}
