//! The problem every model solves: a homogeneous slab lit by a directional source.

use crate::error::{check_range, SppError};

/// A homogeneous slab of thickness `thickness` (may be `f64::INFINITY`) lit from above by a
/// directional source travelling with direction cosine `mu0` (`cos θ0`) into the slab.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Slab {
    /// Total cross section σt (extinction per unit length), > 0.
    pub sigma_t: f64,
    /// Single-scattering albedo σs/σt in `[0, 1]`.
    pub albedo: f64,
    /// Henyey-Greenstein average cosine, `|g| < 1`.
    pub g: f64,
    /// Thickness `w` in the units of `1/σt`'s length; `f64::INFINITY` for a half-space.
    pub thickness: f64,
    /// Cosine of the incidence angle, in `(0, 1]`.
    pub mu0: f64,
}

impl Slab {
    /// A validated slab; every parameter out of range is a clear error.
    pub fn new(
        sigma_t: f64,
        albedo: f64,
        g: f64,
        thickness: f64,
        mu0: f64,
    ) -> Result<Self, SppError> {
        let slab = Self {
            sigma_t,
            albedo,
            g,
            thickness,
            mu0,
        };
        slab.validate()?;
        Ok(slab)
    }

    /// A validated slab lit at `incidence_deg` degrees from the normal.
    pub fn with_incidence_deg(
        sigma_t: f64,
        albedo: f64,
        g: f64,
        thickness: f64,
        incidence_deg: f64,
    ) -> Result<Self, SppError> {
        check_range(
            "incidence",
            incidence_deg,
            0.0,
            89.0,
            "the incidence angle must be in [0, 89] degrees (grazing light never enters a plane-parallel slab)",
        )?;
        Self::new(
            sigma_t,
            albedo,
            g,
            thickness,
            incidence_deg.to_radians().cos(),
        )
    }

    /// Checks every field (a `Slab` built by hand may bypass [`Slab::new`]).
    pub fn validate(&self) -> Result<(), SppError> {
        if !(self.sigma_t.is_finite() && self.sigma_t > 0.0) {
            return Err(SppError::InvalidParameter {
                name: "sigma_t",
                value: self.sigma_t,
                reason: "the total cross section must be finite and > 0",
            });
        }
        check_range(
            "albedo",
            self.albedo,
            0.0,
            1.0,
            "the albedo must be in [0, 1]",
        )?;
        if !(self.g.is_finite() && self.g.abs() < 1.0) {
            return Err(SppError::InvalidParameter {
                name: "g",
                value: self.g,
                reason: "the Henyey-Greenstein g must satisfy |g| < 1",
            });
        }
        if self.thickness.is_nan() || self.thickness <= 0.0 {
            return Err(SppError::InvalidParameter {
                name: "thickness",
                value: self.thickness,
                reason: "the thickness must be > 0 (infinity for a half-space)",
            });
        }
        if !(self.mu0.is_finite() && self.mu0 >= 0.01 && self.mu0 <= 1.0) {
            return Err(SppError::InvalidParameter {
                name: "mu0",
                value: self.mu0,
                reason: "the incidence cosine must be in [0.01, 1]",
            });
        }
        Ok(())
    }

    /// Scattering cross section σs = albedo · σt.
    pub fn sigma_s(&self) -> f64 {
        self.albedo * self.sigma_t
    }

    /// Whether the slab is a half-space.
    pub fn is_semi_infinite(&self) -> bool {
        self.thickness.is_infinite()
    }

    /// Attenuation of the unscattered beam at depth `z`: `exp(-σt z / mu0)`.
    pub fn direct(&self, z: f64) -> f64 {
        (-self.sigma_t * z / self.mu0).exp()
    }

    /// Checks a depth to evaluate at.
    pub fn check_depth(&self, z: f64) -> Result<(), SppError> {
        if z.is_nan() || z < 0.0 || z > self.thickness || z.is_infinite() {
            return Err(SppError::InvalidParameter {
                name: "z",
                value: z,
                reason: "the depth must be finite and inside [0, thickness]",
            });
        }
        Ok(())
    }
}

/// A direction of travel: `mu` is the cosine with +z (into the slab), `phi` the azimuth from
/// the plane of incidence, radians.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Direction {
    pub mu: f64,
    pub phi: f64,
}

impl Direction {
    /// A checked direction; `mu` must be in `[-1, 1]` and not 0 (a horizontal ray never meets a
    /// boundary of an infinite slab).
    pub fn new(mu: f64, phi: f64) -> Result<Self, SppError> {
        check_range("mu", mu, -1.0, 1.0, "a direction cosine must be in [-1, 1]")?;
        if mu == 0.0 {
            return Err(SppError::InvalidParameter {
                name: "mu",
                value: mu,
                reason: "horizontal directions (mu = 0) are not supported",
            });
        }
        if !phi.is_finite() {
            return Err(SppError::InvalidParameter {
                name: "phi",
                value: phi,
                reason: "the azimuth must be finite",
            });
        }
        Ok(Self { mu, phi })
    }

    /// Cosine of the angle between `self` and `other`.
    pub fn cos_angle_to(&self, other: &Direction) -> f64 {
        let s1 = (1.0 - self.mu * self.mu).max(0.0).sqrt();
        let s2 = (1.0 - other.mu * other.mu).max(0.0).sqrt();
        (self.mu * other.mu + s1 * s2 * (self.phi - other.phi).cos()).clamp(-1.0, 1.0)
    }
}

/// Closed-form single-scattered radiance at depth `z` in direction `dir` for σ_t = 1, albedo
/// `albedo`, HG asymmetry `g`, thickness `w`, sun cosine `mu0`:
/// `ω p(s, s0) ∫ e^{-z'/mu0} e^{-|z - z'| / |mu|} dz' / |mu|`. The first-order (low-albedo)
/// reference the full and refined models are tested against.
#[cfg(test)]
pub(crate) fn single_scatter_reference(
    albedo: f64,
    g: f64,
    w: f64,
    mu0: f64,
    z: f64,
    dir: Direction,
) -> f64 {
    let q = 1.0 / mu0;
    let s = 1.0 / dir.mu.abs();
    let path = if dir.mu > 0.0 {
        ((-q * z).exp() - (-s * z).exp()) / (s - q)
    } else {
        (-q * z).exp() * (1.0 - (-(q + s) * (w - z)).exp()) / (q + s)
    };
    let s0 = Direction { mu: mu0, phi: 0.0 };
    albedo * crate::phase::henyey_greenstein(g, dir.cos_angle_to(&s0)) * path * s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_bad_parameters_with_errors() {
        assert!(Slab::new(f64::NAN, 0.5, 0.0, 1.0, 1.0).is_err());
        assert!(Slab::new(-1.0, 0.5, 0.0, 1.0, 1.0).is_err());
        assert!(Slab::new(1.0, 1.5, 0.0, 1.0, 1.0).is_err());
        assert!(Slab::new(1.0, -0.1, 0.0, 1.0, 1.0).is_err());
        assert!(Slab::new(1.0, f64::NAN, 0.0, 1.0, 1.0).is_err());
        assert!(Slab::new(1.0, 0.5, 1.0, 1.0, 1.0).is_err());
        assert!(Slab::new(1.0, 0.5, -1.2, 1.0, 1.0).is_err());
        assert!(Slab::new(1.0, 0.5, 0.0, -2.0, 1.0).is_err());
        assert!(Slab::new(1.0, 0.5, 0.0, 0.0, 1.0).is_err());
        assert!(Slab::new(1.0, 0.5, 0.0, f64::NAN, 1.0).is_err());
        assert!(Slab::new(1.0, 0.5, 0.0, 1.0, 0.0).is_err());
        assert!(Slab::with_incidence_deg(1.0, 0.5, 0.0, 1.0, 90.0).is_err());
        assert!(Slab::new(1.0, 0.5, 0.0, f64::INFINITY, 1.0).is_ok());
        assert!(Direction::new(0.0, 0.0).is_err());
        assert!(Direction::new(1.5, 0.0).is_err());
        assert!(Direction::new(0.5, f64::NAN).is_err());
    }
}
