//! Relighting's base solutions (paper 004) across ranks: `mpirun -np N sylva basis SCENE`.
//!
//! Every model's 19 base solutions in three colours are jobs of the work queue
//! ([`BasisModelJob`]: models × bases × colours, run by [`solve_model_jobs`]). Rank 0 owns the
//! cache as in [`crate::lighting`]: it looks every model up, lists the missing models, and
//! once the queue has gathered their jobs' values puts each model's in a `BasisAssembly` and
//! stores it with the one-process code (`sylva_light::relight::store_basis`: finished,
//! compressed, written), then makes the coarse global grid (`sylva_pipeline::finish_relighting`).
//! A job solved alone is bit for bit that job of the one-process solve (one colour of one
//! base solution: `BasisPlan::run` on one job), so the sets, the cache entries and the global
//! grid are those of one process whatever the rank count. With `everywhere`, rank 0 then
//! sends every compressed set and the global grid to the other ranks (a relit render needs
//! them there, and they may not share rank 0's filesystem).

use std::time::Instant;

use sylva_geom::{Model, Scene};
use sylva_lb::relight::{BasisJob, BasisSet, CompressedBasis, CHANNELS};
use sylva_light::lighting::{LightingError, LightingSource};
use sylva_light::relight::{
    lookup_basis, store_basis, BasisCacheOptions, BasisLookup, BasisPlan, BasisReport, GlobalLight,
    ModelBasis, StoredBasis,
};
use sylva_light::Progress;
use sylva_pipeline::{
    finish_relighting, relight_options, BasisUse, LbPlan, PipelineError, RelightPlan, Relighting,
};
use sylva_render::stage;

use crate::comm::{agree, Comm, CommError, Reader, Writer};
use crate::lighting::{solve_model_jobs, JobModel, ModelJob};
use crate::DistError;

/// One solve of a relighting basis: base solution `job.basis` in colour `job.colour` of
/// model `model` (an index into the scene's models).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BasisModelJob {
    pub model: usize,
    pub job: BasisJob,
}

impl ModelJob for BasisModelJob {
    fn model(&self) -> usize {
        self.model
    }
}

/// A model whose base solutions go through the queue: a rank running its jobs voxelizes it
/// into a [`BasisPlan`] (density grid, medium, schedule) and keeps it for its next job.
struct BasisModel<'a> {
    model: &'a Model,
    opts: &'a BasisCacheOptions,
    sites: usize,
}

impl JobModel for BasisModel<'_> {
    type Grid = BasisPlan;

    fn grid(&self) -> Result<BasisPlan, DistError> {
        BasisPlan::new(self.model, self.opts.grid, &self.opts.preset)
            .map_err(|source| model_error(self.model, source))
    }

    fn sites(&self) -> usize {
        self.sites
    }
}

fn model_error(model: &Model, source: LightingError) -> DistError {
    DistError::Pipeline(PipelineError::Lighting {
        model: model.name.clone(),
        source,
    })
}

/// The basis jobs of `models` (indices into the scene), model after model, each model's in
/// [`BasisPlan::jobs`] order; and per scene model its grid's site count. Every rank makes the
/// same list from the same scene.
pub fn basis_jobs(
    scene: &Scene,
    opts: &[BasisCacheOptions],
    models: &[usize],
) -> Result<(Vec<BasisModelJob>, Vec<usize>), DistError> {
    let mut sites = Vec::with_capacity(scene.models.len());
    let mut per_model = Vec::with_capacity(scene.models.len());
    for (model, o) in scene.models.iter().zip(opts) {
        let (dims, jobs) = BasisPlan::jobs_of(model, o.grid, &o.preset)
            .map_err(|source| model_error(model, source))?;
        sites.push(dims.sites());
        per_model.push(jobs);
    }
    let jobs = models
        .iter()
        .flat_map(|&model| {
            per_model[model]
                .iter()
                .map(move |&job| BasisModelJob { model, job })
        })
        .collect();
    Ok((jobs, sites))
}

/// [`sylva_pipeline::precompute_relighting`] across the ranks of `comm` (every rank calls it
/// with the same scene and plans; that is checked, and with `--basis always` every rank must
/// solve on the same kind of device, since CPU and GPU results differ in the last bits).
/// Rank 0 reads and writes `lb`'s cache, reports each model's basis and the global grid to
/// `progress` and gets what the one-process call returns: the same sets, cache entries and
/// global grid, bit for bit (only the solve times recorded in the entries differ). `None`,
/// on every rank, when the plan takes cached bases only and one is missing. The other ranks
/// get the same relighting when `everywhere` (broadcast from rank 0), else `None`.
pub fn precompute_relighting(
    comm: &dyn Comm,
    scene: &Scene,
    lb: &LbPlan,
    plan: &RelightPlan,
    everywhere: bool,
    progress: &dyn Progress,
) -> Result<Option<Relighting>, DistError> {
    let started = Instant::now();
    let root = comm.rank() == 0;
    let (lopts, bopts) = relight_options(scene, lb, plan)?;
    let _span = tracing::info_span!(stage::LB_PRECOMPUTE).entered();
    let solver = match plan.basis {
        BasisUse::IfCached => None,
        BasisUse::Always => Some(lb.solver),
    };
    if let Some(s) = solver {
        agree(comm, "the LB solver", &s.cache_tag())?;
    }
    agree(
        comm,
        "the basis settings",
        &format!(
            "{} ({} models, presets {:?}) grid {} {plan:?} everywhere {everywhere}",
            scene.name,
            scene.models.len(),
            bopts.iter().map(|o| o.preset.as_str()).collect::<Vec<_>>(),
            lopts.grid,
        ),
    )?;

    // Rank 0: the cache; everyone: the models to solve, or that a cached-only plan falls back.
    let mut found: Vec<Option<(ModelBasis, BasisReport)>> = Vec::new();
    let mut sources: Vec<Option<LightingSource>> = Vec::new();
    let mut todo = Writer::default();
    if root {
        for (model, o) in scene.models.iter().zip(&bopts) {
            match lookup_basis(model, o, solver).map_err(|source| model_error(model, source))? {
                BasisLookup::Hit(hit) => {
                    found.push(Some(*hit));
                    sources.push(None);
                }
                BasisLookup::Miss(source) => {
                    found.push(None);
                    sources.push(Some(source));
                }
            }
        }
        let missing: Vec<usize> = (0..found.len()).filter(|&m| found[m].is_none()).collect();
        let fall_back = solver.is_none() && !missing.is_empty();
        todo.u64(fall_back as u64).u64(missing.len() as u64);
        for m in missing {
            todo.u64(m as u64);
        }
    }
    comm.broadcast(0, &mut todo.0)?;
    let mut r = Reader::new(&todo.0, "models to solve");
    let fall_back = r.u64()? != 0;
    let missing = (0..r.u64()?)
        .map(|_| r.u64().map(|m| m as usize))
        .collect::<Result<Vec<_>, _>>()?;
    r.end()?;
    if missing.iter().any(|&m| m >= scene.models.len()) {
        return Err(CommError::Protocol(format!("models to solve {missing:?}")).into());
    }
    if fall_back {
        return Ok(None);
    }

    let (jobs, sites) = basis_jobs(scene, &bopts, &missing)?;
    let models: Vec<BasisModel> = scene
        .models
        .iter()
        .zip(&bopts)
        .zip(&sites)
        .map(|((model, opts), &sites)| BasisModel { model, opts, sites })
        .collect();
    if root && !jobs.is_empty() {
        progress.start("basis solves", jobs.len() as u64);
    }
    // Without a solver nothing is missing here: no jobs, but every rank still enters the
    // queue (where the failure test hook applies).
    let outcome = solve_model_jobs(
        comm,
        &models,
        &jobs,
        &mut |j: &BasisModelJob, m: &BasisModel, plan: &BasisPlan| {
            let solver = solver.expect("basis jobs only with a solver");
            // The one-process solve's code, on this one job.
            let mut done = plan
                .run(&[j.job], solver, &mut |_, _| {})
                .map_err(|source| model_error(m.model, source))?;
            Ok(done.pop().expect("one job, one result").1)
        },
        &|_| progress.advance(1),
    );
    if root && !jobs.is_empty() {
        progress.finish();
    }
    let outcome = outcome?;

    // Rank 0: each missing model's set assembled and stored as one process does it; then every
    // model's report in scene order, and the global grid.
    let relighting = match outcome {
        Some(values) => {
            let mut values = jobs.iter().zip(values).peekable();
            for &m in &missing {
                let (model, opts) = (&scene.models[m], &bopts[m]);
                let fail = |e: LightingError| model_error(model, e);
                let plan = BasisPlan::new(model, opts.grid, &opts.preset).map_err(fail)?;
                let mut assembly = plan.assembly().map_err(fail)?;
                let mut solve_seconds = 0.0;
                while let Some((job, done)) = values.next_if(|(j, _)| j.model == m) {
                    solve_seconds += done.seconds;
                    assembly
                        .insert(job.job, done.values)
                        .map_err(|e| fail(e.into()))?;
                }
                let stored = store_basis(
                    model,
                    opts,
                    plan,
                    assembly,
                    solver.expect("missing models only with a solver"),
                    sources[m].take().expect("a missing model's lookup"),
                    // Summed over the ranks that ran its jobs.
                    solve_seconds,
                    // Its jobs ran among the other models': its report's wall time counts
                    // from the start of the whole precompute.
                    started,
                )
                .map_err(fail)?;
                found[m] = Some(stored);
            }
            let mut bases = Vec::with_capacity(found.len());
            let mut cached = 0;
            for (model, f) in scene.models.iter().zip(found) {
                let (basis, report) = f.expect("every model found or solved");
                cached += (report.source == LightingSource::Cached) as usize;
                progress.model_basis(model, &report);
                bases.push(basis);
            }
            Some(finish_relighting(
                scene, &lopts, plan, bases, cached, progress,
            )?)
        }
        None => None,
    };
    if !everywhere {
        return Ok(relighting);
    }
    share(comm, scene, relighting).map(Some)
}

/// Rank 0's relighting on every rank: each model's compressed set (and uncompressed one when
/// kept), then the global grid and the count of cached models, broadcast.
fn share(
    comm: &dyn Comm,
    scene: &Scene,
    relighting: Option<Relighting>,
) -> Result<Relighting, DistError> {
    let bad = |what: String| DistError::from(CommError::Protocol(what));
    let mut compressed = Vec::with_capacity(scene.models.len());
    let mut raw = Vec::with_capacity(scene.models.len());
    for (m, model) in scene.models.iter().enumerate() {
        let mut data = Writer::default();
        if let Some(r) = &relighting {
            let Some(StoredBasis::Compressed(c)) = &r.compressed[m] else {
                unreachable!("finish_relighting keeps every model's compressed set")
            };
            data.bytes(&c.to_bytes());
            match &r.raw[m] {
                Some(StoredBasis::Full(set)) => {
                    data.u64(1);
                    for channel in set.channels() {
                        data.f32s(channel);
                    }
                }
                _ => {
                    data.u64(0);
                }
            }
        }
        comm.broadcast(0, &mut data.0)?;
        if relighting.is_some() {
            continue;
        }
        let mut r = Reader::new(&data.0, "a model's basis");
        let c = CompressedBasis::from_bytes(r.bytes()?)
            .map_err(|e| bad(format!("the basis of model '{}': {e}", model.name)))?;
        if r.u64()? != 0 {
            let channels = (0..CHANNELS)
                .map(|_| r.f32s(c.dims.sites()))
                .collect::<Result<Vec<_>, _>>()?;
            let set = BasisSet::new(c.dims, c.bounds, c.medium.clone(), c.options, channels)
                .map_err(|e| bad(format!("the basis of model '{}': {e}", model.name)))?;
            raw.push(Some(StoredBasis::Full(set)));
        } else {
            raw.push(None);
        }
        r.end()?;
        compressed.push(Some(StoredBasis::Compressed(c)));
    }
    let mut data = Writer::default();
    if let Some(r) = &relighting {
        data.u64(r.cached as u64);
        match &r.global {
            Some(g) => data.u64(1).bytes(&g.to_bytes()),
            None => data.u64(0),
        };
    }
    comm.broadcast(0, &mut data.0)?;
    if let Some(r) = relighting {
        return Ok(r);
    }
    let mut r = Reader::new(&data.0, "the global grid");
    let cached = r.u64()? as usize;
    let global = match r.u64()? {
        0 => None,
        _ => Some(
            GlobalLight::from_bytes(r.bytes()?, scene.instances.len())
                .map_err(|e| bad(format!("the global grid: {e}")))?,
        ),
    };
    r.end()?;
    Ok(Relighting {
        compressed,
        raw,
        global,
        cached,
    })
}
