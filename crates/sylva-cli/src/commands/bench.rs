//! `sylva bench`: measured speed of sylva's stages on this machine.

use anyhow::{bail, Result};
use clap::{Args, Subcommand};
use serde::Serialize;
use sylva_lb::{Boundary, DensityGrid, Dims, LbBenchmark, Preset};

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
    /// machine's copy bandwidth measured in the same run.
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
}

#[derive(Args)]
struct BenchLbArgs {
    /// Grid edge N (an N³ grid) or NXxNYxNZ.
    #[arg(long, default_value = "128")]
    grid: String,
    /// Steps per run.
    #[arg(long, default_value_t = 256)]
    steps: usize,
    /// Runs; the median is reported.
    #[arg(long, default_value_t = 3)]
    repeats: usize,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// The medium: `dense` (density 1 everywhere: every site collides) or `empty`
    /// (streaming only, the memory-traffic floor).
    #[arg(long, default_value = "dense", value_parser = ["dense", "empty"])]
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
    }
}

fn bench_lb(a: BenchLbArgs) -> Result<()> {
    let dims = match Dims::parse(&a.grid) {
        Some(d) => d?,
        None => bail!("--grid '{}': expected N or NXxNYxNZ", a.grid),
    };
    if a.steps == 0 || a.repeats == 0 {
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
        bar((a.steps * a.repeats) as u64, "bench lb")
    };
    let LbBenchmark {
        runs,
        kernel,
        bytes_per_update,
        copy_gbs,
    } = backend.benchmark(&grid, &medium, boundary, a.steps, a.repeats, &mut |s| {
        pb.set_position(s as u64)
    })?;
    pb.finish_and_clear();
    let mut sorted = runs.clone();
    sorted.sort_by(f64::total_cmp);
    let seconds = sorted[sorted.len() / 2];
    let mlups = dims.sites() as f64 * a.steps as f64 / seconds / 1e6;
    let effective_gbs = mlups * 1e6 * bytes_per_update as f64 / 1e9;
    let b = LbBench {
        grid: dims.to_string().replace('×', "x"),
        steps: a.steps,
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

/// Run times in seconds, three decimals, space-separated.
pub fn format_runs(runs: &[f64]) -> String {
    runs.iter()
        .map(|t| format!("{t:.3}"))
        .collect::<Vec<_>>()
        .join(" ")
}
