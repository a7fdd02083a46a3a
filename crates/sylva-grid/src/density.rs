//! How plant area becomes an LB site density: the contract between the voxelizer (which
//! measures leaf and bark area per cell) and the solver (which attenuates by `ρ σ_t` per
//! step). Kept beside the lattice because the step's optical depth depends on its weights.

use crate::lattice::{weight, C, Q};

/// Mean projected area per one-sided area of flat leaves of random orientation (the `G`
/// function of a spherical leaf-angle distribution): 1/2.
pub const LEAF_PROJECTION: f64 = 0.5;

/// Mean projected area per surface area of closed convex bodies (Cauchy's formula), for bark:
/// a branch seen from a random direction shows a quarter of its surface.
pub const BARK_PROJECTION: f64 = 0.25;

/// Optical depth per lattice step, in units of the optical depth of one cell edge. Light
/// moves one cell edge per step along the axes and `√2` edges along the diagonals, but the
/// lattice attenuates every direction alike per step; this makes the attenuation per unit
/// length right on average over an isotropic field: `1 / Σ_i w_i / |c_i|` = 1.1716.
pub fn step_optical_depth_factor() -> f64 {
    let mean_inverse_length: f64 = (1..Q)
        .map(|i| {
            let c = C[i];
            weight(i) / ((c[0] * c[0] + c[1] * c[1] + c[2] * c[2]) as f64).sqrt()
        })
        .sum();
    1.0 / mean_inverse_length
}

/// The LB site density and wood fraction of a cell of edge `cell` holding `leaf_area`
/// (one-sided, opaque parts only) and `bark_area` (surface) of plant: the probability that
/// light crossing the cell in one step meets either, `1 - exp(-τ)` with
/// `τ = k (G_leaf A_leaf + G_bark A_bark) / cell²` ([`LEAF_PROJECTION`],
/// [`BARK_PROJECTION`], `k` = [`step_optical_depth_factor`]), and the share of `τ` due to
/// bark.
pub fn collision_probability(leaf_area: f64, bark_area: f64, cell: f64) -> (f64, f64) {
    let leaf = LEAF_PROJECTION * leaf_area.max(0.0);
    let bark = BARK_PROJECTION * bark_area.max(0.0);
    let shadow = leaf + bark;
    if !(shadow > 0.0 && cell > 0.0) {
        return (0.0, 0.0);
    }
    let tau = step_optical_depth_factor() * shadow / (cell * cell);
    (-(-tau).exp_m1(), bark / shadow)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn collision_probability_from_area() {
        // No plant, no collision.
        assert_eq!(collision_probability(0.0, 0.0, 0.1), (0.0, 0.0));
        // A cell holding leaf area A: τ = k · A / 2 / h².
        let (p, wood) = collision_probability(0.02, 0.0, 0.1);
        let tau = step_optical_depth_factor() * 0.5 * 0.02 / 0.01;
        assert!((p - (1.0 - (-tau).exp())).abs() < 1e-12);
        assert_eq!(wood, 0.0);
        // Bark counts a quarter of its surface; the wood fraction is its share of τ.
        let (_, wood) = collision_probability(0.01, 0.04, 0.1);
        assert!((wood - 0.01 / (0.005 + 0.01)).abs() < 1e-12);
        // Dense cells approach 1 and never exceed it.
        let (p, _) = collision_probability(100.0, 0.0, 0.1);
        assert!(p <= 1.0 && p > 0.999999);
    }
}
