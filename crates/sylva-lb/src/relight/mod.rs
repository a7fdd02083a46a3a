//! Relighting (paper 004 §3.1 and §4.2, SPEC §3): per density grid, 19 base solutions that
//! any sun direction combines linearly, and their compression.
//!
//! * [`polyhedron`]: the 32-face polyhedron spanned by the 18 lattice directions, the face a
//!   sun direction crosses with its barycentric weights, and the exact weights
//!   `max(0, n_i · d)`.
//! * [`basis`]: [`BasisSet`] (B_0 … B_18, three colours each), the driver that solves it through
//!   any LB backend as independent jobs ([`BasisJob`]: one basis in one colour, for work
//!   queues), [`BasisWeights`] and the uncompressed combination, and its file format.
//! * [`footprint`]: model space to grid coordinates, and the 2×2×2 sites of a lookup.
//! * [`region`]: the sites where light matters (in and near the medium), where compression
//!   error is measured and where it is spent.
//! * [`compress`]: Haar wavelets on 4³ blocks, PCA across the 57 channels, and both combined,
//!   with footprint decoding for trilinear lookups and relighting in the reduced space; the
//!   compressed set's file (`.scbasis`, CRC-checked).
//!
//! **Normalisation.** [`BasisWeights::exact`] and [`BasisWeights::three_basis`] give weights of
//! `B_1..B_18` that sum to 1. Each `B_j` holds exactly 1 at an unobstructed site (its boundary
//! light streams through unchanged), so these combinations are 1 in free space: the
//! normalisation the renderer applies to a direct sun solve (unobstructed sun = 1). `B_0` holds
//! 18 in free space; [`BasisWeights::with_ambient`]`(a)` adds `a / 18 · B_0`, i.e. `a` in free
//! space. [`BasisWeights::free_space`] states the free-space value of any combination.

pub mod basis;
pub mod compress;
pub mod footprint;
pub mod polyhedron;
pub mod region;

use std::path::PathBuf;

use thiserror::Error;

pub use basis::{
    basis_metadata, parse_basis_metadata, solve_basis, solve_basis_jobs, Ambient, BasisAssembly,
    BasisJob, BasisOptions, BasisProgress, BasisReport, BasisSet, BasisWeights,
};
pub use compress::haar::{HaarCoefs, HaarView};
pub use compress::{
    compress, compress_channels, relit_error, sky_directions, BlockBudget, BlockCache, Codec,
    CompressTarget, CompressedBasis, CompressedChannels, ErrorReport, Precision, ProjectedWeights,
    StoredFields, COMPRESSED_EXTENSION,
};
pub use footprint::{Footprint, Placement};
pub use polyhedron::{exact_weights, face_hit, faces, normalise, DirectionError, Face, FaceHit};
pub use region::Region;

/// Base solutions per grid: `B_0` (ambient) and `B_1..B_18`.
pub const BASES: usize = crate::lattice::Q;
/// Values per site of a basis set: 19 bases × 3 colours, channel `3 j + colour`.
pub const CHANNELS: usize = 3 * BASES;

/// Channel names of a basis grid file, in storage order.
pub use sylva_grid::grid_file::BASIS_CHANNEL_NAMES as CHANNEL_NAMES;

#[derive(Debug, Error)]
pub enum RelightError {
    #[error(transparent)]
    Direction(#[from] DirectionError),
    #[error("basis weight w_{index} = {value} is not a finite number")]
    Weight { index: usize, value: f64 },
    #[error("boundary f_0 = {0} on the shell is not a combination of base solutions (they all have f_0 = 0)")]
    RestBoundary(f32),
    #[error(transparent)]
    Params(#[from] crate::ParamError),
    #[error(transparent)]
    Memory(#[from] sylva_core::MemoryError),
    #[error("solving base solution B_{basis}: {source}")]
    Solve {
        basis: usize,
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    #[error("base solution B_{basis}: the solver returned {what}")]
    SolverResult { basis: usize, what: String },
    #[error("{0}")]
    Mismatch(String),
    #[error(transparent)]
    File(#[from] crate::GridFileError),
    #[error("{}: {what}", .path.display())]
    Format { path: PathBuf, what: String },
    #[error("compression target: {0}")]
    Target(String),
    #[error(transparent)]
    Container(#[from] sylva_core::container::ContainerError),
    #[error("cannot write {}: {source}", .path.display())]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
}
