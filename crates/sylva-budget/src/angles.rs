//! Directions as the budget takes them: the sun's, and the views of the BRF.

use crate::BudgetError;
use glam::Vec3;
use serde::Serialize;

/// A direction's zenith and azimuth angles, degrees; the azimuth from +x towards +z, as a
/// scene's `[sun]` (`sylva_core::Sun::from_angles`). The sun's ([`SunAngles`]) and a view's
/// ([`ViewAngles`]) are the same angles, so the view of the sun's own direction is the hot
/// spot.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Angles {
    pub zenith_deg: f64,
    pub azimuth_deg: f64,
}

/// The sun's direction.
pub type SunAngles = Angles;
/// A view's direction, towards the viewer above the stand.
pub type ViewAngles = Angles;

impl Angles {
    /// The sun's angles as `--sun-zenith` and `--sun-azimuth` accept them.
    pub fn validate_sun(&self) -> Result<(), BudgetError> {
        self.check("--sun-zenith", "--sun-azimuth", " (the sun must be up)")
    }

    /// A view's angles as `--brf` accepts them.
    pub fn validate_view(&self) -> Result<(), BudgetError> {
        self.check("--brf zenith", "--brf azimuth", "")
    }

    fn check(&self, zenith: &str, azimuth: &str, why: &str) -> Result<(), BudgetError> {
        if !(self.zenith_deg.is_finite() && (0.0..90.0).contains(&self.zenith_deg)) {
            return Err(BudgetError::invalid(
                zenith,
                self.zenith_deg,
                format!("degrees from the vertical, 0 to below 90{why}"),
            ));
        }
        if !self.azimuth_deg.is_finite() {
            return Err(BudgetError::invalid(
                azimuth,
                self.azimuth_deg,
                "must be a finite number of degrees",
            ));
        }
        Ok(())
    }

    /// Parses a view, `ZENITH:AZIMUTH` in degrees.
    pub fn parse_view(s: &str) -> Result<ViewAngles, BudgetError> {
        let bad = || {
            BudgetError::invalid(
                "--brf",
                s,
                "expected ZENITH:AZIMUTH in degrees, e.g. 30:180",
            )
        };
        let (z, a) = s.split_once(':').ok_or_else(bad)?;
        let v = Angles {
            zenith_deg: z.trim().parse().map_err(|_| bad())?,
            azimuth_deg: a.trim().parse().map_err(|_| bad())?,
        };
        v.validate_view()?;
        Ok(v)
    }

    /// The direction sunlight from here travels (unit, downwards); NaN for angles the
    /// checks refuse.
    pub fn travel(&self) -> Vec3 {
        sylva_core::Sun::from_angles(90.0 - self.zenith_deg, self.azimuth_deg)
            .map_or(Vec3::NAN, |sun| -sun.to_sun().as_vec3())
    }

    /// The unit direction towards here (upwards): a view's.
    pub fn towards(&self) -> Vec3 {
        -self.travel()
    }
}
