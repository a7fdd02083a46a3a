//! `sylva bench voxelize`: times voxelizing one model into its LB density grid.

use std::time::Instant;

use anyhow::{bail, Result};
use sylva_voxel::{VoxelizeOptions, DEFAULT_GRID};

use super::output::{bench_bar, print_report};

#[derive(clap::Args)]
pub struct BenchVoxelArgs {
    /// The model: a built-in species name or an Arbaro species file (.xml).
    #[arg(default_value = "american_beech")]
    model: String,
    /// Sites along the model's longest edge.
    #[arg(long, default_value_t = DEFAULT_GRID)]
    grid: usize,
    /// Timed runs; the median is reported.
    #[arg(long, default_value_t = 5)]
    runs: usize,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// Count leaves everywhere (skip the texture alpha test), to see what the test costs.
    #[arg(long)]
    no_alpha: bool,
    /// area (the physical density, default) or subcells (000's sub-cell count).
    #[arg(long, value_enum, default_value = "area")]
    occupancy: super::voxelize::OccupancyArg,
}

pub fn run(a: BenchVoxelArgs) -> Result<()> {
    if a.runs == 0 {
        bail!("--runs must be at least 1");
    }
    let t = Instant::now();
    let model = sylva_scene::load_model(&a.model)?;
    let model_seconds = t.elapsed().as_secs_f64();
    let opts = VoxelizeOptions {
        grid: a.grid,
        alpha_test: !a.no_alpha,
        occupancy: a.occupancy.into(),
    };
    let pb = bench_bar(a.json, a.runs, "bench voxelize");
    let b = sylva_voxel::bench::voxelize_runs(&model, model_seconds, &opts, a.runs, &|| pb.inc(1))?;
    pb.finish_and_clear();
    print_report(&b, a.json)
}
