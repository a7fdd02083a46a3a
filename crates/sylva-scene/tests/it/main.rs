//! sylva-scene's integration tests, one test binary (one link instead of 2), per area a module.

mod bands;
mod media;
mod scene;
mod stand;
