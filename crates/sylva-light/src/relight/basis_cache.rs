//! Per model, its 19 base solutions (004 §3.1): voxelized, solved on any [`LbSolver`] as
//! independent jobs, compressed, and cached on disk like the per-sun lighting.
//!
//! * **Jobs.** [`BasisPlan`] holds what a model's basis depends on (its density grid, the
//!   medium, the schedule) and lists the solves as [`BasisJob`]s (one base solution in one
//!   colour); [`BasisPlan::run`] runs any of them on a solver, [`BasisPlan::assembly`]
//!   collects results from anywhere. [`model_basis`] is [`lookup_basis`], every job run in
//!   order, then [`store_basis`]; the distributed precompute (`sylva-mpi`) calls the same
//!   lookup and store around jobs run across MPI ranks.
//! * **Cache.** The compressed set is what is cached (`<model>-<key>.scbasis`,
//!   `sylva_lb::relight::CompressedBasis::write`: CRC-checked, atomic). The key hashes the
//!   model and medium ([`crate::lighting`]'s rules), the grid, the solve schedule, the solver
//!   backend's cache tag and the compression target; it is stored in the file and checked on
//!   reading, with the dimensions and bounds. With [`BasisCacheOptions::keep_raw`] the
//!   uncompressed set is kept as well (`<model>-<key>.sbasis`, a kind-3 grid file, f32): what
//!   compression error is measured against. A damaged or stale entry is reported, solved
//!   again and replaced; an entry that cannot be written is a warning
//!   ([`BasisReport::cache_warning`]). Each entry records how long its solves took.
//! * **Lookup only.** With no solver, [`model_basis`] only reads the cache, under the tag of
//!   any backend (a basis solved on the GPU serves a CPU render), and returns `None` when
//!   there is no valid entry: the render then solves for its sun as before.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;
use sylva_core::cache::{Cache, CacheKey, CacheKind};
use sylva_geom::Model;
use sylva_lb::relight::{
    compress, solve_basis_jobs, Ambient, BasisAssembly, BasisJob, BasisOptions, BasisProgress,
    BasisSet, CompressTarget, CompressedBasis, Region, COMPRESSED_EXTENSION,
};
use sylva_lb::solver::SolveOptions;
use sylva_lb::{DensityGrid, Dims, Element, GridFile, LbSolver, MediumParams, Schedule};
use sylva_voxel::{placement_for, voxelize, VoxelizeOptions};

use crate::lighting::{
    preset_medium, LightingError, LightingOptions, LightingSource, ModelMediumKey, CACHE_VERSION,
    KEY_METADATA, PAPER_OCCUPANCY,
};

/// A model's uncompressed basis ([`basis_key`]).
pub const BASIS_RAW: CacheKind = CacheKind {
    name: "relighting basis",
    version: CACHE_VERSION,
};
/// A model's compressed basis ([`compressed_key`]).
pub const BASIS_COMPRESSED: CacheKind = CacheKind {
    name: "compressed relighting basis",
    version: CACHE_VERSION,
};

/// Extension of uncompressed basis cache entries.
pub const RAW_EXTENSION: &str = "sbasis";
/// Metadata key of the seconds the solves of an entry took.
pub const SOLVE_SECONDS_METADATA: &str = "solve_seconds";
/// The solver cache tags a lookup-only read tries, each with its backend's schedule
/// ([`LbSolver::schedule`]).
const KNOWN_BACKENDS: [(&str, Schedule); 3] = [
    ("cpu", Schedule::CoarseStarted),
    ("gpu-f32", Schedule::Papers),
    ("gpu-f16", Schedule::Papers),
];

/// How models' base solutions are made and kept.
#[derive(Debug, Clone, PartialEq)]
pub struct BasisCacheOptions {
    /// Sites along each model's longest edge (scene `[lb] grid`).
    pub grid: usize,
    /// LB preset name (scene `[lb] preset`).
    pub preset: String,
    /// The cache; `None`: always solve, write nothing.
    pub cache_dir: Option<PathBuf>,
    /// What the stored set is compressed to.
    pub target: CompressTarget,
    /// Also keep the uncompressed set (read and written; 57 × 4 bytes per site).
    pub keep_raw: bool,
}

impl BasisCacheOptions {
    /// The recommended compression, no uncompressed copy.
    pub fn new(lighting: &LightingOptions) -> BasisCacheOptions {
        BasisCacheOptions {
            grid: lighting.grid,
            preset: lighting.preset.clone(),
            cache_dir: lighting.cache_dir.clone(),
            target: CompressTarget::recommended(),
            keep_raw: false,
        }
    }
}

/// A model's basis: the compressed set the renderer reads, and on request the uncompressed one.
#[derive(Debug, Clone)]
pub struct ModelBasis {
    pub compressed: CompressedBasis,
    pub raw: Option<BasisSet>,
    /// The density grid, when this call voxelized the model (the coarse global grid
    /// resamples it).
    pub density: Option<DensityGrid>,
}

/// What [`model_basis`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct BasisReport {
    /// Where the compressed set came from.
    pub source: LightingSource,
    /// Wall-clock seconds of the call.
    pub seconds: f64,
    /// Seconds the base solutions' solves took: measured now, or as recorded in the cache
    /// entry when it was solved.
    pub solve_seconds: Option<f64>,
    /// The compressed cache entry (read or written).
    pub path: Option<PathBuf>,
    pub dims: Dims,
    /// Bytes of the uncompressed set (57 f32 per site) and of the compressed one.
    pub raw_bytes: u64,
    pub compressed_bytes: u64,
    /// Why an entry could not be written (the basis is good, only not kept).
    pub cache_warning: Option<String>,
}

/// Everything a model's uncompressed basis depends on: the solver backend's cache tag, the
/// model and medium (on the paper's occupancy), the solve schedule and how `B_0` is made.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct BasisKey {
    solver: String,
    model: ModelMediumKey,
    max_steps: usize,
    tolerance: Option<f64>,
    extrapolate: bool,
    /// Left out of the key when false, so entries from before coarse starts keep theirs.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    coarse_start: bool,
    ambient: &'static str,
}

impl BasisKey {
    fn new(
        model: &Model,
        grid: usize,
        medium: &MediumParams,
        options: &BasisOptions,
        solver_tag: &str,
    ) -> BasisKey {
        BasisKey {
            solver: solver_tag.to_string(),
            model: ModelMediumKey::new(model, grid, medium, PAPER_OCCUPANCY),
            max_steps: options.solve.max_steps,
            tolerance: options.solve.tolerance,
            extrapolate: options.solve.extrapolate,
            coarse_start: options.solve.coarse_start,
            ambient: match options.ambient {
                Ambient::Sum => "sum",
                Ambient::Solve => "solve",
            },
        }
    }
}

/// Everything a compressed set depends on: the uncompressed basis and the target.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub(crate) struct CompressedKey {
    /// The uncompressed basis's key ([`basis_key`]).
    raw: u64,
    codec: String,
    precision: &'static str,
    far_threshold: f64,
    /// The region compression spends its bits on ([`region_of`]).
    region: &'static str,
}

impl CompressedKey {
    fn new(raw: CacheKey, target: &CompressTarget) -> CompressedKey {
        CompressedKey {
            raw: raw.value(),
            codec: target.codec.name(),
            precision: target.precision.name(),
            far_threshold: target.far_threshold,
            region: "near_medium(1).with_floor(2)",
        }
    }
}

/// The cache key of a model's uncompressed basis solved on a backend tagged `solver_tag`.
pub fn basis_key(
    model: &Model,
    grid: usize,
    medium: &MediumParams,
    options: &BasisOptions,
    solver_tag: &str,
) -> CacheKey {
    CacheKey::new(
        BASIS_RAW,
        &BasisKey::new(model, grid, medium, options, solver_tag),
    )
}

/// The cache key of the compressed set made from the basis of key `raw` with `target`.
pub fn compressed_key(raw: CacheKey, target: &CompressTarget) -> CacheKey {
    CacheKey::new(BASIS_COMPRESSED, &CompressedKey::new(raw, target))
}

/// The cache entry of `model` under `key` with extension `ext`.
pub fn basis_path(cache: &Cache, model: &Model, key: CacheKey, ext: &str) -> PathBuf {
    cache.entry(&sylva_core::file_stem(&model.name, "model"), key, ext)
}

/// Where the renderer reads a model's light: in and next to the medium, and the lowest two
/// layers (the ground under the tree). Compression spends its bits there.
pub fn region_of(density: &DensityGrid) -> Region {
    Region::near_medium(density, 1).with_floor(2)
}

/// What a model's basis depends on, and its solves as independent jobs.
#[derive(Debug, Clone)]
pub struct BasisPlan {
    pub model: String,
    pub density: DensityGrid,
    pub medium: MediumParams,
    pub options: BasisOptions,
}

impl BasisPlan {
    /// Voxelizes `model` at `grid` sites along its longest edge; the medium from `preset`,
    /// `schedule`'s solves (the solver's [`LbSolver::schedule`]), `B_0` summed.
    pub fn new(
        model: &Model,
        grid: usize,
        preset: &str,
        schedule: Schedule,
    ) -> Result<BasisPlan, LightingError> {
        let (medium, placement, options) = basis_setup(model, grid, preset, schedule)?;
        let density = basis_density(model, grid)?;
        debug_assert_eq!(density.dims, placement.dims);
        Ok(BasisPlan {
            model: model.name.clone(),
            density,
            medium,
            options,
        })
    }

    /// Every solve of the basis, basis-major ([`BasisJob::all`]).
    pub fn jobs(&self) -> Vec<BasisJob> {
        BasisJob::all(&self.medium, &self.options)
    }

    /// The dimensions of `model`'s grid at `grid` and its [`BasisPlan::jobs`] with `preset`
    /// and `schedule`, without voxelizing it: the list a work queue hands out before any
    /// rank has the density grid.
    pub fn jobs_of(
        model: &Model,
        grid: usize,
        preset: &str,
        schedule: Schedule,
    ) -> Result<(Dims, Vec<BasisJob>), LightingError> {
        let (medium, placement, options) = basis_setup(model, grid, preset, schedule)?;
        Ok((placement.dims, BasisJob::all(&medium, &options)))
    }

    /// Runs `jobs` (any subset, any order) on `solver`: the jobs of one base solution in one
    /// call. Returns each job's site values. `progress(job index, step)` follows the solves.
    pub fn run(
        &self,
        jobs: &[BasisJob],
        solver: &dyn LbSolver,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<Vec<(BasisJob, Vec<f32>)>, LightingError> {
        let mut out = Vec::with_capacity(jobs.len());
        let mut k = 0;
        while k < jobs.len() {
            // A run of jobs of one basis, each colour once, goes in one call.
            let mut end = k + 1;
            while end < jobs.len()
                && jobs[end].basis == jobs[k].basis
                && !jobs[k..end].iter().any(|j| j.colour == jobs[end].colour)
            {
                end += 1;
            }
            let group = &jobs[k..end];
            let results = solve_basis_jobs(
                &self.density,
                &self.medium,
                &self.options,
                group,
                |g: &DensityGrid,
                 m: &MediumParams,
                 b: sylva_lb::Boundary,
                 o: &SolveOptions,
                 p: &mut dyn FnMut(usize, usize, f64)| {
                    solver.solve_lighting(g, m, b, o, p)
                },
                &mut |colour, step| {
                    let i = group.iter().position(|j| j.colour == colour).unwrap_or(0);
                    progress(k + i, step)
                },
            )?;
            out.extend(results.into_iter().map(|(job, values, _)| (job, values)));
            k = end;
        }
        Ok(out)
    }

    /// An empty assembly for this basis: insert `(job, values)` from anywhere, then finish.
    pub fn assembly(&self) -> Result<BasisAssembly, LightingError> {
        Ok(BasisAssembly::new(
            self.density.dims,
            self.density.bounds,
            &self.medium,
            &self.options,
        )?)
    }
}

/// `model` voxelized at `grid` sites along its longest edge as its basis is solved on (and
/// the paper light's global grid places it).
pub fn basis_density(model: &Model, grid: usize) -> Result<DensityGrid, LightingError> {
    let placement = placement_for(model, grid)?;
    sylva_core::check_memory(
        &format!(
            "voxelizing model '{}' on a {} grid",
            model.name, placement.dims
        ),
        sylva_voxel::memory_needed(placement.dims),
    )?;
    Ok(voxelize(
        model,
        &VoxelizeOptions {
            grid,
            alpha_test: true,
            occupancy: PAPER_OCCUPANCY,
        },
    )?)
}

/// What a model's basis depends on besides its density grid: the medium of `preset`, the
/// grid's placement and the solves' options (`schedule`'s, `B_0` summed).
fn basis_setup(
    model: &Model,
    grid: usize,
    preset: &str,
    schedule: Schedule,
) -> Result<(MediumParams, sylva_voxel::GridPlacement, BasisOptions), LightingError> {
    let medium = preset_medium(preset)?;
    let placement = placement_for(model, grid)?;
    let options = BasisOptions {
        solve: schedule.options(placement.dims),
        ambient: Ambient::Sum,
    };
    Ok((medium, placement, options))
}

/// Reads the compressed entry at `path`; `Err` is why it is unusable, naming the file.
fn read_compressed(
    path: &Path,
    key: CacheKey,
    dims: Dims,
    bounds: sylva_lb::Bounds,
) -> Result<(CompressedBasis, Option<f64>, u64), String> {
    let (set, meta) = CompressedBasis::read(path).map_err(|e| e.to_string())?;
    let shown = path.display();
    let value = |k: &str| meta.iter().find(|(m, _)| m == k).map(|(_, v)| v.as_str());
    key.check(path, value(KEY_METADATA))?;
    if set.dims != dims || set.bounds != bounds {
        return Err(format!(
            "{shown} holds a {} grid over {:?}..{:?}, the model needs {dims} over {:?}..{:?}",
            set.dims, set.bounds.min, set.bounds.max, bounds.min, bounds.max
        ));
    }
    let seconds = value(SOLVE_SECONDS_METADATA).and_then(|v| v.parse().ok());
    let raw_bytes = value("raw_bytes").and_then(|v| v.parse().ok()).unwrap_or(0);
    Ok((set, seconds, raw_bytes))
}

/// Reads the uncompressed entry at `path`; `Err` is why it is unusable, naming the file.
fn read_raw(
    path: &Path,
    key: CacheKey,
    dims: Dims,
    bounds: sylva_lb::Bounds,
) -> Result<(BasisSet, Option<f64>), String> {
    let file = GridFile::read(path).map_err(|e| e.to_string())?;
    let shown = path.display().to_string();
    key.check(path, file.metadata_value(KEY_METADATA))?;
    let seconds = file
        .metadata_value(SOLVE_SECONDS_METADATA)
        .and_then(|v| v.parse().ok());
    let set = BasisSet::from_grid_file(file, path).map_err(|e| e.to_string())?;
    if set.dims != dims || set.bounds != bounds {
        return Err(format!(
            "{shown} holds a {} grid, the model needs {dims}",
            set.dims
        ));
    }
    Ok((set, seconds))
}

/// What the cache holds for a model's basis ([`lookup_basis`]).
#[derive(Debug)]
pub enum BasisLookup {
    /// A valid entry: the compressed set (and the uncompressed one when kept), no solve.
    Hit(Box<(ModelBasis, BasisReport)>),
    /// No valid entry: the basis must be solved. `Computed` when there was none,
    /// `Recomputed` with the reason when a damaged or stale entry is to be replaced.
    Miss(LightingSource),
}

/// Looks `model`'s basis up in the cache of `opts`: under
/// `solver`'s cache tag, or with no solver under the tag of any backend (a basis solved on
/// the GPU serves a CPU render). A compressed entry missing beside a kept uncompressed one
/// is compressed again and written (no solve). Without a cache, always a miss.
pub fn lookup_basis(
    model: &Model,
    opts: &BasisCacheOptions,
    solver: Option<&dyn LbSolver>,
) -> Result<BasisLookup, LightingError> {
    let t0 = Instant::now();
    opts.target.validate()?;
    let backends: Vec<(String, Schedule)> = match solver {
        Some(s) => vec![(s.cache_tag(), s.schedule())],
        None => KNOWN_BACKENDS
            .iter()
            .map(|&(t, s)| (t.to_string(), s))
            .collect(),
    };
    let mut source = LightingSource::Computed;
    let Some(dir) = &opts.cache_dir else {
        return Ok(BasisLookup::Miss(source));
    };
    let cache = Cache::new(dir);
    for (tag, schedule) in &backends {
        let (medium, placement, options) = basis_setup(model, opts.grid, &opts.preset, *schedule)?;
        let (dims, bounds) = (placement.dims, placement.bounds());
        let raw_bytes_of = |d: Dims| BasisSet::memory_needed(d);
        let rkey = basis_key(model, opts.grid, &medium, &options, tag);
        let ckey = compressed_key(rkey, &opts.target);
        let cpath = basis_path(&cache, model, ckey, COMPRESSED_EXTENSION);
        let rpath = basis_path(&cache, model, rkey, RAW_EXTENSION);
        let raw = if opts.keep_raw {
            match rpath.try_exists() {
                Ok(true) => match read_raw(&rpath, rkey, dims, bounds) {
                    Ok(r) => Some(r),
                    Err(reason) => {
                        source = LightingSource::Recomputed { reason };
                        continue;
                    }
                },
                _ => continue,
            }
        } else {
            None
        };
        let compressed = match cpath.try_exists() {
            Ok(true) => match read_compressed(&cpath, ckey, dims, bounds) {
                Ok(c) => Some(c),
                Err(reason) => {
                    if raw.is_none() {
                        source = LightingSource::Recomputed { reason };
                        continue;
                    }
                    None
                }
            },
            Ok(false) => None,
            Err(e) => {
                if raw.is_none() {
                    source = LightingSource::Recomputed {
                        reason: format!("cannot read {}: {e}", cpath.display()),
                    };
                    continue;
                }
                None
            }
        };
        match (compressed, raw) {
            (Some((c, seconds, _)), raw) => {
                let report = BasisReport {
                    source: LightingSource::Cached,
                    seconds: t0.elapsed().as_secs_f64(),
                    solve_seconds: seconds.or(raw.as_ref().and_then(|r| r.1)),
                    path: Some(cpath),
                    dims,
                    raw_bytes: raw_bytes_of(dims),
                    compressed_bytes: c.bytes(),
                    cache_warning: None,
                };
                let basis = ModelBasis {
                    compressed: c,
                    raw: raw.map(|r| r.0),
                    density: None,
                };
                return Ok(BasisLookup::Hit(Box::new((basis, report))));
            }
            (None, Some((raw, seconds))) => {
                // The uncompressed set is there: compress it again (no solve).
                let density = basis_density(model, opts.grid)?;
                let c = compress(&raw, &region_of(&density), &opts.target)?;
                let cache_warning = cache.store(&cpath, |p| {
                    write_compressed(&c, p, ckey, model, opts, seconds, solver)
                });
                let report = BasisReport {
                    source: LightingSource::Cached,
                    seconds: t0.elapsed().as_secs_f64(),
                    solve_seconds: seconds,
                    path: Some(cpath),
                    dims,
                    raw_bytes: raw_bytes_of(dims),
                    compressed_bytes: c.bytes(),
                    cache_warning,
                };
                let basis = ModelBasis {
                    compressed: c,
                    raw: Some(raw),
                    density: Some(density),
                };
                return Ok(BasisLookup::Hit(Box::new((basis, report))));
            }
            (None, None) => {}
        }
    }
    Ok(BasisLookup::Miss(source))
}

/// The end of a model's solve, wherever its jobs ran: `assembly` (every job of `plan`
/// inserted) finished into the basis set, compressed and, with a cache, stored (the
/// compressed entry, and the uncompressed one with `keep_raw`) under `solver`'s tag.
/// `source` is what the lookup found ([`BasisLookup::Miss`]), `solve_seconds` how long the
/// solves took and `started` when the model's work began (for the report).
#[allow(clippy::too_many_arguments)]
pub fn store_basis(
    model: &Model,
    opts: &BasisCacheOptions,
    plan: BasisPlan,
    assembly: BasisAssembly,
    solver: &dyn LbSolver,
    source: LightingSource,
    solve_seconds: f64,
    started: Instant,
) -> Result<(ModelBasis, BasisReport), LightingError> {
    let dims = plan.density.dims;
    let raw = assembly.finish()?;
    let compressed = compress(&raw, &region_of(&plan.density), &opts.target)?;
    let mut path = None;
    let mut cache_warning = None;
    if let Some(dir) = &opts.cache_dir {
        let cache = Cache::new(dir);
        let rkey = basis_key(
            model,
            opts.grid,
            &plan.medium,
            &plan.options,
            &solver.cache_tag(),
        );
        let ckey = compressed_key(rkey, &opts.target);
        let cpath = basis_path(&cache, model, ckey, COMPRESSED_EXTENSION);
        cache_warning = cache.store(&cpath, |p| {
            write_compressed(
                &compressed,
                p,
                ckey,
                model,
                opts,
                Some(solve_seconds),
                Some(solver),
            )
        });
        if opts.keep_raw {
            let rpath = basis_path(&cache, model, rkey, RAW_EXTENSION);
            let mut file = raw.to_grid_file(Element::F32);
            file.metadata.extend([
                rkey.metadata(),
                ("source".to_string(), model.name.clone()),
                (
                    SOLVE_SECONDS_METADATA.to_string(),
                    format!("{solve_seconds:.3}"),
                ),
                ("solver".to_string(), solver.describe()),
            ]);
            sylva_core::check_memory(
                &format!("writing {}", rpath.display()),
                BasisSet::memory_needed(dims) * 2,
            )?;
            let warning = cache.store(&rpath, |p| file.write(p).map_err(|e| e.to_string()));
            cache_warning = cache_warning.or(warning);
        }
        path = Some(cpath);
    }
    let report = BasisReport {
        source,
        seconds: started.elapsed().as_secs_f64(),
        solve_seconds: Some(solve_seconds),
        path,
        dims,
        raw_bytes: BasisSet::memory_needed(dims),
        compressed_bytes: compressed.bytes(),
        cache_warning,
    };
    let basis = ModelBasis {
        compressed,
        raw: opts.keep_raw.then_some(raw),
        density: Some(plan.density),
    };
    Ok((basis, report))
}

/// One model's basis: from the cache when it holds a valid entry ([`lookup_basis`]);
/// otherwise, with a solver, voxelized, solved (every job of [`BasisPlan::jobs`], in this
/// process) and stored ([`store_basis`]). Without a solver only the cache is read, and
/// `None` means there is no valid entry. `progress` counts jobs and steps.
pub fn model_basis(
    model: &Model,
    opts: &BasisCacheOptions,
    solver: Option<&dyn LbSolver>,
    progress: &mut dyn FnMut(BasisProgress),
) -> Result<Option<(ModelBasis, BasisReport)>, LightingError> {
    let t0 = Instant::now();
    let source = match lookup_basis(model, opts, solver)? {
        BasisLookup::Hit(hit) => return Ok(Some(*hit)),
        BasisLookup::Miss(source) => source,
    };
    let Some(solver) = solver else {
        return Ok(None);
    };
    let plan = BasisPlan::new(model, opts.grid, &opts.preset, solver.schedule())?;
    let jobs = plan.jobs();
    let max_steps = plan.options.solve.max_steps;
    let solve_start = Instant::now();
    let mut assembly = plan.assembly()?;
    let results = plan.run(&jobs, solver, &mut |k, step| {
        progress(BasisProgress {
            done: k,
            solves: jobs.len(),
            basis: jobs[k].basis,
            colour: jobs[k].colour,
            step,
            max_steps,
        })
    })?;
    for (job, values) in results {
        assembly.insert(job, values)?;
    }
    let solve_seconds = solve_start.elapsed().as_secs_f64();
    store_basis(
        model,
        opts,
        plan,
        assembly,
        solver,
        source,
        solve_seconds,
        t0,
    )
    .map(Some)
}

fn write_compressed(
    c: &CompressedBasis,
    path: &Path,
    key: CacheKey,
    model: &Model,
    opts: &BasisCacheOptions,
    solve_seconds: Option<f64>,
    solver: Option<&dyn LbSolver>,
) -> Result<(), String> {
    let mut meta = vec![
        key.metadata(),
        ("source".to_string(), model.name.clone()),
        ("preset".to_string(), opts.preset.clone()),
        ("grid".to_string(), opts.grid.to_string()),
        (
            "raw_bytes".to_string(),
            BasisSet::memory_needed(c.dims).to_string(),
        ),
    ];
    if let Some(s) = solve_seconds {
        meta.push((SOLVE_SECONDS_METADATA.to_string(), format!("{s:.3}")));
    }
    if let Some(s) = solver {
        meta.push(("solver".to_string(), s.describe()));
    }
    c.write(path, &meta).map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lighting::{model_medium_variants, sample_model_medium_key};
    use sylva_core::cache::assert_each_field_changes_the_key;
    use sylva_lb::relight::{Codec, Precision};

    #[test]
    fn lookups_without_a_solver_try_the_cpu_on_its_own_schedule() {
        let cpu = sylva_lb::CpuSolver;
        assert!(KNOWN_BACKENDS.contains(&(cpu.cache_tag().as_str(), cpu.schedule())));
    }

    #[test]
    fn basis_key_changes_with_every_field() {
        let base = BasisKey {
            solver: "cpu".into(),
            model: sample_model_medium_key(),
            max_steps: 64,
            tolerance: None,
            extrapolate: true,
            coarse_start: false,
            ambient: "sum",
        };
        let mut variants: Vec<(String, BasisKey)> = vec![
            (
                "solver".into(),
                BasisKey {
                    solver: "gpu-f16".into(),
                    ..base.clone()
                },
            ),
            (
                "max_steps".into(),
                BasisKey {
                    max_steps: 65,
                    ..base.clone()
                },
            ),
            (
                "tolerance".into(),
                BasisKey {
                    tolerance: Some(0.0),
                    ..base.clone()
                },
            ),
            (
                "extrapolate".into(),
                BasisKey {
                    extrapolate: false,
                    ..base.clone()
                },
            ),
            (
                "coarse_start".into(),
                BasisKey {
                    coarse_start: true,
                    ..base.clone()
                },
            ),
            (
                "tolerance value".into(),
                BasisKey {
                    tolerance: Some(1e-6),
                    ..base.clone()
                },
            ),
            (
                "ambient".into(),
                BasisKey {
                    ambient: "solve",
                    ..base.clone()
                },
            ),
        ];
        for (name, m) in model_medium_variants() {
            variants.push((
                format!("model: {name}"),
                BasisKey {
                    model: m,
                    ..base.clone()
                },
            ));
        }
        let named: Vec<(&str, BasisKey)> = variants
            .iter()
            .map(|(n, k)| (n.as_str(), k.clone()))
            .collect();
        assert_each_field_changes_the_key(BASIS_RAW, &base, &named);
    }

    #[test]
    fn compressed_key_changes_with_every_field() {
        let raw = CacheKey::new(BASIS_RAW, &1u8);
        let target = CompressTarget::recommended();
        let base = CompressedKey::new(raw, &target);
        assert_eq!(base.raw, raw.value());
        let other_raw = CacheKey::new(BASIS_RAW, &2u8);
        assert_each_field_changes_the_key(
            BASIS_COMPRESSED,
            &base,
            &[
                ("raw", CompressedKey::new(other_raw, &target)),
                (
                    "codec",
                    CompressedKey::new(
                        raw,
                        &CompressTarget {
                            codec: Codec::Pca { rank: 3 },
                            ..target
                        },
                    ),
                ),
                (
                    "precision",
                    CompressedKey::new(
                        raw,
                        &CompressTarget {
                            precision: Precision::F32,
                            ..target
                        },
                    ),
                ),
                (
                    "far_threshold",
                    CompressedKey::new(
                        raw,
                        &CompressTarget {
                            far_threshold: 0.5,
                            ..target
                        },
                    ),
                ),
                (
                    "region",
                    CompressedKey {
                        region: "near_medium(2)",
                        ..base.clone()
                    },
                ),
            ],
        );
        // The raw and compressed keys of the same inputs never meet.
        assert_ne!(compressed_key(raw, &target), raw);
    }
}
