//! Plane-parallel scattering (paper 003): the full discrete-ordinates model, the simplified (SPP) model and a Monte Carlo reference in slabs, and the SPP model applied to trees.
//!
//! This crate owns the physics of paper 003:
//!
//! * [`full::FullModel`]: eq. 7 (discrete directions, Henyey-Greenstein phase function eq. 2)
//!   solved per azimuthal Fourier mode by eigenvalue decomposition, boundary conditions eq. 21,
//!   radiance at any depth and direction by integrating the source function along the ray.
//! * [`spp::SppModel`]: the simplified plane-parallel model, eqs. 8-22 in closed form, and its
//!   ray-marching refinement (Appendix A.1).
//! * [`monte_carlo`]: photons through the slab with Henyey-Greenstein scattering, an independent
//!   reference for both solvers, deterministic for a seed whatever the thread count.
//! * [`tables`]: 003 Tables 1 and 2 (RMS error of the simplified and refined SPP against the full
//!   model) recomputed beside the paper's values.
//! * [`trees`]: §4-5, the model on trees: depth and thickness per leaf mesh (eq. 29), the
//!   G-factor (eqs. 23-28, A.2-A.3), deep opacity maps, instance grids and eq. 31, shading
//!   (eq. 32), the renderer's SPP light, and the Monte Carlo test of Table 3 (eq. 30) with
//!   sylva's LB lighting beside it.
//!
//! Slab conventions: `z` is the depth below the lit face (`0 <= z <= w`); a direction is given by
//! `mu`, the cosine of its angle with +z (so `mu > 0` travels deeper, the paper's Ω+), and `phi`,
//! its azimuth measured from the plane of incidence (`phi = 0` is the azimuth the sun's light
//! travels in). The incident light is `δ(s - s0)`: a unit flux through a surface normal to the
//! beam, so the horizontal irradiance at `z = 0` is `mu0`. Radiances returned are the *diffuse*
//! (scattered at least once) part; the unscattered beam `exp(-σt z / mu0) δ(s - s0)` is the same
//! in every model and is reported separately.

pub mod error;
pub mod exp_sum;
pub mod full;
pub mod monte_carlo;
pub mod phase;
pub mod quadrature;
pub mod report;
pub mod slab;
pub mod spp;
pub mod tables;
pub mod trees;

pub use error::SppError;
pub use full::FullModel;
pub use slab::{Direction, Slab};
pub use spp::SppModel;
