//! Model files in, scenes out.
//!
//! * [`import`]: users' own models from OBJ (+ MTL) and glTF 2.0 / GLB files
//!   ([`load_mesh_file`]), with leaf and wood materials like the grown species.
//! * [`export`]: a built scene as OBJ (flattened) or as a Mitsuba 3 scene (instanced), to
//!   check sylva against a path tracer.

pub mod export;
pub mod import;

pub use import::{load_mesh_file, ImportError, ImportOptions};
