//! A GPU for a test, or the reason there is none.

use sylva_wgpu::{ContextOptions, GpuContext, GpuError};

use crate::{missing, Need};

/// The adapter `opts` asks for, its description in the test's captured output. `None` when no
/// adapter exists: the test then has nothing to compare and returns, after [`missing`] said
/// so (a failure under `SYLVA_REQUIRE_GPU=1`). Any other error opening it fails the test.
#[track_caller]
pub fn gpu_context(opts: &ContextOptions) -> Option<GpuContext> {
    match GpuContext::new(opts) {
        Ok(ctx) => {
            eprintln!("GPU tests on {}", ctx.describe());
            Some(ctx)
        }
        Err(e @ GpuError::NoAdapter { .. }) => {
            missing(Need::Gpu, &e.to_string());
            None
        }
        Err(e) => panic!("opening the GPU failed: {e}"),
    }
}
