//! `sylva bench voxelize`: times voxelizing one model into its LB density grid.

use std::time::Instant;

use anyhow::{bail, Result};
use serde::Serialize;
use sylva_voxel::{voxelize, VoxelizeOptions, DEFAULT_GRID};

use super::progress::bar;

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

#[derive(Serialize)]
struct VoxelBench {
    model: String,
    triangles: usize,
    grid: String,
    /// Median seconds of one voxelization (the model already in memory).
    seconds: f64,
    triangles_per_s: f64,
    /// Seconds to grow or load the model, once, not part of `seconds`.
    model_seconds: f64,
    occupied_sites: usize,
    mean_density: f64,
    threads: usize,
    alpha_test: bool,
    occupancy: &'static str,
    runs: Vec<f64>,
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
    let pb = if a.json {
        indicatif::ProgressBar::hidden()
    } else {
        bar(a.runs as u64, "bench voxelize")
    };
    let mut runs = Vec::with_capacity(a.runs);
    let mut grid = None;
    for _ in 0..a.runs {
        let t = Instant::now();
        let g = voxelize(&model, &opts)?;
        runs.push(t.elapsed().as_secs_f64());
        grid = Some(g);
        pb.inc(1);
    }
    pb.finish_and_clear();
    let grid = grid.expect("runs ≥ 1");
    let mut sorted = runs.clone();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len();
    let seconds = if n % 2 == 1 {
        sorted[n / 2]
    } else {
        0.5 * (sorted[n / 2 - 1] + sorted[n / 2])
    };
    let (mean_density, occupied_sites) = grid.occupancy();
    let b = VoxelBench {
        model: model.name.clone(),
        triangles: model.triangle_count(),
        grid: grid.dims.to_string().replace('×', "x"),
        seconds,
        triangles_per_s: model.triangle_count() as f64 / seconds,
        model_seconds,
        occupied_sites,
        mean_density,
        threads: rayon::current_num_threads(),
        alpha_test: !a.no_alpha,
        occupancy: opts.occupancy.name(),
        runs,
    };
    if a.json {
        println!("{}", serde_json::to_string(&b)?);
    } else {
        println!(
            "voxelize {}, {} triangles, {} grid, {} threads{}",
            b.model,
            b.triangles,
            b.grid,
            b.threads,
            if b.alpha_test { "" } else { ", no alpha test" }
        );
        println!("  runs (s):     {}", super::bench::format_runs(&b.runs));
        println!("  median:       {:.3} s", b.seconds);
        println!(
            "  throughput:   {:.2} M triangles/s",
            b.triangles_per_s / 1e6
        );
        println!(
            "  model:        {:.3} s to build (not timed above)",
            b.model_seconds
        );
        println!(
            "  result:       {} occupied sites, mean density {:.5}",
            b.occupied_sites, b.mean_density
        );
    }
    Ok(())
}
