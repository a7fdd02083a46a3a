//! A budget for people: per band the fractions with their standard errors, fAPAR over the
//! PAR bands, what the stand was; as a text table or JSON.

use crate::lattice::LbRun;
use crate::photons::{BandBudget, SunAngles};
use crate::stand::Stand;
use crate::Band;
use serde::Serialize;

/// The result of `sylva budget`.
#[derive(Debug, Clone, Serialize)]
pub struct Budget {
    pub stand: String,
    pub method: &'static str,
    pub sun: SunAngles,
    pub cyclic: bool,
    pub plot_m: [f64; 2],
    /// Leaf area of the stand over the plot's area, and the crowns' cover (crown stands).
    pub lai: f64,
    pub cover: Option<f64>,
    pub crowns: usize,
    pub triangles: usize,
    /// The Monte Carlo budget per band (none when only the lattice ran).
    pub bands: Vec<BandBudget>,
    /// The lattice-Boltzmann budget, when asked for.
    pub lattice: Option<LbRun>,
    /// Canopy absorption over the PAR bands, weighted by their `weight` (the Monte Carlo's
    /// where it ran, else the lattice's); none without PAR bands.
    pub fapar: Option<f64>,
    pub build_seconds: f64,
    pub seconds: f64,
}

impl Budget {
    /// The budget of `stand` from the Monte Carlo's `bands` (may be empty) and the lattice's
    /// run (if any).
    pub fn new(
        stand: &Stand,
        sun: SunAngles,
        bands: Vec<BandBudget>,
        lattice: Option<LbRun>,
        build_seconds: f64,
    ) -> Budget {
        let absorbed: Vec<f64> = if bands.is_empty() {
            lattice
                .iter()
                .flat_map(|l| l.bands.iter().map(|b| b.canopy_absorbed))
                .collect()
        } else {
            bands.iter().map(|b| b.canopy_absorbed.value).collect()
        };
        let fapar = fapar(&stand.bands, &absorbed);
        let method = match (bands.is_empty(), lattice.is_some()) {
            (false, false) => "monte-carlo",
            (true, _) => "lattice-boltzmann",
            (false, true) => "both",
        };
        Budget {
            stand: stand.name.clone(),
            method,
            sun,
            cyclic: stand.cyclic,
            plot_m: stand.half.map(|h| 2.0 * h),
            lai: stand.lai,
            cover: stand.cover,
            crowns: stand.crowns,
            triangles: stand.triangles(),
            seconds: bands.iter().map(|b| b.seconds).sum::<f64>()
                + lattice
                    .iter()
                    .flat_map(|l| l.bands.iter().map(|b| b.seconds))
                    .sum::<f64>(),
            bands,
            lattice,
            fapar,
            build_seconds,
        }
    }
}

/// Weighted mean canopy absorption of the PAR bands.
pub fn fapar(bands: &[Band], canopy_absorbed: &[f64]) -> Option<f64> {
    let (mut sum, mut weight) = (0.0, 0.0);
    for (b, a) in bands.iter().zip(canopy_absorbed) {
        if b.par {
            sum += b.weight * a;
            weight += b.weight;
        }
    }
    (weight > 0.0).then(|| sum / weight)
}

pub fn budget_json(b: &Budget) -> String {
    serde_json::to_string_pretty(b).expect("a budget serialises")
}

pub fn budget_text(b: &Budget) -> String {
    let mut s = format!(
        "{}: {} plot {} m × {} m, LAI {:.3}{}, {} triangles; sun zenith {}°, azimuth {}°\n",
        b.stand,
        if b.cyclic { "cyclic" } else { "isolated" },
        b.plot_m[0],
        b.plot_m[1],
        b.lai,
        match b.cover {
            Some(c) => format!(", {} crowns covering {:.3}", b.crowns, c),
            None => String::new(),
        },
        b.triangles,
        b.sun.zenith_deg,
        b.sun.azimuth_deg,
    );
    if !b.bands.is_empty() {
        s += "Fractions of the incoming sunlight (Monte Carlo, ± one standard error):\n";
        s += "| band | canopy absorbed | reflected (albedo) | to the ground | of it direct | soil absorbed | lost sideways | photons |\n";
        s += "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n";
        for r in &b.bands {
            let f = |x: &crate::photons::Fraction| format!("{:.4} ± {:.4}", x.value, x.std_error);
            s += &format!(
                "| {} | {} | {} | {} | {} | {} | {} | {} |\n",
                r.band,
                f(&r.canopy_absorbed),
                f(&r.reflected),
                f(&r.ground_arrived),
                f(&r.ground_direct),
                f(&r.soil_absorbed),
                f(&r.side_lost),
                r.photons
            );
        }
    }
    if let Some(l) = &b.lattice {
        s += &lattice_text(l, &b.bands);
    }
    if b.bands.iter().any(|r| !r.brf.is_empty()) {
        s += "BRF towards each view (zenith°:azimuth°, ± one standard error):\n| band |";
        for v in &b.bands[0].brf {
            s += &format!(" {}:{} |", v.view.zenith_deg, v.view.azimuth_deg);
        }
        s += "\n| --- |";
        s += &" ---: |".repeat(b.bands[0].brf.len());
        s += "\n";
        for r in &b.bands {
            s += &format!("| {} |", r.band);
            for v in &r.brf {
                s += &format!(" {:.4} ± {:.4} |", v.brf.value, v.brf.std_error);
            }
            s += "\n";
        }
    }
    if let Some(f) = b.fapar {
        s += &format!("fAPAR {f:.4}\n");
    }
    let unfinished: f64 = b.bands.iter().map(|r| r.unfinished.value).sum();
    if unfinished > 0.0 {
        s +=
            &format!("{unfinished:.2e} of the photons were still bouncing after the event limit\n");
    }
    s += &format!(
        "stand built in {:.2} s, {} in {:.2} s\n",
        b.build_seconds,
        match b.method {
            "monte-carlo" => "photons traced",
            "lattice-boltzmann" => "the lattice solved",
            _ => "photons traced and the lattice solved",
        },
        b.seconds
    );
    s
}

/// The lattice's table and, beside a Monte Carlo run, the differences to it.
fn lattice_text(l: &LbRun, mc: &[BandBudget]) -> String {
    let mut s = format!(
        "Fractions of the incoming sunlight (lattice-Boltzmann, cells of {:.3} m, {}×{}×{}, LAI {:.3} as binned):\n",
        l.cell_m, l.grid[0], l.grid[1], l.grid[2], l.lai
    );
    s += "| band | canopy absorbed | reflected (albedo) | to the ground | of it direct | soil absorbed | balance | LB steps | seconds |\n";
    s += "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n";
    for r in &l.bands {
        s += &format!(
            "| {} | {:.4} | {:.4} | {:.4} | {:.4} | {:.4} | {:.1e} | {}{} | {:.1} |\n",
            r.band,
            r.canopy_absorbed,
            r.reflected,
            r.ground_arrived,
            r.ground_direct,
            r.soil_absorbed,
            r.balance,
            r.steps,
            if r.converged { "" } else { " (not converged)" },
            r.seconds
        );
    }
    if mc.len() == l.bands.len() {
        s += "Lattice − Monte Carlo:\n| band | canopy absorbed | reflected | to the ground | soil absorbed | largest |\n| --- | ---: | ---: | ---: | ---: | ---: |\n";
        for (r, m) in l.bands.iter().zip(mc) {
            let d = [
                r.canopy_absorbed - m.canopy_absorbed.value,
                r.reflected - m.reflected.value,
                r.ground_arrived - m.ground_arrived.value,
                r.soil_absorbed - m.soil_absorbed.value,
            ];
            let largest = d.iter().fold(0.0f64, |a, v| a.max(v.abs()));
            s += &format!(
                "| {} | {:+.4} | {:+.4} | {:+.4} | {:+.4} | {:.4} |\n",
                r.band, d[0], d[1], d[2], d[3], largest
            );
        }
    }
    s
}
