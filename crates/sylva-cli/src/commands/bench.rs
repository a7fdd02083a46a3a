//! `sylva bench`: measured speed of sylva's stages on this machine.

use anyhow::{bail, Result};
use clap::{Args, Subcommand};
use sylva_lb::bench::{self, BenchMedium};
use sylva_lb::kernel::KernelIsa;
use sylva_lb::{Dims, SolveOptions};
use sylva_pipeline::bench::CloudSolve;

use super::output::{bench_bar, print_report};

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
    /// The kd-tree alone on three sets of rays from a scene's view: primary, shadow (to the
    /// sun) and incoherent (cosine from the primary hits); rays per second, and with
    /// `--export DIR` the scene and rays for `tools/embree/compare.py` (default scene: demo).
    Rays(super::bench_rays::BenchRaysArgs),
    /// 003's rendering system step by step (deep opacity maps and instance grids, sky, sun,
    /// a frame with the plane-parallel light) beside the paper's Table 4 (default: red_maple
    /// on a 4 × 4 lattice, 22 directions).
    Spp(super::bench_spp::BenchSppArgs),
    /// Relighting (004 Table 1): frame time over 24 suns (kd-tree and sun-grid shadows)
    /// against the static frame, basis solve time, compressed bytes, image RMSE of the
    /// compression (default scene: demo; 004 measured catalpa and canopy). The physical light
    /// from its base solutions (the default; `--against-direct` also against the light solved
    /// per sun), or 004's paper light with `--light paper`.
    Relight(super::bench_relight::BenchRelightArgs),
    /// The canopy radiation budget (`sylva budget`): building the stand and each band's
    /// photons, medians of several runs, photons and rays per second (default: the built-in
    /// `crowns`, 10⁶ photons a band).
    Budget(super::budget::BenchBudgetArgs),
    /// The viewer (`sylva view`) driven as the page drives it: input-to-frame latency and
    /// frames per second while the sun is dragged, and the refined frame's delay after the
    /// last input (default scene: demo, 512x512).
    View(super::view::BenchViewArgs),
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
    /// CPU only: run this kernel instead of the widest this CPU has (avx512f, avx2+fma or
    /// portable), to compare kernels back to back.
    #[arg(long, value_parser = ["avx512f", "avx2+fma", "portable"])]
    kernel: Option<String>,
}

impl BenchLbArgs {
    /// The backend `--device`, `--precision` and `--kernel` ask for.
    fn solver(&self) -> Result<Box<dyn sylva_lb::LbSolver>> {
        let Some(name) = &self.kernel else {
            return super::device::open_solver(self.device, self.precision);
        };
        if self.device != super::device::DeviceArg::Cpu {
            bail!("--kernel chooses a CPU kernel: it needs --device cpu");
        }
        let isa = KernelIsa::from_name(name).expect("clap checked the name");
        match sylva_lb::CpuSolver::with_kernel(isa) {
            Some(solver) => Ok(Box::new(solver)),
            None => bail!("--kernel {name}: this CPU lacks its instructions"),
        }
    }
}

pub fn run(args: BenchArgs, runner: &dyn sylva_pipeline::Runner) -> Result<()> {
    match args.command {
        BenchCommand::Lb(a) => bench_lb(a),
        BenchCommand::Scene(a) => super::bench_scene::run(a),
        BenchCommand::Voxelize(a) => super::bench_voxel::run(a),
        BenchCommand::Trace(a) => super::bench_trace::run(a, runner),
        BenchCommand::Rays(a) => super::bench_rays::run(a, runner),
        BenchCommand::Spp(a) => super::bench_spp::run(a),
        BenchCommand::Budget(a) => super::budget::bench(a),
        BenchCommand::Relight(a) => super::bench_relight::run(a),
        BenchCommand::View(a) => super::view::bench(a),
    }
}

fn bench_lb(a: BenchLbArgs) -> Result<()> {
    if a.medium == "cloud" {
        return bench_cloud(a);
    }
    if a.tolerance.is_some() {
        bail!("--tolerance applies to --medium cloud (dense and empty runs take a fixed --steps)");
    }
    let dims = parse_grid(a.grid.as_deref().unwrap_or("128"))?;
    let steps = a.steps.unwrap_or(256);
    if steps == 0 || a.repeats == 0 {
        bail!("--steps and --repeats must be at least 1");
    }
    let medium = match a.medium.as_str() {
        "empty" => BenchMedium::Empty,
        _ => BenchMedium::Dense,
    };
    let backend = a.solver()?;
    let pb = bench_bar(a.json, steps * a.repeats, "bench lb");
    let b = bench::dense(backend.as_ref(), dims, medium, steps, a.repeats, &mut |s| {
        pb.set_position(s as u64)
    })?;
    pb.finish_and_clear();
    print_report(&b, a.json)
}

/// The built-in cloud's LB solve, as `sylva render cloud` runs it.
fn bench_cloud(a: BenchLbArgs) -> Result<()> {
    let dims = a.grid.as_deref().map(parse_grid).transpose()?;
    if a.repeats == 0 {
        bail!("--repeats must be at least 1");
    }
    let cloud = CloudSolve::builtin(dims)?;
    if a.steps == Some(0) {
        bail!("--steps must be at least 1");
    }
    let opts = SolveOptions::for_run(a.steps, a.tolerance, cloud.grid.dims);
    let backend = a.solver()?;
    let pb = bench_bar(a.json, opts.max_steps * a.repeats, "bench cloud");
    let b = bench::solve(
        backend.as_ref(),
        &cloud.grid,
        &cloud.medium,
        cloud.boundary,
        &opts,
        a.repeats,
        &mut |s| pb.set_position(s as u64),
    )?;
    pb.finish_and_clear();
    print_report(&b, a.json)
}

fn parse_grid(g: &str) -> Result<Dims> {
    match Dims::parse(g) {
        Some(d) => Ok(d?),
        None => bail!("--grid '{g}': expected N or NXxNYxNZ"),
    }
}
