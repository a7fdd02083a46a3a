//! The light of sylva: everything the LB computes for a scene and how a renderer reads it
//! back (docs/light.md, docs/relight.md; papers 000 §3, 002, 004).
//!
//! * [`lighting`]: per model, the LB lighting grid (voxelize, solve, cache on disk) and its
//!   trilinear lookup in model space; the light models ([`Light`]: physical, the default, and
//!   paper 000's) and the plant medium from the materials' optics.
//! * [`forest`]: the coarse forest grid over every instance, which weighs each instance's
//!   light parts by its neighbours' shade and scattered light.
//! * [`relight`]: paper 004: per model the 19 base solutions (jobs on any solver,
//!   compressed, cached), an instance's weights for the sun in its model space, the coarse
//!   global grid, and [`RelitLight`], which moves the sun without an LB solve.
//! * [`indirect`]: [`IndirectLight`], the light scattered in the canopy as shading reads it
//!   (the seam between light and renderer), and [`ModelGridLight`], one LB grid per model.
//! * [`device`]: the seam's device side ([`DeviceLight`]): each light packs what the GPU
//!   frame kernel reads of it, beside its CPU lookup, or says why it has none ([`NoDevice`]).
//! * [`media`]: participating media (clouds): their LB light and the volume that carries it
//!   with the density, which the renderer integrates along rays ([`Media`]).
//! * [`progress`]: what the long stages report ([`Progress`]); [`report`]: those reports as
//!   the lines a front end shows.
//!
//! May import the leaf crates (core, geom, grid, lb, voxel) and `sylva-trace` for the
//! instance placements; never the renderer, the scene files or the pipeline.

pub mod device;
pub mod forest;
pub mod indirect;
pub mod lighting;
pub mod media;
pub mod progress;
pub mod relight;
pub mod report;

pub use device::{DeviceLight, NoDevice};
pub use indirect::{IndirectLight, ModelGridLight, NoIndirectLight};
pub use lighting::{Illumination, Light};
pub use media::{Media, MediumVolume, Segment};
pub use progress::{Progress, Silent};
pub use relight::{RelitIllumination, RelitLight, SunWeights};
