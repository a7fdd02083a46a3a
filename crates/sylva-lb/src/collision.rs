//! The collision matrix Ω (002 eqs. 5-9) and the reduced form the kernels apply.

// Matrix loops index rows and columns together; indices read clearer than zips.
#![allow(clippy::needless_range_loop)]

use crate::lattice::{dot, opposite, weight, Q};
use crate::params::ColourParams;

/// Ω as a dense 19×19 matrix: `omega[i][j]` scatters from direction j into direction i.
#[derive(Debug, Clone, PartialEq)]
pub struct Omega(pub [[f64; Q]; Q]);

/// Normalised Henyey-Greenstein factors `pn[i][j]` for i, j ≥ 1 (eq. 8), with the exact
/// limits at g = ±1, where eq. 9 is 0/0: all of column j goes to j itself (g = 1) or to its
/// opposite (g = -1), normalised so that Σ_i w_i pn_ij = 1.
pub fn normalised_phase(g: f64) -> [[f64; Q]; Q] {
    let mut pn = [[0.0; Q]; Q];
    if g == 1.0 || g == -1.0 {
        for j in 1..Q {
            let target = if g == 1.0 { j } else { opposite(j) };
            pn[target][j] = 1.0 / weight(target);
        }
        return pn;
    }
    for j in 1..Q {
        let mut norm = 0.0;
        for i in 1..Q {
            let p = (1.0 - g * g) / (1.0 - 2.0 * g * dot(i, j) + g * g).powf(1.5);
            pn[i][j] = p;
            // Eq. 8's normaliser: (Σ_axial 2p + Σ_diagonal p) / 24 = Σ_i w_i p_ij.
            norm += weight(i) * p;
        }
        for row in pn.iter_mut().skip(1) {
            row[j] /= norm;
        }
    }
    pn
}

impl Omega {
    /// Eqs. 5-7 with every σ_s of rows 1..18 multiplied by `pn_ij(g)` (eq. 8).
    pub fn new(p: &ColourParams) -> Omega {
        let pn = normalised_phase(p.g);
        let mut o = [[0.0; Q]; Q];
        o[0][0] = -1.0;
        for (j, e) in o[0].iter_mut().enumerate().skip(1) {
            let _ = j;
            *e = p.sigma_a;
        }
        for i in 1..Q {
            let w = weight(i);
            o[i][0] = w;
            for j in 1..Q {
                o[i][j] = p.sigma_s * w * pn[i][j];
            }
            o[i][i] -= p.sigma_t();
        }
        Omega(o)
    }

    /// Σ_i Ω_ij for column j: zero for density conservation.
    pub fn column_sum(&self, j: usize) -> f64 {
        (0..Q).map(|i| self.0[i][j]).sum()
    }
}

/// Ω rewritten for the kernel. Ω is invariant under reversing both directions
/// (`Ω[m̄][n̄] = Ω[m][n]`), so with the pair sums `s_q = f_q + f_q̄` and differences
/// `d_q = f_q - f_q̄` over the nine pairs, `(Ωf)_p = e_p + o_p` and `(Ωf)_p̄ = e_p - o_p`, where
/// `e_p = Ω_p0 f_0 + Σ_q E_pq s_q` and `o_p = Σ_q O_pq d_q`. `O_pq` vanishes whenever
/// `n_p ⟂ n_q` (24 of 81 entries), so this costs about 150 multiply-adds per site instead of
/// 361.
#[derive(Debug, Clone, PartialEq)]
pub struct ReducedOmega {
    /// `Ω_00` (always -1; kept for clarity of the kernel).
    pub o00: f32,
    /// `Ω_0q`, the same for every moving direction (σ_a).
    pub o0q: f32,
    /// `Ω_p0` for each pair (the lattice weight).
    pub op0: [f32; PAIRS],
    /// Even part `E_pq`.
    pub even: [[f32; PAIRS]; PAIRS],
    /// Odd part `O_pq` at the structurally non-zero positions of [`ODD_PATTERN`].
    pub odd: [f32; ODD_TERMS],
}

/// Nine direction pairs; pair q is directions `2q+1` and `2q+2`.
pub const PAIRS: usize = 9;

/// Number of (p, q) pairs with `n_p · n_q ≠ 0`.
pub const ODD_TERMS: usize = 57;

/// The (p, q) positions with `n_p · n_q ≠ 0`, row by row.
pub const ODD_PATTERN: [(u8, u8); ODD_TERMS] = odd_pattern();

const fn odd_pattern() -> [(u8, u8); ODD_TERMS] {
    let c = crate::lattice::C;
    let mut out = [(0u8, 0u8); ODD_TERMS];
    let mut n = 0;
    let mut p = 0;
    while p < PAIRS {
        let mut q = 0;
        while q < PAIRS {
            let (a, b) = (c[2 * p + 1], c[2 * q + 1]);
            if a[0] * b[0] + a[1] * b[1] + a[2] * b[2] != 0 {
                out[n] = (p as u8, q as u8);
                n += 1;
            }
            q += 1;
        }
        p += 1;
    }
    assert!(n == ODD_TERMS);
    out
}

impl ReducedOmega {
    pub fn new(omega: &Omega) -> ReducedOmega {
        let o = &omega.0;
        let mut even = [[0.0; PAIRS]; PAIRS];
        let mut odd = [0.0; ODD_TERMS];
        let mut op0 = [0.0; PAIRS];
        for p in 0..PAIRS {
            let m = 2 * p + 1;
            op0[p] = o[m][0] as f32;
            for q in 0..PAIRS {
                let n = 2 * q + 1;
                even[p][q] = (0.5 * (o[m][n] + o[m][n + 1])) as f32;
            }
        }
        for (t, &(p, q)) in ODD_PATTERN.iter().enumerate() {
            let (m, n) = (2 * p as usize + 1, 2 * q as usize + 1);
            odd[t] = (0.5 * (o[m][n] - o[m][n + 1])) as f32;
        }
        ReducedOmega {
            o00: o[0][0] as f32,
            o0q: o[0][1] as f32,
            op0,
            even,
            odd,
        }
    }

    /// `(Ωf)` for one site through the reduced form (reference for the vector kernels).
    pub fn apply(&self, f: &[f32; Q]) -> [f32; Q] {
        let mut s = [0.0f32; PAIRS];
        let mut d = [0.0f32; PAIRS];
        for q in 0..PAIRS {
            s[q] = f[2 * q + 1] + f[2 * q + 2];
            d[q] = f[2 * q + 1] - f[2 * q + 2];
        }
        let mut out = [0.0f32; Q];
        out[0] = self.o00 * f[0] + self.o0q * s.iter().sum::<f32>();
        let mut o = [0.0f32; PAIRS];
        for (t, &(p, q)) in ODD_PATTERN.iter().enumerate() {
            o[p as usize] += self.odd[t] * d[q as usize];
        }
        for p in 0..PAIRS {
            let mut e = self.op0[p] * f[0];
            for q in 0..PAIRS {
                e += self.even[p][q] * s[q];
            }
            out[2 * p + 1] = e + o[p];
            out[2 * p + 2] = e - o[p];
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn params(sa: f64, ss: f64, g: f64) -> ColourParams {
        ColourParams {
            sigma_a: sa,
            sigma_s: ss,
            g,
        }
    }

    /// Mean cosine of the lattice phase for light arriving along direction `j`:
    /// `Σ_i w_i pn_ij (n_i · n_j)`, the discrete counterpart of the continuous HG's g.
    fn lattice_mean_cosine(g: f64, j: usize) -> f64 {
        let pn = normalised_phase(g);
        (1..Q).map(|i| weight(i) * pn[i][j] * dot(i, j)).sum()
    }

    #[test]
    fn the_cloud_g_is_far_more_forward_on_the_lattice() {
        // docs/media.md ("Against Mitsuba"): eq. 8 normalises HG over the 18 directions, so at
        // the cloud's g = 0.9 nearly all scattered light returns to its own direction and the
        // lattice phase's mean cosine is about 0.995 (axial) and 0.990 (diagonal), not 0.9.
        let (axial, diagonal) = (lattice_mean_cosine(0.9, 1), lattice_mean_cosine(0.9, 7));
        assert!((axial - 0.9952).abs() < 5e-4, "axial {axial}");
        assert!((diagonal - 0.9896).abs() < 5e-4, "diagonal {diagonal}");
        let pn = normalised_phase(0.9);
        let back_to_itself = weight(1) * pn[1][1];
        assert!((back_to_itself - 0.992).abs() < 1e-3, "{back_to_itself}");
        // The lattice g whose axial mean cosine is 0.9 (bisection: it grows with g).
        let (mut lo, mut hi) = (0.0, 0.9);
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if lattice_mean_cosine(mid, 1) < 0.9 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        assert!((lo - 0.730).abs() < 1e-3, "{lo}");
        // Isotropic scattering stays isotropic on the lattice.
        assert!(lattice_mean_cosine(0.0, 1).abs() < 1e-12);
    }

    proptest! {
        #[test]
        fn every_column_sums_to_zero(sa in 0.0f64..0.5, ss in 0.0f64..0.5, g in -1.0f64..=1.0) {
            let om = Omega::new(&params(sa, ss, g));
            for j in 0..Q {
                prop_assert!(om.column_sum(j).abs() < 1e-13, "column {} sums to {}", j, om.column_sum(j));
            }
        }

        #[test]
        fn reduced_form_equals_dense(sa in 0.0f64..0.5, ss in 0.0f64..0.5, g in -1.0f64..=1.0,
                                     f in proptest::array::uniform19(0.0f32..1.0)) {
            let om = Omega::new(&params(sa, ss, g));
            let red = ReducedOmega::new(&om);
            let got = red.apply(&f);
            for i in 0..Q {
                let want: f64 = (0..Q).map(|j| om.0[i][j] * f[j] as f64).sum();
                prop_assert!((got[i] as f64 - want).abs() < 1e-5, "row {}: {} vs {}", i, got[i], want);
            }
        }
    }

    #[test]
    fn limits_at_g_plus_minus_one_are_continuous() {
        for (limit, near) in [(1.0, 0.999_999), (-1.0, -0.999_999)] {
            let a = Omega::new(&params(0.1, 0.8, limit));
            let b = Omega::new(&params(0.1, 0.8, near));
            for i in 0..Q {
                for j in 0..Q {
                    assert!((a.0[i][j] - b.0[i][j]).abs() < 1e-3, "{i},{j}");
                }
            }
        }
    }

    #[test]
    fn forward_limit_without_absorption_is_identity_transport() {
        // σ_a = 0, g = 1: rows 1..18 of Ω vanish, so collision leaves moving densities alone.
        let om = Omega::new(&params(0.0, 0.7, 1.0));
        for i in 1..Q {
            for j in 1..Q {
                assert!(om.0[i][j].abs() < 1e-15, "{i},{j} = {}", om.0[i][j]);
            }
        }
        // g = -1: everything scattered leaves through the opposite direction.
        let om = Omega::new(&params(0.0, 0.7, -1.0));
        assert!((om.0[2][1] - 0.7).abs() < 1e-15);
        assert!((om.0[1][1] + 0.7).abs() < 1e-15);
    }

    #[test]
    fn isotropic_phase_is_uniform() {
        let pn = normalised_phase(0.0);
        for row in pn.iter().skip(1) {
            for &v in row.iter().skip(1) {
                assert!((v - 1.0).abs() < 1e-15);
            }
        }
    }

    #[test]
    fn odd_pattern_counts() {
        // Axial pairs meet 1 axial + 4 diagonal pairs; diagonal pairs 2 axial + 5 diagonal.
        let per_row = |p: u8| ODD_PATTERN.iter().filter(|t| t.0 == p).count();
        for p in 0..3 {
            assert_eq!(per_row(p), 5);
        }
        for p in 3..9 {
            assert_eq!(per_row(p), 7);
        }
    }
}
