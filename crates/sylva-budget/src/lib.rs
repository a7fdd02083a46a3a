//! The canopy radiation budget (issue 29 items 3-5): what a stand of plants does with the
//! sunlight it receives, per spectral band: the fractions absorbed by the canopy (fAPAR in
//! the PAR bands), reflected to the sky (the albedo), transmitted to the ground and absorbed
//! by it.
//!
//! Owns the abstract canopies that radiation-transfer intercomparisons use ([`spec`]: a TOML
//! description; [`stand`]: its leaves as meshes): spherical or ellipsoidal crowns filled with
//! flat leaves of uniformly random orientation, placed without overlap, or a homogeneous
//! layer; the bands with their leaf reflectance and transmittance and soil albedo; and the
//! Monte Carlo photon budget of such a stand in a cyclic plot ([`photons`]: light leaving a
//! side re-enters on the opposite one, so the plot stands for an infinite stand), the
//! reference the other methods are held to, with the BRF towards chosen view directions by
//! local estimates ([`report`] formats it).
//!
//! May import `sylva-core`, `sylva-geom` (meshes, models, instances) and `sylva-trace` (the
//! kd-trees the photons are traced through).

pub mod photons;
pub mod report;
pub mod spec;
pub mod stand;

pub use photons::{
    trace_budget, BandBudget, BudgetConfig, Fraction, SunAngles, ViewAngles, ViewBrf, MAX_VIEWS,
};
pub use report::{budget_json, budget_text, Budget};
pub use spec::{Band, BudgetError, CanopySpec, CrownShape, LeafShape};
pub use stand::Stand;
