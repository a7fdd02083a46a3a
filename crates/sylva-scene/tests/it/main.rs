//! sylva-scene's integration tests, one test binary (one link instead of 2), per area a module.

mod media;
mod scene;
mod stand;
