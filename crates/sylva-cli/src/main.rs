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
    /// Plane-parallel scattering in slabs (paper 003): radiance, Tables 1 and 2.
    Spp(commands::spp::SppArgs),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Version => {
            println!("sylva {}", env!("CARGO_PKG_VERSION"));
            Ok(())
        }
        Command::Spp(args) => commands::spp::run(args),
    };
    commands::finish(result)
}
