//! The D3Q19 lattice (SPEC §1): rest direction 0, six axial directions 1..=6, twelve
//! face diagonals 7..=18.

/// Number of lattice directions.
pub const Q: usize = 19;

/// Integer velocities `c_m`. Opposite directions sit next to each other (1/2, 3/4, ...), so
/// `opposite(m)` is `m ± 1`; the collision kernel relies on that pairing.
pub const C: [[i32; 3]; Q] = [
    [0, 0, 0],
    [1, 0, 0],
    [-1, 0, 0],
    [0, 1, 0],
    [0, -1, 0],
    [0, 0, 1],
    [0, 0, -1],
    [1, 1, 0],
    [-1, -1, 0],
    [1, -1, 0],
    [-1, 1, 0],
    [1, 0, 1],
    [-1, 0, -1],
    [1, 0, -1],
    [-1, 0, 1],
    [0, 1, 1],
    [0, -1, -1],
    [0, 1, -1],
    [0, -1, 1],
];

/// Lattice weights: 1/12 axial, 1/24 diagonal (eqs. 6-7); the rest direction has none.
pub fn weight(m: usize) -> f64 {
    match m {
        0 => 0.0,
        1..=6 => 1.0 / 12.0,
        _ => 1.0 / 24.0,
    }
}

/// The direction opposite to `m` (`c_opposite = -c_m`).
pub const fn opposite(m: usize) -> usize {
    if m == 0 {
        0
    } else if m % 2 == 1 {
        m + 1
    } else {
        m - 1
    }
}

/// Unit vector `n_m = c_m / |c_m|` (zero for the rest direction).
pub fn unit(m: usize) -> [f64; 3] {
    let c = C[m];
    let len = ((c[0] * c[0] + c[1] * c[1] + c[2] * c[2]) as f64).sqrt();
    if len == 0.0 {
        return [0.0; 3];
    }
    [c[0] as f64 / len, c[1] as f64 / len, c[2] as f64 / len]
}

/// `n_a · n_b`.
pub fn dot(a: usize, b: usize) -> f64 {
    let (x, y) = (unit(a), unit(b));
    x[0] * y[0] + x[1] * y[1] + x[2] * y[2]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn opposites_pair_up() {
        for m in 0..Q {
            let o = opposite(m);
            assert_eq!(opposite(o), m);
            for a in 0..3 {
                assert_eq!(C[o][a], -C[m][a]);
            }
        }
    }

    #[test]
    fn weights_make_isotropic_lattice() {
        // Σ w = 1 over moving directions, Σ w c = 0, Σ w c_a c_b = δ_ab / 2: the second moment
        // is isotropic, which the diffusion limit needs.
        let total: f64 = (1..Q).map(weight).sum();
        assert!((total - 1.0).abs() < 1e-15);
        for a in 0..3 {
            let first: f64 = (1..Q).map(|m| weight(m) * C[m][a] as f64).sum();
            assert_eq!(first, 0.0);
            for b in 0..3 {
                let second: f64 = (1..Q).map(|m| weight(m) * (C[m][a] * C[m][b]) as f64).sum();
                let expect = if a == b { 0.5 } else { 0.0 };
                assert!((second - expect).abs() < 1e-15, "{a}{b}: {second}");
            }
        }
        // All 18 moving directions are distinct.
        for a in 1..Q {
            for b in a + 1..Q {
                assert_ne!(C[a], C[b]);
            }
        }
    }
}
