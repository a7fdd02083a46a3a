//! `sylva spp`: plane-parallel scattering (paper 003): radiance in slabs from the full,
//! simplified and refined models, 003 Tables 1 and 2 recomputed, and Table 3 on trees
//! (`spp trees`, in `spp_trees.rs`).

use anyhow::{bail, Context, Result};
use serde::Serialize;
use std::fmt::Write as _;
use std::path::PathBuf;
use sylva_spp::monte_carlo::{simulate, McConfig, McResult};
use sylva_spp::tables::{self, RmsProtocol, Table1Row, Table2Row};
use sylva_spp::{Direction, FullModel, Slab, SppModel};

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
            emit(&text, a.out)
        }
        SppCommand::Table2(a) => {
            let rows = tables::table2(&RmsProtocol::paper()).context("computing Table 2")?;
            let text = if a.json {
                serde_json::to_string_pretty(&rows)? + "\n"
            } else {
                table2_text(&rows)
            };
            emit(&text, a.out)
        }
    }
}

pub fn emit(text: &str, out: Option<PathBuf>) -> Result<()> {
    match out {
        Some(path) => sylva_core::atomic_write(&path, text.as_bytes())
            .with_context(|| format!("writing {}", path.display())),
        None => {
            print!("{text}");
            Ok(())
        }
    }
}

fn parse_thickness(s: &str) -> Result<f64> {
    match s.trim().to_ascii_lowercase().as_str() {
        "inf" | "infinity" | "∞" => Ok(f64::INFINITY),
        other => other
            .parse::<f64>()
            .with_context(|| format!("--thickness must be a number or \"inf\", got {s:?}")),
    }
}

#[derive(Serialize)]
struct RadianceRow {
    depth: f64,
    polar_deg: f64,
    azimuth_deg: f64,
    mu: f64,
    full: f64,
    simplified: f64,
    refined: f64,
}

#[derive(Serialize)]
struct ConvergenceRow {
    streams: usize,
    reflectance: f64,
    diffuse_transmittance: f64,
}

#[derive(Serialize)]
struct SlabReport {
    sigma_t: f64,
    albedo: f64,
    g: f64,
    #[serde(serialize_with = "thickness_json")]
    thickness: f64,
    incidence_deg: f64,
    streams: usize,
    reflectance_full: f64,
    reflectance_simplified: f64,
    diffuse_transmittance_full: f64,
    diffuse_transmittance_simplified: f64,
    direct_transmittance: f64,
    monte_carlo: Option<McResult>,
    convergence: Vec<ConvergenceRow>,
    radiance: Vec<RadianceRow>,
}

fn thickness_json<S: serde::Serializer>(w: &f64, s: S) -> std::result::Result<S::Ok, S::Error> {
    if w.is_infinite() {
        s.serialize_str("inf")
    } else {
        s.serialize_f64(*w)
    }
}

fn slab(a: SlabArgs) -> Result<()> {
    let thickness = parse_thickness(&a.thickness)?;
    let slab = Slab::with_incidence_deg(a.sigma_t, a.albedo, a.g, thickness, a.incidence)?;
    for &z in &a.depths {
        slab.check_depth(z)?;
    }
    let mut directions = Vec::new();
    for &polar in &a.angles {
        if !(0.0..=180.0).contains(&polar) {
            bail!("polar angles must be in [0, 180] degrees, got {polar}");
        }
        if (polar - 90.0).abs() < 1e-6 {
            bail!("a horizontal direction (polar angle 90) never meets a face of the slab; pick another angle");
        }
        for &azimuth in &a.azimuths {
            if !azimuth.is_finite() {
                bail!("azimuths must be finite, got {azimuth}");
            }
            directions.push((
                polar,
                azimuth,
                Direction::new(polar.to_radians().cos(), azimuth.to_radians())?,
            ));
        }
    }
    let full = FullModel::with_streams(slab, a.streams)?;
    let spp = SppModel::new(slab)?;
    let mut radiance = Vec::new();
    for &z in &a.depths {
        for &(polar, azimuth, dir) in &directions {
            radiance.push(RadianceRow {
                depth: z,
                polar_deg: polar,
                azimuth_deg: azimuth,
                mu: dir.mu,
                full: full.radiance(z, dir)?,
                simplified: spp.radiance(z, dir)?,
                refined: spp.refined_radiance(z, dir)?,
            });
        }
    }
    let monte_carlo = match a.photons {
        Some(n) => Some(simulate(&slab, &McConfig::new(n, a.seed))?),
        None => None,
    };
    let mut convergence = Vec::new();
    if a.convergence {
        for n in [2, 4, 8, 16, 32, 64] {
            let m = FullModel::with_streams(slab, n)?;
            convergence.push(ConvergenceRow {
                streams: n,
                reflectance: m.reflectance(),
                diffuse_transmittance: m.diffuse_transmittance(),
            });
        }
    }
    let report = SlabReport {
        sigma_t: slab.sigma_t,
        albedo: slab.albedo,
        g: slab.g,
        thickness,
        incidence_deg: a.incidence,
        streams: a.streams,
        reflectance_full: full.reflectance(),
        reflectance_simplified: spp.reflectance(),
        diffuse_transmittance_full: full.diffuse_transmittance(),
        diffuse_transmittance_simplified: spp.diffuse_transmittance(),
        direct_transmittance: if thickness.is_infinite() {
            0.0
        } else {
            slab.direct(thickness)
        },
        monte_carlo,
        convergence,
        radiance,
    };
    let text = if a.json {
        serde_json::to_string_pretty(&report)? + "\n"
    } else {
        slab_text(&report)
    };
    emit(&text, a.out)
}

fn slab_text(r: &SlabReport) -> String {
    let mut s = String::new();
    let w = if r.thickness.is_infinite() {
        "inf".to_string()
    } else {
        format!("{}", r.thickness)
    };
    let _ = writeln!(
        s,
        "slab: sigma_t {} albedo {} g {} thickness {} incidence {}°  ({} directions per hemisphere)",
        r.sigma_t, r.albedo, r.g, w, r.incidence_deg, r.streams
    );
    let _ = writeln!(
        s,
        "fluxes per unit incident flux:      full      simplified"
    );
    let _ = writeln!(
        s,
        "  diffuse reflectance            {:9.6}  {:9.6}",
        r.reflectance_full, r.reflectance_simplified
    );
    let _ = writeln!(
        s,
        "  diffuse transmittance          {:9.6}  {:9.6}",
        r.diffuse_transmittance_full, r.diffuse_transmittance_simplified
    );
    let _ = writeln!(
        s,
        "  direct transmittance           {:9.6}",
        r.direct_transmittance
    );
    if let Some(mc) = &r.monte_carlo {
        let _ = writeln!(
            s,
            "Monte Carlo ({} photons): reflectance {:.6} ± {:.6}, diffuse transmittance {:.6} ± {:.6}, direct {:.6} ± {:.6}",
            mc.photons,
            mc.reflectance.mean,
            mc.reflectance.std_error,
            mc.diffuse_transmittance.mean,
            mc.diffuse_transmittance.std_error,
            mc.direct_transmittance.mean,
            mc.direct_transmittance.std_error
        );
    }
    if !r.convergence.is_empty() {
        let _ = writeln!(s, "full model vs directions per hemisphere:");
        for c in &r.convergence {
            let _ = writeln!(
                s,
                "  {:3}  R {:.8}  T {:.8}",
                c.streams, c.reflectance, c.diffuse_transmittance
            );
        }
    }
    let _ = writeln!(
        s,
        "diffuse radiance I(z, s) per unit incident flux (the unscattered beam excluded):"
    );
    let _ = writeln!(
        s,
        "  depth  polar°  azim°        full  simplified     refined"
    );
    for row in &r.radiance {
        let _ = writeln!(
            s,
            "  {:5.2}  {:6.1}  {:5.1}  {:10.6}  {:10.6}  {:10.6}",
            row.depth,
            row.polar_deg,
            row.azimuth_deg,
            tidy(row.full),
            tidy(row.simplified),
            tidy(row.refined)
        );
    }
    s
}

/// Shows rounding residues of exact zeros (a boundary condition, ±1e-17) as 0.
fn tidy(x: f64) -> f64 {
    if x.abs() < 1e-15 {
        0.0
    } else {
        x
    }
}

fn pct(x: f64) -> String {
    format!("{:5.2}", 100.0 * x)
}

fn pct_opt(x: Option<f64>) -> String {
    x.map_or_else(|| "    -".to_string(), |v| format!("{:5.1}", 100.0 * v))
}

fn albedo_label(a: Option<f64>) -> String {
    a.map_or_else(|| "total".to_string(), |v| format!("{v}"))
}

const TABLE_NOTE: &str = "RMS of the diffuse-radiance difference against the full model, per unit incident flux, in percent;\n\
averaged over incidence 0-60° (step 15°), depths 0..min(w, 10) step 0.5, and the whole sphere of directions.\n";

fn table1_text(rows: &[Table1Row]) -> String {
    let mut s = String::from(
        "003 Table 1 (w = 10/σt): simplified (S.) and refined (R.) SPP vs the full model\n",
    );
    s += TABLE_NOTE;
    let _ = writeln!(
        s,
        "     g  albedo    S. ours  S. paper    R. ours  R. paper"
    );
    for r in rows {
        let _ = writeln!(
            s,
            "  {:4.1}  {:>6}    {}     {}      {}     {}",
            r.g,
            albedo_label(r.albedo),
            pct(r.simplified),
            pct_opt(r.paper_simplified),
            pct(r.refined),
            pct_opt(r.paper_refined)
        );
    }
    s
}

fn table2_text(rows: &[Table2Row]) -> String {
    let mut s = String::from("003 Table 2 (g = 0): SPP vs the full model by thickness (σt = 1)\n");
    s += TABLE_NOTE;
    s += "The paper prints one value per cell; it matches the simplified model's error.\n";
    let _ = writeln!(s, "      w  albedo    S. ours  paper    R. ours");
    for r in rows {
        let w = if r.thickness.is_infinite() {
            "inf".to_string()
        } else {
            format!("{}", r.thickness)
        };
        let _ = writeln!(
            s,
            "  {:>5}  {:>6}    {}  {}      {}",
            w,
            albedo_label(r.albedo),
            pct(r.simplified),
            pct_opt(r.paper_simplified),
            pct(r.refined)
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thickness_accepts_numbers_and_infinity_and_rejects_junk() {
        assert_eq!(parse_thickness("2.5").unwrap(), 2.5);
        assert!(parse_thickness("inf").unwrap().is_infinite());
        assert!(parse_thickness("thick").is_err());
    }

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
