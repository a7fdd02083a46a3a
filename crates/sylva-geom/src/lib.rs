//! Geometry and the built scene as plain data: what every stage after scene building reads.
//!
//! * [`mesh`]: [`Aabb`], indexed triangle [`Mesh`]es and [`Model`]s (mesh + materials +
//!   bounds).
//! * [`material`]: leaf, wood and solid [`Material`]s and their [`Optics`] (per-colour
//!   reflectance and transmittance: the one material model of renderer, LB and export), a
//!   species' [`Measured`] leaf and which [`LeafOptics`] a run forms the factors from.
//! * [`medium`]: participating [`Medium`]s (clouds): density grids placed in the world.
//! * [`texture`]: RGBA8 [`Texture`]s with their wrap and filter modes, and THE texel opacity
//!   rule ([`is_opaque`]) the voxelizer, the tracer's alpha test and the cache keys share.
//! * [`scene`]: the built [`Scene`]: models (each with its LB preset), [`Instance`]s, media,
//!   [`Ground`], sun, sky, [`Camera`] and [`LbSettings`].
//! * [`params`]: the LB presets a scene names ([`Preset`]) and their per-colour scattering
//!   parameters ([`MediumParams`]): plain numbers that the LB solver (`sylva-lb`, which
//!   re-exports them) and the exporters (`sylva-io`) both read.
//!
//! No file formats, no generators, no LB solver here: scene files and growing live in
//! `sylva-scene` and `sylva-grow`, model files in `sylva-io`, the density grid in
//! `sylva-voxel`, the solver in `sylva-lb`.

pub mod bands;
pub mod material;
pub mod medium;
pub mod mesh;
pub mod params;
pub mod scene;
pub mod texture;

pub use bands::Bands;
pub use material::{
    LeafOptics, Material, MaterialKind, Measured, Optics, FOREST_LEAF_TRANSMISSION,
    KNAPP_CARTER_LEAF,
};
pub use medium::Medium;
pub use mesh::{Aabb, Mesh, Model};
pub use params::{ColourParams, MediumParams, ParamError, Preset};
pub use scene::{Camera, Ground, Instance, LbSettings, ModelOrigin, Scene};
pub use texture::{is_opaque, nearest_texel_coords, Filter, Texture, Wrap, OPAQUE_ALPHA};
