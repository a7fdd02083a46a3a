//! `sylva`: renders forests with lattice-Boltzmann global illumination.
//!
//! Thin: argument parsing and progress display only; each command lives in
//! `commands/<name>.rs` and calls into the library crates.

mod commands;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "sylva",
    version,
    about = "Render forest ecosystems with lattice-Boltzmann global illumination",
    long_about = "sylva lights plants and forests with a lattice-Boltzmann photon-transport \
solver (leaf transparency, light scattered between leaves and trees) and renders them with a \
ray tracer. Run `sylva <command> --help` for each command's options."
)]
struct Cli {
    /// Worker threads, 1 to 256 (default: all cores). Results do not depend on it.
    // Signed, and negative numbers taken as values: `--threads -1` gets the range message
    // below instead of clap's "unexpected argument '-1'".
    #[arg(long, global = true, allow_negative_numbers = true)]
    threads: Option<i64>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Inspect scenes: `sylva scene info SCENE [--json]`, `sylva scene list`, `sylva scene source`.
    Scene(commands::scene::SceneArgs),
    /// The species library: `sylva species list`, `sylva species show NAME`.
    Species(commands::species::SpeciesArgs),
    /// Turn a model (species name, Arbaro file, OBJ, glTF or GLB) into an LB density grid
    /// (.sgrid) and a preview: `sylva voxelize red_maple --grid 128 -o maple.sgrid`.
    Voxelize(commands::voxelize::VoxelizeArgs),
    /// Lattice-Boltzmann lighting: solve a grid, describe grid files.
    Lb(commands::lb::LbArgs),
    /// Plane-parallel scattering in slabs (paper 003): radiance, Tables 1 and 2.
    Spp(commands::spp::SppArgs),
    /// Write a scene for other renderers: OBJ (flattened) or Mitsuba 3 (instanced), e.g.
    /// `sylva export demo --format mitsuba -o out/`.
    Export(commands::export::ExportArgs),
    /// Render a scene (default: the built-in demo) to sylva-out/<scene>.png: sunlight, shadows,
    /// light through leaves and LB indirect light, e.g. `sylva render beech --rpp 4 --hdr`.
    Render(commands::render::RenderArgs),
    /// Precompute every model's 19 base solutions (paper 004), compressed and cached, and the
    /// scene's coarse global grid: afterwards the sun moves with no LB solve, e.g.
    /// `sylva basis canopy` (`--device gpu` solves on the GPU; `mpirun -np N sylva basis`
    /// across processes, with the `mpi` feature). Base solutions are the paper light's
    /// (`--light paper`, the default here; docs/relight.md).
    Basis(commands::basis::BasisArgs),
    /// Relight a scene over a moving sun (004 Table 1): numbered PNGs, an animated PNG and
    /// per-frame times, e.g. `sylva relight catalpa --suns 24`. Under the paper light, whose
    /// base solutions these are (`--light paper`, the default here).
    Relight(commands::relight::RelightArgs),
    /// Measure speed on this machine: `bench lb` (LB solver against copy bandwidth),
    /// `bench scene` (generation and scene building), `bench voxelize`, `bench trace`
    /// (acceleration build and frame time), `bench spp`, `bench relight` (moving the sun).
    Bench(commands::bench::BenchArgs),
}

/// Whether `command` runs across MPI ranks, and its name for messages.
fn distributed(command: &Command) -> Result<(), &'static str> {
    match command {
        Command::Render(_) | Command::Basis(_) | Command::Relight(_) => Ok(()),
        Command::Bench(b) if b.is_trace() => Ok(()),
        Command::Bench(_) => Err("bench (other than bench trace)"),
        Command::Scene(_) => Err("scene"),
        Command::Species(_) => Err("species"),
        Command::Voxelize(_) => Err("voxelize"),
        Command::Lb(_) => Err("lb"),
        Command::Spp(_) => Err("spp"),
        Command::Export(_) => Err("export"),
    }
}

/// Runs `command`; its LB solves and frames go through `runner` (this process, or every
/// rank of an MPI job).
fn run(command: Command, runner: &dyn sylva_core::jobs::Runner) -> anyhow::Result<()> {
    match command {
        Command::Lb(a) => commands::lb::run(a),
        Command::Voxelize(a) => commands::voxelize::run(a),
        Command::Spp(a) => commands::spp::run(a),
        Command::Scene(a) => commands::scene::run(a),
        Command::Species(a) => commands::species::run(a),
        Command::Bench(a) => commands::bench::run(a, runner),
        Command::Export(a) => commands::export::run(a),
        Command::Render(a) => commands::render::run(a, runner),
        Command::Basis(a) => commands::basis::run(a, runner),
        Command::Relight(a) => commands::relight::run(a, runner),
    }
}

fn main() -> std::process::ExitCode {
    // Before any thread exists: it may set an environment variable.
    sylva_wgpu::quiet_headless_probing();
    // `sylva lb info x.sgrid | head -1`: a closed pipe ends the process quietly, as it does
    // other Unix tools, instead of a panic in println.
    #[cfg(unix)]
    // SAFETY: restoring the default action of a signal before any thread exists.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    // Ctrl-C while outputs are written removes the temporaries and replaces nothing.
    sylva_core::interrupt::install();
    let cli = Cli::parse();
    let mut threads = None;
    if let Some(n) = cli.threads {
        let range = sylva_core::limits::THREADS;
        match usize::try_from(n) {
            Ok(k) if range.contains(&k) => threads = Some(k),
            _ => {
                return commands::finish(Err(anyhow::anyhow!(
                    "--threads {n}: must be {}",
                    sylva_core::limits::describe(&range)
                )))
            }
        }
    }
    // One of several processes started by mpirun: the command must split its work.
    let ranks = sylva_mpi::launch::launched_size().filter(|&n| n > 1);
    if let Some(n) = ranks {
        if let Err(what) = distributed(&cli.command) {
            return commands::finish(Err(anyhow::anyhow!(
                "started by mpirun as one of {n} processes, but `sylva {what}` does not split \
                 its work across processes: run it without mpirun (render, basis, relight and bench trace do)"
            )));
        }
        if !cfg!(feature = "mpi") {
            return commands::finish(Err(anyhow::anyhow!(
                "started by mpirun as one of {n} processes, but this sylva was built without \
                 MPI: every process would render the whole image. Build it with \
                 `cargo build --release --features mpi` (README: Across machines with MPI)"
            )));
        }
    }
    // Under mpirun, the ranks on one machine share its cores unless told otherwise.
    let threads = threads.or_else(|| {
        let local = sylva_mpi::launch::local_size().filter(|_| ranks.is_some())?;
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        Some((cores / local.max(1)).clamp(1, *sylva_core::limits::THREADS.end()))
    });
    if let Some(n) = threads {
        if let Err(e) = rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
        {
            return commands::finish(Err(e.into()));
        }
    }
    if ranks.is_some() {
        return run_mpi(cli.command);
    }
    commands::finish(run(cli.command, &sylva_core::jobs::Local))
}

/// Runs a command as one MPI rank: a failure on any rank is printed there and ends the
/// whole job (MPI_Abort), so no rank waits forever for it.
#[cfg(feature = "mpi")]
fn run_mpi(command: Command) -> std::process::ExitCode {
    use sylva_mpi::Comm;
    let mpi = match sylva_mpi::mpi::Mpi::init() {
        Ok(m) => m,
        Err(e) => return commands::finish(Err(anyhow::Error::new(e).context("starting MPI"))),
    };
    match run(command, &sylva_mpi::QueueRunner::new(&mpi)) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            let (rank, size) = (mpi.rank(), mpi.size());
            // One write for the whole report: eprintln! writes a formatted line in pieces,
            // and mpirun relays each as it comes, so its abort banner could split the line.
            let mut report = commands::error_report(&format!("error: rank {rank} of {size}: "), &e);
            report.push_str(&format!(
                "sylva: rank {rank} failed; aborting the MPI job\n"
            ));
            {
                use std::io::Write;
                let mut err = std::io::stderr().lock();
                // Nothing better to do if stderr is gone: the abort below still ends the job.
                let _ = err.write_all(report.as_bytes());
                let _ = err.flush();
            }
            mpi.abort(1)
        }
    }
}

#[cfg(not(feature = "mpi"))]
fn run_mpi(_command: Command) -> std::process::ExitCode {
    unreachable!("refused above without the mpi feature")
}
