//! Tree models, the species generator and forest scenes: what sylva lights and renders.
//!
//! * [`weber_penn`]: the Weber & Penn generator with Arbaro's parameters; [`arbaro`] reads
//!   Arbaro species files.
//! * [`species`]: the built-in species (the trees of the papers), each with generated leaf and
//!   bark textures; [`Species::build_model`] gives a [`Model`].
//! * [`scene`]: the TOML scene file and [`Scene`], the built forest: unique models plus
//!   instances that reference them; [`builtin_scenes`] holds the papers' scenes.
//! * [`export`]: a scene as OBJ (flattened) or as a Mitsuba 3 scene (instanced), to check
//!   sylva against a path tracer.

pub mod arbaro;
pub mod builtin_scenes;
pub mod export;
pub mod layout;
pub mod material;
pub mod mesh;
pub mod rng;
pub mod scene;
pub mod species;
pub mod texture;
pub mod textures;
pub mod weber_penn;

pub use material::{Material, MaterialKind};
pub use mesh::{Aabb, Mesh, Model};
pub use scene::{Camera, Instance, LbSettings, Scene, SceneDesc, SceneError};

pub use species::Species;
pub use texture::{Filter, Texture, Wrap};
