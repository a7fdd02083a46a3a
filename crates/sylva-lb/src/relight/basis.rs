//! The base solutions of one density grid (004 §3.1, SPEC §3) and their combination.
//!
//! `B_j` (j = 1..18) is the steady state under the boundary `f_i = δ_ij`; `B_0` (ambient) under
//! `f_i = 1` for every i ≥ 1. All three colours each, with the medium's parameters.
//!
//! **`B_0` is summed, not solved** ([`Ambient::Sum`], the default): the update is linear in the
//! state (the collision, and the zeroing of `f_0` on green and brown sites, are both linear), the
//! shell holds fixed values and the interior starts at zero, so after any fixed number of steps
//! `B_0 = Σ_{j≥1} B_j` exactly; a solve would only add rounding (tested: within 1e-5 relative).
//! Summing saves 3 of the 57 solves. With a convergence stop (`SolveOptions::tolerance`) each
//! solve stops after its own number of steps and linearity holds only to the tolerance;
//! [`Ambient::Solve`] then solves `B_0` like the others.
//!
//! The driver [`solve_basis`] takes the single solve as a function with the signature of
//! [`crate::solve_lighting`] (which is the default, [`BasisSet::solve`]), so any backend that
//! lights a grid under one boundary can produce a basis set.

use std::path::Path;
use std::time::Instant;

use rayon::prelude::*;

use super::footprint::{Footprint, Placement};
use super::polyhedron::{exact_weights, face_hit};
use super::{RelightError, BASES, CHANNELS};
use crate::grid::{Bounds, DensityGrid, Dims, LightingGrid};
use crate::grid_file::{Element, GridFile, GridKind};
use crate::params::{ColourParams, MediumParams, COLOUR_NAMES};
use crate::solver::{solve_lighting, Boundary, SolveOptions, SolveReport};

/// Free-space value of `B_0` (18 unit boundary values stream through) and of each `B_j`.
pub const AMBIENT_FREE_SPACE: f64 = (BASES - 1) as f64;

/// How the ambient base solution `B_0` is obtained.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ambient {
    /// `B_0 = Σ_{j≥1} B_j` (exact by linearity for a fixed step count).
    Sum,
    /// Solved with its own boundary `f_i = 1`.
    Solve,
}

/// How a basis set is solved.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BasisOptions {
    /// Run length of each solve.
    pub solve: SolveOptions,
    pub ambient: Ambient,
}

impl BasisOptions {
    /// The papers' schedule (2 × the longest edge) for every solve, `B_0` summed.
    pub fn papers(dims: Dims) -> BasisOptions {
        BasisOptions {
            solve: SolveOptions::papers(dims),
            ambient: Ambient::Sum,
        }
    }
}

/// Where a basis solve is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BasisProgress {
    /// Solves finished before this one.
    pub done: usize,
    /// Solves in all (18, or 19 with [`Ambient::Solve`]).
    pub solves: usize,
    /// The base solution being solved.
    pub basis: usize,
    pub colour: usize,
    pub step: usize,
    pub max_steps: usize,
}

/// What the solve of one base solution did.
#[derive(Debug, Clone, PartialEq)]
pub struct BasisReport {
    pub basis: usize,
    /// Per colour, as the backend reported (colours with equal parameters repeat a report).
    pub colours: Vec<SolveReport>,
    /// Wall-clock seconds of the whole solve.
    pub seconds: f64,
}

/// The 19 base solutions of one density grid, three colours each.
#[derive(Debug, Clone, PartialEq)]
pub struct BasisSet {
    pub dims: Dims,
    pub bounds: Bounds,
    pub medium: MediumParams,
    pub options: BasisOptions,
    /// Channel `3 j + colour` holds `B_j` in that colour, site order as in [`LightingGrid`].
    channels: Vec<Vec<f32>>,
}

/// One independent piece of a basis solve: base solution `basis` in colour `colour`. A basis
/// set is [`BasisJob::all`] of them; each can run anywhere ([`solve_basis_jobs`], one at a
/// time or several of one basis in one call) and [`BasisAssembly`] collects the results, so
/// the precompute can be spread over processes or machines as a work queue.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct BasisJob {
    pub basis: usize,
    pub colour: usize,
}

impl BasisJob {
    /// The solves a basis set of `medium` needs under `options`, basis-major: `B_1..B_18`
    /// (then `B_0` with [`Ambient::Solve`]), each in every colour whose parameters differ from
    /// all earlier colours' (a repeated colour is copied by [`BasisAssembly::finish`]).
    pub fn all(medium: &MediumParams, options: &BasisOptions) -> Vec<BasisJob> {
        let colours: Vec<usize> = (0..3)
            .filter(|&c| (0..c).all(|p| medium.colours[p] != medium.colours[c]))
            .collect();
        solved_bases(options)
            .into_iter()
            .flat_map(|basis| {
                colours
                    .iter()
                    .map(move |&colour| BasisJob { basis, colour })
            })
            .collect()
    }
}

/// The bases that are solved (not summed), in solve order.
fn solved_bases(options: &BasisOptions) -> Vec<usize> {
    match options.ambient {
        Ambient::Sum => (1..BASES).collect(),
        Ambient::Solve => (1..BASES).chain([0]).collect(),
    }
}

/// Runs `jobs`, all of one base solution, in one call of `solve` (the signature of
/// [`solve_lighting`]): the medium handed to it holds the jobs' colours in their places and
/// repeats the first job's colour elsewhere, so a backend that solves equal colours once (the
/// CPU and GPU solvers do) solves exactly the jobs asked for. Returns per job its site values
/// and the backend's report. `progress(colour, step)` follows the solve.
pub fn solve_basis_jobs<S, E>(
    grid: &DensityGrid,
    medium: &MediumParams,
    options: &BasisOptions,
    jobs: &[BasisJob],
    mut solve: S,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Vec<(BasisJob, Vec<f32>, SolveReport)>, RelightError>
where
    S: FnMut(
        &DensityGrid,
        &MediumParams,
        Boundary,
        &SolveOptions,
        &mut dyn FnMut(usize, usize, f64),
    ) -> Result<(LightingGrid, Vec<SolveReport>), E>,
    E: Into<Box<dyn std::error::Error + Send + Sync>>,
{
    medium.validate()?;
    let Some(first) = jobs.first() else {
        return Err(RelightError::Mismatch("no basis jobs to run".into()));
    };
    let j = first.basis;
    for (k, job) in jobs.iter().enumerate() {
        if job.basis >= BASES || job.colour >= 3 {
            return Err(RelightError::Mismatch(format!(
                "basis job (B_{}, colour {}) is out of range",
                job.basis, job.colour
            )));
        }
        if job.basis != j {
            return Err(RelightError::Mismatch(format!(
                "one call solves one base solution: B_{j} and B_{} asked for",
                job.basis
            )));
        }
        if jobs[..k].iter().any(|o| o.colour == job.colour) {
            return Err(RelightError::Mismatch(format!(
                "basis job (B_{j}, colour {}) asked for twice",
                job.colour
            )));
        }
    }
    let mut call_medium = medium.clone();
    for c in 0..3 {
        if !jobs.iter().any(|job| job.colour == c) {
            call_medium.colours[c] = medium.colours[first.colour];
        }
    }
    let (light, reports) = solve(
        grid,
        &call_medium,
        Boundary::basis(j),
        &options.solve,
        &mut |colour, step, _residual| progress(colour, step),
    )
    .map_err(|e| RelightError::Solve {
        basis: j,
        source: e.into(),
    })?;
    check_result(j, grid.dims, &light)?;
    let mut colours = light.colours.map(Some);
    jobs.iter()
        .map(|job| {
            let values = colours[job.colour].take().expect("each colour once");
            let report =
                reports
                    .get(job.colour)
                    .cloned()
                    .ok_or_else(|| RelightError::SolverResult {
                        basis: j,
                        what: format!("{} reports for 3 colours", reports.len()),
                    })?;
            Ok((*job, values, report))
        })
        .collect()
}

/// Collects the results of basis jobs (in any order, from anywhere) into a [`BasisSet`].
#[derive(Debug, Clone)]
pub struct BasisAssembly {
    dims: Dims,
    bounds: Bounds,
    medium: MediumParams,
    options: BasisOptions,
    /// Channel `3 j + colour`; empty until its job arrives.
    channels: Vec<Vec<f32>>,
}

impl BasisAssembly {
    /// An empty set for a grid of `dims` over `bounds` (its memory is checked here).
    pub fn new(
        dims: Dims,
        bounds: Bounds,
        medium: &MediumParams,
        options: &BasisOptions,
    ) -> Result<BasisAssembly, RelightError> {
        medium.validate()?;
        sylva_core::check_memory(
            &format!("a relighting basis set on a {dims} grid (57 channels)"),
            BasisSet::memory_needed(dims),
        )?;
        Ok(BasisAssembly {
            dims,
            bounds,
            medium: medium.clone(),
            options: *options,
            channels: vec![Vec::new(); CHANNELS],
        })
    }

    /// The jobs whose results are still missing.
    pub fn missing(&self) -> Vec<BasisJob> {
        BasisJob::all(&self.medium, &self.options)
            .into_iter()
            .filter(|j| self.channels[3 * j.basis + j.colour].is_empty())
            .collect()
    }

    /// Stores one job's result: one value per site, all finite.
    pub fn insert(&mut self, job: BasisJob, values: Vec<f32>) -> Result<(), RelightError> {
        if !BasisJob::all(&self.medium, &self.options).contains(&job) {
            return Err(RelightError::Mismatch(format!(
                "(B_{}, colour {}) is not a job of this basis set",
                job.basis, job.colour
            )));
        }
        let bad = |what: String| {
            Err(RelightError::SolverResult {
                basis: job.basis,
                what,
            })
        };
        if values.len() != self.dims.sites() {
            return bad(format!(
                "{} {} values for {} sites",
                values.len(),
                COLOUR_NAMES[job.colour],
                self.dims.sites()
            ));
        }
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            let (x, y, z) = self.dims.coords(i);
            return bad(format!(
                "{} {} at site ({x}, {y}, {z})",
                values[i], COLOUR_NAMES[job.colour]
            ));
        }
        self.channels[3 * job.basis + job.colour] = values;
        Ok(())
    }

    /// The basis set: repeated colours copied, `B_0` summed when [`Ambient::Sum`]. Every job
    /// must have arrived.
    pub fn finish(self) -> Result<BasisSet, RelightError> {
        let missing = self.missing();
        if let Some(j) = missing.first() {
            return Err(RelightError::Mismatch(format!(
                "{} basis jobs have no result yet, the first (B_{}, colour {})",
                missing.len(),
                j.basis,
                j.colour
            )));
        }
        let mut channels = self.channels;
        for j in solved_bases(&self.options) {
            for c in 0..3 {
                if let Some(p) = (0..c).find(|&p| self.medium.colours[p] == self.medium.colours[c])
                {
                    channels[3 * j + c] = channels[3 * j + p].clone();
                }
            }
        }
        if self.options.ambient == Ambient::Sum {
            let all: Vec<(usize, f64)> = (1..BASES).map(|j| (j, 1.0)).collect();
            for c in 0..3 {
                channels[c] = combine(&channels, &all, c, self.dims.sites());
            }
        }
        Ok(BasisSet {
            dims: self.dims,
            bounds: self.bounds,
            medium: self.medium,
            options: self.options,
            channels,
        })
    }
}

/// Solves the basis set of `grid` with `solve`, one boundary at a time (all colours of a
/// basis in one call, [`solve_basis_jobs`]): `B_1..B_18`, then `B_0` as `options.ambient`
/// says. `solve` has the signature of [`solve_lighting`] (pass it, or a closure around
/// another backend); progress counts jobs ([`BasisJob::all`]).
pub fn solve_basis<S, E>(
    grid: &DensityGrid,
    medium: &MediumParams,
    options: &BasisOptions,
    mut solve: S,
    progress: &mut dyn FnMut(BasisProgress),
) -> Result<(BasisSet, Vec<BasisReport>), RelightError>
where
    S: FnMut(
        &DensityGrid,
        &MediumParams,
        Boundary,
        &SolveOptions,
        &mut dyn FnMut(usize, usize, f64),
    ) -> Result<(LightingGrid, Vec<SolveReport>), E>,
    E: Into<Box<dyn std::error::Error + Send + Sync>>,
{
    let mut assembly = BasisAssembly::new(grid.dims, grid.bounds, medium, options)?;
    let jobs = BasisJob::all(medium, options);
    let max_steps = options.solve.max_steps;
    let mut reports = Vec::new();
    let mut done = 0;
    for j in solved_bases(options) {
        let group: Vec<BasisJob> = jobs.iter().filter(|b| b.basis == j).copied().collect();
        let start = Instant::now();
        let results = solve_basis_jobs(
            grid,
            medium,
            options,
            &group,
            &mut solve,
            &mut |colour, step| {
                let k = group.iter().position(|b| b.colour == colour).unwrap_or(0);
                progress(BasisProgress {
                    done: done + k,
                    solves: jobs.len(),
                    basis: j,
                    colour,
                    step,
                    max_steps,
                })
            },
        )?;
        done += group.len();
        let mut by_colour: Vec<Option<SolveReport>> = vec![None; 3];
        for (job, values, report) in results {
            by_colour[job.colour] = Some(report);
            assembly.insert(job, values)?;
        }
        let colours = (0..3)
            .map(|c| {
                let p = (0..=c)
                    .find(|&p| medium.colours[p] == medium.colours[c])
                    .unwrap_or(c);
                by_colour[p].expect("the first of equal colours is a job")
            })
            .collect();
        reports.push(BasisReport {
            basis: j,
            colours,
            seconds: start.elapsed().as_secs_f64(),
        });
    }
    Ok((assembly.finish()?, reports))
}

/// A backend's result must be a finite lighting grid of the right size.
fn check_result(basis: usize, dims: Dims, light: &LightingGrid) -> Result<(), RelightError> {
    let bad = |what: String| Err(RelightError::SolverResult { basis, what });
    if light.dims != dims {
        return bad(format!("a {} grid for a {dims} medium", light.dims));
    }
    for (c, values) in light.colours.iter().enumerate() {
        if values.len() != dims.sites() {
            return bad(format!(
                "{} {} values for {} sites",
                values.len(),
                COLOUR_NAMES[c],
                dims.sites()
            ));
        }
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            let (x, y, z) = dims.coords(i);
            return bad(format!(
                "{} {} at site ({x}, {y}, {z})",
                values[i], COLOUR_NAMES[c]
            ));
        }
    }
    Ok(())
}

/// `Σ_terms w_j B_j` in colour `c` at every site, accumulated in f64 per site in term order
/// (so the result does not depend on the thread count).
fn combine(channels: &[Vec<f32>], terms: &[(usize, f64)], c: usize, sites: usize) -> Vec<f32> {
    let mut out = vec![0.0f32; sites];
    out.par_chunks_mut(CHUNK)
        .enumerate()
        .for_each(|(k, chunk)| {
            let base = k * CHUNK;
            let mut acc = vec![0.0f64; chunk.len()];
            for &(j, w) in terms {
                let src = &channels[3 * j + c][base..base + chunk.len()];
                for (a, &v) in acc.iter_mut().zip(src) {
                    *a += w * v as f64;
                }
            }
            for (o, a) in chunk.iter_mut().zip(&acc) {
                *o = *a as f32;
            }
        });
    out
}

/// Sites per parallel work item of whole-grid passes.
const CHUNK: usize = 1 << 14;

impl BasisSet {
    /// Solves with the CPU solver ([`solve_lighting`]).
    pub fn solve(
        grid: &DensityGrid,
        medium: &MediumParams,
        options: &BasisOptions,
        progress: &mut dyn FnMut(BasisProgress),
    ) -> Result<(BasisSet, Vec<BasisReport>), RelightError> {
        solve_basis(grid, medium, options, solve_lighting, progress)
    }

    /// A basis set from its channels (`3 j + colour`); lengths and finiteness are checked.
    pub fn new(
        dims: Dims,
        bounds: Bounds,
        medium: MediumParams,
        options: BasisOptions,
        channels: Vec<Vec<f32>>,
    ) -> Result<BasisSet, RelightError> {
        medium.validate()?;
        if channels.len() != CHANNELS {
            return Err(RelightError::Mismatch(format!(
                "a basis set has {CHANNELS} channels, got {}",
                channels.len()
            )));
        }
        for (ch, values) in channels.iter().enumerate() {
            if values.len() != dims.sites() {
                return Err(RelightError::Mismatch(format!(
                    "channel {} has {} values, a {dims} grid needs {}",
                    super::CHANNEL_NAMES[ch],
                    values.len(),
                    dims.sites()
                )));
            }
            if let Some(i) = values.iter().position(|v| !v.is_finite()) {
                let (x, y, z) = dims.coords(i);
                return Err(RelightError::Mismatch(format!(
                    "channel {} is {} at site ({x}, {y}, {z})",
                    super::CHANNEL_NAMES[ch],
                    values[i]
                )));
            }
        }
        Ok(BasisSet {
            dims,
            bounds,
            medium,
            options,
            channels,
        })
    }

    /// Bytes the 57 channels take in memory.
    pub fn memory_needed(dims: Dims) -> u64 {
        (CHANNELS * dims.sites() * 4) as u64
    }

    /// `B_j` in colour `c`.
    pub fn channel(&self, j: usize, c: usize) -> &[f32] {
        &self.channels[3 * j + c]
    }

    /// All channels, `3 j + colour`.
    pub fn channels(&self) -> &[Vec<f32>] {
        &self.channels
    }

    /// `Σ_j w_j B_j` over the whole grid (accumulated in f64 per site, so the result does not
    /// depend on the thread count). With [`BasisWeights::exact`] this is the normalised
    /// lighting of a direct sun solve.
    pub fn relight(&self, weights: &BasisWeights) -> Result<LightingGrid, RelightError> {
        let sites = self.dims.sites();
        sylva_core::check_memory(
            &format!("relighting a {} grid", self.dims),
            (3 * sites * 4) as u64,
        )?;
        let terms: Vec<(usize, f64)> = weights.terms().collect();
        let colours = std::array::from_fn(|c| combine(&self.channels, &terms, c, sites));
        Ok(LightingGrid {
            dims: self.dims,
            bounds: self.bounds,
            colours,
        })
    }

    /// The combination `Σ_j w_j B_j` interpolated trilinearly at grid coordinates `g` (in
    /// sites; clamped to the grid): the uncompressed run-time lookup, four 3-D texture reads
    /// for a three-basis combination with ambient (004 §3.1).
    pub fn sample(&self, g: [f32; 3], weights: &BasisWeights) -> [f32; 3] {
        let fp = Footprint::at(self.dims, g);
        let (sites, tri) = (fp.sites(self.dims), fp.weights());
        let mut out = [0.0f32; 3];
        for (j, w) in weights.terms() {
            for (c, o) in out.iter_mut().enumerate() {
                let ch = &self.channels[3 * j + c];
                let v: f32 = (0..8).map(|k| tri[k] * ch[sites[k]]).sum();
                *o += w as f32 * v;
            }
        }
        out
    }

    /// Model space to grid coordinates for [`BasisSet::sample`].
    pub fn placement(&self) -> Placement {
        Placement::new(self.dims, self.bounds)
    }

    /// The grid file of this set (kind [`GridKind::Basis`]), with the medium and the solve
    /// schedule in its metadata.
    pub fn to_grid_file(&self, element: Element) -> GridFile {
        let mut metadata = vec![("basis".to_string(), "B0..B18 × red,green,blue".to_string())];
        metadata.extend(basis_metadata(&self.medium, &self.options));
        GridFile {
            kind: GridKind::Basis,
            dims: self.dims,
            element,
            bounds: self.bounds,
            metadata,
            channels: self.channels.clone(),
        }
    }

    /// Writes the set as a grid file (atomically; f16 halves the size).
    pub fn write(&self, path: &Path, element: Element) -> Result<(), RelightError> {
        // The file is built in memory: a copy of the channels and the encoded payload.
        sylva_core::check_memory(
            &format!("writing {}", path.display()),
            Self::memory_needed(self.dims) * 2,
        )?;
        self.to_grid_file(element).write(path)?;
        Ok(())
    }

    /// Reads a basis file written by [`BasisSet::write`]; a truncated or corrupted file, one
    /// of another kind, or one whose metadata or values are invalid is refused with an error
    /// naming it.
    pub fn read(path: &Path) -> Result<BasisSet, RelightError> {
        let file = GridFile::read(path)?;
        Self::from_grid_file(file, path)
    }

    /// A basis set from a grid file's contents (`path` names it in errors).
    pub fn from_grid_file(file: GridFile, path: &Path) -> Result<BasisSet, RelightError> {
        let bad = |what: String| RelightError::Format {
            path: path.into(),
            what,
        };
        if file.kind != GridKind::Basis {
            return Err(crate::GridFileError::WrongKind {
                path: path.into(),
                expected: "relighting basis",
                found: file.kind.name(),
            }
            .into());
        }
        let (medium, options) = parse_basis_metadata(&|k| file.metadata_value(k)).map_err(bad)?;
        BasisSet::new(file.dims, file.bounds, medium, options, file.channels)
            .map_err(|e| bad(e.to_string()))
    }
}

/// A flag's metadata value.
fn yes_no(flag: bool) -> String {
    if flag { "yes" } else { "no" }.to_string()
}

/// The medium and solve schedule of a basis set as `key=value` metadata (basis grid files and
/// compressed basis files share it).
pub fn basis_metadata(medium: &MediumParams, options: &BasisOptions) -> Vec<(String, String)> {
    let mut metadata = vec![
        (
            "ambient".to_string(),
            match options.ambient {
                Ambient::Sum => "sum",
                Ambient::Solve => "solved",
            }
            .to_string(),
        ),
        ("steps".into(), options.solve.max_steps.to_string()),
        (
            "tolerance".into(),
            options
                .solve
                .tolerance
                .map_or("none".into(), |t| t.to_string()),
        ),
        ("extrapolate".into(), yes_no(options.solve.extrapolate)),
        ("coarse_start".into(), yes_no(options.solve.coarse_start)),
    ];
    for (p, name) in medium.colours.iter().zip(COLOUR_NAMES) {
        metadata.push((
            format!("medium.{name}"),
            format!("{},{},{}", p.sigma_a, p.sigma_s, p.g),
        ));
    }
    if let Some(brown) = &medium.brown {
        for (p, name) in brown.iter().zip(COLOUR_NAMES) {
            metadata.push((
                format!("medium.brown.{name}"),
                format!("{},{},{}", p.sigma_a, p.sigma_s, p.g),
            ));
        }
    }
    metadata.extend([
        (
            "zero_f0_on_green".into(),
            medium.zero_f0_on_green.to_string(),
        ),
        (
            "zero_f0_on_brown".into(),
            medium.zero_f0_on_brown.to_string(),
        ),
        ("brown_threshold".into(), medium.brown_threshold.to_string()),
    ]);
    metadata
}

/// Reads what [`basis_metadata`] wrote; `value(key)` looks a key up. The error says which key
/// is missing or invalid.
pub fn parse_basis_metadata<'a>(
    value: &dyn Fn(&str) -> Option<&'a str>,
) -> Result<(MediumParams, BasisOptions), String> {
    let get = |key: &str| {
        value(key).ok_or_else(|| format!("metadata has no '{key}': not a basis written by sylva"))
    };
    let float = |key: &str, text: &str| {
        text.trim()
            .parse::<f64>()
            .map_err(|_| format!("metadata '{key}' = '{text}' is not a number"))
    };
    let flag = |key: &str| match get(key)? {
        "true" => Ok(true),
        "false" => Ok(false),
        v => Err(format!("metadata '{key}' = '{v}' is not true or false")),
    };
    let params = |key: &str| -> Result<ColourParams, String> {
        let text = get(key)?;
        let parts: Vec<&str> = text.split(',').collect();
        let [a, s, g] = parts[..] else {
            return Err(format!(
                "metadata '{key}' = '{text}' is not sigma_a,sigma_s,g"
            ));
        };
        Ok(ColourParams {
            sigma_a: float(key, a)?,
            sigma_s: float(key, s)?,
            g: float(key, g)?,
        })
    };
    let mut colours = [ColourParams {
        sigma_a: 0.0,
        sigma_s: 0.0,
        g: 0.0,
    }; 3];
    for (p, name) in colours.iter_mut().zip(COLOUR_NAMES) {
        *p = params(&format!("medium.{name}"))?;
    }
    // Brown sites' own coefficients, where the set was solved with them.
    let brown = match value("medium.brown.red") {
        None => None,
        Some(_) => {
            let mut b = colours;
            for (p, name) in b.iter_mut().zip(COLOUR_NAMES) {
                *p = params(&format!("medium.brown.{name}"))?;
            }
            Some(b)
        }
    };
    let medium = MediumParams {
        colours,
        zero_f0_on_green: flag("zero_f0_on_green")?,
        zero_f0_on_brown: flag("zero_f0_on_brown")?,
        brown_threshold: float("brown_threshold", get("brown_threshold")?)?,
        brown,
    };
    medium
        .validate()
        .map_err(|e| format!("medium in metadata: {e}"))?;
    let ambient = match get("ambient")? {
        "sum" => Ambient::Sum,
        "solved" => Ambient::Solve,
        v => return Err(format!("metadata 'ambient' = '{v}' is not sum or solved")),
    };
    let steps = get("steps")?;
    let max_steps = steps
        .parse::<usize>()
        .ok()
        .filter(|&s| s > 0)
        .ok_or_else(|| format!("metadata 'steps' = '{steps}' is not a step count"))?;
    let tolerance = match get("tolerance")? {
        "none" => None,
        t => Some(float("tolerance", t)?),
    };
    // Files written before extrapolated solves have no entry: they ran plain steps.
    let flag = |key: &str| match value(key) {
        None | Some("no") => Ok(false),
        Some("yes") => Ok(true),
        Some(v) => Err(format!("metadata '{key}' = '{v}' is not yes or no")),
    };
    let extrapolate = flag("extrapolate")?;
    // Nor files written before coarse-started solves: they started empty.
    let coarse_start = flag("coarse_start")?;
    let options = BasisOptions {
        solve: SolveOptions {
            max_steps,
            tolerance,
            extrapolate,
            coarse_start,
        },
        ambient,
    };
    Ok((medium, options))
}

/// Weights `w_j` of a combination `Σ_j w_j B_j` of the 19 base solutions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BasisWeights(pub [f64; BASES]);

impl BasisWeights {
    /// Checked weights: each must be finite.
    pub fn new(w: [f64; BASES]) -> Result<BasisWeights, RelightError> {
        if let Some(index) = w.iter().position(|v| !v.is_finite()) {
            return Err(RelightError::Weight {
                index,
                value: w[index],
            });
        }
        Ok(BasisWeights(w))
    }

    /// The exact sun (SPEC §3) travelling along `travel`: `w_j ∝ max(0, n_j · d)`, scaled to sum
    /// 1 so that unobstructed sunlight is 1 (the renderer's normalisation).
    pub fn exact(travel: [f64; 3]) -> Result<BasisWeights, RelightError> {
        let mut w = exact_weights(travel)?;
        let total: f64 = w.iter().sum();
        w.iter_mut().for_each(|v| *v /= total);
        Ok(BasisWeights(w))
    }

    /// The three base solutions of the polyhedron face that `travel` crosses, with its
    /// barycentric weights (004 §3.1); they sum to 1, so unobstructed sunlight is 1.
    pub fn three_basis(travel: [f64; 3]) -> Result<BasisWeights, RelightError> {
        let hit = face_hit(travel)?;
        let mut w = [0.0; BASES];
        for (&v, &x) in hit.vertices.iter().zip(&hit.weights) {
            w[v] = x;
        }
        Ok(BasisWeights(w))
    }

    /// The combination equal to a solve with `boundary` (raw solver units, not normalised):
    /// `w_j = f_j` on the shell. Only boundaries with `f_0 = 0` are combinations of the bases.
    pub fn from_boundary(boundary: &Boundary) -> Result<BasisWeights, RelightError> {
        if boundary.values[0] != 0.0 {
            return Err(RelightError::RestBoundary(boundary.values[0]));
        }
        BasisWeights::new(boundary.values.map(f64::from))
    }

    /// Adds ambient light `a / 18 · B_0`: `a` in free space.
    pub fn with_ambient(self, a: f64) -> Result<BasisWeights, RelightError> {
        let mut w = self.0;
        w[0] += a / AMBIENT_FREE_SPACE;
        BasisWeights::new(w)
    }

    /// What the combination holds at an unobstructed site: `Σ_{j≥1} w_j + 18 w_0`.
    pub fn free_space(&self) -> f64 {
        self.0[1..].iter().sum::<f64>() + AMBIENT_FREE_SPACE * self.0[0]
    }

    /// The combination scaled to free-space value 1 (unchanged when that value is 0).
    pub fn normalised(&self) -> BasisWeights {
        let f = self.free_space();
        if f == 0.0 {
            *self
        } else {
            BasisWeights(self.0.map(|w| w / f))
        }
    }

    /// The non-zero weights `(j, w_j)` in basis order.
    pub fn terms(&self) -> impl Iterator<Item = (usize, f64)> + '_ {
        self.0
            .iter()
            .enumerate()
            .filter(|(_, &w)| w != 0.0)
            .map(|(j, &w)| (j, w))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lattice::unit;

    #[test]
    fn metadata_round_trips_every_schedule() {
        let medium = crate::Preset::Leaf.params();
        let dims = Dims::new(24, 20, 18).unwrap();
        for solve in [
            SolveOptions::papers(dims),
            SolveOptions::extrapolated(dims),
            SolveOptions::coarse_started(Dims::new(80, 20, 18).unwrap()),
            SolveOptions {
                max_steps: 90,
                tolerance: Some(1e-6),
                extrapolate: false,
                coarse_start: false,
            },
        ] {
            let options = BasisOptions {
                solve,
                ambient: Ambient::Solve,
            };
            let meta = basis_metadata(&medium, &options);
            let value = |k: &str| {
                meta.iter()
                    .find(|(key, _)| key == k)
                    .map(|(_, v)| v.as_str())
            };
            let (m, o) = parse_basis_metadata(&value).unwrap();
            assert_eq!((m, o), (medium.clone(), options));
            // Files from before extrapolated solves have no entry: plain steps.
            if !solve.extrapolate {
                let older = |k: &str| match k {
                    "extrapolate" | "coarse_start" => None,
                    k => value(k),
                };
                assert_eq!(parse_basis_metadata(&older).unwrap().1, options);
            }
            // Nor from before coarse-started ones: they started empty.
            if !solve.coarse_start {
                let older = |k: &str| if k == "coarse_start" { None } else { value(k) };
                assert_eq!(parse_basis_metadata(&older).unwrap().1, options);
            }
        }
        let meta = basis_metadata(&medium, &BasisOptions::papers(dims));
        for (flag, wrong, message) in [
            ("extrapolate", "maybe", "'extrapolate' = 'maybe'"),
            ("coarse_start", "1", "'coarse_start' = '1' is not yes or no"),
        ] {
            let bad = |k: &str| match k {
                k if k == flag => Some(wrong),
                k => meta
                    .iter()
                    .find(|(key, _)| key == k)
                    .map(|(_, v)| v.as_str()),
            };
            let e = parse_basis_metadata(&bad).unwrap_err();
            assert!(e.contains(message), "{e}");
        }
    }

    #[test]
    fn weights_and_their_free_space_values() {
        let d = [0.3, -0.9, 0.2];
        let exact = BasisWeights::exact(d).unwrap();
        assert!((exact.free_space() - 1.0).abs() < 1e-12);
        let three = BasisWeights::three_basis(d).unwrap();
        assert!((three.free_space() - 1.0).abs() < 1e-12);
        assert_eq!(three.terms().count(), 3);
        let amb = three.with_ambient(0.25).unwrap();
        assert!((amb.free_space() - 1.25).abs() < 1e-12);
        assert!((amb.0[0] - 0.25 / 18.0).abs() < 1e-15);
        // A raw sun boundary of intensity 2 normalises to the exact weights.
        let n = super::super::polyhedron::normalise(d).unwrap();
        let raw = BasisWeights::from_boundary(&Boundary::sun(n, 2.0)).unwrap();
        let norm = raw.normalised();
        for j in 0..BASES {
            assert!((norm.0[j] - exact.0[j]).abs() < 1e-6, "{j}");
        }
        // At a lattice direction the three-basis combination is that basis alone.
        for j in 1..BASES {
            let w = BasisWeights::three_basis(unit(j)).unwrap();
            assert_eq!(w.terms().collect::<Vec<_>>(), vec![(j, 1.0)]);
        }
        assert!(matches!(
            BasisWeights::from_boundary(&Boundary { values: [1.0; 19] }),
            Err(RelightError::RestBoundary(_))
        ));
        assert!(matches!(
            three.with_ambient(f64::NAN),
            Err(RelightError::Weight { index: 0, .. })
        ));
        assert!(BasisWeights::exact([0.0; 3]).is_err());
    }
}
