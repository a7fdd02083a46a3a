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
    /// Worker threads (default: all cores). Results do not depend on it.
    #[arg(long, global = true)]
    threads: Option<usize>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Inspect scenes: `sylva scene info SCENE [--json]`, `sylva scene list`, `sylva scene source`.
    Scene(commands::scene::SceneArgs),
    /// The species library: `sylva species list`, `sylva species show NAME`.
    Species(commands::species::SpeciesArgs),
    /// Turn a model (species name or Arbaro file) into an LB density grid (.sgrid) and a
    /// preview: `sylva voxelize red_maple --grid 128 -o maple.sgrid`.
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
    /// Measure speed on this machine (LB solver against copy bandwidth, scene building).
    Bench(commands::bench::BenchArgs),
}

fn main() -> std::process::ExitCode {
    // Before any thread exists: it may set an environment variable.
    sylva_wgpu::quiet_headless_probing();
    let cli = Cli::parse();
    if let Some(n) = cli.threads {
        if n == 0 {
            return commands::finish(Err(anyhow::anyhow!("--threads must be at least 1")));
        }
        if let Err(e) = rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
        {
            return commands::finish(Err(e.into()));
        }
    }
    let result = match cli.command {
        Command::Lb(a) => commands::lb::run(a),
        Command::Voxelize(a) => commands::voxelize::run(a),
        Command::Spp(a) => commands::spp::run(a),
        Command::Scene(a) => commands::scene::run(a),
        Command::Species(a) => commands::species::run(a),
        Command::Bench(a) => commands::bench::run(a),
        Command::Export(a) => commands::export::run(a),
        Command::Render(a) => commands::render::run(a),
    };
    commands::finish(result)
}
