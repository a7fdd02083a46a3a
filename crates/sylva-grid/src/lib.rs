//! The lattice and the grids every LB stage shares, without the solver: the D3Q19 lattice
//! ([`lattice`]), density and lighting grids ([`grid`]), their file format ([`grid_file`]),
//! what `sylva lb info` shows of a file and raw density files ([`info`]), and how plant area
//! becomes a site density ([`density`]).
//!
//! Imports only `sylva-core`. The voxelizer (`sylva-voxel`) writes these grids, the solver
//! (`sylva-lb`, which re-exports them) reads and writes them, and neither needs the other.

// Tests index lattice tables by direction and axis together.
#![cfg_attr(test, allow(clippy::needless_range_loop))]

pub mod density;
pub mod grid;
pub mod grid_file;
pub mod info;
pub mod lattice;

pub use grid::{Bounds, DensityGrid, Dims, DimsFlagError, GridError, LightingGrid, RawElement};
pub use grid_file::{Element, GridFile, GridFileError, GridKind};
