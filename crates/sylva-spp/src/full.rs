//! The full plane-parallel model (003 eq. 7): discrete directions, solved by eigenvalue
//! decomposition with the boundary conditions of eq. 21.
//!
//! The radiance is split into azimuthal Fourier modes, `I = Σ_m (2 - δ_m0) I_m(z, mu) cos(m φ)`,
//! which decouple because the Henyey-Greenstein phase function depends only on the scattering
//! angle. Each mode is discretised on a double-Gauss rule (`n` cosines per hemisphere), which
//! turns eq. 7 into `2n` linear ODEs `dI/dz = A I + source · exp(-σt z / mu0)`. The up/down
//! symmetry of `A` reduces its eigenproblem to a symmetric `n × n` one (the eigenvalues come
//! in pairs `±k`), solved with nalgebra's `SymmetricEigen`; the beam gives a particular
//! solution; and the `2n` constants come from eq. 21 (no diffuse light enters at `z = 0`
//! going down or at `z = w` going up). Radiance in any direction is the source function
//! integrated exactly along the ray ([`crate::exp_sum::ray_integral`]).

use crate::error::SppError;
use crate::exp_sum::{ray_integral, ExpTerm};
use crate::phase::{azimuth_samples_for, azimuthal_coefficients};
use crate::quadrature::gauss_legendre;
use crate::slab::{Direction, Slab};
use nalgebra::{Cholesky, DMatrix, DVector, SymmetricEigen};
use std::f64::consts::PI;

/// Directions per hemisphere used unless told otherwise; `docs/spp.md` shows the answer no
/// longer changes beyond it (table values move by < 0.01 percentage point from 16 to 32).
pub const DEFAULT_STREAMS: usize = 16;

/// The conservative case (albedo 1) has a double eigenvalue `k = 0` whose solution is linear in
/// `z`; the albedo is capped just below 1 instead. In a finite slab that changes results by
/// ~1e-9 times the mean path length; in a half-space, where absorption scales as
/// `sqrt(1 - albedo)`, the reflectance comes out 0.99993 instead of 1. A smaller cap would make
/// `k²` smaller than the rounding error of the eigenproblem.
pub const MAX_ALBEDO: f64 = 1.0 - 1e-9;

/// Fourier modes whose phase coefficients are all below this fraction of the largest are
/// dropped (they contribute below rounding).
const MODE_CUTOFF: f64 = 1e-13;

/// One azimuthal mode's solution: eigen-rates, eigenvectors, particular solution and the
/// constants fixed by the boundary conditions.
#[derive(Clone, Debug)]
struct Mode {
    /// Eigen-rates `k_j > 0`.
    k: Vec<f64>,
    /// Column `j`: the downward (`+mu_i`) components of the solution decaying as `exp(-k_j z)`.
    g_down: DMatrix<f64>,
    /// Column `j`: its upward (`-mu_i`) components.
    g_up: DMatrix<f64>,
    /// Weights of the solutions decaying from the top.
    a: Vec<f64>,
    /// Weights of the solutions decaying from the bottom (all zero for a half-space).
    b: Vec<f64>,
    /// Particular solution for the beam, downward and upward components.
    z_down: Vec<f64>,
    z_up: Vec<f64>,
    /// The ODE system, kept for the residual tests: `α`, `β` and the beam source `s±`.
    #[cfg_attr(not(test), allow(dead_code))]
    alpha: DMatrix<f64>,
    #[cfg_attr(not(test), allow(dead_code))]
    beta: DMatrix<f64>,
    #[cfg_attr(not(test), allow(dead_code))]
    s_down: Vec<f64>,
    #[cfg_attr(not(test), allow(dead_code))]
    s_up: Vec<f64>,
}

/// Solved full plane-parallel model for one slab.
#[derive(Clone, Debug)]
pub struct FullModel {
    slab: Slab,
    sigma_s: f64,
    mu: Vec<f64>,
    weight: Vec<f64>,
    azimuth_samples: usize,
    /// Decay rate of the beam, `σt / mu0` (nudged off an eigen-rate if they coincide).
    q: f64,
    /// Scale making the discrete single-scattering of the beam conserve energy exactly.
    source_scale: f64,
    modes: Vec<Mode>,
}

/// Diffuse radiance at the quadrature directions at one depth, per Fourier mode.
#[derive(Clone, Debug)]
pub struct NodeField {
    /// `down[m][i]`: mode `m` at direction `+mu_i`.
    pub down: Vec<Vec<f64>>,
    /// `up[m][i]`: mode `m` at direction `-mu_i`.
    pub up: Vec<Vec<f64>>,
}

impl NodeField {
    /// Radiance at node `i` (downward if `down`) and azimuth `phi`.
    pub fn radiance(&self, i: usize, down: bool, phi: f64) -> f64 {
        let modes = if down { &self.down } else { &self.up };
        modes
            .iter()
            .enumerate()
            .map(|(m, v)| {
                if m == 0 {
                    v[i]
                } else {
                    2.0 * v[i] * (m as f64 * phi).cos()
                }
            })
            .sum()
    }
}

impl FullModel {
    /// Solves with [`DEFAULT_STREAMS`] directions per hemisphere.
    pub fn new(slab: Slab) -> Result<Self, SppError> {
        Self::with_streams(slab, DEFAULT_STREAMS)
    }

    /// Solves with `streams` Gauss directions per hemisphere (1..=128).
    pub fn with_streams(slab: Slab, streams: usize) -> Result<Self, SppError> {
        slab.validate()?;
        if !(1..=128).contains(&streams) {
            return Err(SppError::InvalidParameter {
                name: "streams",
                value: streams as f64,
                reason: "directions per hemisphere must be in 1..=128",
            });
        }
        let n = streams;
        let (mu, weight) = gauss_legendre(n, 0.0, 1.0);
        let g = slab.g;
        let azimuth_samples = azimuth_samples_for(g);
        // Isotropic scattering has only the m = 0 mode.
        let max_modes = if g == 0.0 { 1 } else { 2 * n };

        let coeff = |a: f64, b: f64| azimuthal_coefficients(g, a, b, max_modes, azimuth_samples);
        let mut p_same = vec![vec![Vec::new(); n]; n];
        let mut p_opp = vec![vec![Vec::new(); n]; n];
        for i in 0..n {
            for j in 0..n {
                p_same[i][j] = coeff(mu[i], mu[j]);
                p_opp[i][j] = coeff(mu[i], -mu[j]);
            }
        }
        let src_down: Vec<Vec<f64>> = mu.iter().map(|&m| coeff(m, slab.mu0)).collect();
        let src_up: Vec<Vec<f64>> = mu.iter().map(|&m| coeff(-m, slab.mu0)).collect();

        let mut largest = vec![0.0f64; max_modes];
        for m in 0..max_modes {
            for i in 0..n {
                for j in 0..n {
                    largest[m] = largest[m]
                        .max(p_same[i][j][m].abs())
                        .max(p_opp[i][j][m].abs());
                }
                largest[m] = largest[m].max(src_down[i][m].abs()).max(src_up[i][m].abs());
            }
        }
        let n_modes = (0..max_modes)
            .rev()
            .find(|&m| largest[m] > MODE_CUTOFF * largest[0])
            .map_or(1, |m| m + 1);

        // Renormalise the discrete phase function so that Σ_j 2π w_j p(mu_i, ·) = 1 exactly
        // (symmetric scaling d_i d_j keeps reciprocity): quadrature error would otherwise make
        // the albedo-1 slab gain or lose energy.
        let mut d = vec![1.0; n];
        for _ in 0..200 {
            let mut worst = 0.0f64;
            let sums: Vec<f64> = (0..n)
                .map(|i| {
                    (0..n)
                        .map(|j| {
                            2.0 * PI * weight[j] * d[i] * d[j] * (p_same[i][j][0] + p_opp[i][j][0])
                        })
                        .sum::<f64>()
                })
                .collect();
            for i in 0..n {
                worst = worst.max((sums[i] - 1.0).abs());
                d[i] /= sums[i].sqrt();
            }
            if worst < 1e-15 {
                break;
            }
        }
        let beam_sum: f64 = (0..n)
            .map(|j| 2.0 * PI * weight[j] * (src_down[j][0] + src_up[j][0]))
            .sum();
        let source_scale = 1.0 / beam_sum;

        let sigma_t = slab.sigma_t;
        let sigma_s = slab.albedo.min(MAX_ALBEDO) * sigma_t;
        let w = slab.thickness;

        // Eigen-rates first (they do not depend on the beam), then the beam rate nudged off any
        // of them: an exact coincidence makes the particular solution singular.
        let mut q = sigma_t / slab.mu0;
        let mut eigen = Vec::with_capacity(n_modes);
        for m in 0..n_modes {
            let ps = DMatrix::from_fn(n, n, |i, j| d[i] * d[j] * p_same[i][j][m]);
            let po = DMatrix::from_fn(n, n, |i, j| d[i] * d[j] * p_opp[i][j][m]);
            eigen.push(eigen_solve(&ps, &po, &mu, &weight, sigma_t, sigma_s)?);
        }
        for _ in 0..8 {
            let close = eigen
                .iter()
                .flat_map(|(k, _, _, _, _)| k.iter())
                .any(|k| (k - q).abs() < 1e-9 * q);
            if !close {
                break;
            }
            q *= 1.0 + 1e-7;
        }

        let mut modes = Vec::with_capacity(n_modes);
        for (m, (k, g_down, g_up, alpha, beta)) in eigen.into_iter().enumerate() {
            // Particular solution Z exp(-q z): (α + q) Z+ + β Z- = -s+, β Z+ + (α - q) Z- = -s-.
            let s_down: Vec<f64> = (0..n)
                .map(|i| sigma_s * source_scale * src_down[i][m] / mu[i])
                .collect();
            let s_up: Vec<f64> = (0..n)
                .map(|i| sigma_s * source_scale * src_up[i][m] / mu[i])
                .collect();
            let mut sys = DMatrix::zeros(2 * n, 2 * n);
            let mut rhs = DVector::zeros(2 * n);
            for i in 0..n {
                for j in 0..n {
                    sys[(i, j)] = alpha[(i, j)] + if i == j { q } else { 0.0 };
                    sys[(i, n + j)] = beta[(i, j)];
                    sys[(n + i, j)] = beta[(i, j)];
                    sys[(n + i, n + j)] = alpha[(i, j)] - if i == j { q } else { 0.0 };
                }
                rhs[i] = -s_down[i];
                rhs[n + i] = -s_up[i];
            }
            let z = sys
                .lu()
                .solve(&rhs)
                .ok_or(SppError::Solve("singular particular-solution system"))?;
            let z_down: Vec<f64> = (0..n).map(|i| z[i]).collect();
            let z_up: Vec<f64> = (0..n).map(|i| z[n + i]).collect();

            // Boundary conditions (eq. 21): no diffuse light going down at z = 0, none going up
            // at z = w.
            let (a, b) = if w.is_infinite() {
                let rhs = DVector::from_fn(n, |i, _| -z_down[i]);
                let sol = g_down
                    .clone()
                    .lu()
                    .solve(&rhs)
                    .ok_or(SppError::Solve("singular half-space boundary system"))?;
                (sol.iter().copied().collect(), vec![0.0; n])
            } else {
                let decay: Vec<f64> = k.iter().map(|k| (-k * w).exp()).collect();
                let beam_bottom = (-q * w).exp();
                let mut bc = DMatrix::zeros(2 * n, 2 * n);
                let mut rhs = DVector::zeros(2 * n);
                for i in 0..n {
                    for j in 0..n {
                        bc[(i, j)] = g_down[(i, j)];
                        bc[(i, n + j)] = g_up[(i, j)] * decay[j];
                        bc[(n + i, j)] = g_up[(i, j)] * decay[j];
                        bc[(n + i, n + j)] = g_down[(i, j)];
                    }
                    rhs[i] = -z_down[i];
                    rhs[n + i] = -z_up[i] * beam_bottom;
                }
                let sol = bc
                    .lu()
                    .solve(&rhs)
                    .ok_or(SppError::Solve("singular slab boundary system"))?;
                (
                    (0..n).map(|j| sol[j]).collect(),
                    (0..n).map(|j| sol[n + j]).collect(),
                )
            };
            modes.push(Mode {
                k,
                g_down,
                g_up,
                a,
                b,
                z_down,
                z_up,
                alpha,
                beta,
                s_down,
                s_up,
            });
        }

        Ok(Self {
            slab,
            sigma_s,
            mu,
            weight,
            azimuth_samples,
            q,
            source_scale,
            modes,
        })
    }

    /// The slab this model solves.
    pub fn slab(&self) -> &Slab {
        &self.slab
    }

    /// Gauss cosines `mu_i` in (0, 1) and weights of one hemisphere.
    pub fn nodes(&self) -> (&[f64], &[f64]) {
        (&self.mu, &self.weight)
    }

    /// Number of azimuthal Fourier modes kept.
    pub fn mode_count(&self) -> usize {
        self.modes.len()
    }

    /// Depth profile of mode `m` at node `i` going down (`down`) or up, as exponential terms.
    #[cfg(test)]
    fn node_terms(&self, m: usize, i: usize, down: bool) -> Vec<ExpTerm> {
        let mode = &self.modes[m];
        let n = self.mu.len();
        let mut terms = Vec::with_capacity(2 * n + 1);
        for j in 0..n {
            let (top, bottom) = if down {
                (mode.g_down[(i, j)], mode.g_up[(i, j)])
            } else {
                (mode.g_up[(i, j)], mode.g_down[(i, j)])
            };
            terms.push(ExpTerm::top(mode.a[j] * top, mode.k[j]));
            if mode.b[j] != 0.0 {
                terms.push(ExpTerm::bottom(mode.b[j] * bottom, mode.k[j]));
            }
        }
        let zp = if down { mode.z_down[i] } else { mode.z_up[i] };
        terms.push(ExpTerm::top(zp, self.q));
        terms
    }

    /// Diffuse radiance modes at all quadrature directions at depth `z`.
    pub fn node_field(&self, z: f64) -> Result<NodeField, SppError> {
        self.slab.check_depth(z)?;
        let w = self.slab.thickness;
        let n = self.mu.len();
        let mut down = Vec::with_capacity(self.modes.len());
        let mut up = Vec::with_capacity(self.modes.len());
        for mode in &self.modes {
            let top: Vec<f64> = mode.k.iter().map(|k| (-k * z).exp()).collect();
            let bottom: Vec<f64> = if w.is_infinite() {
                vec![0.0; n]
            } else {
                mode.k.iter().map(|k| (-k * (w - z)).exp()).collect()
            };
            let beam = (-self.q * z).exp();
            let mut dv = vec![0.0; n];
            let mut uv = vec![0.0; n];
            for i in 0..n {
                let mut sd = mode.z_down[i] * beam;
                let mut su = mode.z_up[i] * beam;
                for j in 0..n {
                    let (at, bb) = (mode.a[j] * top[j], mode.b[j] * bottom[j]);
                    sd += at * mode.g_down[(i, j)] + bb * mode.g_up[(i, j)];
                    su += at * mode.g_up[(i, j)] + bb * mode.g_down[(i, j)];
                }
                dv[i] = sd;
                uv[i] = su;
            }
            down.push(dv);
            up.push(uv);
        }
        Ok(NodeField { down, up })
    }

    /// Hemispheric integrals of the diffuse radiance at depth `z`: `(∫_{Ω+} I, ∫_{Ω-} I)`, the
    /// quantities the SPP model's `α`, `β` amplitudes stand for.
    pub fn hemispheric_totals(&self, z: f64) -> Result<(f64, f64), SppError> {
        let f = self.node_field(z)?;
        let down: f64 = (0..self.mu.len())
            .map(|i| 2.0 * PI * self.weight[i] * f.down[0][i])
            .sum();
        let up: f64 = (0..self.mu.len())
            .map(|i| 2.0 * PI * self.weight[i] * f.up[0][i])
            .sum();
        Ok((down, up))
    }

    /// Net diffuse flux at depth `z` going down minus going up, per unit incident horizontal
    /// flux `mu0`.
    pub fn net_diffuse_flux(&self, z: f64) -> Result<f64, SppError> {
        let f = self.node_field(z)?;
        let flux: f64 = (0..self.mu.len())
            .map(|i| 2.0 * PI * self.weight[i] * self.mu[i] * (f.down[0][i] - f.up[0][i]))
            .sum();
        Ok(flux / self.slab.mu0)
    }

    /// Diffuse reflectance: upward flux leaving `z = 0` over the incident horizontal flux.
    pub fn reflectance(&self) -> f64 {
        let f = self.node_field(0.0).expect("0 is a valid depth");
        let flux: f64 = (0..self.mu.len())
            .map(|i| 2.0 * PI * self.weight[i] * self.mu[i] * f.up[0][i])
            .sum();
        flux / self.slab.mu0
    }

    /// Diffuse transmittance: scattered flux leaving `z = w` over the incident horizontal flux
    /// (0 for a half-space). The unscattered beam adds `exp(-σt w / mu0)`.
    pub fn diffuse_transmittance(&self) -> f64 {
        if self.slab.is_semi_infinite() {
            return 0.0;
        }
        let f = self
            .node_field(self.slab.thickness)
            .expect("w is a valid depth");
        let flux: f64 = (0..self.mu.len())
            .map(|i| 2.0 * PI * self.weight[i] * self.mu[i] * f.down[0][i])
            .sum();
        flux / self.slab.mu0
    }

    /// The source function `J_m(z', mu)` of mode `m` for direction cosine `mu` as exponential
    /// terms: in-scattering of the discrete field plus single scattering of the beam.
    fn source_terms(&self, m: usize, coeffs: &DirectionCoefficients) -> Vec<ExpTerm> {
        let n = self.mu.len();
        let mode = &self.modes[m];
        let to_down: Vec<f64> = coeffs.to_down.iter().map(|c| c[m]).collect();
        let to_up: Vec<f64> = coeffs.to_up.iter().map(|c| c[m]).collect();
        let mut terms = Vec::with_capacity(2 * n + 1);
        for j in 0..n {
            let mut top = 0.0;
            let mut bottom = 0.0;
            for i in 0..n {
                let wi = 2.0 * PI * self.weight[i];
                top += wi * (to_down[i] * mode.g_down[(i, j)] + to_up[i] * mode.g_up[(i, j)]);
                bottom += wi * (to_down[i] * mode.g_up[(i, j)] + to_up[i] * mode.g_down[(i, j)]);
            }
            terms.push(ExpTerm::top(self.sigma_s * mode.a[j] * top, mode.k[j]));
            if mode.b[j] != 0.0 {
                terms.push(ExpTerm::bottom(
                    self.sigma_s * mode.b[j] * bottom,
                    mode.k[j],
                ));
            }
        }
        let mut beam = self.source_scale * coeffs.to_beam[m];
        for i in 0..n {
            beam +=
                2.0 * PI * self.weight[i] * (to_down[i] * mode.z_down[i] + to_up[i] * mode.z_up[i]);
        }
        terms.push(ExpTerm::top(self.sigma_s * beam, self.q));
        terms
    }

    fn coefficients_for(&self, mu_dir: f64) -> DirectionCoefficients {
        let modes = self.modes.len();
        let coeff =
            |b: f64| azimuthal_coefficients(self.slab.g, mu_dir, b, modes, self.azimuth_samples);
        DirectionCoefficients {
            to_down: self.mu.iter().map(|&b| coeff(b)).collect(),
            to_up: self.mu.iter().map(|&b| coeff(-b)).collect(),
            to_beam: coeff(self.slab.mu0),
        }
    }

    /// Azimuthal modes `I_m(z, mu)` of the diffuse radiance at depth `z`, direction cosine `mu`.
    pub fn radiance_modes(&self, z: f64, mu: f64) -> Result<Vec<f64>, SppError> {
        self.slab.check_depth(z)?;
        Direction::new(mu, 0.0)?;
        let coeffs = self.coefficients_for(mu);
        Ok((0..self.modes.len())
            .map(|m| {
                let terms = self.source_terms(m, &coeffs);
                ray_integral(&terms, z, self.slab.thickness, mu, self.slab.sigma_t)
            })
            .collect())
    }

    /// Azimuth-averaged diffuse radiance `I_0(z, mu)`.
    pub fn azimuthal_mean_radiance(&self, z: f64, mu: f64) -> Result<f64, SppError> {
        self.slab.check_depth(z)?;
        Direction::new(mu, 0.0)?;
        let coeffs = self.coefficients_for(mu);
        let terms = self.source_terms(0, &coeffs);
        Ok(ray_integral(
            &terms,
            z,
            self.slab.thickness,
            mu,
            self.slab.sigma_t,
        ))
    }

    /// Diffuse radiance `I(z, s)` at any depth and direction (the unscattered beam excluded).
    pub fn radiance(&self, z: f64, dir: Direction) -> Result<f64, SppError> {
        let modes = self.radiance_modes(z, dir.mu)?;
        Ok(modes
            .iter()
            .enumerate()
            .map(|(m, v)| {
                if m == 0 {
                    *v
                } else {
                    2.0 * v * (m as f64 * dir.phi).cos()
                }
            })
            .sum())
    }

    /// Diffuse flux leaving a face through the cone `mu_lo <= |mu| <= mu_hi` (azimuth
    /// integrated), over the incident horizontal flux: the top face if `top`, else the bottom.
    pub fn exit_flux_in_band(&self, top: bool, mu_lo: f64, mu_hi: f64) -> Result<f64, SppError> {
        let (x, wt) = gauss_legendre(24, mu_lo, mu_hi);
        let mut total = 0.0;
        for (m, w) in x.iter().zip(&wt) {
            let (z, dir) = if top {
                (0.0, -m)
            } else {
                (self.slab.thickness, *m)
            };
            if z.is_infinite() {
                return Ok(0.0);
            }
            total += w * 2.0 * PI * m * self.azimuthal_mean_radiance(z, dir)?;
        }
        Ok(total / self.slab.mu0)
    }
}

/// Phase-function Fourier coefficients from the quadrature directions and the beam into one
/// direction, all modes.
struct DirectionCoefficients {
    to_down: Vec<Vec<f64>>,
    to_up: Vec<Vec<f64>>,
    to_beam: Vec<f64>,
}

type EigenParts = (
    Vec<f64>,
    DMatrix<f64>,
    DMatrix<f64>,
    DMatrix<f64>,
    DMatrix<f64>,
);

/// Homogeneous solutions of one mode: `dI+/dz = α I+ + β I-`, `dI-/dz = -β I+ - α I-` with
/// `α = M⁻¹(2π σs P++ W - σt)`, `β = M⁻¹ 2π σs P+- W`. With `S = G+ + G-`, `D = G+ - G-` and
/// `I ∝ exp(-k z)`: `(α - β)(α + β) S = k² S`, `D = -(α + β) S / k`. The product is similar to
/// `Cᵀ(-L)C` with `-K = C Cᵀ` (`K`, `L` symmetric, from `α ∓ β`), a symmetric eigenproblem.
/// Returns `(k, G+, G-, α, β)`.
fn eigen_solve(
    p_same: &DMatrix<f64>,
    p_opp: &DMatrix<f64>,
    mu: &[f64],
    weight: &[f64],
    sigma_t: f64,
    sigma_s: f64,
) -> Result<EigenParts, SppError> {
    let n = mu.len();
    let sw: Vec<f64> = weight.iter().map(|w| w.sqrt()).collect();
    let sm: Vec<f64> = mu.iter().map(|m| m.sqrt()).collect();
    // H± = 2π σs W^½ (P++ ± P+-) W^½ - σt; K, L = M^-½ H∓± M^-½.
    let sym = |sign: f64| {
        DMatrix::from_fn(n, n, |i, j| {
            let h = 2.0 * PI * sigma_s * sw[i] * sw[j] * (p_same[(i, j)] + sign * p_opp[(i, j)])
                - if i == j { sigma_t } else { 0.0 };
            h / (sm[i] * sm[j])
        })
    };
    let neg_k = -sym(-1.0);
    let neg_l = -sym(1.0);
    let chol =
        Cholesky::new(neg_k.clone()).ok_or(SppError::Solve("(α-β) is not negative definite"))?;
    let c = chol.l();
    let mut a = c.transpose() * &neg_l * &c;
    a = (&a + a.transpose()) * 0.5;
    let eig = SymmetricEigen::new(a);

    let alpha = DMatrix::from_fn(n, n, |i, j| {
        (2.0 * PI * sigma_s * p_same[(i, j)] * weight[j] - if i == j { sigma_t } else { 0.0 })
            / mu[i]
    });
    let beta = DMatrix::from_fn(n, n, |i, j| {
        2.0 * PI * sigma_s * p_opp[(i, j)] * weight[j] / mu[i]
    });
    let alpha_plus_beta = &alpha + &beta;

    let mut k = Vec::with_capacity(n);
    let mut g_down = DMatrix::zeros(n, n);
    let mut g_up = DMatrix::zeros(n, n);
    for j in 0..n {
        let k2 = eig.eigenvalues[j];
        if k2.is_nan() || k2 <= 0.0 {
            return Err(SppError::Solve("non-positive eigenvalue k²"));
        }
        let kj = k2.sqrt();
        let s_scaled = &c * eig.eigenvectors.column(j);
        let s = DVector::from_fn(n, |i, _| s_scaled[i] / (sw[i] * sm[i]));
        let dvec = -(&alpha_plus_beta * &s) / kj;
        let gd = (&s + &dvec) * 0.5;
        let gu = (&s - &dvec) * 0.5;
        let scale = gd.amax().max(gu.amax());
        g_down.set_column(j, &(gd / scale));
        g_up.set_column(j, &(gu / scale));
        k.push(kj);
    }
    Ok((k, g_down, g_up, alpha, beta))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::exp_sum::eval;

    fn slab(albedo: f64, g: f64, w: f64, deg: f64) -> Slab {
        Slab::with_incidence_deg(1.0, albedo, g, w, deg).unwrap()
    }

    #[test]
    fn albedo_one_conserves_energy() {
        for &(g, w, deg) in &[
            (0.0, 1.0, 0.0),
            (0.5, 2.0, 30.0),
            (-0.5, 10.0, 60.0),
            (0.5, 0.3, 75.0),
        ] {
            let model = FullModel::new(slab(1.0, g, w, deg)).unwrap();
            let s = model.slab();
            let total = model.reflectance() + model.diffuse_transmittance() + s.direct(w);
            assert!(
                (total - 1.0).abs() < 1e-7,
                "g {g} w {w} deg {deg}: R+T = {total}"
            );
            // The net flux (diffuse + beam) is the same at every depth when nothing is absorbed.
            for &z in &[0.0, 0.3 * w, w] {
                let net = model.net_diffuse_flux(z).unwrap() + s.direct(z);
                assert!((net - model.diffuse_transmittance() - s.direct(w)).abs() < 1e-7);
            }
        }
    }

    #[test]
    fn albedo_zero_is_beer_lambert() {
        let model = FullModel::new(slab(0.0, 0.5, 3.0, 40.0)).unwrap();
        assert_eq!(model.reflectance(), 0.0);
        assert_eq!(model.diffuse_transmittance(), 0.0);
        for &z in &[0.0, 1.0, 3.0] {
            for &mu in &[-0.9, -0.2, 0.3, 1.0] {
                assert_eq!(
                    model.radiance(z, Direction::new(mu, 0.4).unwrap()).unwrap(),
                    0.0
                );
            }
        }
        let s = model.slab();
        assert!((s.direct(3.0) - (-3.0 / 40f64.to_radians().cos()).exp()).abs() < 1e-15);
    }

    #[test]
    fn satisfies_the_discrete_equations_and_boundary_conditions() {
        // Residual of dI/dz = α I+ + β I- (+ beam) at the nodes, via the exact derivative of each
        // exponential term, and eq. 21 at both faces.
        let model = FullModel::with_streams(slab(0.9, 0.5, 4.0, 30.0), 8).unwrap();
        let w = 4.0;
        let n = model.mu.len();
        for m in 0..model.modes.len() {
            for i in 0..n {
                let down = model.node_terms(m, i, true);
                let up = model.node_terms(m, i, false);
                assert!(eval(&down, 0.0, w).abs() < 1e-12, "mode {m} node {i} top");
                assert!(eval(&up, w, w).abs() < 1e-12, "mode {m} node {i} bottom");
            }
            let mode = &model.modes[m];
            for &z in &[0.0, 1.3, 4.0] {
                let vals = |down: bool| -> Vec<f64> {
                    (0..n)
                        .map(|j| eval(&model.node_terms(m, j, down), z, w))
                        .collect()
                };
                let slope = |i: usize, down: bool| -> f64 {
                    model
                        .node_terms(m, i, down)
                        .iter()
                        .map(|t| t.derivative(z, w))
                        .sum()
                };
                let (ip, im) = (vals(true), vals(false));
                let beam = (-model.q * z).exp();
                for i in 0..n {
                    let mut rhs_down = mode.s_down[i] * beam;
                    let mut rhs_up = -mode.s_up[i] * beam;
                    for j in 0..n {
                        rhs_down += mode.alpha[(i, j)] * ip[j] + mode.beta[(i, j)] * im[j];
                        rhs_up -= mode.beta[(i, j)] * ip[j] + mode.alpha[(i, j)] * im[j];
                    }
                    let scale = 1.0 + rhs_down.abs() + rhs_up.abs();
                    assert!(
                        (slope(i, true) - rhs_down).abs() < 1e-10 * scale,
                        "mode {m} z {z} node {i} down"
                    );
                    assert!(
                        (slope(i, false) - rhs_up).abs() < 1e-10 * scale,
                        "mode {m} z {z} node {i} up"
                    );
                }
            }
        }
    }

    #[test]
    fn ray_integrated_radiance_reproduces_the_nodes() {
        let model = FullModel::with_streams(slab(0.95, 0.5, 3.0, 45.0), 12).unwrap();
        let (mu, _) = model.nodes();
        for &z in &[0.0, 1.2, 3.0] {
            let field = model.node_field(z).unwrap();
            for i in [0, 5, 11] {
                for &phi in &[0.0, 1.0, 3.0] {
                    for down in [true, false] {
                        let dir = Direction::new(if down { mu[i] } else { -mu[i] }, phi).unwrap();
                        let node = field.radiance(i, down, phi);
                        let ray = model.radiance(z, dir).unwrap();
                        assert!(
                            (node - ray).abs() < 1e-6 * node.abs().max(1e-3),
                            "z {z} i {i} phi {phi} down {down}: {node} vs {ray}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn low_albedo_radiance_is_single_scattering() {
        // To first order in the albedo the diffuse radiance is the closed-form single scatter
        // σs p(s, s0) ∫ e^{-q z'} e^{-σt |z - z'| / |mu|} dz' / |mu|.
        let albedo = 1e-4;
        let (w, mu0) = (2.0, 0.6f64);
        let model = FullModel::new(Slab::new(1.0, albedo, 0.5, w, mu0).unwrap()).unwrap();
        for &z in &[0.0, 0.7, 2.0] {
            for &(mu, phi) in &[(0.3, 0.0), (0.9, 2.0), (-0.5, 0.5), (-0.95, 3.1)] {
                let dir = Direction::new(mu, phi).unwrap();
                let want = crate::slab::single_scatter_reference(albedo, 0.5, w, mu0, z, dir);
                let got = model.radiance(z, dir).unwrap();
                if want == 0.0 {
                    assert!(got.abs() < 1e-12);
                } else {
                    assert!(
                        (got / want - 1.0).abs() < 1e-3,
                        "z {z} mu {mu}: {got} vs {want}"
                    );
                }
            }
        }
    }

    #[test]
    fn answer_stops_changing_as_directions_are_added() {
        let s = slab(0.95, 0.5, 5.0, 30.0);
        let r: Vec<(f64, f64)> = [4, 8, 16, 32]
            .iter()
            .map(|&n| {
                let m = FullModel::with_streams(s, n).unwrap();
                (m.reflectance(), m.diffuse_transmittance())
            })
            .collect();
        let diff = |a: (f64, f64), b: (f64, f64)| (a.0 - b.0).abs().max((a.1 - b.1).abs());
        // Successive differences shrink and 16 → 32 is below 1e-4 of the incident flux.
        assert!(diff(r[2], r[3]) < 1e-4, "{r:?}");
        assert!(diff(r[2], r[3]) < diff(r[0], r[1]), "{r:?}");
    }

    #[test]
    fn half_space_matches_a_thick_slab() {
        let thick = FullModel::new(slab(0.9, 0.5, 60.0, 30.0)).unwrap();
        let half = FullModel::new(slab(0.9, 0.5, f64::INFINITY, 30.0)).unwrap();
        assert!((thick.reflectance() - half.reflectance()).abs() < 1e-10);
        let dir = Direction::new(-0.4, 1.0).unwrap();
        let (a, b) = (
            thick.radiance(2.0, dir).unwrap(),
            half.radiance(2.0, dir).unwrap(),
        );
        assert!((a - b).abs() < 1e-10 * a.abs(), "{a} vs {b}");
    }

    #[test]
    fn bad_inputs_are_errors() {
        let s = slab(0.9, 0.0, 2.0, 0.0);
        assert!(FullModel::with_streams(s, 0).is_err());
        let m = FullModel::with_streams(s, 4).unwrap();
        assert!(m.node_field(-1.0).is_err());
        assert!(m.node_field(2.5).is_err());
        assert!(m.node_field(f64::NAN).is_err());
        assert!(m.radiance_modes(1.0, 0.0).is_err());
    }
}
