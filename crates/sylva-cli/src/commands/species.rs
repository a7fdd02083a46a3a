//! `sylva species list|show`: the built-in species and Arbaro files.

use super::output::{emit, emit_report};
use sylva_grow::arbaro;
use sylva_grow::sheet::{resolve, SpeciesSheet, SpeciesTable};

#[derive(clap::Args)]
pub struct SpeciesArgs {
    #[command(subcommand)]
    pub command: SpeciesCommand,
}

#[derive(clap::Subcommand)]
pub enum SpeciesCommand {
    /// The built-in species with their triangle counts.
    List {
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// A species' parameters, look and triangle count.
    Show {
        /// A built-in species name or an Arbaro species file (.xml).
        name: String,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        /// Print the parameters as an Arbaro species file.
        #[arg(long, conflicts_with = "json")]
        xml: bool,
    },
}

pub fn run(args: SpeciesArgs) -> anyhow::Result<()> {
    match args.command {
        SpeciesCommand::List { json } => {
            let table = SpeciesTable::builtin()?;
            emit_report(&table, json)
        }
        SpeciesCommand::Show { name, json, xml } => {
            let s = resolve(&name)?;
            if xml {
                return emit(&arbaro::to_xml(&s.name, &s.params));
            }
            let sheet = SpeciesSheet::of(&s)?;
            emit_report(&sheet, json)
        }
    }
}
