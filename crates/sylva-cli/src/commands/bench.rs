//! `sylva bench`: measured speed of sylva's stages on this machine.

use anyhow::{bail, Result};
use clap::{Args, Subcommand};
use serde::Serialize;
use sylva_lb::{Boundary, DensityGrid, Dims, LbBenchmark, Preset, SolveOptions, StopReason};

use super::progress::bar;

#[derive(Args)]
pub struct BenchArgs {
    #[command(subcommand)]
    command: BenchCommand,
}

impl BenchArgs {
    /// `bench trace`: the one benchmark that runs across MPI ranks.
    pub fn is_trace(&self) -> bool {
        matches!(self.command, BenchCommand::Trace(_))
    }
}

#[derive(Subcommand)]
enum BenchCommand {
    /// The LB solver on one colour of a dense medium (every site collides), against this
    /// machine's copy bandwidth measured in the same run; or (`--medium cloud`) the whole
    /// solve of the built-in cloud (002 Table 3), with the papers' step count or a
    /// convergence stop.
    Lb(BenchLbArgs),
    /// Generating each built-in species and building a scene's models and instances.
    Scene(super::bench_scene::BenchSceneArgs),
    /// Voxelizing a model into its LB density grid (default: american_beech at 128).
    Voxelize(super::bench_voxel::BenchVoxelArgs),
    /// Rendering a scene's view: acceleration build, frame time at 1 and 4 rays per pixel,
    /// primary and shadow rays per second, memory (default scene: demo; try beech, catalpa).
    Trace(super::bench_trace::BenchTraceArgs),
    /// 003's rendering system step by step (deep opacity maps and instance grids, sky, sun,
    /// a frame with the plane-parallel light) beside the paper's Table 4 (default: red_maple
    /// on a 4 × 4 lattice, 22 directions).
    Spp(super::bench_spp::BenchSppArgs),
    /// Relighting (004 Table 1): frame time over 24 suns (kd-tree and sun-grid shadows)
    /// against the static frame, basis solve time, compressed bytes, image RMSE of the
    /// compression (default scene: demo; 004 measured catalpa and canopy). Under the paper
    /// light, whose base solutions these are.
    Relight(super::bench_relight::BenchRelightArgs),
}

#[derive(Args)]
struct BenchLbArgs {
    /// Grid edge N (an N³ grid) or NXxNYxNZ (default 128; for the cloud 256x128x128, the
    /// paper's).
    #[arg(long)]
    grid: Option<String>,
    /// Steps per run (default 256; for the cloud 2 × the longest edge, the papers' count,
    /// or with --tolerance the most allowed, 10 × the longest edge).
    #[arg(long)]
    steps: Option<usize>,
    /// Cloud only: stop each solve once the relative change of total density per step is
    /// below this (a convergence stop instead of the papers' fixed count).
    #[arg(long, requires = "medium")]
    tolerance: Option<f64>,
    /// Runs; the median is reported.
    #[arg(long, default_value_t = 3)]
    repeats: usize,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// The medium: `dense` (density 1 everywhere: every site collides), `empty` (streaming
    /// only, the memory-traffic floor), or `cloud`: the built-in cloud scene's cumulus (its
    /// generator at --grid) under its sun, the full three-colour solve the renderer runs
    /// (the cloud preset's colours are equal, so one is solved).
    #[arg(long, default_value = "dense", value_parser = ["dense", "empty", "cloud"])]
    medium: String,
    /// Where the solver runs: cpu, gpu (the best adapter, a software one such as lavapipe
    /// included) or auto (a hardware GPU if present, else the CPU). On the GPU, copy_gbs is
    /// the GPU's buffer-copy bandwidth.
    #[arg(long, value_enum, default_value = "auto")]
    device: super::device::DeviceArg,
    /// GPU state storage: f32 or f16.
    #[arg(long, value_enum, default_value = "f32")]
    precision: super::device::PrecisionArg,
}

#[derive(Serialize)]
struct LbBench {
    grid: String,
    steps: usize,
    seconds: f64,
    mlups: f64,
    bytes_per_update: usize,
    effective_gbs: f64,
    copy_gbs: f64,
    ratio: f64,
    threads: usize,
    kernel: String,
    runs: Vec<f64>,
    /// "cpu" or "gpu".
    device: &'static str,
    /// The GPU adapter's name (absent on the CPU).
    #[serde(skip_serializing_if = "Option::is_none")]
    adapter: Option<String>,
}

pub fn run(args: BenchArgs, comm: Option<&dyn sylva_mpi::Comm>) -> Result<()> {
    match args.command {
        BenchCommand::Lb(a) => bench_lb(a),
        BenchCommand::Scene(a) => super::bench_scene::run(a),
        BenchCommand::Voxelize(a) => super::bench_voxel::run(a),
        BenchCommand::Trace(a) => super::bench_trace::run(a, comm),
        BenchCommand::Spp(a) => super::bench_spp::run(a),
        BenchCommand::Relight(a) => super::bench_relight::run(a),
    }
}

fn bench_lb(a: BenchLbArgs) -> Result<()> {
    if a.medium == "cloud" {
        return bench_cloud(a);
    }
    if a.tolerance.is_some() {
        bail!("--tolerance applies to --medium cloud (dense and empty runs take a fixed --steps)");
    }
    let grid_arg = a.grid.as_deref().unwrap_or("128");
    let dims = match Dims::parse(grid_arg) {
        Some(d) => d?,
        None => bail!("--grid '{grid_arg}': expected N or NXxNYxNZ"),
    };
    let steps = a.steps.unwrap_or(256);
    if steps == 0 || a.repeats == 0 {
        bail!("--steps and --repeats must be at least 1");
    }
    // The grid and the solver's state, checked before either is allocated.
    sylva_lb::solver::check_solve_memory(dims)?;
    // A dense cloud-like medium: every site runs the full collision.
    let mut grid = DensityGrid::empty(dims);
    if a.medium == "dense" {
        grid.density.fill(1.0);
    }
    let medium = Preset::Cloud.params();
    let boundary = Boundary::sun([0.3, -0.9, 0.3], 1.0);
    let backend = super::device::open_solver(a.device, a.precision)?;
    let pb = if a.json {
        indicatif::ProgressBar::hidden()
    } else {
        bar((steps * a.repeats) as u64, "bench lb")
    };
    let LbBenchmark {
        runs,
        kernel,
        bytes_per_update,
        copy_gbs,
    } = backend.benchmark(&grid, &medium, boundary, steps, a.repeats, &mut |s| {
        pb.set_position(s as u64)
    })?;
    pb.finish_and_clear();
    let mut sorted = runs.clone();
    sorted.sort_by(f64::total_cmp);
    let seconds = sorted[sorted.len() / 2];
    let mlups = dims.sites() as f64 * steps as f64 / seconds / 1e6;
    let effective_gbs = mlups * 1e6 * bytes_per_update as f64 / 1e9;
    let b = LbBench {
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
    };
    if a.json {
        println!("{}", serde_json::to_string(&b)?);
    } else {
        println!(
            "LB solver, {} grid, {} steps, one colour, {}",
            b.grid,
            b.steps,
            backend.describe()
        );
        println!("  runs (s):        {}", format_runs(&b.runs));
        println!("  median:          {:.3} s", b.seconds);
        println!("  MLUPS:           {:.1}", b.mlups);
        println!("  bytes/update:    {}", b.bytes_per_update);
        println!("  effective:       {:.2} GB/s", b.effective_gbs);
        println!(
            "  copy bandwidth:  {:.2} GB/s (read + write, same run{})",
            b.copy_gbs,
            if b.device == "gpu" {
                ", GPU buffer copies"
            } else {
                ""
            }
        );
        println!("  ratio:           {:.2}", b.ratio);
    }
    Ok(())
}

#[derive(Serialize)]
struct CloudBench {
    grid: String,
    /// Sites with density.
    occupied: usize,
    /// Steps each run took (the same for every run).
    steps: usize,
    /// `step limit` or `converged`.
    stop: String,
    tolerance: Option<f64>,
    /// Median seconds of the whole solve (all colours).
    seconds: f64,
    /// Site updates per second of the solved colours, millions.
    mlups: f64,
    /// Colours solved (equal colours are solved once).
    solves: usize,
    runs: Vec<f64>,
    threads: usize,
    device: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    adapter: Option<String>,
    /// The goal of the issue (002 Table 3: 100 s on a 4-thread i7, 6 s on a GTX 480).
    goal_seconds: f64,
}

/// The built-in cloud's LB solve, as `sylva render cloud` runs it.
fn bench_cloud(a: BenchLbArgs) -> Result<()> {
    let desc = sylva_scene::SceneDesc::load("cloud")?;
    let mut medium = desc
        .media
        .first()
        .cloned()
        .expect("the built-in cloud scene has a medium");
    let sylva_scene::scene::MediumGenerator::Cumulus(params) = &mut medium.generator;
    if let Some(g) = &a.grid {
        let dims = match Dims::parse(g) {
            Some(d) => d?,
            None => bail!("--grid '{g}': expected N or NXxNYxNZ"),
        };
        *params =
            sylva_grow::cloud::CumulusParams::for_grid([dims.nx, dims.ny, dims.nz], params.seed);
    }
    if a.repeats == 0 {
        bail!("--repeats must be at least 1");
    }
    let m = medium.build(&desc.origin)?;
    let dims = Dims::new(m.dims[0], m.dims[1], m.dims[2])?;
    let opts = match (a.steps, a.tolerance) {
        (Some(0), _) => bail!("--steps must be at least 1"),
        (Some(s), t) => SolveOptions {
            max_steps: s,
            tolerance: t,
        },
        (None, None) => SolveOptions::papers(dims),
        (None, Some(t)) => SolveOptions {
            max_steps: 10 * dims.longest_edge(),
            tolerance: Some(t),
        },
    };
    let grid = DensityGrid::new(
        dims,
        sylva_lb::Bounds::UNIT,
        m.density.to_vec(),
        vec![0.0; dims.sites()],
    )?;
    let preset = Preset::parse(&m.preset)?.params();
    let travel = desc.sun.travel().to_array();
    let boundary = Boundary::sun(travel, 1.0);
    let backend = super::device::open_solver(a.device, a.precision)?;
    let pb = if a.json {
        indicatif::ProgressBar::hidden()
    } else {
        bar((opts.max_steps * a.repeats) as u64, "bench cloud")
    };
    let mut runs = Vec::with_capacity(a.repeats);
    let mut last = None;
    for r in 0..a.repeats {
        let t0 = std::time::Instant::now();
        let (_, reports) =
            backend.solve_lighting(&grid, &preset, boundary, &opts, &mut |_, s, _| {
                pb.set_position((r * opts.max_steps + s) as u64)
            })?;
        runs.push(t0.elapsed().as_secs_f64());
        last = Some(reports);
    }
    pb.finish_and_clear();
    let reports = last.expect("at least one run");
    let mut sorted = runs.clone();
    sorted.sort_by(f64::total_cmp);
    let seconds = sorted[sorted.len() / 2];
    // Colours with equal parameters are copied, not solved.
    let solves = (0..3)
        .filter(|&c| (0..c).all(|p| preset.colours[p] != preset.colours[c]))
        .count();
    let steps = reports[0].steps;
    let (_, occupied) = m.occupancy();
    let b = CloudBench {
        grid: dims.to_string().replace('×', "x"),
        occupied,
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
        goal_seconds: 16.0,
    };
    if a.json {
        println!("{}", serde_json::to_string(&b)?);
    } else {
        println!(
            "LB solve of the built-in cloud, {} grid ({} occupied sites), {}",
            b.grid,
            b.occupied,
            backend.describe()
        );
        println!(
            "  steps:           {} ({}{})",
            b.steps,
            b.stop,
            b.tolerance
                .map(|t| format!(", tolerance {t:e}"))
                .unwrap_or_default()
        );
        println!("  runs (s):        {}", format_runs(&b.runs));
        println!(
            "  median:          {:.3} s ({} colour solve(s))",
            b.seconds, b.solves
        );
        println!("  MLUPS:           {:.1}", b.mlups);
        println!(
            "  goal:            ≤ {} s on 2 cores: {}",
            b.goal_seconds,
            if b.seconds <= b.goal_seconds {
                "met"
            } else {
                "missed"
            }
        );
    }
    Ok(())
}

/// Run times in seconds, three decimals, space-separated.
pub fn format_runs(runs: &[f64]) -> String {
    runs.iter()
        .map(|t| format!("{t:.3}"))
        .collect::<Vec<_>>()
        .join(" ")
}
