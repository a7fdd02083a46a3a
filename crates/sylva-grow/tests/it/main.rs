//! sylva-grow's integration tests, one test binary (one link instead of 3), per area a module.

mod cloud;
mod species;
mod teapot;
