//! The simplified plane-parallel (SPP) model, 003 eqs. 8-22, and its ray-marching refinement
//! (Appendix A.1).
//!
//! The cosine factor is frozen at the incident one (eq. 8, `cos θ ≈ ±mu0`) and the phase
//! function replaced by hemispheric averages (eq. 9): a fraction `T` of scattered light stays in
//! the hemisphere it travels in and `R = 1 - T` crosses over, with `T` the exact HG fraction for
//! the incident direction (eq. 10). The diffuse field is then uniform over each hemisphere and
//! its hemispheric integrals `E+(z)`, `E-(z)` obey two linear ODEs (eqs. 11-12) solved in
//! closed form (eqs. 13-22).
//!
//! Three places where the extracted text of eqs. 17-22 is not self-consistent, and what is done
//! here instead (each checked by a test that eqs. 11-12 and 21 hold to rounding):
//!
//! * The Type II solution and the beam decay as `exp(-σt z / mu0)` in the depth `z`; eq. 18's
//!   `exp(-σt z)` holds only at normal incidence or for `z` measured along the beam.
//! * The growing Type I solution has its hemispheres swapped, `(βU+ + αU-) exp(λz)` (the ODEs
//!   are symmetric under `λ → -λ`, `α ↔ β`); this is what makes eq. 22's denominator
//!   `α²E3 - β²E1`. With it, eq. 21 gives `c3 = +βE1 c2 / (α²E3 - β²E1)` (the printed minus sign
//!   does not satisfy eq. 21).
//! * `c2 = -∫ i0 = -1`: eqs. 11-12 hold for `(c2 U+ + i0) exp(-σt z / mu0)` only if its
//!   integral over Ω+ vanishes (the Type II condition), which rules out eq. 20's `/T`.
//!
//! For numerical safety the solution is written with `ρ = 1/α` and each exponential anchored at
//! the face it decays from: `E+ = A1 e^{-λz} - e^{-qz} + ρ A3 e^{-λ(w-z)}`,
//! `E- = ρ A1 e^{-λz} + A3 e^{-λ(w-z)}`, `A1 = 1/(1 - ρ²e^{-2λw})`, `A3 = -ρ e^{-λw} A1`.

use crate::error::SppError;
use crate::exp_sum::{eval, ray_integral, ExpTerm};
use crate::full::MAX_ALBEDO;
use crate::phase::{fraction_into_lower_hemisphere, henyey_greenstein};
use crate::slab::{Direction, Slab};
use std::f64::consts::PI;

/// Solved SPP model for one slab.
#[derive(Clone, Debug)]
pub struct SppModel {
    slab: Slab,
    sigma_s: f64,
    /// Eq. 10: fraction of the light scattered from the beam that keeps going down.
    t: f64,
    /// Eq. 10: the fraction that turns up, `1 - T`.
    r: f64,
    /// Eq. 17: decay rate per unit depth.
    lambda: f64,
    /// `1/α` of eq. 17.
    rho: f64,
    /// Beam decay rate per unit depth, `σt / mu0`.
    q: f64,
    down: Vec<ExpTerm>,
    up: Vec<ExpTerm>,
}

/// The parameters of eqs. 17, 20 and 22 in the paper's notation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SppConstants {
    pub t: f64,
    pub r: f64,
    pub lambda: f64,
    pub alpha: f64,
    pub beta: f64,
    pub c1: f64,
    pub c2: f64,
    /// `c3` of eq. 19 (multiplying `exp(λz)`); 0 for a half-space.
    pub c3: f64,
}

impl SppModel {
    /// Solves the SPP model for `slab`.
    pub fn new(slab: Slab) -> Result<Self, SppError> {
        slab.validate()?;
        let t = fraction_into_lower_hemisphere(slab.g, slab.mu0);
        Self::with_forward_fraction(slab, t)
    }

    /// Solves the SPP model for `slab` with eq. 10's `T` given (the fraction of light
    /// scattered from the beam that keeps going down, in [0, 1]) instead of computed from
    /// `slab.g`: for many slabs sharing one phase function and incidence (the meshes of a
    /// tree), and for phase functions that are not Henyey-Greenstein.
    pub fn with_forward_fraction(slab: Slab, t: f64) -> Result<Self, SppError> {
        slab.validate()?;
        crate::error::check_range("T", t, 0.0, 1.0, "the forward fraction must be in [0, 1]")?;
        let sigma_t = slab.sigma_t;
        let sigma_s = slab.albedo.min(MAX_ALBEDO) * sigma_t;
        let mu0 = slab.mu0;
        let r = 1.0 - t;
        // Eq. 17: (λ mu0)² = (σt - δσ)(σt - σs), δσ = σs (T - R).
        let kappa = ((sigma_t - sigma_s * (t - r)) * (sigma_t - sigma_s))
            .max(0.0)
            .sqrt();
        let lambda = kappa / mu0;
        // α = σs R / (σt - σs T - λ mu0) = (σt - σs T + λ mu0) / (σs R), so ρ = 1/α is the
        // form that stays finite at albedo 0.
        let rho = sigma_s * r / (sigma_t - sigma_s * t + kappa);
        let q = sigma_t / mu0;
        let w = slab.thickness;
        let edge = if w.is_infinite() {
            0.0
        } else {
            (-lambda * w).exp()
        };
        let a1 = 1.0 / (1.0 - rho * rho * edge * edge);
        let a3 = -rho * edge * a1;
        let down = vec![
            ExpTerm::top(a1, lambda),
            ExpTerm::top(-1.0, q),
            ExpTerm::bottom(rho * a3, lambda),
        ];
        let up = vec![ExpTerm::top(rho * a1, lambda), ExpTerm::bottom(a3, lambda)];
        Ok(Self {
            slab,
            sigma_s,
            t,
            r,
            lambda,
            rho,
            q,
            down,
            up,
        })
    }

    /// The slab this model solves.
    pub fn slab(&self) -> &Slab {
        &self.slab
    }

    /// The paper's constants (eqs. 17, 20, 22) with `β = 1`. `α` and `c1` are infinite and 0
    /// at albedo 0, where the diffuse field vanishes; `c3` is `A3 ρ e^{-λw}` rescaled to
    /// multiply `exp(λz)` and underflows to 0 for thick slabs.
    pub fn constants(&self) -> SppConstants {
        let w = self.slab.thickness;
        let a1 = self.down[0].coef;
        let a3 = self.up[1].coef;
        let c3 = if w.is_infinite() {
            0.0
        } else {
            // (βU+ + αU-) c3 e^{λz} = A3 (ρU+ + U-) e^{-λ(w-z)} ⇒ c3 = A3 ρ e^{-λw}.
            a3 * self.rho * (-self.lambda * w).exp()
        };
        SppConstants {
            t: self.t,
            r: self.r,
            lambda: self.lambda,
            alpha: 1.0 / self.rho,
            beta: 1.0,
            c1: a1 * self.rho,
            c2: -1.0,
            c3,
        }
    }

    /// Hemispheric integrals of the diffuse field at depth `z`: `(E+, E-)`.
    pub fn hemispheric_totals(&self, z: f64) -> Result<(f64, f64), SppError> {
        self.slab.check_depth(z)?;
        let w = self.slab.thickness;
        Ok((eval(&self.down, z, w), eval(&self.up, z, w)))
    }

    /// Depth derivatives `(dE+/dz, dE-/dz)` at `z`, from the closed form.
    pub fn hemispheric_derivatives(&self, z: f64) -> Result<(f64, f64), SppError> {
        self.slab.check_depth(z)?;
        let w = self.slab.thickness;
        let d = |terms: &[ExpTerm]| terms.iter().map(|t| t.derivative(z, w)).sum::<f64>();
        Ok((d(&self.down), d(&self.up)))
    }

    /// Simplified diffuse radiance (eq. 19 without the beam): uniform over each hemisphere.
    pub fn radiance(&self, z: f64, dir: Direction) -> Result<f64, SppError> {
        let (down, up) = self.hemispheric_totals(z)?;
        Ok(if dir.mu > 0.0 { down } else { up } / (2.0 * PI))
    }

    /// The direction-independent parts of the refined solution at `z` for cosine `mu`:
    /// `(∫ E+ ·ray, ∫ E- ·ray, ∫ beam ·ray)`, each the ray integral of Appendix A.1.
    pub fn refined_parts(&self, z: f64, mu: f64) -> Result<(f64, f64, f64), SppError> {
        self.slab.check_depth(z)?;
        Direction::new(mu, 0.0)?;
        let (w, st) = (self.slab.thickness, self.slab.sigma_t);
        Ok((
            ray_integral(&self.down, z, w, mu, st),
            ray_integral(&self.up, z, w, mu, st),
            ray_integral(&[ExpTerm::top(1.0, self.q)], z, w, mu, st),
        ))
    }

    /// Combines [`Self::refined_parts`] for a direction: the source function is the exact phase
    /// function applied to the SPP field, `σs (S+ E+ + S- E- + p(s, s0) e^{-qz})` with
    /// `S± = f±(mu)/2π` the hemispheric fractions.
    pub fn refined_from_parts(
        &self,
        parts: (f64, f64, f64),
        dir: Direction,
        frac_down: f64,
    ) -> f64 {
        let s0 = Direction {
            mu: self.slab.mu0,
            phi: 0.0,
        };
        let p_beam = henyey_greenstein(self.slab.g, dir.cos_angle_to(&s0));
        self.sigma_s
            * ((parts.0 * frac_down + parts.1 * (1.0 - frac_down)) / (2.0 * PI) + p_beam * parts.2)
    }

    /// Refined diffuse radiance (Appendix A.1): the SPP field scattered once more with the exact
    /// phase function and integrated along the ray to `(z, s)`.
    pub fn refined_radiance(&self, z: f64, dir: Direction) -> Result<f64, SppError> {
        let parts = self.refined_parts(z, dir.mu)?;
        let frac = fraction_into_lower_hemisphere(self.slab.g, dir.mu);
        Ok(self.refined_from_parts(parts, dir, frac))
    }

    /// Diffuse reflectance of the simplified model: `mu0 E-(0)` over the incident horizontal
    /// flux `mu0` (the model's fluxes carry the frozen cosine `mu0`).
    pub fn reflectance(&self) -> f64 {
        self.hemispheric_totals(0.0).expect("0 is a valid depth").1
    }

    /// Diffuse transmittance of the simplified model, `E+(w)` (0 for a half-space).
    pub fn diffuse_transmittance(&self) -> f64 {
        if self.slab.is_semi_infinite() {
            return 0.0;
        }
        self.hemispheric_totals(self.slab.thickness)
            .expect("w is a valid depth")
            .0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn slab(albedo: f64, g: f64, w: f64, deg: f64) -> Slab {
        Slab::with_incidence_deg(1.3, albedo, g, w, deg).unwrap()
    }

    /// Residuals of eqs. 11-12 written for the hemispheric integrals, with the beam's own
    /// hemispheric integral `e^{-qz}` counted in Ω+ (it is part of `I` in eq. 11's integrals).
    fn residuals(model: &SppModel, z: f64) -> (f64, f64) {
        let s = model.slab();
        let (ep, em) = model.hemispheric_totals(z).unwrap();
        let (dp, dm) = model.hemispheric_derivatives(z).unwrap();
        let beam = s.direct(z);
        let (t, r, ss) = (model.t, model.r, model.sigma_s);
        let eq11 = s.mu0 * dp - (-s.sigma_t * ep + ss * (t * (ep + beam) + r * em));
        let eq12 = -s.mu0 * dm - (-s.sigma_t * em + ss * (r * (ep + beam) + t * em));
        (eq11, eq12)
    }

    #[test]
    fn satisfies_eqs_11_12_and_boundary_conditions_to_rounding() {
        for &albedo in &[0.0, 0.3, 0.9, 0.99, 1.0] {
            for &g in &[-0.5, 0.0, 0.5, 0.9] {
                for &w in &[0.5, 5.0, 16.0, 200.0, f64::INFINITY] {
                    for &deg in &[0.0, 30.0, 70.0] {
                        let model = SppModel::new(slab(albedo, g, w, deg)).unwrap();
                        let depths: Vec<f64> = if w.is_infinite() {
                            vec![0.0, 0.5, 3.0, 20.0]
                        } else {
                            vec![0.0, 0.25 * w, 0.5 * w, w]
                        };
                        // Conservative slabs are solved with the albedo 1e-9 below 1, whose
                        // nearly cancelling modes cost a few digits.
                        let tol = if albedo == 1.0 { 1e-6 } else { 1e-12 };
                        for &z in &depths {
                            let (a, b) = residuals(&model, z);
                            assert!(
                                a.abs() < tol && b.abs() < tol,
                                "a {albedo} g {g} w {w} deg {deg} z {z}: {a} {b}"
                            );
                        }
                        let (down_top, _) = model.hemispheric_totals(0.0).unwrap();
                        assert!(down_top.abs() < 1e-12, "I(0, Ω+) = i0 violated: {down_top}");
                        if w.is_finite() {
                            let (_, up_bottom) = model.hemispheric_totals(w).unwrap();
                            assert!(
                                up_bottom.abs() < 1e-12,
                                "I(w, Ω-) = 0 violated: {up_bottom}"
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn paper_constants_satisfy_eqs_14_to_17_and_22() {
        let model = SppModel::new(slab(0.9, 0.5, 3.0, 30.0)).unwrap();
        let c = model.constants();
        let s = model.slab();
        let (st, ss, mu0) = (s.sigma_t, model.sigma_s, s.mu0);
        // Eq. 14 with β = 1.
        assert!(
            (-c.lambda * c.alpha * mu0 - (-st * c.alpha + ss * (c.alpha * c.t + c.r))).abs()
                < 1e-12
        );
        assert!((c.lambda * mu0 - (-st + ss * (c.alpha * c.r + c.t))).abs() < 1e-12);
        assert!((c.t + c.r - 1.0).abs() < 1e-15);
        // Eq. 22 (with the sign of c3 that satisfies eq. 21).
        let (e1, e3) = ((-c.lambda * 3.0).exp(), (c.lambda * 3.0).exp());
        let den = c.alpha * c.alpha * e3 - e1;
        assert!((c.c1 - (-c.alpha * e3 * c.c2 / den)).abs() < 1e-12);
        assert!((c.c3 - (e1 * c.c2 / den)).abs() < 1e-12);
        // Eq. 19 rebuilt from the paper's constants equals the model at a depth.
        let z = 1.1;
        let e = (-model.q * z).exp();
        let down = c.c1 * c.alpha * (-c.lambda * z).exp()
            + c.c2 * e
            + c.c3 * c.beta * (c.lambda * z).exp();
        let up = c.c1 * c.beta * (-c.lambda * z).exp() + c.c3 * c.alpha * (c.lambda * z).exp();
        let (ep, em) = model.hemispheric_totals(z).unwrap();
        assert!((down - ep).abs() < 1e-12 && (up - em).abs() < 1e-12);
    }

    #[test]
    fn albedo_zero_is_beer_lambert() {
        let model = SppModel::new(slab(0.0, 0.5, 4.0, 50.0)).unwrap();
        for &z in &[0.0, 1.0, 4.0] {
            let (a, b) = model.hemispheric_totals(z).unwrap();
            assert!(a.abs() < 1e-15 && b.abs() < 1e-15);
            for &mu in &[0.5, -0.5] {
                let dir = Direction::new(mu, 0.3).unwrap();
                assert_eq!(model.refined_radiance(z, dir).unwrap(), 0.0);
            }
        }
        assert!(model.diffuse_transmittance().abs() < 1e-15);
    }

    #[test]
    fn refinement_is_exact_for_single_scattering() {
        // To first order in the albedo the refined radiance is the closed-form single scatter
        // σs p(s, s0) ∫ e^{-q z'} e^{-σt |z - z'| / |mu|} dz' / |mu|, while the simplified one is
        // off by O(1) relative (it spreads the single scatter uniformly over the hemisphere).
        let albedo = 1e-4;
        let (w, mu0) = (2.0, 0.6f64);
        let model = SppModel::new(Slab::new(1.0, albedo, 0.5, w, mu0).unwrap()).unwrap();
        for &z in &[0.4, 1.5] {
            for &(mu, phi) in &[(0.3, 0.0), (0.9, 2.0), (-0.5, 0.5), (-0.95, 3.1)] {
                let dir = Direction::new(mu, phi).unwrap();
                let want = crate::slab::single_scatter_reference(albedo, 0.5, w, mu0, z, dir);
                let refined = model.refined_radiance(z, dir).unwrap();
                assert!(
                    (refined / want - 1.0).abs() < 1e-3,
                    "z {z} mu {mu}: {refined} vs {want}"
                );
                let simplified = model.radiance(z, dir).unwrap();
                assert!(
                    (simplified / want - 1.0).abs() > 0.05,
                    "simplified should differ here"
                );
            }
        }
    }

    #[test]
    fn refinement_is_the_ray_integral_of_the_spp_source() {
        // Brute force: integrate σs(∫p(s,s') I_spp(z',s') ds' + p(s,s0) e^{-qz'}) e^{-σt l} along
        // the ray with the hemispheric fractions from a direct 2D quadrature of the phase function.
        use crate::quadrature::gauss_legendre;
        let model = SppModel::new(slab(0.95, 0.5, 3.0, 30.0)).unwrap();
        let s = *model.slab();
        for &(z, mu, phi) in &[(1.0, 0.6, 0.4), (2.0, -0.3, 2.0), (0.0, -0.9, 0.0)] {
            let dir = Direction::new(mu, phi).unwrap();
            let s0 = Direction {
                mu: s.mu0,
                phi: 0.0,
            };
            let frac = crate::phase::fraction_into_lower_hemisphere(s.g, mu);
            let (a, b) = if mu > 0.0 { (0.0, z) } else { (z, s.thickness) };
            let (xs, ws) = gauss_legendre(400, a, b);
            let mut want = 0.0;
            for (zp, wq) in xs.iter().zip(&ws) {
                let (ep, em) = model.hemispheric_totals(*zp).unwrap();
                let j = model.sigma_s
                    * ((ep * frac + em * (1.0 - frac)) / (2.0 * PI)
                        + henyey_greenstein(s.g, dir.cos_angle_to(&s0)) * s.direct(*zp));
                want += wq * j * (-s.sigma_t * (z - zp).abs() / mu.abs()).exp() / mu.abs();
            }
            let got = model.refined_radiance(z, dir).unwrap();
            assert!((got - want).abs() < 1e-10 * want, "{got} vs {want}");
        }
    }
}
