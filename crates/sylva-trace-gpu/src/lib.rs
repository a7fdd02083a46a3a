//! Ray tracing on GPUs through wgpu compute shaders (WGSL), as paper 000 §4 traced on CUDA:
//! the two-level kd-trees the CPU tracer (`sylva-trace`) built, uploaded as they are, and
//! its short-stack traversal with kd-restart, instancing and alpha-tested leaves, function
//! by function.
//!
//! * [`scene`]: [`GpuScene`], the CPU tracer's arrays on the device (split over several
//!   storage bindings where one is too small, as on lavapipe) and the WGSL that traverses
//!   them (`trace.wgsl` after a generated prelude). Other kernels (GPU shading) include it.
//! * [`tracer`]: [`GpuTracer`], the [`sylva_trace::RayQuery`] the renderer uses on a GPU:
//!   large batches of closest-hit and shadow rays, one invocation per ray, 64 per
//!   workgroup.
//! * [`split`]: arrays larger than one storage binding, and WGSL helpers.
//!
//! Answers are the CPU tracer's: the same closest hit `(t, instance, triangle, u, v)` bit
//! for bit on an adapter that rounds like the CPU (lavapipe; tested), the same shadow
//! answers. See docs/gpu.md.

pub mod scene;
pub mod split;
pub mod tracer;

pub use scene::{scene_device_bytes, GpuScene, SCENE_GROUP, TRACE_WGSL};
pub use tracer::GpuTracer;

/// What can go wrong putting a scene on a GPU.
#[derive(Debug, thiserror::Error)]
pub enum TraceGpuError {
    #[error(transparent)]
    Gpu(#[from] sylva_wgpu::GpuError),
    #[error("scene too large for this GPU: {0}")]
    TooLarge(String),
    #[error(transparent)]
    Memory(#[from] sylva_core::MemoryError),
}
