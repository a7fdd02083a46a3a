//! `sylva spp`: plane-parallel scattering (paper 003): radiance in slabs from the full,
//! simplified and refined models, 003 Tables 1 and 2 recomputed, and Table 3 on trees
//! (`spp trees`, in `spp_trees.rs`).

use super::output::emit_to;
use anyhow::{Context, Result};
use std::path::PathBuf;
use sylva_spp::report::{
    directions, parse_thickness, slab_report, slab_text, table1_text, table2_text, SlabQuery,
};
use sylva_spp::tables::{self, RmsProtocol};
use sylva_spp::Slab;

#[derive(clap::Args)]
pub struct SppArgs {
    #[command(subcommand)]
    cmd: SppCommand,
}

#[derive(clap::Subcommand)]
enum SppCommand {
    /// Diffuse radiance I(z, s) in a slab lit by a directional source: full, simplified and
    /// refined models side by side.
    Slab(SlabArgs),
    /// Recompute 003 Table 1 (SPP error vs the full model by albedo and g, w = 10/σt).
    Table1(TableArgs),
    /// Recompute 003 Table 2 (SPP error vs the full model by albedo and thickness, g = 0).
    Table2(TableArgs),
    /// 003 Table 3 on a scene's trees: per-leaf irradiance from a Monte Carlo reference
    /// against SPPG, SPP, single scattering and sylva's LB lighting (eq. 30), e.g.
    /// `sylva spp trees catalpa` and `sylva spp trees catalpa --repeat 3`.
    Trees(super::spp_trees::TreesArgs),
}

#[derive(clap::Args)]
struct SlabArgs {
    /// Total cross section σt (per unit length).
    #[arg(long, default_value_t = 1.0, allow_hyphen_values = true)]
    sigma_t: f64,
    /// Single-scattering albedo σs/σt, in [0, 1].
    #[arg(long, default_value_t = 0.9, allow_hyphen_values = true)]
    albedo: f64,
    /// Henyey-Greenstein asymmetry g, |g| < 1.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    g: f64,
    /// Slab thickness w (same length unit as 1/σt), or "inf" for a half-space.
    #[arg(long, default_value = "10", allow_hyphen_values = true)]
    thickness: String,
    /// Incidence angle of the light, degrees from the slab normal, in [0, 89].
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    incidence: f64,
    /// Depths z at which to report the radiance (comma-separated, within [0, w]).
    #[arg(long, value_delimiter = ',', default_values_t = vec![0.0, 1.0, 2.0, 5.0], allow_hyphen_values = true)]
    depths: Vec<f64>,
    /// Polar angles of the reported directions, degrees from the inward normal
    /// (0 = straight down into the slab, 180 = straight up; 90 is not allowed).
    #[arg(long, value_delimiter = ',', default_values_t = vec![0.0, 30.0, 60.0, 120.0, 150.0, 180.0], allow_hyphen_values = true)]
    angles: Vec<f64>,
    /// Azimuths of the reported directions, degrees from the plane of incidence.
    #[arg(long, value_delimiter = ',', default_values_t = vec![0.0], allow_hyphen_values = true)]
    azimuths: Vec<f64>,
    /// Discrete directions per hemisphere of the full model.
    #[arg(long, default_value_t = sylva_spp::full::DEFAULT_STREAMS)]
    streams: usize,
    /// Also trace this many Monte Carlo photons and print their reflectance/transmittance.
    #[arg(long)]
    photons: Option<u64>,
    /// Seed of the Monte Carlo run (the result depends on it only, not on the thread count).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Also show the full model's reflectance and transmittance for 2..64 directions per
    /// hemisphere (how many are enough).
    #[arg(long)]
    convergence: bool,
    /// Print JSON instead of a text table.
    #[arg(long)]
    json: bool,
    /// Write the output to this file (atomically) instead of standard output.
    #[arg(long)]
    out: Option<PathBuf>,
}

#[derive(clap::Args)]
struct TableArgs {
    /// Print JSON (a list of rows) instead of a text table.
    #[arg(long)]
    json: bool,
    /// Write the output to this file (atomically) instead of standard output.
    #[arg(long)]
    out: Option<PathBuf>,
}

pub fn run(args: SppArgs) -> Result<()> {
    match args.cmd {
        SppCommand::Slab(a) => slab(a),
        SppCommand::Trees(a) => super::spp_trees::run(a),
        SppCommand::Table1(a) => {
            let rows = tables::table1(&RmsProtocol::paper()).context("computing Table 1")?;
            let text = if a.json {
                serde_json::to_string_pretty(&rows)? + "\n"
            } else {
                table1_text(&rows)
            };
            emit_to(&text, a.out)
        }
        SppCommand::Table2(a) => {
            let rows = tables::table2(&RmsProtocol::paper()).context("computing Table 2")?;
            let text = if a.json {
                serde_json::to_string_pretty(&rows)? + "\n"
            } else {
                table2_text(&rows)
            };
            emit_to(&text, a.out)
        }
    }
}

fn slab(a: SlabArgs) -> Result<()> {
    let thickness = parse_thickness(&a.thickness)?;
    let slab = Slab::with_incidence_deg(a.sigma_t, a.albedo, a.g, thickness, a.incidence)?;
    let directions = directions(&a.angles, &a.azimuths)?;
    let report = slab_report(
        slab,
        &SlabQuery {
            incidence_deg: a.incidence,
            streams: a.streams,
            depths: a.depths,
            directions,
            photons: a.photons,
            seed: a.seed,
            convergence: a.convergence,
        },
    )?;
    let text = if a.json {
        serde_json::to_string_pretty(&report)? + "\n"
    } else {
        slab_text(&report)
    };
    emit_to(&text, a.out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table2_json_is_written_atomically_with_inf_thickness() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t2.json");
        run(SppArgs {
            cmd: SppCommand::Table2(TableArgs {
                json: true,
                out: Some(path.clone()),
            }),
        })
        .unwrap();
        let rows: Vec<serde_json::Value> =
            serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        assert_eq!(rows.len(), 24);
        assert_eq!(rows[0]["thickness"], "inf");
        let simplified = rows[0]["simplified"].as_f64().unwrap();
        assert!(simplified > 0.0 && simplified < 0.1);
    }
}
