//! The renderer of sylva (SPEC §2, paper 000 §3-4.3): from a built scene to an image.
//!
//! * [`lighting`]: per model, the LB lighting grid (voxelize, solve, cache on disk) and its
//!   trilinear lookup in model space.
//! * [`tonemap`]: Reinhard's global operator and sRGB encoding.
//! * [`output`]: PNG (8-bit sRGB) and EXR (linear) files, written atomically.

pub mod lighting;
pub mod output;
pub mod tonemap;
