//! sylva-trace's integration tests, one test binary (one link instead of 4), per area a module.

mod kdtree;
mod packet;
mod primitives;
mod sun_grid;
