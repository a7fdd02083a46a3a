//! The geometric compensation factor (003 §4.1, eqs. 23-28, Appendix A.2-A.3).
//!
//! The plane-parallel models assume the medium fills the whole slab. At a point P at depth
//! `z0` (along the light, σt = 1) of a slab of thickness `w`, light arriving in direction `s`
//! was scattered along the line P–B0 back to the slab's face, while in a real crown the
//! medium ends earlier, at B1. With the unscattered light `e^{-z}` as the source (eq. 23 with
//! `I' = I0`), the scattered radiance gathered along the line at optical distance `l` from P
//! is `σs p(s, s0) e^{-z(l)} e^{-l}`, with `z(l) = z0 − l μ` and `μ = s·s0`, so
//!
//! `δI(P, B) ∝ e^{-z0} ∫_{l_B}^{l_0} e^{-a l} dl`, `a = 1 − μ ≥ 0`,
//!
//! where `l_0` is P–B0 (`z0/μ` towards the lit face for `μ > 0`, `(w − z0)/|μ|` towards the far
//! face for `μ < 0`, unbounded for `μ = 0`) and `l_B` the distance to `B`. Eq. 26 is then
//!
//! `G_s = δI(P, B1)/δI(P, P) = (e^{-a τ} − e^{-a l_0}) / (1 − e^{-a l_0})`
//!
//! with `τ = min(P–B1, l_0)` the optical distance to the real boundary, which a deep opacity
//! map in direction `s` gives as the number of surfaces before P. This is A.3's
//! `(1 − E(h))/(1 − E(z0))` form (`h = l_0 − τ`, the missing stretch B1–B0) written with
//! decaying exponentials; the phase function and `e^{-z0}` cancel from the ratio. `G_s` runs
//! from 0 (B1 = B0: nothing missing) to 1 (B1 = P: everything missing), and eq. 27 averages it
//! over the sample directions: `G = 1 − Σ G_s / N`. Eq. 28 blends the plane-parallel
//! irradiance with the direct light: `I_G = G I_pp + (1 − G) I0`.

use glam::Vec3;

/// Eq. 26 by Appendix A.2-A.3: the fraction of the single-scattered light arriving in a
/// direction with cosine `mu` to the light (`μ = s·s0`) that the plane-parallel model
/// counts but a medium ending `tau` (optical distance, σt = 1) before the point does not
/// have, for a point at depth `z0` of a slab of thickness `w` (both along the light).
pub fn missing_fraction(mu: f64, z0: f64, w: f64, tau: f64) -> f64 {
    let mu = mu.clamp(-1.0, 1.0);
    let z0 = z0.max(0.0);
    let w = w.max(z0);
    let tau = tau.max(0.0);
    // Distance from P to the slab's face along −s.
    let l0 = if mu > 0.0 {
        z0 / mu
    } else if mu < 0.0 {
        (w - z0) / -mu
    } else {
        f64::INFINITY
    };
    if l0 <= 0.0 || tau >= l0 {
        // No slab behind P in this direction, or the real medium reaches the slab's face.
        return 0.0;
    }
    let a = 1.0 - mu;
    if l0.is_infinite() {
        return (-a * tau).exp();
    }
    // (e^{-aτ} − e^{-a l0}) / (1 − e^{-a l0}) with expm1 so that a → 0 (s = s0) gives the
    // limit (l0 − τ)/l0 to rounding.
    let den = -(-a * l0).exp_m1();
    if den <= 0.0 {
        return (l0 - tau) / l0;
    }
    ((-a * tau).exp() * -(-a * (l0 - tau)).exp_m1() / den).clamp(0.0, 1.0)
}

/// Eq. 27: `G = 1 − (1/N) Σ_i G_{s_i}` over sample directions given as `(μ_i, τ_i)`.
/// 1 with no samples.
pub fn g_factor(z0: f64, w: f64, samples: impl IntoIterator<Item = (f64, f64)>) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for (mu, tau) in samples {
        sum += missing_fraction(mu, z0, w, tau);
        n += 1;
    }
    if n == 0 {
        1.0
    } else {
        1.0 - sum / n as f64
    }
}

/// `n` directions spread evenly over the sphere (a spherical Fibonacci lattice: equal-area
/// bands in `y`, golden-angle steps in azimuth), +y up. Deterministic.
pub fn sample_directions(n: usize) -> Vec<Vec3> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let y = 1.0 - (2.0 * i as f64 + 1.0) / n as f64;
            let r = (1.0 - y * y).max(0.0).sqrt();
            let phi = golden * i as f64;
            Vec3::new((r * phi.cos()) as f32, y as f32, (r * phi.sin()) as f32).normalize()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quadrature::gauss_legendre;

    /// Eq. 25 by quadrature: ∫_{l_B}^{l_0} e^{-z(l)} e^{-l} dl with z(l) = z0 − lμ, straight
    /// from the geometry (not from the closed form).
    fn delta_i(mu: f64, z0: f64, w: f64, l_b: f64) -> f64 {
        let l0 = if mu > 0.0 {
            z0 / mu
        } else if mu < 0.0 {
            (w - z0) / -mu
        } else {
            200.0
        };
        if l_b >= l0 {
            return 0.0;
        }
        let (xs, ws) = gauss_legendre(200, l_b, l0);
        xs.iter()
            .zip(&ws)
            .map(|(&l, &wt)| wt * (-(z0 - l * mu)).exp() * (-l).exp())
            .sum()
    }

    #[test]
    fn closed_form_equals_the_integral_of_eq_25() {
        for &(mu, z0, w, tau) in &[
            (0.8, 3.0, 10.0, 1.0),
            (0.3, 2.0, 5.0, 0.5),
            (0.999, 4.0, 8.0, 2.0),
            (1.0, 4.0, 8.0, 2.0),
            (-0.5, 2.0, 6.0, 3.0),
            (-0.95, 1.0, 3.0, 0.2),
        ] {
            let want = delta_i(mu, z0, w, tau) / delta_i(mu, z0, w, 0.0);
            let got = missing_fraction(mu, z0, w, tau);
            assert!(
                (got - want).abs() < 1e-10,
                "{mu} {z0} {w} {tau}: {got} vs {want}"
            );
        }
        // Horizontal directions: the slab extends without end, the integral to ∞ is e^{-τ}.
        let want = delta_i(0.0, 2.0, 4.0, 1.5) / delta_i(0.0, 2.0, 4.0, 0.0);
        assert!((missing_fraction(0.0, 2.0, 4.0, 1.5) - want).abs() < 1e-10);
    }

    #[test]
    fn limits_of_appendix_a2() {
        for &mu in &[0.9, 0.2, 0.0, -0.4] {
            // B1 = P: everything beyond P is missing.
            assert!((missing_fraction(mu, 3.0, 7.0, 0.0) - 1.0).abs() < 1e-12);
            // B1 at or beyond B0: the plane-parallel model is right.
            if mu != 0.0 {
                let l0 = if mu > 0.0 { 3.0 / mu } else { 4.0 / -mu };
                assert_eq!(missing_fraction(mu, 3.0, 7.0, l0), 0.0);
                assert_eq!(missing_fraction(mu, 3.0, 7.0, l0 + 5.0), 0.0);
            }
            // Decreasing in τ.
            let mut last = 1.0;
            for k in 1..40 {
                let g = missing_fraction(mu, 3.0, 7.0, 0.25 * k as f64);
                assert!(g <= last + 1e-15 && g >= 0.0);
                last = g;
            }
        }
        // A point on the lit face has no slab above it: nothing to miss from above.
        assert_eq!(missing_fraction(0.7, 0.0, 5.0, 0.0), 0.0);
        // s = s0 is the limit of nearby directions.
        let exact = missing_fraction(1.0, 4.0, 8.0, 1.0);
        assert!(
            (exact - 0.75).abs() < 1e-12,
            "(l0 − τ)/l0 = 0.75, got {exact}"
        );
        assert!((missing_fraction(1.0 - 1e-9, 4.0, 8.0, 1.0) - exact).abs() < 1e-8);
    }

    #[test]
    fn g_is_one_inside_an_infinite_slab_and_falls_at_its_edge() {
        let dirs = sample_directions(22);
        let s0 = Vec3::new(0.0, -1.0, 0.0);
        let (z0, w) = (3.0, 8.0);
        // Infinite slab: the line in every direction reaches the face, τ = l0.
        let inside = dirs.iter().map(|s| {
            let mu = s.dot(s0) as f64;
            let tau = if mu > 0.0 {
                z0 / mu
            } else if mu < 0.0 {
                (w - z0) / -mu
            } else {
                f64::INFINITY
            };
            (mu, tau)
        });
        assert!((g_factor(z0, w, inside) - 1.0).abs() < 1e-12);
        // A lone point (no medium around it in any direction): G = 0, the single-scattering
        // limit, only if every direction has a slab behind it; horizontal-ish ones always do.
        let lone = g_factor(z0, w, dirs.iter().map(|s| (s.dot(s0) as f64, 0.0)));
        assert!(lone.abs() < 1e-12, "{lone}");
        // Half the directions cut short: in between.
        let half = g_factor(
            z0,
            w,
            dirs.iter()
                .enumerate()
                .map(|(k, s)| (s.dot(s0) as f64, if k % 2 == 0 { 0.0 } else { 100.0 })),
        );
        assert!(half > 0.3 && half < 0.7, "{half}");
    }

    #[test]
    fn sample_directions_are_unit_and_balanced() {
        for n in [1, 16, 22] {
            let d = sample_directions(n);
            assert_eq!(d.len(), n);
            assert!(d.iter().all(|v| (v.length() - 1.0).abs() < 1e-6));
            if n > 1 {
                let mean: Vec3 = d.iter().copied().sum::<Vec3>() / n as f32;
                assert!(mean.length() < 0.1, "{mean}");
            }
        }
    }
}
