//! The renderer of sylva (SPEC §2, paper 000 §3-4.3): from a built scene to an image.
//!
//! * [`lighting`]: per model, the LB lighting grid (voxelize, solve, cache on disk) and its
//!   trilinear lookup in model space.
//! * [`shade`]: local sunlight (two-sided leaves, transmission, specular) and the indirect,
//!   albedo and sky parts the comparison modes combine.
//! * [`render`]: primary rays, shadow rays and shading over 8×8 tiles; the modes of 000 Fig. 2.
//! * [`tonemap`]: Reinhard's global operator and sRGB encoding.
//! * [`output`]: PNG (8-bit sRGB) and EXR (linear) files, written atomically.

pub mod lighting;
pub mod output;
pub mod render;
pub mod shade;
pub mod tonemap;

pub use render::{mean_luminance, Frame, FrameTimings, Mode, RenderSettings, Renderer};
pub use shade::{Radiance, ShadingParams};
pub use tonemap::ToneMap;
