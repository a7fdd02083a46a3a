//! Gauss-Legendre quadrature.

/// Nodes and weights of the `n`-point Gauss-Legendre rule on `[a, b]`, nodes ascending.
pub fn gauss_legendre(n: usize, a: f64, b: f64) -> (Vec<f64>, Vec<f64>) {
    assert!(n > 0, "a quadrature needs at least one node");
    let mut nodes = vec![0.0; n];
    let mut weights = vec![0.0; n];
    let half = (b - a) / 2.0;
    let mid = (b + a) / 2.0;
    for i in 0..n.div_ceil(2) {
        // Tricomi's initial guess, then Newton on P_n.
        let mut x = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
        let mut dp = 1.0;
        for _ in 0..100 {
            let (p, d) = legendre_and_derivative(n, x);
            dp = d;
            let dx = p / d;
            x -= dx;
            if dx.abs() < 1e-16 {
                break;
            }
        }
        let (_, d) = legendre_and_derivative(n, x);
        if d != 0.0 {
            dp = d;
        }
        let w = 2.0 / ((1.0 - x * x) * dp * dp);
        // x is the i-th largest root.
        nodes[n - 1 - i] = mid + half * x;
        nodes[i] = mid - half * x;
        weights[n - 1 - i] = w * half;
        weights[i] = w * half;
    }
    (nodes, weights)
}

fn legendre_and_derivative(n: usize, x: f64) -> (f64, f64) {
    let (mut p0, mut p1) = (1.0, x);
    for k in 2..=n {
        let p2 = ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64;
        p0 = p1;
        p1 = p2;
    }
    let p = if n == 0 { 1.0 } else { p1 };
    let pm1 = if n == 0 { 0.0 } else { p0 };
    let d = n as f64 * (x * p - pm1) / (x * x - 1.0);
    (p, d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integrates_polynomials_of_degree_2n_minus_1_exactly() {
        for n in 1..=20 {
            let (x, w) = gauss_legendre(n, 0.0, 1.0);
            for deg in 0..(2 * n) {
                let sum: f64 = x.iter().zip(&w).map(|(x, w)| w * x.powi(deg as i32)).sum();
                let exact = 1.0 / (deg as f64 + 1.0);
                assert!(
                    (sum - exact).abs() < 1e-13,
                    "n {n} deg {deg}: {sum} vs {exact}"
                );
            }
            assert!(x.windows(2).all(|p| p[0] < p[1]));
        }
    }
}
