//! sylva-io's integration tests, one test binary (one link instead of 2), per area a module.

mod export;
mod import;
