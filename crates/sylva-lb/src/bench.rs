//! `sylva bench lb`: the solver's speed on one colour of a dense (or empty) medium against
//! the device's copy bandwidth measured in the same run, and the whole solve of a medium
//! (the built-in cloud, 002 Table 3).

use std::fmt;
use std::time::Instant;

use serde::Serialize;
use sylva_core::measure::{format_runs, median};

use crate::{
    Boundary, DensityGrid, Dims, LbBenchmark, LbSolver, LbSolverError, MediumParams, Preset,
    SolveOptions, StopReason,
};

/// The medium of [`dense`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BenchMedium {
    /// Density 1 everywhere: every site runs the full collision.
    Dense,
    /// Streaming only: the memory-traffic floor.
    Empty,
}

/// What [`dense`] measured.
#[derive(Debug, Clone, Serialize)]
pub struct LbBench {
    pub grid: String,
    pub steps: usize,
    /// Median seconds of a run.
    pub seconds: f64,
    pub mlups: f64,
    pub bytes_per_update: usize,
    pub effective_gbs: f64,
    pub copy_gbs: f64,
    pub ratio: f64,
    pub threads: usize,
    pub kernel: String,
    pub runs: Vec<f64>,
    /// "cpu" or "gpu".
    pub device: &'static str,
    /// The GPU adapter's name (absent on the CPU).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub adapter: Option<String>,
    /// The backend in words (text only).
    #[serde(skip)]
    pub backend: String,
}

/// `repeats` runs of `steps` steps of one colour on a `dims` grid of `medium`, the cloud
/// preset's parameters, sunlight from above; `progress(done_steps)` over all runs.
pub fn dense(
    backend: &dyn LbSolver,
    dims: Dims,
    medium: BenchMedium,
    steps: usize,
    repeats: usize,
    progress: &mut dyn FnMut(usize),
) -> Result<LbBench, LbSolverError> {
    // The grid and the solver's state, checked before either is allocated.
    crate::solver::check_solve_memory(dims).map_err(crate::SolveError::from)?;
    let mut grid = DensityGrid::empty(dims);
    if medium == BenchMedium::Dense {
        grid.density.fill(1.0);
    }
    let params = Preset::Cloud.params();
    let boundary = Boundary::sun([0.3, -0.9, 0.3], 1.0);
    let LbBenchmark {
        runs,
        kernel,
        bytes_per_update,
        copy_gbs,
    } = backend.benchmark(&grid, &params, boundary, steps, repeats, progress)?;
    let seconds = median(runs.clone());
    let mlups = dims.sites() as f64 * steps as f64 / seconds / 1e6;
    let effective_gbs = mlups * 1e6 * bytes_per_update as f64 / 1e9;
    Ok(LbBench {
        grid: dims.to_string().replace('×', "x"),
        steps,
        seconds,
        mlups,
        bytes_per_update,
        effective_gbs,
        copy_gbs,
        ratio: effective_gbs / copy_gbs,
        threads: rayon::current_num_threads(),
        kernel,
        runs,
        device: backend.device(),
        adapter: backend.adapter(),
        backend: backend.describe(),
    })
}

impl fmt::Display for LbBench {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "LB solver, {} grid, {} steps, one colour, {}",
            self.grid, self.steps, self.backend
        )?;
        writeln!(f, "  runs (s):        {}", format_runs(&self.runs))?;
        writeln!(f, "  median:          {:.3} s", self.seconds)?;
        writeln!(f, "  MLUPS:           {:.1}", self.mlups)?;
        writeln!(f, "  bytes/update:    {}", self.bytes_per_update)?;
        writeln!(f, "  effective:       {:.2} GB/s", self.effective_gbs)?;
        writeln!(
            f,
            "  copy bandwidth:  {:.2} GB/s (read + write, same run{})",
            self.copy_gbs,
            if self.device == "gpu" {
                ", GPU buffer copies"
            } else {
                ""
            }
        )?;
        writeln!(f, "  ratio:           {:.2}", self.ratio)
    }
}

/// What [`solve`] measured.
#[derive(Debug, Clone, Serialize)]
pub struct SolveBench {
    pub grid: String,
    /// Sites with density.
    pub occupied: usize,
    /// Steps each run took (the same for every run).
    pub steps: usize,
    /// `step limit` or `converged`.
    pub stop: String,
    pub tolerance: Option<f64>,
    /// Median seconds of the whole solve (all colours).
    pub seconds: f64,
    /// Site updates per second of the solved colours, millions.
    pub mlups: f64,
    /// Colours solved (equal colours are solved once).
    pub solves: usize,
    pub runs: Vec<f64>,
    pub threads: usize,
    pub device: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub adapter: Option<String>,
    /// The goal (002 Table 3: 100 s on a 4-thread i7, 6 s on a GTX 480; ours on 2 cores).
    pub goal_seconds: f64,
    /// The backend in words (text only).
    #[serde(skip)]
    pub backend: String,
}

/// The goal of the cloud's solve on 2 cores, seconds.
pub const CLOUD_GOAL_SECONDS: f64 = 16.0;

/// `repeats` whole three-colour solves of `grid` under `params` and `boundary`;
/// `progress(done_steps)` counts `opts.max_steps` per run.
pub fn solve(
    backend: &dyn LbSolver,
    grid: &DensityGrid,
    params: &MediumParams,
    boundary: Boundary,
    opts: &SolveOptions,
    repeats: usize,
    progress: &mut dyn FnMut(usize),
) -> Result<SolveBench, LbSolverError> {
    let mut runs = Vec::with_capacity(repeats);
    let mut last = None;
    for r in 0..repeats.max(1) {
        let t0 = Instant::now();
        let (_, reports) =
            backend.solve_lighting(grid, params, boundary, opts, &mut |_, s, _| {
                progress(r * opts.max_steps + s)
            })?;
        runs.push(t0.elapsed().as_secs_f64());
        last = Some(reports);
    }
    let reports = last.expect("at least one run");
    let seconds = median(runs.clone());
    // Colours with equal parameters are copied, not solved.
    let solves = (0..3)
        .filter(|&c| (0..c).all(|p| params.colours[p] != params.colours[c]))
        .count();
    let dims = grid.dims;
    let steps = reports[0].steps;
    Ok(SolveBench {
        grid: dims.to_string().replace('×', "x"),
        occupied: grid.occupancy().1,
        steps,
        stop: match reports[0].stop {
            StopReason::StepLimit => "step limit".into(),
            StopReason::Converged => "converged".into(),
        },
        tolerance: opts.tolerance,
        seconds,
        mlups: (solves * dims.sites() * steps) as f64 / seconds / 1e6,
        solves,
        runs,
        threads: rayon::current_num_threads(),
        device: backend.device(),
        adapter: backend.adapter(),
        goal_seconds: CLOUD_GOAL_SECONDS,
        backend: backend.describe(),
    })
}

impl fmt::Display for SolveBench {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "LB solve of the built-in cloud, {} grid ({} occupied sites), {}",
            self.grid, self.occupied, self.backend
        )?;
        writeln!(
            f,
            "  steps:           {} ({}{})",
            self.steps,
            self.stop,
            self.tolerance
                .map(|t| format!(", tolerance {t:e}"))
                .unwrap_or_default()
        )?;
        writeln!(f, "  runs (s):        {}", format_runs(&self.runs))?;
        writeln!(
            f,
            "  median:          {:.3} s ({} colour solve(s))",
            self.seconds, self.solves
        )?;
        writeln!(f, "  MLUPS:           {:.1}", self.mlups)?;
        writeln!(
            f,
            "  goal:            ≤ {} s on 2 cores: {}",
            self.goal_seconds,
            if self.seconds <= self.goal_seconds {
                "met"
            } else {
                "missed"
            }
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::CpuSolver;

    #[test]
    fn dense_bench_counts_site_updates_of_its_median_run() {
        let dims = Dims::new(8, 8, 8).unwrap();
        let mut ticks = 0;
        let b = dense(&CpuSolver, dims, BenchMedium::Dense, 4, 3, &mut |s| {
            ticks = s
        })
        .unwrap();
        assert_eq!(b.runs.len(), 3);
        assert_eq!(b.grid, "8x8x8");
        assert!(b.runs.contains(&b.seconds));
        let mlups = 512.0 * 4.0 / b.seconds / 1e6;
        assert!((b.mlups - mlups).abs() <= 1e-9 * mlups);
        assert_eq!(ticks, 12, "progress counts steps over all runs");
    }

    #[test]
    fn solve_bench_solves_equal_colours_once() {
        let dims = Dims::new(6, 6, 6).unwrap();
        let mut grid = DensityGrid::empty(dims);
        grid.density[..50].fill(1.0);
        let params = Preset::Cloud.params();
        let opts = SolveOptions {
            max_steps: 5,
            tolerance: None,
            extrapolate: false,
            coarse_start: false,
        };
        let b = solve(
            &CpuSolver,
            &grid,
            &params,
            Boundary::sun([0.0, -1.0, 0.0], 1.0),
            &opts,
            1,
            &mut |_| {},
        )
        .unwrap();
        assert_eq!(
            (b.steps, b.stop.as_str(), b.occupied),
            (5, "step limit", 50)
        );
        assert_eq!(b.solves, 1, "the cloud preset's colours are equal");
    }
}
