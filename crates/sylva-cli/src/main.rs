//! `sylva`: renders forests with lattice-Boltzmann global illumination.
//!
//! Thin: argument parsing and progress display only; each command lives in
//! `commands/<name>.rs` and calls into the library crates.

mod commands;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "sylva", version, about = "Render forest ecosystems with lattice-Boltzmann global illumination", long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print version and build information.
    Version,
    /// Inspect scenes: `sylva scene info SCENE [--json]`, `sylva scene list`.
    Scene(commands::scene::SceneArgs),
    /// The species library: `sylva species list`, `sylva species show NAME`.
    Species(commands::species::SpeciesArgs),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Version => {
            println!("sylva {}", env!("CARGO_PKG_VERSION"));
            Ok(())
        }
        Command::Scene(args) => commands::scene::run(args),
        Command::Species(args) => commands::species::run(args),
    };
    commands::finish(result)
}
