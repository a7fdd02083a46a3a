//! Where 003 Tables 1 and 2 differ from ours: the pooling of the paper's own cells into its
//! "total" rows, and Table 2 (g = 0) under other readings of "averaged over a number of
//! directions and depth values" (depth range, depths relative to the thickness, the mean of
//! per-sample RMS values instead of the RMS of all samples).
//!
//! `cargo run --release -p sylva-spp --example tables_study`

use std::f64::consts::PI;
use sylva_spp::phase::fraction_into_lower_hemisphere;
use sylva_spp::tables::{ALBEDOS, PAPER_TABLE1, PAPER_TABLE2, TABLE2_THICKNESS};
use sylva_spp::{Direction, FullModel, Slab, SppModel};

/// Sphere-averaged squared errors (simplified, refined) of SPP against the full model at each
/// (incidence, depth), per unit incident flux, on the full model's quadrature.
fn samples(albedo: f64, g: f64, w: f64, depths: &[f64]) -> Vec<(f64, f64)> {
    let azimuths = 32;
    let mut out = Vec::new();
    for deg in [0.0, 15.0, 30.0, 45.0, 60.0] {
        let slab = Slab::with_incidence_deg(1.0, albedo, g, w, deg).unwrap();
        let full = FullModel::new(slab).unwrap();
        let spp = SppModel::new(slab).unwrap();
        let (mu, weight) = full.nodes();
        for &z in depths {
            let field = full.node_field(z).unwrap();
            let (down_t, up_t) = spp.hemispheric_totals(z).unwrap();
            let (mut ss, mut sr) = (0.0, 0.0);
            for (i, (&m, &wi)) in mu.iter().zip(weight).enumerate() {
                for down in [true, false] {
                    let cos = if down { m } else { -m };
                    let frac = fraction_into_lower_hemisphere(g, cos);
                    let simplified = if down { down_t } else { up_t } / (2.0 * PI);
                    let parts = spp.refined_parts(z, cos).unwrap();
                    for k in 0..azimuths {
                        let phi = 2.0 * PI * k as f64 / azimuths as f64;
                        let reference = field.radiance(i, down, phi);
                        let refined =
                            spp.refined_from_parts(parts, Direction { mu: cos, phi }, frac);
                        let dw = wi * 2.0 * PI / azimuths as f64 / (4.0 * PI);
                        ss += dw * (simplified - reference).powi(2);
                        sr += dw * (refined - reference).powi(2);
                    }
                }
            }
            out.push((ss, sr));
        }
    }
    out
}

fn rms(s: &[(f64, f64)]) -> (f64, f64) {
    let n = s.len() as f64;
    (
        (s.iter().map(|x| x.0).sum::<f64>() / n).sqrt(),
        (s.iter().map(|x| x.1).sum::<f64>() / n).sqrt(),
    )
}

fn mean_of_rms(s: &[(f64, f64)]) -> (f64, f64) {
    let n = s.len() as f64;
    (
        s.iter().map(|x| x.0.sqrt()).sum::<f64>() / n,
        s.iter().map(|x| x.1.sqrt()).sum::<f64>() / n,
    )
}

/// A reading of the depth average: its name, the depths for a thickness, and whether the
/// per-sample RMS values are averaged (instead of the squared errors pooled).
type Reading = (&'static str, Box<dyn Fn(f64) -> Vec<f64>>, bool);

fn steps(from: f64, to: f64, step: f64) -> Vec<f64> {
    let n = ((to - from) / step + 1e-9).floor() as usize;
    (0..=n).map(|k| from + k as f64 * step).collect()
}

fn main() {
    println!("1. The paper's totals against its own cells (percent):");
    let pool = |cells: &[f64]| {
        let n = cells.len() as f64;
        (
            cells.iter().sum::<f64>() / n,
            (cells.iter().map(|c| c * c).sum::<f64>() / n).sqrt(),
        )
    };
    for (gi, g) in ["0", "0.5", "-0.5"].iter().enumerate() {
        for (k, name) in ["S.", "R."].iter().enumerate() {
            let cells: Vec<f64> = (0..5)
                .map(|a| {
                    100.0
                        * if k == 0 {
                            PAPER_TABLE1[gi][a].0
                        } else {
                            PAPER_TABLE1[gi][a].1
                        }
                })
                .collect();
            let printed = 100.0
                * if k == 0 {
                    PAPER_TABLE1[gi][5].0
                } else {
                    PAPER_TABLE1[gi][5].1
                };
            let (mean, rms) = pool(&cells);
            println!("  Table 1 g = {g:>4} {name}: printed total {printed:.1}, mean of cells {mean:.2}, RMS of cells {rms:.2}");
        }
    }
    for (wi, w) in TABLE2_THICKNESS.iter().enumerate() {
        let cells: Vec<f64> = (0..5).map(|a| 100.0 * PAPER_TABLE2[wi][a]).collect();
        let (mean, rms) = pool(&cells);
        println!(
            "  Table 2 w = {w:>4}: printed total {:.1}, mean of cells {mean:.2}, RMS of cells {rms:.2}",
            100.0 * PAPER_TABLE2[wi][5]
        );
    }

    println!(
        "\n2. Table 2 (g = 0, simplified model) under readings of the depth average (percent):"
    );
    let readings: [Reading; 5] = [
        (
            "ours: z = 0..min(w,10) step 0.5, RMS",
            Box::new(|w: f64| steps(0.0, w.min(10.0), 0.5)),
            false,
        ),
        (
            "z = 0..min(w,5) step 0.5, RMS",
            Box::new(|w: f64| steps(0.0, w.min(5.0), 0.5)),
            false,
        ),
        (
            "z = 0..min(w,16) step 0.5, RMS",
            Box::new(|w: f64| steps(0.0, w.min(16.0), 0.5)),
            false,
        ),
        (
            "z = 11 points over 0..w (0..10 for inf), RMS",
            Box::new(|w: f64| {
                let top = if w.is_finite() { w } else { 10.0 };
                steps(0.0, top, top / 10.0)
            }),
            false,
        ),
        (
            "ours, mean of per-(θ0, z) RMS",
            Box::new(|w: f64| steps(0.0, w.min(10.0), 0.5)),
            true,
        ),
    ];
    for (name, depths, mean) in &readings {
        println!("  {name}");
        for (wi, &w) in TABLE2_THICKNESS.iter().enumerate() {
            let mut row = Vec::new();
            let mut all = Vec::new();
            for &albedo in &ALBEDOS {
                let s = samples(albedo, 0.0, w, &depths(w));
                let (simplified, _) = if *mean { mean_of_rms(&s) } else { rms(&s) };
                row.push(format!("{:5.2}", 100.0 * simplified));
                all.extend(s);
            }
            let (total, _) = if *mean { mean_of_rms(&all) } else { rms(&all) };
            let paper: Vec<String> = (0..6)
                .map(|a| format!("{:4.1}", 100.0 * PAPER_TABLE2[wi][a]))
                .collect();
            println!(
                "    w {w:>4}: {}  total {:5.2}   (paper {})",
                row.join(" "),
                100.0 * total,
                paper.join(" ")
            );
        }
    }
}
