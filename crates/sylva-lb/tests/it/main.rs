//! sylva-lb's integration tests, one test binary (one link instead of 3), per area a module.

mod light;
mod physics;
mod relight;
