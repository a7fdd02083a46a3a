//! A budget for people: per band the fractions with their standard errors, fAPAR over the
//! PAR bands, what the stand was; as a text table or JSON.

use crate::photons::{BandBudget, SunAngles};
use crate::stand::Stand;
use crate::{Band, CanopySpec};
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
    pub bands: Vec<BandBudget>,
    /// Canopy absorption over the PAR bands, weighted by their `weight`; none without PAR
    /// bands.
    pub fapar: Option<f64>,
    pub build_seconds: f64,
    pub seconds: f64,
}

impl Budget {
    pub fn new(
        spec: &CanopySpec,
        stand: &Stand,
        sun: SunAngles,
        bands: Vec<BandBudget>,
        build_seconds: f64,
    ) -> Budget {
        let fapar = fapar(&spec.bands, &bands);
        Budget {
            stand: spec.name.clone(),
            method: "monte-carlo",
            sun,
            cyclic: spec.plot.cyclic,
            plot_m: spec.plot.size,
            lai: stand.lai,
            cover: stand.cover,
            crowns: if spec.crowns.is_some() {
                stand.placed
            } else {
                0
            },
            triangles: stand.triangles(),
            seconds: bands.iter().map(|b| b.seconds).sum(),
            bands,
            fapar,
            build_seconds,
        }
    }
}

/// Weighted mean canopy absorption of the PAR bands.
pub fn fapar(bands: &[Band], budgets: &[BandBudget]) -> Option<f64> {
    let (mut sum, mut weight) = (0.0, 0.0);
    for (b, r) in bands.iter().zip(budgets) {
        if b.par {
            sum += b.weight * r.canopy_absorbed.value;
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
        "{}: {} plot {} m × {} m, LAI {:.3}{}, {} leaf triangles; sun zenith {}°, azimuth {}°\n",
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
        "stand built in {:.2} s, photons traced in {:.2} s\n",
        b.build_seconds, b.seconds
    );
    s
}
