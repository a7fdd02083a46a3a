//! Scene descriptions: what a forest is made of and where everything stands.
//!
//! * [`scene`]: the TOML scene file ([`SceneDesc`]), checked with file and line in every
//!   error, and [`SceneDesc::build`], which grows (`sylva-grow`), imports (`sylva-io`) or
//!   makes (the teapot) each unique model once, places the instances and generates the media
//!   (clouds) into a plain-data [`sylva_geom::Scene`].
//! * [`layout`]: the placement generators (scatter with minimum spacing, rotation, scale
//!   jitter).
//! * [`builtin_scenes`]: the papers' scenes by name.
//! * [`info`]: what `sylva scene info` reports about a built scene ([`SceneInfo`]).
//! * [`model_source`]: a model named on the command line (species name or model file), or
//!   one model of a scene.

pub mod bench;
pub mod builtin_scenes;
pub mod info;
pub mod layout;
pub mod model_source;
pub mod scene;

pub use info::SceneInfo;
pub use model_source::{load_model, ModelSourceError};
pub use scene::{load, MediumStats, SceneDesc, SceneError, SceneStats, LB_PRESETS};
