//! Processes working on one job (000 §4.3, Table 4; `docs/mpi.md`): the transport and the
//! work queue. What the processes compute (the models' LB light, the forest's parts,
//! relighting's bases, a frame's units) is planned by `sylva-pipeline` as jobs of a
//! [`sylva_core::jobs::Runner`]; this crate runs them across processes ([`QueueRunner`]).
//!
//! * [`comm`]: what the work needs from a transport ([`Comm`]): tagged messages, a broadcast,
//!   an abort. [`LocalComm`] runs ranks as threads (tests); `Mpi` (feature `mpi`) is MPI.
//! * [`queue`]: the work queue, jobs handed out on demand by rank 0 (which works too),
//!   results gathered at rank 0.
//! * [`runner`]: [`QueueRunner`], the pipeline's job runner over the queue and `Comm`.
//! * [`launch`]: whether this process was started by `mpirun` as one of several.
//!
//! Whatever fails on one rank is returned there as an error; the caller prints it and calls
//! [`Comm::abort`], which ends every rank (the others may be waiting for it).

pub mod comm;
pub mod launch;
#[cfg(feature = "mpi")]
pub mod mpi;
pub mod queue;
pub mod runner;

pub use comm::{Comm, CommError, LocalComm};
pub use queue::{run_queue, QueueOutcome};
pub use runner::QueueRunner;

/// Why a rank cannot go on.
#[derive(Debug, thiserror::Error)]
pub enum DistError {
    #[error(transparent)]
    Comm(#[from] CommError),
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

impl From<sylva_core::wire::WireError> for DistError {
    fn from(e: sylva_core::wire::WireError) -> DistError {
        DistError::Comm(e.into())
    }
}
