//! Weber & Penn parametric trees ("Creation and rendering of realistic trees", SIGGRAPH 1995)
//! with Arbaro's parameter names.

pub mod generator;
pub mod params;

pub use generator::{generate, generate_with_limit, shape_ratio, GenerateError, LEAF, WOOD};
pub use params::{ParamError, ParamSpec, Params, GENERAL_SPECS, LEVEL_SPECS};
