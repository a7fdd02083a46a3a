//! Lattice-Boltzmann photon transport (papers 000 §2.2-3, 002 §3, 004 §2.2; SPEC §1).
//!
//! Owns the collision matrix with Henyey-Greenstein anisotropy, the
//! parameter presets, the solver (boundary shell, green/brown sites, convergence), grid
//! previews, the built-in test
//! shapes, relighting of one grid (paper 004: base solutions solved as independent jobs,
//! the 32-face polyhedron, compression and the compressed file) and the lattice over a
//! cyclic plot on a reflecting soil with its face tallies ([`plot`], for the radiation
//! budget);
//! [`LbSolver`] is the solver as a backend ([`CpuSolver`] here, the GPU one in
//! `sylva-lb-gpu`).

// Tests index lattice tables by direction and axis together.
#![cfg_attr(test, allow(clippy::needless_range_loop))]

pub mod alloc;
pub mod backend;
pub mod bandwidth;
pub mod bench;
pub mod collision;
pub mod kernel;
/// The lattice, the grids and their file format live in `sylva-grid` (the voxelizer writes
/// them without the solver); re-exported here under their old paths.
pub use sylva_grid::{grid, grid_file, lattice};
pub mod light;
pub mod plot;
/// The presets and per-colour parameters live in `sylva-geom` (scenes name presets, and
/// export reads their optics without the solver); re-exported here where the solver uses them.
pub use sylva_geom::params;
pub mod preview;
pub mod relight;
pub mod report;
pub mod shapes;
pub mod solver;

pub use backend::{
    count_solve, solves_started, CpuKernelSolver, CpuSolver, LbBenchmark, LbSolver, LbSolverError,
    OnSchedule,
};
pub use grid::{Bounds, DensityGrid, Dims, GridError, LightingGrid, RawElement};
pub use grid_file::{Element, GridFile, GridFileError, GridKind};
pub use params::{ColourParams, MediumParams, ParamError, Preset};
pub use solver::{
    solve_lighting, solve_lighting_rgb, solve_lighting_rgb_on, Boundary, Floor, Flows, Lattice,
    RunMonitor, Schedule, SolveError, SolveOptions, SolveReport, StopReason, VolumeSource,
};
