//! Growing in code, no downloads: plant models, and the other things the papers render.
//!
//! * [`weber_penn`]: the Weber & Penn generator with Arbaro's parameters; [`arbaro`] reads
//!   and writes Arbaro species files.
//! * [`species`]: the built-in species (the trees of the papers), each with generated leaf and
//!   bark [`textures`]; [`Species::build_model`] gives a [`sylva_geom::Model`].
//! * [`cloud`]: a cumulus cloud's density grid from a parcel model of convection (002 §3.2.1).
//! * [`stand`]: abstract canopies (crowns of flat leaves placed without overlap, or a
//!   homogeneous layer) from their TOML description, for `sylva budget` and scenes.
//! * [`teapot`]: the Newell teapot's 32 Bézier patches, tessellated (002 §3.2.3).
//! * [`sheet`]: what `sylva species list|show` report about species.
//! * [`rng`]: the generators' seeded random stream (also the scene layout's).

pub mod arbaro;
pub mod cloud;
pub mod rng;
pub mod sheet;
pub mod species;
pub mod stand;
pub mod teapot;
pub mod textures;
pub mod weber_penn;

pub use species::Species;
