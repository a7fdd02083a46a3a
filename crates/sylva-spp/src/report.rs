//! `sylva spp slab|table1|table2`'s reports: a slab's fluxes and radiances from the full,
//! simplified and refined models (and Monte Carlo), and 003 Tables 1 and 2 as text.

use std::fmt::Write as _;

use serde::Serialize;

use crate::monte_carlo::{simulate, McConfig, McResult};
use crate::tables::{Table1Row, Table2Row};
use crate::trees::experiment::{self, TreeReport};
use crate::{Direction, FullModel, Slab, SppError, SppModel};

#[derive(Debug, Clone, Serialize)]
pub struct RadianceRow {
    pub depth: f64,
    pub polar_deg: f64,
    pub azimuth_deg: f64,
    pub mu: f64,
    pub full: f64,
    pub simplified: f64,
    pub refined: f64,
}

#[derive(Debug, Clone, Serialize)]
pub struct ConvergenceRow {
    pub streams: usize,
    pub reflectance: f64,
    pub diffuse_transmittance: f64,
}

#[derive(Debug, Clone, Serialize)]
/// The slab's fluxes and radiances under the full, simplified and refined models.
pub struct SlabReport {
    pub sigma_t: f64,
    pub albedo: f64,
    pub g: f64,
    #[serde(serialize_with = "thickness_json")]
    pub thickness: f64,
    pub incidence_deg: f64,
    pub streams: usize,
    pub reflectance_full: f64,
    pub reflectance_simplified: f64,
    pub diffuse_transmittance_full: f64,
    pub diffuse_transmittance_simplified: f64,
    pub direct_transmittance: f64,
    pub monte_carlo: Option<McResult>,
    pub convergence: Vec<ConvergenceRow>,
    pub radiance: Vec<RadianceRow>,
}

fn thickness_json<S: serde::Serializer>(w: &f64, s: S) -> Result<S::Ok, S::Error> {
    if w.is_infinite() {
        s.serialize_str("inf")
    } else {
        s.serialize_f64(*w)
    }
}

/// A slab query from the command line refused, with the flag or value named.
#[derive(Debug, thiserror::Error)]
pub enum QueryError {
    #[error("--thickness must be a number or \"inf\", got {text:?}")]
    Thickness {
        text: String,
        #[source]
        source: std::num::ParseFloatError,
    },
    #[error("polar angles must be in [0, 180] degrees, got {0}")]
    Polar(f64),
    #[error(
        "a horizontal direction (polar angle 90) never meets a face of the slab; pick another angle"
    )]
    Horizontal,
    #[error("azimuths must be finite, got {0}")]
    Azimuth(f64),
    #[error(transparent)]
    Spp(#[from] SppError),
}

/// `--thickness`: a length, or `inf` (also `infinity`, `∞`) for a half-space.
pub fn parse_thickness(text: &str) -> Result<f64, QueryError> {
    match text.trim().to_ascii_lowercase().as_str() {
        "inf" | "infinity" | "∞" => Ok(f64::INFINITY),
        other => other
            .parse::<f64>()
            .map_err(|source| QueryError::Thickness {
                text: text.to_string(),
                source,
            }),
    }
}

/// The reported directions: every polar angle (degrees from the inward normal, 0 to 180,
/// not 90) at every azimuth (degrees from the plane of incidence), as [`SlabQuery`] holds
/// them.
pub fn directions(
    polar_deg: &[f64],
    azimuths_deg: &[f64],
) -> Result<Vec<(f64, f64, Direction)>, QueryError> {
    let mut directions = Vec::new();
    for &polar in polar_deg {
        if !(0.0..=180.0).contains(&polar) {
            return Err(QueryError::Polar(polar));
        }
        if (polar - 90.0).abs() < 1e-6 {
            return Err(QueryError::Horizontal);
        }
        for &azimuth in azimuths_deg {
            if !azimuth.is_finite() {
                return Err(QueryError::Azimuth(azimuth));
            }
            let d = Direction::new(polar.to_radians().cos(), azimuth.to_radians())?;
            directions.push((polar, azimuth, d));
        }
    }
    Ok(directions)
}

/// What [`slab_report`] computes besides the fluxes.
#[derive(Debug, Clone)]
pub struct SlabQuery {
    /// Incidence angle of the light, degrees (reported as given).
    pub incidence_deg: f64,
    /// Discrete directions per hemisphere of the full model.
    pub streams: usize,
    /// Depths at which the radiance is reported.
    pub depths: Vec<f64>,
    /// Directions of the reported radiance: polar and azimuth degrees, and the direction.
    pub directions: Vec<(f64, f64, Direction)>,
    /// Monte Carlo photons, and their seed.
    pub photons: Option<u64>,
    pub seed: u64,
    /// Also the full model's fluxes for 2 to 64 directions per hemisphere.
    pub convergence: bool,
}

/// The report of `slab` (thickness `slab.thickness`, infinite for a half-space).
pub fn slab_report(slab: Slab, q: &SlabQuery) -> Result<SlabReport, SppError> {
    for &z in &q.depths {
        slab.check_depth(z)?;
    }
    let thickness = slab.thickness;
    let full = FullModel::with_streams(slab, q.streams)?;
    let spp = SppModel::new(slab)?;
    let mut radiance = Vec::new();
    for &z in &q.depths {
        for &(polar, azimuth, dir) in &q.directions {
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
    let monte_carlo = match q.photons {
        Some(n) => Some(simulate(&slab, &McConfig::new(n, q.seed))?),
        None => None,
    };
    let mut convergence = Vec::new();
    if q.convergence {
        for n in [2, 4, 8, 16, 32, 64] {
            let m = FullModel::with_streams(slab, n)?;
            convergence.push(ConvergenceRow {
                streams: n,
                reflectance: m.reflectance(),
                diffuse_transmittance: m.diffuse_transmittance(),
            });
        }
    }
    Ok(SlabReport {
        sigma_t: slab.sigma_t,
        albedo: slab.albedo,
        g: slab.g,
        thickness,
        incidence_deg: q.incidence_deg,
        streams: q.streams,
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
    })
}

/// The report as a text table.
pub fn slab_text(r: &SlabReport) -> String {
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

/// 003 Table 1 beside the paper's values, as text.
pub fn table1_text(rows: &[Table1Row]) -> String {
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

/// 003 Table 2 beside the paper's values, as text.
pub fn table2_text(rows: &[Table2Row]) -> String {
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

/// Photons of `spp trees` by default: ten per leaf mesh (a quad, two triangles) of the
/// scene's instances, at least two million.
pub fn default_photons(scene: &sylva_geom::Scene) -> u64 {
    let leaf_meshes: u64 = scene
        .instances
        .iter()
        .map(|i| {
            let m = &scene.models[i.model as usize];
            m.mesh
                .material_ids
                .iter()
                .filter(|&&id| {
                    m.materials
                        .get(id as usize)
                        .is_some_and(|mat| mat.is_leaf())
                })
                .count() as u64
                / 2
        })
        .sum();
    (10 * leaf_meshes).max(2_000_000)
}

fn pct1(x: f64) -> String {
    format!("{:6.1}", 100.0 * x)
}

/// `sylva spp trees`'s report as text; `categories`: with the table of depth-thickness bins.
pub fn tree_text(r: &TreeReport, categories: bool) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "003 Table 3 on scene {}: {} instance(s), {} prototype(s), albedo {}, light travelling ({:.3}, {:.3}, {:.3})",
        r.scene, r.instances, r.prototypes, r.albedo, r.light[0], r.light[1], r.light[2]
    );
    let _ = writeln!(
        s,
        "  leaf meshes {} ({} compared, {} met by no light ray); mean depth {:.2}, thickness {:.2} surfaces, |n·s0| {:.2}; {} light rays {:.3} apart; {} directions, {} grid cells",
        r.leaf_meshes, r.compared_meshes, r.unmet_meshes, r.mean_depth, r.mean_thickness, r.mean_cos_light, r.depth_rays, r.ray_spacing, r.sample_directions, r.grid_cells
    );
    let b = &r.balance;
    let _ = writeln!(
        s,
        "  Monte Carlo: {} photons (seed {}); escaped {:.4}, absorbed by leaves {:.4}, by wood {:.4}, unfinished {:.1e}; {:.2} leaf and {:.2} wood interactions per photon",
        b.photons, r.seed, b.escaped, b.absorbed_leaves, b.absorbed_wood, b.unfinished, b.leaf_hits_per_photon, b.wood_hits_per_photon
    );
    let e = &r.errors;
    let _ = writeln!(s, "eq. 30 RMS error against the Monte Carlo, percent:");
    let _ = writeln!(s, "             SPPG     SPP      SS      LB");
    let _ = writeln!(
        s,
        "  sylva     {}  {}  {}  {}",
        pct1(e.sppg),
        pct1(e.spp),
        pct1(e.ss),
        e.lb.map_or("     -".into(), pct)
    );
    if let Some(p) = &r.paper {
        let _ = writeln!(
            s,
            "  paper     {}  {}  {}       -   ({})",
            pct1(p.sppg),
            pct1(p.spp),
            pct1(p.ss),
            p.configuration
        );
    }
    let _ = writeln!(
        s,
        "  (Monte Carlo noise in these numbers: about {:.1} %; {} depth-thickness bins of >= {} meshes, {} meshes)",
        100.0 * e.mc_noise, r.categories_used, experiment::MIN_CATEGORY_MESHES, r.meshes_in_categories
    );
    let _ = writeln!(
        s,
        "  SPPG / SPP with eq. 19's totals read as radiance integrals (half the diffuse light): {} / {}",
        pct1(e.sppg_radiance_reading),
        pct1(e.spp_radiance_reading)
    );
    let m = &r.means;
    let _ = writeln!(
        s,
        "mean two-sided irradiance per unit beam irradiance (area-weighted): MC {:.4} (direct {:.4}), SPPG {:.4}, SPP {:.4}, SS {:.4}{}; mean G {:.3}",
        m.mc,
        m.mc_direct,
        m.sppg,
        m.spp,
        m.ss,
        m.lb.map_or(String::new(), |v| format!(", LB {v:.4}")),
        m.g
    );
    let t = &r.timings;
    let _ = writeln!(
        s,
        "seconds: kd-trees {:.2}, meshes {:.2}, eq. 29 counts {:.2}, maps {:.2} + grids {:.2} + light maps {:.2} + G {:.2} + sky {:.3}, photons {:.2}, LB {:.2}; total {:.2}",
        t.accel, t.meshes, t.depth_counts, t.system.sample_maps, t.system.grid_depths, t.system.light_maps, t.system.light_grid, t.system.sky, t.photons, t.lb, t.total
    );
    if categories {
        let _ = writeln!(
            s,
            "   d    w  meshes        MC    direct      SPPG       SPP        SS        LB      G"
        );
        for c in &r.categories {
            let _ = writeln!(
                s,
                "{:4} {:4} {:7} {:9.4} {:9.4} {:9.4} {:9.4} {:9.4} {:>9} {:6.3}",
                c.depth,
                c.thickness,
                c.meshes,
                c.mc,
                c.mc_direct,
                c.sppg,
                c.spp,
                c.ss,
                c.lb.map_or("-".into(), |v| format!("{v:.4}")),
                c.g
            );
        }
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

    /// Every polar angle at every azimuth, in order; 90°, out-of-range angles and
    /// non-finite azimuths refused.
    #[test]
    fn directions_cross_polar_angles_with_azimuths() {
        let d = directions(&[0.0, 120.0], &[0.0, 45.0]).unwrap();
        let angles: Vec<(f64, f64)> = d.iter().map(|&(p, a, _)| (p, a)).collect();
        assert_eq!(
            angles,
            [(0.0, 0.0), (0.0, 45.0), (120.0, 0.0), (120.0, 45.0)]
        );
        assert!((d[2].2.mu - 120f64.to_radians().cos()).abs() < 1e-12);
        assert!(matches!(
            directions(&[90.0], &[0.0]),
            Err(QueryError::Horizontal)
        ));
        assert!(matches!(
            directions(&[200.0], &[0.0]),
            Err(QueryError::Polar(_))
        ));
        assert!(matches!(
            directions(&[0.0], &[f64::NAN]),
            Err(QueryError::Azimuth(_))
        ));
    }

    #[test]
    fn slab_report_has_a_row_per_depth_and_direction_and_names_infinity() {
        let slab = Slab::with_incidence_deg(1.0, 0.9, 0.0, f64::INFINITY, 0.0).unwrap();
        let down = Direction::new(1.0, 0.0).unwrap();
        let up = Direction::new(-0.5, 0.0).unwrap();
        let q = SlabQuery {
            incidence_deg: 0.0,
            streams: 8,
            depths: vec![0.0, 1.0, 2.0],
            directions: vec![(0.0, 0.0, down), (120.0, 0.0, up)],
            photons: None,
            seed: 1,
            convergence: true,
        };
        let r = slab_report(slab, &q).unwrap();
        assert_eq!(r.radiance.len(), 6);
        assert_eq!(r.convergence.len(), 6);
        assert_eq!(
            r.direct_transmittance, 0.0,
            "a half-space lets no beam through"
        );
        assert!(r.reflectance_full > 0.0 && r.reflectance_full < 1.0);
        let json = serde_json::to_value(&r).unwrap();
        assert_eq!(json["thickness"], "inf");
        assert!(slab_text(&r).contains("thickness inf"));
        // A depth outside the slab is refused, not reported.
        let thin = Slab::with_incidence_deg(1.0, 0.9, 0.0, 1.0, 0.0).unwrap();
        assert!(slab_report(thin, &q).is_err());
    }
}
