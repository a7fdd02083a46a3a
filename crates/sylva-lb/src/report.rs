//! What `sylva lb solve` reports of one lighting grid solved for one sun ([`SolvedGrid`]): a
//! line per colour (its parameters, steps, stop, residual and speed) and the metadata the
//! grid file records.

use std::fmt;

use sylva_core::Sun;

use crate::params::{MediumParams, COLOUR_NAMES};
use crate::{Dims, SolveReport};

/// A grid solved for one sun, as `sylva lb solve` reports and records it.
pub struct SolvedGrid<'a> {
    /// The medium's name (a shape, file or model).
    pub source: &'a str,
    pub preset: &'a str,
    pub medium: &'a MediumParams,
    pub sun: &'a Sun,
    pub dims: Dims,
    /// Per colour (R, G, B).
    pub reports: &'a [SolveReport],
}

impl SolvedGrid<'_> {
    /// What the lighting grid file records: source, preset, sun, parameters and steps.
    pub fn metadata(&self) -> Vec<(String, String)> {
        let to_sun = self.sun.to_sun();
        vec![
            ("source".to_string(), self.source.to_string()),
            ("preset".to_string(), self.preset.to_string()),
            (
                "sun_to".to_string(),
                format!("{:.6},{:.6},{:.6}", to_sun.x, to_sun.y, to_sun.z),
            ),
            (
                "params".to_string(),
                self.medium
                    .colours
                    .iter()
                    .map(|c| format!("{}/{}/{}", c.sigma_a, c.sigma_s, c.g))
                    .collect::<Vec<_>>()
                    .join(" "),
            ),
            (
                "steps".to_string(),
                self.reports
                    .iter()
                    .map(|r| r.steps.to_string())
                    .collect::<Vec<_>>()
                    .join(","),
            ),
        ]
    }
}

impl fmt::Display for SolvedGrid<'_> {
    fn fmt(&self, o: &mut fmt::Formatter<'_>) -> fmt::Result {
        for ((r, p), name) in self
            .reports
            .iter()
            .zip(&self.medium.colours)
            .zip(COLOUR_NAMES)
        {
            writeln!(
                o,
                "  {:>5}: σ_a {:.3} σ_s {:.3} g {:+.3}: {} steps, stop: {}, final residual {:.2e}, {:.2} s, {:.0} MLUPS",
                name,
                p.sigma_a,
                p.sigma_s,
                p.g,
                r.steps,
                r.stop,
                r.residual,
                r.seconds,
                r.mlups(self.dims)
            )?;
        }
        Ok(())
    }
}
