//! Scene descriptions: what a forest is made of and where everything stands.
//!
//! * [`scene`]: the TOML scene file ([`SceneDesc`]), checked with file and line in every
//!   error, and [`SceneDesc::build`], which grows (`sylva-grow`) or imports (`sylva-io`) each
//!   unique model once and places the instances into a plain-data [`sylva_geom::Scene`].
//! * [`layout`]: the placement generators (scatter with minimum spacing, rotation, scale
//!   jitter).
//! * [`builtin_scenes`]: the papers' scenes by name.
//! * [`model_source`]: a model named on the command line (species name or model file), or
//!   one model of a scene.

pub mod builtin_scenes;
pub mod layout;
pub mod model_source;
pub mod scene;

pub use model_source::{load_model, ModelSourceError};
pub use scene::{load, SceneDesc, SceneError, SceneStats, LB_PRESETS};
