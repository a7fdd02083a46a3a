//! The measurements of `sylva bench trace|relight|spp`: each returns a plain report (JSON
//! through serde, text through `Display`); the command line only parses and prints.

mod rays;
mod relight;
pub mod scaling;
mod spp;
mod trace;

pub use rays::{export_rays, ray_sets, rays, Answers, RaySetMeasure, RaySets, RaysBench};
pub use relight::{
    against_direct, relight, relight_physical, AgainstDirect, DirectSolve, PhysicalRelightBench,
    RelightBench, RelightBenchPlan, SunAgainstDirect,
};
pub use spp::{spp, PaperScene, SppBench};
pub use trace::trace;
pub use trace::{
    measure_frames, tile_times, FrameMeasure, RankSplit, ScalingModel, ScalingRow, SplitSummary,
    TileTimes, TimedFrame, TraceBench, TraceMemory, TraceRun,
};

use sylva_lb::{Boundary, Bounds, DensityGrid, Dims, GridError, MediumParams, ParamError, Preset};
use sylva_scene::SceneError;
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
    #[error(transparent)]
    Scene(#[from] SceneError),
    #[error(transparent)]
    Grid(#[from] GridError),
    #[error(transparent)]
    Param(#[from] ParamError),
}

/// The built-in cloud's LB solve as `sylva render cloud` runs it (`sylva bench lb --medium
/// cloud`): its cumulus, generated at `dims` sites when given, under its sun, with its
/// preset's parameters (the cloud preset's colours are equal).
pub struct CloudSolve {
    pub grid: DensityGrid,
    pub medium: MediumParams,
    pub boundary: Boundary,
}

impl CloudSolve {
    pub fn builtin(dims: Option<Dims>) -> Result<CloudSolve, BenchError> {
        let desc = sylva_scene::SceneDesc::load("cloud")?;
        let mut medium = desc
            .media
            .first()
            .cloned()
            .expect("the built-in cloud scene has a medium");
        if let Some(d) = dims {
            medium = medium.at_grid([d.nx, d.ny, d.nz]);
        }
        let m = medium.build(&desc.origin)?;
        let dims = Dims::new(m.dims[0], m.dims[1], m.dims[2])?;
        let density = m.density.to_vec();
        let grid = DensityGrid::new(dims, Bounds::UNIT, density, vec![0.0; dims.sites()])?;
        Ok(CloudSolve {
            grid,
            medium: Preset::parse(&m.preset)?.params(),
            boundary: Boundary::sun(desc.sun.travel().to_array(), 1.0),
        })
    }
}
