//! Pinhole camera: primary rays from a scene's [`Camera`].
//!
//! Conventions (the same as `sylva-scene`'s previews): +y is up; `fov_deg` is the full
//! *vertical* angle of view, the horizontal one follows from the aspect ratio
//! `width / height`; `right = forward × +y`, `up = right × forward`. Pixel coordinates are
//! continuous, `(0, 0)` the top-left corner of the image, x to the right, y down; pixel
//! `(i, j)` has its centre at `(i + 0.5, j + 0.5)`. Ray directions are unit vectors, so `t`
//! is a distance in metres.

use crate::ray::Ray;
use crate::scene::TraceError;
use glam::{Vec2, Vec3};
use sylva_geom::Camera;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PinholeCamera {
    pub position: Vec3,
    pub forward: Vec3,
    pub right: Vec3,
    pub up: Vec3,
    pub width: u32,
    pub height: u32,
    /// tan(fov / 2), vertical.
    tan_half: f32,
    aspect: f32,
}

impl PinholeCamera {
    /// Checks the camera: finite position and target, distinct, not looking straight up or
    /// down, 0 < fov < 180°, non-zero resolution.
    pub fn new(cam: &Camera) -> Result<PinholeCamera, TraceError> {
        let bad = |m: String| Err(TraceError::Camera(m));
        if !(cam.position.is_finite() && cam.look_at.is_finite()) {
            return bad(format!(
                "position {} and look_at {} must be finite",
                cam.position, cam.look_at
            ));
        }
        if !(cam.fov_deg > 0.0 && cam.fov_deg < 180.0) {
            return bad(format!(
                "fov must lie in (0, 180) degrees, got {}",
                cam.fov_deg
            ));
        }
        if cam.width == 0 || cam.height == 0 {
            return bad(format!(
                "resolution {}x{} must not be empty",
                cam.width, cam.height
            ));
        }
        let forward = (cam.look_at - cam.position).normalize_or_zero();
        if forward == Vec3::ZERO {
            return bad("position and look_at coincide".into());
        }
        let right = forward.cross(Vec3::Y);
        if right.length() < 1e-6 {
            return bad(
                "looking straight up or down: the image's up direction is undefined".into(),
            );
        }
        let right = right.normalize();
        let up = right.cross(forward);
        Ok(PinholeCamera {
            position: cam.position,
            forward,
            right,
            up,
            width: cam.width,
            height: cam.height,
            tan_half: (0.5 * cam.fov_deg.to_radians()).tan(),
            aspect: cam.width as f32 / cam.height as f32,
        })
    }

    /// tan(fov / 2) of the vertical field of view.
    pub fn tan_half(&self) -> f32 {
        self.tan_half
    }

    /// Width over height.
    pub fn aspect(&self) -> f32 {
        self.aspect
    }

    /// The ray through continuous pixel coordinates `(px, py)`.
    #[inline]
    pub fn ray(&self, px: f32, py: f32) -> Ray {
        let nx = (px / self.width as f32) * 2.0 - 1.0;
        let ny = 1.0 - (py / self.height as f32) * 2.0;
        let d = self.forward
            + self.right * (nx * self.tan_half * self.aspect)
            + self.up * (ny * self.tan_half);
        Ray::new(self.position, d.normalize())
    }

    /// The ray through the centre of pixel `(x, y)`.
    #[inline]
    pub fn pixel_ray(&self, x: u32, y: u32) -> Ray {
        self.ray(x as f32 + 0.5, y as f32 + 0.5)
    }

    /// Continuous pixel coordinates of world point `p`, or `None` when it is not in front of
    /// the camera. Points outside the image give coordinates outside `[0, w] × [0, h]`.
    pub fn project(&self, p: Vec3) -> Option<Vec2> {
        let d = p - self.position;
        let z = d.dot(self.forward);
        if z.is_nan() || z <= 0.0 {
            return None;
        }
        let nx = d.dot(self.right) / (z * self.tan_half * self.aspect);
        let ny = d.dot(self.up) / (z * self.tan_half);
        Some(Vec2::new(
            (nx + 1.0) * 0.5 * self.width as f32,
            (1.0 - ny) * 0.5 * self.height as f32,
        ))
    }
}
