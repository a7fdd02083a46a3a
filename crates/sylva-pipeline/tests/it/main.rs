//! The pipeline's integration tests, one binary (one link instead of five): scenes lit,
//! rendered, relit and compared end to end, per area a module. `tests/pipeline.rs` stays a
//! binary of its own: it counts `tracing` spans, and a callsite's interest is process-wide,
//! so spans of tests on other threads race with its scoped subscriber.

mod bands;
mod distributed;
mod forest;
mod gpu;
mod media;
mod physical;
mod rays;
mod relight;
mod render;
