//! What `sylva lb solve` reports of one lighting grid solved for one sun ([`SolvedGrid`]): a
//! line per colour (its parameters, steps, stop, residual and speed) and the metadata the
//! grid file records.

use std::fmt;
use std::path::{Path, PathBuf};

use sylva_core::{OutputSet, Sun};

use crate::params::{MediumParams, COLOUR_NAMES};
use crate::preview::lighting_preview_png;
use crate::{DensityGrid, Dims, Element, GridFile, LightingGrid, SolveReport};

/// The line before a solve: the medium `name`, its grid and occupancy, the preset and the
/// sun.
pub fn lighting_line(name: &str, grid: &DensityGrid, preset: &str, sun: &Sun) -> String {
    let (mean, occupied) = grid.occupancy();
    format!(
        "lighting {name}: {} grid, {occupied} occupied sites (mean density {mean:.4}), preset {preset}, sun elevation {:.1}° azimuth {:.1}°",
        grid.dims,
        sun.elevation_deg(),
        sun.azimuth_deg()
    )
}

/// Why a solved grid or its preview could not be written.
#[derive(Debug, thiserror::Error)]
pub enum WriteError {
    #[error(transparent)]
    Output(#[from] sylva_core::OutputError),
    #[error("cannot encode the preview {}", path.display())]
    Preview {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

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

/// Writes `file` to `output` and `preview` (a PNG, or why it could not be encoded) to `png`
/// through `outputs` (replaced when the set is committed).
pub fn write_with_preview(
    file: &GridFile,
    preview: std::io::Result<Vec<u8>>,
    outputs: &mut OutputSet,
    output: &Path,
    png: &Path,
) -> Result<(), WriteError> {
    file.write_into(outputs, output)?;
    let preview = preview.map_err(|source| WriteError::Preview {
        path: png.to_path_buf(),
        source,
    })?;
    outputs.write_bytes(png, &preview)?;
    Ok(())
}

impl SolvedGrid<'_> {
    /// Writes `lighting` (stored as `element`, with [`SolvedGrid::metadata`]) to `output` and
    /// its preview PNG to `png`, through `outputs` (replaced when the set is committed).
    pub fn write(
        &self,
        lighting: &LightingGrid,
        element: Element,
        outputs: &mut OutputSet,
        output: &Path,
        png: &Path,
    ) -> Result<(), WriteError> {
        let file = GridFile::from_lighting(lighting, element, self.metadata());
        write_with_preview(&file, lighting_preview_png(lighting), outputs, output, png)
    }

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::Preset;
    use crate::StopReason;

    /// The metadata gives back the sun it was solved for and each colour's steps; the text
    /// has a line per colour.
    #[test]
    fn metadata_records_the_sun_and_the_steps() {
        let sun = Sun::from_angles(30.0, 100.0).unwrap();
        let medium = Preset::Leaf.params();
        let report = |steps| SolveReport {
            steps,
            stop: StopReason::StepLimit,
            residual: 1e-3,
            seconds: 0.5,
        };
        let reports = [report(10), report(12), report(14)];
        let solved = SolvedGrid {
            source: "sphere",
            preset: "leaf",
            medium: &medium,
            sun: &sun,
            dims: Dims::cube(8).unwrap(),
            reports: &reports,
        };
        let meta = solved.metadata();
        let get = |k: &str| meta.iter().find(|(key, _)| key == k).unwrap().1.clone();
        assert_eq!(get("steps"), "10,12,14");
        let to_sun: Vec<f64> = get("sun_to")
            .split(',')
            .map(|v| v.parse().unwrap())
            .collect();
        let d = sun.to_sun();
        for (a, b) in to_sun.iter().zip([d.x, d.y, d.z]) {
            assert!((a - b).abs() < 1e-6);
        }
        let text = solved.to_string();
        assert_eq!(text.lines().count(), 3);
        assert!(text.lines().nth(1).unwrap().contains("green") && text.contains("12 steps"));
    }
}
