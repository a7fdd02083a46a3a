//! The canopy radiation budget (issue 29 items 3-5): what a stand of plants does with the
//! sunlight it receives, per spectral band: the fractions absorbed by the canopy (fAPAR in
//! the PAR bands), reflected to the sky (the albedo), transmitted to the ground and absorbed
//! by it.
//!
//! The abstract canopies themselves (spherical or ellipsoidal crowns filled with flat leaves
//! of uniformly random orientation placed without overlap, or a homogeneous layer; the bands
//! with their leaf reflectance and transmittance and soil albedo) are grown in
//! `sylva_grow::stand`, where scenes find them too. This crate owns the stand as the photons
//! see it ([`stand`]: repeated over the sides of a cyclic plot) and the Monte Carlo photon
//! budget of it ([`photons`]: light leaving a side re-enters on the opposite one, so the plot
//! stands for an infinite stand), the
//! reference the other methods are held to, with the BRF towards chosen view directions by
//! local estimates ([`report`] formats it) and as an image of the plot from one of them
//! ([`brf_image`]).
//!
//! The lattice-Boltzmann budget of the same plot ([`lattice`]: the leaves binned into cells,
//! the direct beam traced exactly, the scattered light carried by `sylva_lb::plot`) is held
//! to it.
//!
//! May import `sylva-core`, `sylva-geom` (meshes, models, instances), `sylva-grow` (the
//! stands), `sylva-trace` (the kd-trees the photons are traced through), `sylva-grid` and
//! `sylva-lb` (the cells and the lattice). The BRF image's files are the pipeline's
//! (`sylva_pipeline::brf_images`).

pub mod angles;
pub mod bench;
pub mod brf_image;
pub mod lattice;
pub mod photons;
pub mod report;
pub mod stand;

pub use brf_image::{BrfImage, BrfImageSpec};
pub use lattice::{lb_budget, LbBand, LbConfig, LbRun};
pub use photons::{
    trace_budget, Angles, BandBudget, BudgetConfig, Fraction, SunAngles, ViewAngles, ViewBrf,
    MAX_VIEWS,
};
pub use report::{budget_json, budget_text, Budget};
pub use stand::{Stand, Surfaces};
pub use sylva_grow::stand::{Band, CanopySpec, CrownShape, LeafShape, StandError};

/// Why a budget was refused: one line naming the file or setting and the problem (a bad
/// setting is a [`StandError::Invalid`], as a bad stand file's are).
#[derive(Debug, thiserror::Error)]
pub enum BudgetError {
    #[error(transparent)]
    Stand(#[from] StandError),
    #[error(transparent)]
    Memory(#[from] sylva_core::MemoryError),
    #[error("{scene}: {message}")]
    Scene { scene: String, message: String },
    #[error("building the stand's kd-trees: {0}")]
    Trace(#[from] sylva_trace::TraceError),
}

impl BudgetError {
    pub fn invalid(what: impl Into<String>, value: impl ToString, why: impl Into<String>) -> Self {
        BudgetError::Stand(StandError::invalid(what, value, why))
    }
}
