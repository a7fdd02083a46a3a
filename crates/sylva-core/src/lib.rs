//! Conventions and small utilities every sylva crate shares.
//!
//! * The world frame is right-handed with **+y up**; the ground is the plane y = 0.
//! * A [`Sun`] is given by the unit vector pointing *towards* the sun (the `L` of `N·L`);
//!   light travels along its negation, [`Sun::travel`].
//! * Elevation is measured in degrees above the horizon, azimuth in degrees from +x towards
//!   +z (so azimuth 90° puts the sun over +z). North is -z and east +x: a compass azimuth
//!   `A` is the world azimuth `A - 90°`; [`solar`] places the sun by date, time and place.
//! * Files are written atomically with [`atomic_write`]: a temporary file beside the target,
//!   then a rename, so a crash never leaves a half-written cache or image.
//! * A command's output files are written together with an [`OutputSet`]: all or none
//!   replaced, never an input, temporaries removed on Ctrl-C ([`interrupt`]).
//! * Input files are read with [`read_file`]: regular files only, sizes bounded; the limits
//!   on inputs live in [`limits`]. Cache files of sylva's own binary formats use the checked
//!   [`container`] (header, metadata, CRC-32).
//! * Large allocations are checked first with [`check_memory`].
//! * Independent jobs run through a [`jobs::Runner`]: this process or many, the same bytes.
//! * Light colours are linear sRGB; [`blackbody_rgb`] gives a black body's (the sun is 6500 K).
//! * Randomness comes from [`SplitMix64`], seeded per task so results do not depend on the
//!   thread count.
//! * Computed results are cached through one [`cache::Cache`]: keys derived from one
//!   serialized struct of every input ([`cache::CacheKey`], xxh3 of postcard bytes), entries
//!   in the checked [`container`], a hit, miss or bad entry reported, a failed write a warning.
//! * Geometry fingerprints are hashed with [`Fnv64`] (FNV-1a over explicit little-endian
//!   bytes): stable across Rust releases and platforms.

mod atomic;
pub mod cache;
pub mod colour;
pub mod container;
mod hash;
mod input;
pub mod interrupt;
pub mod jobs;
pub mod limits;
pub mod measure;
mod memory;
mod names;
mod rng;
pub mod solar;
mod sun;
mod text;
pub mod wire;

pub use atomic::{atomic_write, atomic_write_with, companion_path, OutputError, OutputSet};
pub use colour::{blackbody_rgb, try_blackbody_rgb, SUN_TEMPERATURE_K};
pub use hash::Fnv64;
pub use input::{open_file, protect_input, read_file, read_text_file, resolve_inside, InputError};
pub use memory::{available_memory_bytes, check_memory, format_bytes, MemoryError};
pub use names::file_stem;
pub use rng::SplitMix64;
pub use sun::{Sun, SunError, SunFlagError};
pub use text::thousands;
