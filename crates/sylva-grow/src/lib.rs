//! Tree growing: plant models made in code, no downloads.
//!
//! * [`weber_penn`]: the Weber & Penn generator with Arbaro's parameters; [`arbaro`] reads
//!   and writes Arbaro species files.
//! * [`species`]: the built-in species (the trees of the papers), each with generated leaf and
//!   bark [`textures`]; [`Species::build_model`] gives a [`sylva_geom::Model`].
//! * [`rng`]: the generators' seeded random stream (also the scene layout's).

pub mod arbaro;
pub mod rng;
pub mod species;
pub mod textures;
pub mod weber_penn;

pub use species::Species;
