//! The one place where the light falling on the scene becomes base-solution weights.
//!
//! A model's LB light is linear in its boundary, so any lighting is `Σ_j w_j B_j` over the
//! stored fields ([`super::light::StoredBasis`]); [`RelitIllumination::weights`] is the function
//! from the world's lighting and an instance's placement to those weights. Today it takes the
//! sun (its direction carried into the instance's model space, rotation included) and a
//! user-scaled ambient `B_0`; sky and ground radiance, or a split of direct and scattered
//! light, are further terms of the same function.

use glam::{Affine3A, Vec3};
use sylva_lb::relight::{BasisWeights, RelightError};

/// How the sun's direction becomes weights of `B_1..B_18`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SunWeights {
    /// The three base solutions of the polyhedron face the direction crosses, with its
    /// barycentric weights (004 §3.1): three lookups per fragment.
    #[default]
    ThreeBasis,
    /// `w_j ∝ max(0, n_j · d)` (SPEC §3): equal to a direct LB solve for that sun, up to
    /// rounding; up to 18 lookups per fragment (5 to 9 in practice).
    Exact,
}

impl SunWeights {
    pub fn parse(s: &str) -> Option<SunWeights> {
        Some(match s {
            "three" | "3" | "three-basis" => SunWeights::ThreeBasis,
            "exact" => SunWeights::Exact,
            _ => return None,
        })
    }

    pub fn name(self) -> &'static str {
        match self {
            SunWeights::ThreeBasis => "three-basis",
            SunWeights::Exact => "exact",
        }
    }
}

/// The light that falls on the scene, in the world frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RelitIllumination {
    /// Towards the sun (any length).
    pub to_sun: Vec3,
    pub sun: SunWeights,
    /// Ambient light `a / 18 · B_0`: `a` in free space, added to the sun's 1.
    pub ambient: f64,
}

impl RelitIllumination {
    pub fn new(to_sun: Vec3, sun: SunWeights, ambient: f64) -> RelitIllumination {
        RelitIllumination {
            to_sun,
            sun,
            ambient,
        }
    }

    /// Whether the values can make weights: a finite non-zero sun, a finite ambient ≥ 0.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.to_sun.is_finite() && self.to_sun.length_squared() > 0.0) {
            return Err(format!(
                "sun direction {} must be a finite, non-zero vector",
                self.to_sun
            ));
        }
        if !(self.ambient.is_finite() && self.ambient >= 0.0) {
            return Err(format!(
                "ambient {} must be a finite number ≥ 0",
                self.ambient
            ));
        }
        Ok(())
    }

    /// The sun's travel direction in the frame `to_local` maps world vectors into (an
    /// instance's world → model transform: rotation about +y and a uniform scale; the scale
    /// does not matter, the direction is what the weights read).
    pub fn travel_in(&self, to_local: &Affine3A) -> [f64; 3] {
        let t = to_local.transform_vector3(-self.to_sun);
        [t.x as f64, t.y as f64, t.z as f64]
    }

    /// The weights of the 19 base solutions for an instance whose world → model transform is
    /// `to_model` ([`Affine3A::IDENTITY`] for the world-aligned coarse grid). Unobstructed
    /// light is `1 + ambient`.
    pub fn weights(&self, to_model: &Affine3A) -> Result<BasisWeights, RelightError> {
        let d = self.travel_in(to_model);
        let w = match self.sun {
            SunWeights::ThreeBasis => BasisWeights::three_basis(d)?,
            SunWeights::Exact => BasisWeights::exact(d)?,
        };
        w.with_ambient(self.ambient)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Quat;

    #[test]
    fn weights_follow_the_sun_into_model_space() {
        let sun = Vec3::new(0.3, 0.8, -0.2);
        let ill = RelitIllumination::new(sun, SunWeights::Exact, 0.25);
        ill.validate().unwrap();
        let w = ill.weights(&Affine3A::IDENTITY).unwrap();
        assert!((w.free_space() - 1.25).abs() < 1e-12);
        // An instance rotated by θ (and scaled) sees the sun rotated by -θ: the same weights
        // as an unrotated instance under the sun rotated by -θ.
        for deg in [17.0f32, 90.0, 200.0] {
            let q = Quat::from_rotation_y(deg.to_radians());
            let to_world = Affine3A::from_scale_rotation_translation(
                Vec3::splat(1.7),
                q,
                Vec3::new(4.0, 0.0, -3.0),
            );
            let rotated = ill.weights(&to_world.inverse()).unwrap();
            let back = RelitIllumination::new(q.inverse() * sun, SunWeights::Exact, 0.25)
                .weights(&Affine3A::IDENTITY)
                .unwrap();
            for j in 0..19 {
                assert!((rotated.0[j] - back.0[j]).abs() < 1e-6, "{deg}° w_{j}");
            }
        }
        let three = RelitIllumination {
            sun: SunWeights::ThreeBasis,
            ..ill
        };
        assert_eq!(
            three.weights(&Affine3A::IDENTITY).unwrap().terms().count(),
            4
        );
        for bad in [
            RelitIllumination::new(Vec3::ZERO, SunWeights::Exact, 0.0),
            RelitIllumination::new(Vec3::NAN, SunWeights::Exact, 0.0),
            RelitIllumination::new(sun, SunWeights::Exact, -1.0),
            RelitIllumination::new(sun, SunWeights::Exact, f64::INFINITY),
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
        assert_eq!(SunWeights::parse("exact"), Some(SunWeights::Exact));
        assert_eq!(SunWeights::parse("three"), Some(SunWeights::ThreeBasis));
        assert_eq!(SunWeights::parse("four"), None);
    }
}
