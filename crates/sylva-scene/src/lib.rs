//! Tree models, the species generator and forest scenes: what sylva lights and renders.
//!
//! * [`weber_penn`]: the Weber & Penn generator with Arbaro's parameters; [`arbaro`] reads
//!   Arbaro species files.
//! * [`species`]: the built-in species (the trees of the papers), each with generated leaf and
//!   bark textures; [`Species::build_model`] gives a [`Model`].
//! * [`scene`]: the TOML scene file and [`Scene`], the built forest: unique models plus
//!   instances that reference them; [`builtin_scenes`] holds the papers' scenes.
//! * [`voxelize`]: a model's triangles → the LB density grid (000 §4.2); [`model_source`]
//!   resolves a model named on the command line (species name or model file).
//! * [`import`]: users' own models from OBJ and glTF files ([`load_mesh_file`]).
//! * [`export`]: a scene as OBJ (flattened) or as a Mitsuba 3 scene (instanced), to check
//!   sylva against a path tracer.

pub mod arbaro;
pub mod builtin_scenes;
pub mod export;
pub mod import;
pub mod layout;
pub mod material;
pub mod mesh;
pub mod model_source;
pub mod rng;
pub mod scene;
pub mod species;
pub mod texture;
pub mod textures;
pub mod voxelize;
pub mod weber_penn;

pub use import::{load_mesh_file, ImportError, ImportOptions};
pub use material::{Material, MaterialKind};
pub use mesh::{Aabb, Mesh, Model};
pub use model_source::{load_model, ModelSourceError};
pub use scene::{Camera, Instance, LbSettings, Scene, SceneDesc, SceneError};

pub use species::Species;
pub use texture::{Filter, Texture, Wrap};
pub use voxelize::{voxelize, VoxelizeError, VoxelizeOptions};
