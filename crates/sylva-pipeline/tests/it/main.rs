//! The pipeline's integration tests, one binary (one link instead of six): scenes lit,
//! rendered, relit and compared end to end, per area a module.

mod forest;
mod gpu;
mod media;
mod pipeline;
mod relight;
mod render;
