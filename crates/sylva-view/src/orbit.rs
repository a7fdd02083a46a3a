//! The page's camera: an orbit about a target point (yaw, pitch, distance), which the page
//! turns, pans and zooms, and which becomes the renderer's pinhole camera here.

use glam::Vec3;
use serde::{Deserialize, Serialize};
use sylva_geom::Camera;

/// Steepest pitch, in degrees: straight up or down the image's up direction is undefined.
pub const MAX_PITCH_DEG: f32 = 89.0;
/// Farthest the camera may be from its target, and the target from the origin, in metres.
pub const MAX_DISTANCE: f32 = 1.0e6;

/// A camera looking at `target` from `distance` metres, `yaw_deg` about the vertical (from
/// +x towards +z) and `pitch_deg` above the horizontal.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Orbit {
    pub yaw_deg: f32,
    pub pitch_deg: f32,
    pub distance: f32,
    pub target: [f32; 3],
}

impl Orbit {
    /// The orbit that sees what `camera` sees (its position about its look-at point).
    pub fn of_camera(camera: &Camera) -> Orbit {
        let d = camera.position - camera.look_at;
        let distance = d.length().max(1e-3);
        let pitch = (d.y / distance).clamp(-1.0, 1.0).asin().to_degrees();
        Orbit {
            yaw_deg: d.z.atan2(d.x).to_degrees(),
            pitch_deg: pitch.clamp(-MAX_PITCH_DEG, MAX_PITCH_DEG),
            distance,
            target: camera.look_at.to_array(),
        }
    }

    /// Checks that the orbit is a camera: finite, pitch within ±89°, distance in (0, 10⁶] m.
    pub fn check(&self) -> Result<(), String> {
        let finite = self.yaw_deg.is_finite()
            && self.pitch_deg.is_finite()
            && self.distance.is_finite()
            && self.target.iter().all(|t| t.is_finite());
        if !finite {
            return Err(format!("camera {self:?}: not numbers"));
        }
        if self.pitch_deg.abs() > MAX_PITCH_DEG {
            return Err(format!(
                "camera pitch {}°: within ±{MAX_PITCH_DEG}°",
                self.pitch_deg
            ));
        }
        if !(self.distance > 0.0 && self.distance <= MAX_DISTANCE) {
            return Err(format!(
                "camera distance {}: in (0, {MAX_DISTANCE}] metres",
                self.distance
            ));
        }
        if self.target.iter().any(|t| t.abs() > MAX_DISTANCE) {
            return Err(format!(
                "camera target {:?}: within {MAX_DISTANCE} metres of the origin",
                self.target
            ));
        }
        Ok(())
    }

    /// Where the camera stands.
    pub fn position(&self) -> Vec3 {
        let (yaw, pitch) = (self.yaw_deg.to_radians(), self.pitch_deg.to_radians());
        Vec3::from_array(self.target)
            + self.distance
                * Vec3::new(
                    pitch.cos() * yaw.cos(),
                    pitch.sin(),
                    pitch.cos() * yaw.sin(),
                )
    }

    /// The pinhole camera of this orbit at `width × height`, with `scene`'s field of view.
    pub fn camera(&self, scene: &Camera, width: u32, height: u32) -> Camera {
        Camera {
            position: self.position(),
            look_at: Vec3::from_array(self.target),
            width,
            height,
            ..*scene
        }
    }
}
