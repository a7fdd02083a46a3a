//! `sylva bench trace SCENE`: acceleration build time and frame time (primary rays, shadow
//! rays, shading) at 1 and 4 rays per pixel, with LB lighting from the cache; the measuring
//! is `sylva_pipeline::bench`'s.

use anyhow::Result;
use sylva_pipeline::bench::{self, TraceRun};
use sylva_pipeline::Runner;
use sylva_render::stage;

use super::output::emit_report;
use super::render::{prepare, FrameArgs, PrepareRequest, Say};

#[derive(clap::Args, Debug)]
pub struct BenchTraceArgs {
    #[command(flatten)]
    pub frame: FrameArgs,
    /// Timed frames per rays-per-pixel setting (after one untimed warm-up); medians reported.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub runs: u32,
    /// Without LB lighting (local light only): no precompute on a cold cache.
    #[arg(long)]
    pub no_lb: bool,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
    /// Also time every 8×8 tile alone at 1 ray/pixel (median of --runs) and model the frame
    /// on 1-16 ranks: the paper's fixed strips against units on demand (000 Table 4).
    #[arg(long)]
    pub tile_costs: bool,
}

impl BenchTraceArgs {
    fn request(&self) -> PrepareRequest<'static> {
        PrepareRequest {
            need_lb: !self.no_lb,
            rays_per_pixel: Some(4),
            output_images: 1,
            say: Say::Stderr,
            ..PrepareRequest::default()
        }
    }
}

pub fn run(a: BenchTraceArgs, runner: &dyn Runner) -> Result<()> {
    let several = runner.processes() > 1;
    if a.tile_costs && several {
        anyhow::bail!("--tile-costs times tiles in one process: run it without mpirun");
    }
    let clock = super::stage_clock();
    clock.reset();
    let prepared = prepare(&a.frame, a.request(), runner)?;
    let run = TraceRun {
        runs: a.runs,
        mpi_ranks: several.then(|| runner.processes()),
        lb: !a.no_lb,
        accel_build_seconds: clock.seconds(stage::ACCEL_BUILD),
        lb_seconds: clock.seconds(stage::LB_PRECOMPUTE),
    };
    let size = (prepared.width, prepared.height);
    let seed = a.frame.view.seed;
    let bench = bench::trace(&prepared.scene, size, seed, run, runner, a.tile_costs)?;
    let Some(report) = bench else {
        return Ok(()); // rank 0 reports
    };
    emit_report(&report, a.json)
}
