//! What the light's long stages report ([`LightEvent`], one per [`crate::Progress`] report),
//! as the lines a front end shows: a model's LB light from the cache or solved, its base
//! solutions, the global grid, the neighbours' shade; and the warnings of a bad cache entry
//! recomputed or an entry that could not be written.

use sylva_geom::Model;

use crate::lighting::{LightingReport, LightingSource};
use crate::relight::{BasisReport, GlobalReport};

/// One report of the light's preparation.
pub enum LightEvent<'a> {
    /// A model's LB light for the sun, or a medium's (its sun and its sky solves), by name.
    Lit(&'a str, &'a LightingReport),
    /// A model's base solutions.
    Basis(&'a Model, &'a BasisReport),
    /// The coarse global grid.
    Global(&'a GlobalReport),
    /// A model's neighbours' foliage added to its density in a forest: (model, own optical
    /// depth, added).
    Shade(&'a str, f64, f64),
    /// A model's cached density voxelized again or not kept: (model, why).
    Density(&'a str, &'a str),
    /// A forest's cached neighbours' foliage measured again or not kept: why.
    Shades(&'a str),
    /// The models' kd-trees: (read from the cache, built, why an entry was not used or kept).
    KdTrees(usize, usize, &'a [String]),
}

/// The warnings of an entry: a bad one recomputed, and one that could not be written (a
/// read-only cache: the result is good, only not kept).
fn warnings(source: &LightingSource, cache_warning: &Option<String>) -> Option<String> {
    let lines: Vec<String> = [
        match source {
            LightingSource::Recomputed { reason } => Some(format!("warning: {reason}; recomputed")),
            _ => None,
        },
        cache_warning.as_ref().map(|w| format!("warning: {w}")),
    ]
    .into_iter()
    .flatten()
    .collect();
    (!lines.is_empty()).then(|| lines.join("\n"))
}

impl LightEvent<'_> {
    /// The event's warnings, one per line (`None`: nothing went wrong).
    pub fn warning(&self) -> Option<String> {
        match self {
            LightEvent::Lit(_, r) => warnings(&r.source, &r.cache_warning),
            LightEvent::Basis(_, r) => warnings(&r.source, &r.cache_warning),
            LightEvent::Global(r) => warnings(&r.source, &r.cache_warning),
            LightEvent::Shade(..) => None,
            LightEvent::Density(_, why) => Some(format!("warning: {why}")),
            LightEvent::Shades(why) => Some(format!("warning: {why}")),
            LightEvent::KdTrees(_, _, why) if !why.is_empty() => Some(
                why.iter()
                    .map(|w| format!("warning: {w}"))
                    .collect::<Vec<_>>()
                    .join("\n"),
            ),
            LightEvent::KdTrees(..) => None,
        }
    }

    /// The event's line.
    pub fn line(&self) -> String {
        match self {
            LightEvent::Lit(name, report) => match &report.source {
                LightingSource::Cached => format!(
                    "  LB {}: {} grid from cache ({:.2} s)",
                    name, report.dims, report.seconds
                ),
                LightingSource::Computed => format!(
                    "  LB {}: {} grid solved in {:.1} s{}",
                    name,
                    report.dims,
                    report.seconds,
                    report
                        .path
                        .as_ref()
                        .filter(|_| report.cache_warning.is_none())
                        .map(|p| format!(", cached as {}", p.display()))
                        .unwrap_or_default()
                ),
                LightingSource::Recomputed { .. } => format!(
                    "  LB {}: {} grid solved again in {:.1} s",
                    name, report.dims, report.seconds
                ),
            },
            LightEvent::Basis(model, report) => {
                let how = match &report.source {
                    LightingSource::Cached => format!("from cache ({:.2} s)", report.seconds),
                    LightingSource::Computed => format!("solved in {:.1} s", report.seconds),
                    LightingSource::Recomputed { .. } => {
                        format!("solved again in {:.1} s", report.seconds)
                    }
                };
                format!(
                    "  basis {}: {} grid {how}{}; {} → {} ({:.1}×){}",
                    model.name,
                    report.dims,
                    report
                        .solve_seconds
                        .map(|s| format!(", 54 solves {s:.1} s"))
                        .unwrap_or_default(),
                    sylva_core::format_bytes(report.raw_bytes),
                    sylva_core::format_bytes(report.compressed_bytes),
                    report.raw_bytes as f64 / report.compressed_bytes.max(1) as f64,
                    match (&report.source, &report.path, &report.cache_warning) {
                        (LightingSource::Cached, _, _) | (_, None, _) | (_, _, Some(_)) => {
                            String::new()
                        }
                        (_, Some(p), None) => format!(", cached as {}", p.display()),
                    }
                )
            }
            LightEvent::Global(report) => {
                let how = match &report.source {
                    LightingSource::Cached => "from cache",
                    LightingSource::Computed => "solved",
                    LightingSource::Recomputed { .. } => "solved again",
                };
                format!(
                    "  {}: {} {how} in {:.2} s",
                    report.what, report.dims, report.seconds
                )
            }
            LightEvent::Shade(name, own, added) => format!(
                "  {name}: neighbours' foliage inside its boxes adds {:.0} % to its optical depth",
                100.0 * added / own.max(1e-12)
            ),
            LightEvent::Density(name, _) => format!("  {name}: density voxelized"),
            LightEvent::Shades(_) => "  the neighbours' foliage measured".to_string(),
            LightEvent::KdTrees(cached, built, _) => {
                format!("  kd-trees: {cached} from cache, {built} built")
            }
        }
    }
}
