//! The SPP model on a tree (003 §4.2, §5.3): the slab solution at a mesh's depth and
//! thickness, and the shading of a Lambertian leaf by eq. 32.
//!
//! Depth `d` and thickness `w` are counted along the light (eq. 29), so the slab they define
//! has its normal along the light and is lit at normal incidence: that is where eq. 18's
//! `exp(−σt z)` holds as printed, and `cos θ0 = 1` in eqs. 8-22. Leaves that reflect and
//! transmit alike (R = T, the paper's choice) scatter as much forward as back, so the
//! hemispheric split of eq. 10 is `T = 1/2` (the paper calls the phase function isotropic).
//!
//! **What the hemispheric totals are.** Eqs. 11-12 transport the whole diffuse field at the
//! frozen cosine `cos θ0` (here 1), so the model's `E+`, `E−` are the *fluxes* of the diffuse
//! light through planes across the light (per unit flux of the beam), and that is the reading
//! used here: the diffuse field is taken isotropic within each hemisphere with those fluxes,
//! radiance `E±/π`, i.e. `I = 2E+ U+ + 2E− U− + e^{−d} δ(s − s0)` with eq. 10's normalised
//! `U±`. Read instead as radiance integrals (`I = E+ U+ + E− U−`, eq. 19 as printed) the same
//! totals give half the diffuse irradiance; in a slab-shaped "tree" (random leaves filling a
//! wide thin box, `examples/slab_tree.rs`) the Monte Carlo leaf irradiance near the lit face
//! agrees with the flux reading within 2-10 % and is 1.6-1.9 times the other (docs/spp.md).
//!
//! A leaf with unit normal `n` receives from a hemisphere of flux `F`, isotropic within it,
//! the irradiance `F (1 ∓ n·s0)/2` on its face `n` (the sky-view factor `(1 + cos β)/2`), so its
//! two faces together get `E+ + E−` whatever its orientation, plus the beam's `|n·s0| e^{−d}`:
//! the two-sided irradiance compared with the Monte Carlo count. Eq. 32 for a Lambertian leaf
//! (`B = R/π` on the lit face's side, `T/π` through it) is the radiance
//! `(R E_front + T E_back)/π` towards a viewer on the side of `n`.

use crate::error::SppError;
use crate::slab::Slab;
use crate::spp::SppModel;

/// The SPP model for the meshes of a tree whose leaves scatter with the given albedo.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TreeSpp {
    albedo: f64,
    /// Eq. 10's `T` for the leaves' phase function.
    forward: f64,
}

impl TreeSpp {
    /// Leaves with reflectance = transmittance = `albedo / 2` (`T = 1/2`).
    pub fn new(albedo: f64) -> Result<TreeSpp, SppError> {
        crate::error::check_range(
            "albedo",
            albedo,
            0.0,
            1.0,
            "the leaf albedo must be in [0, 1]",
        )?;
        Ok(TreeSpp {
            albedo,
            forward: 0.5,
        })
    }

    pub fn albedo(&self) -> f64 {
        self.albedo
    }

    /// Hemispheric totals `(E+, E−)` of the diffuse SPP field at depth `d` of a slab of
    /// thickness `w` (both along the light, σt = 1): the diffuse fluxes down and up. A slab of
    /// no thickness (a lone leaf) holds no diffuse light; `d` is clamped into `[0, w]`.
    pub fn diffuse(&self, d: f64, w: f64) -> Result<(f64, f64), SppError> {
        for (name, v) in [("depth", d), ("thickness", w)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(SppError::InvalidParameter {
                    name,
                    value: v,
                    reason: "mesh depth and thickness must be finite and >= 0",
                });
            }
        }
        if w <= 0.0 || self.albedo == 0.0 {
            return Ok((0.0, 0.0));
        }
        let slab = Slab::new(1.0, self.albedo, 0.0, w, 1.0)?;
        SppModel::with_forward_fraction(slab, self.forward)?.hemispheric_totals(d.min(w))
    }

    /// Two-sided irradiance of a leaf at depth `d` of thickness `w` whose faces meet the light
    /// at `|n·s0| = cos_light`: `E+ + E− + cos_light e^{−d}` (per unit flux across the beam).
    /// Returns `(diffuse part, direct part)`.
    pub fn irradiance(&self, d: f64, w: f64, cos_light: f64) -> Result<(f64, f64), SppError> {
        let (ep, em) = self.diffuse(d, w)?;
        Ok((ep + em, cos_light.abs() * (-d).exp()))
    }
}

/// Irradiance on the two faces of a leaf with unit normal `n`, where `cos_n = n·s0` (`s0`
/// the light's direction of travel), in the field `2E+ U+ + 2E− U− + direct δ(s − s0)`
/// (diffuse fluxes `E±`, isotropic within each hemisphere): `(face n, face −n)`.
pub fn leaf_faces(e_plus: f64, e_minus: f64, direct: f64, cos_n: f64) -> (f64, f64) {
    let face =
        |c: f64| e_plus * (1.0 - c) / 2.0 + e_minus * (1.0 + c) / 2.0 + direct * (-c).max(0.0);
    (face(cos_n), face(-cos_n))
}

/// Eq. 32 for a Lambertian leaf with reflectance `r` and transmittance `t` in the field of
/// [`leaf_faces`]: the radiance towards a viewer on the side of the unit normal `n`
/// (`cos_n = n·s0`).
pub fn leaf_radiance(e_plus: f64, e_minus: f64, direct: f64, cos_n: f64, r: f64, t: f64) -> f64 {
    let (front, back) = leaf_faces(e_plus, e_minus, direct, cos_n);
    (r * front + t * back) / std::f64::consts::PI
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quadrature::gauss_legendre;
    use std::f64::consts::PI;

    #[test]
    fn a_mesh_is_the_slab_model_at_normal_incidence() {
        // The tree model is the slab model with the slab's normal along the light: E± at a
        // mesh equal SppModel's for (σt 1, albedo, T = 1/2, w, mu0 = 1) at depth d, and with
        // an isotropic phase function T = 1/2 is what eq. 10 gives too.
        let tree = TreeSpp::new(0.95).unwrap();
        for &(d, w) in &[(0.0, 3.0), (1.5, 3.0), (4.0, 10.0), (2.0, 2.0)] {
            let slab = Slab::new(1.0, 0.95, 0.0, w, 1.0).unwrap();
            let want = SppModel::new(slab).unwrap().hemispheric_totals(d).unwrap();
            let got = tree.diffuse(d, w).unwrap();
            assert!((got.0 - want.0).abs() < 1e-12 && (got.1 - want.1).abs() < 1e-12);
        }
        assert_eq!(tree.diffuse(0.0, 0.0).unwrap(), (0.0, 0.0));
        assert!(tree.diffuse(f64::NAN, 1.0).is_err());
        assert!(tree.diffuse(1.0, -1.0).is_err());
        assert!(TreeSpp::new(1.2).is_err());
    }

    #[test]
    fn face_irradiance_equals_the_integral_over_the_field() {
        // ∫ I(s) max(0, −n·s) ds over the sphere for hemispheres of radiance E±/π (fluxes
        // E±), by quadrature in the light's frame (s0 = +z).
        let (ep, em, direct) = (0.7, 0.4, 0.3);
        let (xs, ws) = gauss_legendre(200, -1.0, 1.0);
        for &theta in &[0.0f64, 0.4, 1.2, 0.5 * PI, 2.5, PI] {
            let n = [theta.sin(), 0.0, theta.cos()];
            let mut sum = 0.0;
            for (mu, wmu) in xs.iter().zip(&ws) {
                let sin = (1.0 - mu * mu).sqrt();
                let k = 400;
                for j in 0..k {
                    let phi = 2.0 * PI * (j as f64 + 0.5) / k as f64;
                    let s = [sin * phi.cos(), sin * phi.sin(), *mu];
                    let c = -(n[0] * s[0] + n[1] * s[1] + n[2] * s[2]);
                    let radiance = if *mu > 0.0 { ep } else { em } / PI;
                    sum += wmu * (2.0 * PI / k as f64) * radiance * c.max(0.0);
                }
            }
            sum += direct * (-n[2]).max(0.0);
            let (front, back) = leaf_faces(ep, em, direct, n[2]);
            assert!((front - sum).abs() < 2e-4, "θ {theta}: {front} vs {sum}");
            assert!((front + back - (ep + em + direct * n[2].abs())).abs() < 1e-12);
        }
        // Eq. 32 with R = T is (R/π) × the two-sided irradiance.
        let l = leaf_radiance(ep, em, direct, 0.3, 0.45, 0.45);
        let (f, b) = leaf_faces(ep, em, direct, 0.3);
        assert!((l - 0.45 * (f + b) / PI).abs() < 1e-12);
    }
}
