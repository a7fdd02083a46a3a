//! The measurements of `sylva bench trace|relight|spp`: each returns a plain report (JSON
//! through serde, text through `Display`); the command line only parses and prints.

mod relight;
pub mod scaling;
mod spp;
mod trace;

pub use relight::{
    against_direct, relight, relight_physical, AgainstDirect, DirectSolve, PhysicalRelightBench,
    RelightBench, RelightBenchPlan, SunAgainstDirect,
};
pub use spp::{spp, PaperScene, SppBench};
pub use trace::{
    measure_frames, tile_times, FrameMeasure, RankSplit, ScalingModel, ScalingRow, SplitSummary,
    TileTimes, TimedFrame, TraceBench, TraceMemory, TraceRun,
};

use sylva_spp::trees::TreeError;

/// Why a benchmark failed.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error(transparent)]
    Pipeline(#[from] crate::PipelineError),
    #[error("building the deep opacity maps and instance grids")]
    SppBuild(#[source] TreeError),
    #[error(transparent)]
    Spp(#[from] TreeError),
    #[error(transparent)]
    Sun(#[from] sylva_core::SunError),
}
