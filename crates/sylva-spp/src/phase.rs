//! The Henyey-Greenstein phase function (003 eq. 2) and the integrals of it the models need.

use crate::quadrature::gauss_legendre;
use std::f64::consts::PI;

/// Below this |g| the isotropic formulas are used: the HG inverse CDF cancels catastrophically
/// as g → 0 and the difference is O(g).
const ISOTROPIC_G: f64 = 1e-9;

/// Henyey-Greenstein phase function per steradian, normalised to 1 over the sphere:
/// `p = (1/4π)(1 - g²)/(1 - 2g cosΘ + g²)^{3/2}`.
pub fn henyey_greenstein(g: f64, cos_theta: f64) -> f64 {
    let denom = 1.0 + g * g - 2.0 * g * cos_theta;
    (1.0 - g * g) / (4.0 * PI * denom * denom.sqrt())
}

/// Probability that a scattering angle cosine is `<= x` (the CDF of `cosΘ` on `[-1, 1]`).
pub fn hg_cdf(g: f64, x: f64) -> f64 {
    if g.abs() < ISOTROPIC_G {
        return ((x + 1.0) / 2.0).clamp(0.0, 1.0);
    }
    let c =
        (1.0 - g * g) / (2.0 * g) * (1.0 / (1.0 + g * g - 2.0 * g * x).sqrt() - 1.0 / (1.0 + g));
    c.clamp(0.0, 1.0)
}

/// The scattering angle cosine with CDF value `u` (inverse-CDF sampling of HG).
pub fn hg_inverse_cdf(g: f64, u: f64) -> f64 {
    if g.abs() < ISOTROPIC_G {
        return (2.0 * u - 1.0).clamp(-1.0, 1.0);
    }
    let t = (1.0 - g * g) / (1.0 - g + 2.0 * g * u);
    ((1.0 + g * g - t * t) / (2.0 * g)).clamp(-1.0, 1.0)
}

/// Fraction of the light scattered from a direction with cosine `mu` that goes into the lower
/// hemisphere Ω+ (`mu' > 0`): `∫_{Ω+} p(s, s') ds'`. This is the paper's `T` (eq. 10) for
/// `mu = mu0`, and `2π S+(s)` of Appendix A.1 for any `s`.
///
/// Written as an integral over the CDF of the scattering angle: a cone of half-angle Θ around
/// `s` has the closed-form fraction `acos(-cosΘ·mu / (sinΘ·sinθ))/π` of its circle in Ω+, so the
/// integrand is bounded for any g (the HG peak is absorbed by the change of variable) and only
/// has kinks where the cone touches the horizon, at `cosΘ = ±sinθ`, where the rule is split.
pub fn fraction_into_lower_hemisphere(g: f64, mu: f64) -> f64 {
    let mu = mu.clamp(-1.0, 1.0);
    let sin_theta = (1.0 - mu * mu).max(0.0).sqrt();
    let cone_fraction = |x: f64| -> f64 {
        let sin_cone = (1.0 - x * x).max(0.0).sqrt();
        let s = sin_cone * sin_theta;
        let num = x * mu;
        if s <= 1e-300 {
            return if num > 0.0 {
                1.0
            } else if num < 0.0 {
                0.0
            } else {
                0.5
            };
        }
        (-num / s).clamp(-1.0, 1.0).acos() / PI
    };
    let mut breaks = [0.0, hg_cdf(g, -sin_theta), hg_cdf(g, sin_theta), 1.0];
    breaks.sort_by(|a, b| a.total_cmp(b));
    let (nodes, weights) = gauss_legendre(GAUSS_SEGMENT, 0.0, 1.0);
    let mut total = 0.0;
    for seg in breaks.windows(2) {
        let (a, b) = (seg[0], seg[1]);
        if b <= a {
            continue;
        }
        // The kinks are square-root like; the substitution t = τ² (left) and 1 - τ² (right)
        // would remove them, but a split midpoint with a cubic map is enough: t = a + (b-a)·h(τ)
        // with h(τ) = 3τ² - 2τ³ has h' = 0 at both ends, smoothing endpoint square roots.
        for (tau, wt) in nodes.iter().zip(&weights) {
            let h = tau * tau * (3.0 - 2.0 * tau);
            let dh = 6.0 * tau * (1.0 - tau);
            let u = a + (b - a) * h;
            total += wt * (b - a) * dh * cone_fraction(hg_inverse_cdf(g, u));
        }
    }
    total.clamp(0.0, 1.0)
}

const GAUSS_SEGMENT: usize = 64;

/// Azimuthal Fourier cosine coefficients of the phase function between two directions with
/// cosines `mu` and `mu_prime`:
/// `p_m(mu, mu') = (1/2π) ∫ p(cosΘ(Δφ)) cos(mΔφ) dΔφ`, for `m = 0..modes`, so that
/// `p = Σ_m (2 - δ_m0) p_m cos(mΔφ)`. The trapezoid rule in Δφ is spectrally accurate for this
/// smooth periodic integrand.
pub fn azimuthal_coefficients(
    g: f64,
    mu: f64,
    mu_prime: f64,
    modes: usize,
    samples: usize,
) -> Vec<f64> {
    let s = (1.0 - mu * mu).max(0.0).sqrt() * (1.0 - mu_prime * mu_prime).max(0.0).sqrt();
    let c = mu * mu_prime;
    let mut out = vec![0.0; modes];
    for k in 0..samples {
        let dphi = 2.0 * PI * k as f64 / samples as f64;
        let cos1 = dphi.cos();
        let p = henyey_greenstein(g, (c + s * cos1).clamp(-1.0, 1.0));
        // cos(mΔφ) by the Chebyshev recurrence cos((m+1)x) = 2 cos x cos(mx) - cos((m-1)x).
        let (mut prev, mut cur) = (cos1, 1.0);
        for o in out.iter_mut() {
            *o += p * cur;
            let next = 2.0 * cos1 * cur - prev;
            prev = cur;
            cur = next;
        }
    }
    for o in &mut out {
        *o /= samples as f64;
    }
    out
}

/// How many azimuth samples [`azimuthal_coefficients`] needs for `g`: the integrand's peak width
/// in Δφ scales like `1 - |g|`.
pub fn azimuth_samples_for(g: f64) -> usize {
    let want = (96.0 / (1.0 - g.abs())).ceil() as usize;
    want.next_power_of_two().clamp(256, 16384)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hg_is_normalised_and_has_mean_cosine_g() {
        for &g in &[-0.7, -0.5, 0.0, 0.3, 0.5, 0.9] {
            let (x, w) = gauss_legendre(400, -1.0, 1.0);
            let norm: f64 = x
                .iter()
                .zip(&w)
                .map(|(x, w)| w * 2.0 * PI * henyey_greenstein(g, *x))
                .sum();
            let mean: f64 = x
                .iter()
                .zip(&w)
                .map(|(x, w)| w * 2.0 * PI * x * henyey_greenstein(g, *x))
                .sum();
            assert!((norm - 1.0).abs() < 1e-9, "g {g}: norm {norm}");
            assert!((mean - g).abs() < 1e-9, "g {g}: mean {mean}");
        }
    }

    #[test]
    fn inverse_cdf_inverts_cdf() {
        for &g in &[-0.5, 0.0, 1e-12, 0.5, 0.95] {
            for i in 0..=20 {
                let u = i as f64 / 20.0;
                let x = hg_inverse_cdf(g, u);
                assert!((hg_cdf(g, x) - u).abs() < 1e-9, "g {g} u {u}");
            }
        }
    }

    /// Brute-force 2D integral of HG over the lower hemisphere.
    fn brute_fraction(g: f64, mu: f64) -> f64 {
        let (xs, ws) = gauss_legendre(200, 0.0, 1.0);
        let n_phi = 2048;
        let st = (1.0 - mu * mu).sqrt();
        let mut total = 0.0;
        for (mp, w) in xs.iter().zip(&ws) {
            let sp = (1.0 - mp * mp).sqrt();
            let mut ring = 0.0;
            for k in 0..n_phi {
                let phi = 2.0 * PI * k as f64 / n_phi as f64;
                ring += henyey_greenstein(g, mu * mp + st * sp * phi.cos());
            }
            total += w * ring * 2.0 * PI / n_phi as f64;
        }
        total
    }

    #[test]
    fn hemisphere_fraction_matches_brute_force_and_closed_form() {
        // Normal incidence has a closed form: T = (1+g)/(2g) (1 - (1-g)/sqrt(1+g²)).
        for &g in &[-0.5f64, 0.25, 0.5, 0.8] {
            let closed = (1.0 + g) / (2.0 * g) * (1.0 - (1.0 - g) / (1.0 + g * g).sqrt());
            let got = fraction_into_lower_hemisphere(g, 1.0);
            assert!((got - closed).abs() < 1e-12, "g {g}: {got} vs {closed}");
        }
        for &g in &[0.0, -0.5, 0.5] {
            for &mu in &[0.1, 0.5, 0.8, -0.3] {
                let got = fraction_into_lower_hemisphere(g, mu);
                let want = brute_fraction(g, mu);
                assert!((got - want).abs() < 1e-7, "g {g} mu {mu}: {got} vs {want}");
                // Reversing the direction swaps the hemispheres.
                let rev = fraction_into_lower_hemisphere(g, -mu);
                assert!((got + rev - 1.0).abs() < 1e-9);
            }
        }
        assert!((fraction_into_lower_hemisphere(0.0, 0.3) - 0.5).abs() < 1e-12);
    }

    #[test]
    fn azimuthal_coefficients_resum_to_the_phase_function() {
        let (g, mu, mup): (f64, f64, f64) = (0.5, 0.7, -0.2);
        let modes = 60;
        let pm = azimuthal_coefficients(g, mu, mup, modes, azimuth_samples_for(g));
        for &dphi in &[0.0, 0.9, 2.5] {
            let sum: f64 = pm
                .iter()
                .enumerate()
                .map(|(m, p)| {
                    if m == 0 {
                        *p
                    } else {
                        2.0 * p * (m as f64 * dphi).cos()
                    }
                })
                .sum();
            let st = (1.0 - mu * mu).sqrt() * (1.0 - mup * mup).sqrt();
            let want = henyey_greenstein(g, mu * mup + st * f64::cos(dphi));
            assert!(
                (sum - want).abs() < 1e-12 * want.max(1.0),
                "{sum} vs {want}"
            );
        }
    }
}
