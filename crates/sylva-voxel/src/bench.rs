//! `sylva bench voxelize`: the voxelizer's speed on one model already in memory.

use std::fmt;
use std::time::Instant;

use serde::Serialize;
use sylva_core::measure::{format_runs, median};
use sylva_geom::Model;

use crate::{voxelize, VoxelizeError, VoxelizeOptions};

/// What [`voxelize_runs`] measured.
#[derive(Debug, Clone, Serialize)]
pub struct VoxelBench {
    pub model: String,
    pub triangles: usize,
    pub grid: String,
    /// Median seconds of one voxelization (the model already in memory).
    pub seconds: f64,
    pub triangles_per_s: f64,
    /// Seconds to grow or load the model, once, not part of `seconds`.
    pub model_seconds: f64,
    pub occupied_sites: usize,
    pub mean_density: f64,
    pub threads: usize,
    pub alpha_test: bool,
    pub occupancy: &'static str,
    pub runs: Vec<f64>,
}

/// `runs` (at least one) timed voxelizations of `model`, built in `model_seconds`;
/// `tick` after each.
pub fn voxelize_runs(
    model: &Model,
    model_seconds: f64,
    opts: &VoxelizeOptions,
    runs: usize,
    tick: &dyn Fn(),
) -> Result<VoxelBench, VoxelizeError> {
    let mut times = Vec::with_capacity(runs);
    let mut grid = None;
    for _ in 0..runs.max(1) {
        let t = Instant::now();
        let g = voxelize(model, opts)?;
        times.push(t.elapsed().as_secs_f64());
        grid = Some(g);
        tick();
    }
    let grid = grid.expect("runs ≥ 1");
    let seconds = median(times.clone());
    let (mean_density, occupied_sites) = grid.occupancy();
    Ok(VoxelBench {
        model: model.name.clone(),
        triangles: model.triangle_count(),
        grid: grid.dims.to_string().replace('×', "x"),
        seconds,
        triangles_per_s: model.triangle_count() as f64 / seconds,
        model_seconds,
        occupied_sites,
        mean_density,
        threads: rayon::current_num_threads(),
        alpha_test: opts.alpha_test,
        occupancy: opts.occupancy.name(),
        runs: times,
    })
}

impl fmt::Display for VoxelBench {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "voxelize {}, {} triangles, {} grid, {} threads{}",
            self.model,
            self.triangles,
            self.grid,
            self.threads,
            if self.alpha_test {
                ""
            } else {
                ", no alpha test"
            }
        )?;
        writeln!(f, "  runs (s):     {}", format_runs(&self.runs))?;
        writeln!(f, "  median:       {:.3} s", self.seconds)?;
        writeln!(
            f,
            "  throughput:   {:.2} M triangles/s",
            self.triangles_per_s / 1e6
        )?;
        writeln!(
            f,
            "  model:        {:.3} s to build (not timed above)",
            self.model_seconds
        )?;
        writeln!(
            f,
            "  result:       {} occupied sites, mean density {:.5}",
            self.occupied_sites, self.mean_density
        )
    }
}
