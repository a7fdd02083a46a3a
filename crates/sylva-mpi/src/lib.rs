//! Rendering and LB precomputation across processes (000 §4.3, Table 4; `docs/mpi.md`).
//!
//! * [`comm`]: what the work needs from a transport ([`Comm`]): tagged messages, a broadcast,
//!   an abort. [`LocalComm`] runs ranks as threads (tests); `Mpi` (feature `mpi`) is MPI.
//! * [`queue`]: the work queue, jobs handed out on demand by rank 0 (which works too),
//!   results gathered at rank 0.
//! * [`frame`]: a frame cut into units of whole tiles, rendered through the queue, gathered
//!   at rank 0: bit-identical to a one-process frame.
//! * [`lighting`]: every model's LB lighting, colours solved as queue jobs, the cache at rank
//!   0, the grids broadcast to every rank.
//! * [`forest`]: the physical light's parts of a scene lit through the forest grid, models ×
//!   parts as queue jobs, stored in rank 0's cache.
//! * [`relight`]: relighting's base solutions (paper 004), models × bases × colours as queue
//!   jobs, assembled, compressed and cached at rank 0 as one process does (`sylva basis`).
//! * [`runner`]: [`QueueRunner`], the pipeline's job runner over the queue and `Comm`.
//! * [`model`]: frame times on N ranks from measured per-tile costs, fixed strips (the
//!   paper's split) against units on demand.
//! * [`launch`]: whether this process was started by `mpirun` as one of several.
//!
//! Whatever fails on one rank is returned there as a [`DistError`]; the caller prints it and
//! calls [`Comm::abort`], which ends every rank (the others may be waiting for it).

pub mod comm;
pub mod forest;
pub mod frame;
pub mod launch;
pub mod lighting;
pub mod model;
#[cfg(feature = "mpi")]
pub mod mpi;
pub mod queue;
pub mod relight;
pub mod runner;

pub use comm::{Comm, CommError, LocalComm};
pub use forest::solve_forest_parts;
pub use frame::{render_frame, DistributedFrame, RankWork, UnitLayout};
pub use lighting::{light_models, LbJob};
pub use queue::{run_queue, QueueOutcome};
pub use relight::{precompute_relighting, BasisModelJob};
pub use runner::QueueRunner;

/// Why a rank cannot go on.
#[derive(Debug, thiserror::Error)]
pub enum DistError {
    #[error(transparent)]
    Comm(#[from] CommError),
    #[error(transparent)]
    Pipeline(#[from] sylva_pipeline::PipelineError),
    #[error(transparent)]
    Render(#[from] sylva_render::RenderError),
    /// Ranks started with different inputs.
    #[error("ranks disagree: {0}")]
    Disagree(String),
    /// A job of a [`sylva_core::jobs::Runner`] failed.
    #[error(transparent)]
    Job(sylva_core::jobs::JobError),
    /// A failure asked for by the test hook [`queue::FAIL_RANK_ENV`].
    #[error("{0}")]
    Injected(String),
}
