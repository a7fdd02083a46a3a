//! Depth profiles that are sums of exponentials, and their exact integral along a ray.
//!
//! Both models' solutions are sums of `exp(-k z)` (decaying from the lit face) and
//! `exp(-k (w - z))` (decaying from the far face). Writing every term anchored at the face it
//! decays from keeps every exponent non-positive, so thick slabs never overflow. Integrating
//! such a source function along a ray is the "ray-marching" of 003 Appendix A.1 done exactly.

/// Which face an exponential term decays from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Anchor {
    /// `exp(-k z)`.
    Top,
    /// `exp(-k (w - z))`; absent for a half-space.
    Bottom,
}

/// One term `coef · exp(-rate · distance from its anchor face)`, `rate >= 0`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExpTerm {
    pub coef: f64,
    pub rate: f64,
    pub anchor: Anchor,
}

impl ExpTerm {
    pub fn top(coef: f64, rate: f64) -> Self {
        Self {
            coef,
            rate,
            anchor: Anchor::Top,
        }
    }

    pub fn bottom(coef: f64, rate: f64) -> Self {
        Self {
            coef,
            rate,
            anchor: Anchor::Bottom,
        }
    }

    /// The term's value at depth `z` in a slab of thickness `w`.
    pub fn value(&self, z: f64, w: f64) -> f64 {
        match self.anchor {
            Anchor::Top => self.coef * (-self.rate * z).exp(),
            Anchor::Bottom => {
                if w.is_infinite() {
                    0.0
                } else {
                    self.coef * (-self.rate * (w - z)).exp()
                }
            }
        }
    }

    /// The term's derivative with respect to `z`.
    pub fn derivative(&self, z: f64, w: f64) -> f64 {
        match self.anchor {
            Anchor::Top => -self.rate * self.value(z, w),
            Anchor::Bottom => self.rate * self.value(z, w),
        }
    }
}

/// Sum of the terms at depth `z`.
pub fn eval(terms: &[ExpTerm], z: f64, w: f64) -> f64 {
    terms.iter().map(|t| t.value(z, w)).sum()
}

/// `∫_0^len exp(-c t) dt` for `c >= 0`, `len` possibly infinite, without cancellation.
fn segment(c: f64, len: f64) -> f64 {
    if len.is_infinite() {
        return 1.0 / c;
    }
    let x = c * len;
    if x < 1e-8 {
        len * (1.0 - 0.5 * x)
    } else {
        -(-x).exp_m1() / c
    }
}

/// Radiance at depth `z` in direction cosine `mu` produced by the source function
/// `J(z') = Σ terms` (per unit length, per steradian) along the ray, with no light entering
/// from outside:
/// `I = (1/|mu|) ∫ J(z') exp(-σt |z - z'| / |mu|) dz'` from the face the ray comes from.
pub fn ray_integral(terms: &[ExpTerm], z: f64, w: f64, mu: f64, sigma_t: f64) -> f64 {
    let s = sigma_t / mu.abs();
    let mut total = 0.0;
    for t in terms {
        if t.coef == 0.0 {
            continue;
        }
        let k = t.rate;
        let v = match (mu > 0.0, t.anchor) {
            // Downward ray: source from 0 to z.
            (true, Anchor::Top) => (-k.min(s) * z).exp() * segment((s - k).abs(), z),
            (true, Anchor::Bottom) => {
                if w.is_infinite() {
                    continue;
                }
                (-k * (w - z)).exp() * segment(k + s, z)
            }
            // Upward ray: source from z to w.
            (false, Anchor::Top) => (-k * z).exp() * segment(k + s, w - z),
            (false, Anchor::Bottom) => {
                if w.is_infinite() {
                    continue;
                }
                let len = w - z;
                (-k.min(s) * len).exp() * segment((s - k).abs(), len)
            }
        };
        total += t.coef * v;
    }
    total / mu.abs()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::quadrature::gauss_legendre;

    fn numeric(terms: &[ExpTerm], z: f64, w: f64, mu: f64, sigma_t: f64) -> f64 {
        let (a, b) = if mu > 0.0 { (0.0, z) } else { (z, w) };
        let (x, wt) = gauss_legendre(200, a, b);
        x.iter()
            .zip(&wt)
            .map(|(zp, wq)| wq * eval(terms, *zp, w) * (-sigma_t * (z - zp).abs() / mu.abs()).exp())
            .sum::<f64>()
            / mu.abs()
    }

    #[test]
    fn ray_integral_matches_quadrature_including_resonant_rates() {
        let w = 3.0;
        let sigma_t = 1.3;
        for &mu in &[0.4, 1.0, -0.65, -1.0] {
            let s = sigma_t / f64::abs(mu);
            let terms = [
                ExpTerm::top(0.7, 0.9),
                ExpTerm::top(-0.2, s),
                ExpTerm::top(0.3, 0.0),
                ExpTerm::bottom(1.1, 2.0),
                ExpTerm::bottom(0.4, s),
            ];
            for &z in &[0.0, 0.5, 1.7, 3.0] {
                let got = ray_integral(&terms, z, w, mu, sigma_t);
                let want = numeric(&terms, z, w, mu, sigma_t);
                assert!((got - want).abs() < 1e-12, "mu {mu} z {z}: {got} vs {want}");
            }
        }
    }

    #[test]
    fn half_space_upward_ray_integrates_to_infinity() {
        // ∫_z^∞ e^{-k z'} e^{-s (z'-z)} dz' / mu = e^{-k z} / ((k + s) mu).
        let (k, sigma_t, mu, z) = (0.5, 1.0, -0.5, 2.0);
        let got = ray_integral(&[ExpTerm::top(1.0, k)], z, f64::INFINITY, mu, sigma_t);
        let want = (-k * z).exp() / ((k + 2.0) * 0.5);
        assert!((got - want).abs() < 1e-14);
    }
}
