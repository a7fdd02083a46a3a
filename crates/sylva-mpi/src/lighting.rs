//! LB precomputation across ranks: every model's lighting, its colours solved as jobs of the
//! work queue, shared with every rank.
//!
//! Rank 0 owns the cache: it reads the entries it has, lists the solves the rest need as jobs
//! (models × colours today; relighting's base solutions only add jobs to the list, see
//! [`LbJob`]), hands them out on demand, assembles each model's colours, writes the cache
//! entry, and broadcasts every model's grid, cached or solved, to the other ranks. No rank
//! relies on seeing rank 0's files, so ranks on machines without a shared filesystem get the
//! same grids. A colour solved alone is bit for bit that colour of a three-colour solve
//! ([`sylva_lb::LbSolver::solve_colour`]), so the grids, the cache entries and the pictures
//! are those of one process.

use std::time::Instant;

use sylva_geom::Scene;
use sylva_lb::{DensityGrid, LightingGrid};
use sylva_light::lighting::{
    CacheLookup, LightingPlan, LightingReport, LightingSource, ModelLighting,
};
use sylva_light::Progress;
use sylva_pipeline::{lighting_options, scene_illumination, scene_to_sun, LbPlan};
use sylva_render::stage;

use crate::comm::{agree, Comm, CommError, Reader, Writer};
use crate::queue::run_queue;
use crate::DistError;

/// A solve that needs one model's grid: what the LB queue runs. [`solve_model_jobs`] runs
/// any list of them; the result of each is one value per site of its model's grid.
pub trait ModelJob: Sync {
    /// Index into the scene's models (and their plans, [`JobModel`]).
    fn model(&self) -> usize;
}

/// A model as its jobs need it on the rank that runs them: built there ([`JobModel::grid`]:
/// voxelized) and kept while that rank's next job is of the same model.
pub trait JobModel {
    /// What a rank builds once for the model's jobs: its density grid ([`LightingPlan`]), or
    /// a basis plan holding one ([`crate::relight`]).
    type Grid;
    fn grid(&self) -> Result<Self::Grid, DistError>;
    /// Values of one job's result: one per site of the model's grid.
    fn sites(&self) -> usize;
}

impl JobModel for LightingPlan<'_> {
    type Grid = DensityGrid;

    fn grid(&self) -> Result<DensityGrid, DistError> {
        self.density()
            .map_err(|source| lighting_error(self, source))
    }

    fn sites(&self) -> usize {
        self.dims().sites()
    }
}

/// One solve of the LB precomputation: a model's colour under the sun. (Relighting's base
/// solutions are the other kind: [`crate::relight::BasisModelJob`].)
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LbJob {
    /// Index into the scene's models.
    pub model: usize,
    /// 0, 1, 2: R, G, B.
    pub colour: usize,
}

impl ModelJob for LbJob {
    fn model(&self) -> usize {
        self.model
    }
}

/// The jobs that light `models` (indices into `plans`): each colour that does not repeat an
/// earlier colour's parameters.
pub fn lb_jobs(plans: &[LightingPlan], models: &[usize]) -> Vec<LbJob> {
    let mut jobs = Vec::new();
    for &model in models {
        for (colour, &source) in plans[model].colour_sources().iter().enumerate() {
            if source == colour {
                jobs.push(LbJob { model, colour });
            }
        }
    }
    jobs
}

/// One job's values (one per site of its model's grid) and the seconds it took where it ran.
#[derive(Debug, Clone, PartialEq)]
pub struct JobValues {
    pub values: Vec<f32>,
    pub seconds: f64,
}

/// What computes one job on the rank that gets it: `solve(job, plan, grid)`, one value per
/// site of the model's grid.
pub type SolveModelJob<'f, J, P> =
    dyn FnMut(&J, &P, &<P as JobModel>::Grid) -> Result<Vec<f32>, DistError> + 'f;

/// Runs `jobs` across the ranks through the work queue (every rank calls it with the same
/// list): `solve(job, plan, grid)` computes a job on whichever rank gets it, the model's
/// grid built there ([`JobModel::grid`]) and kept while that rank's next job is of the same
/// model. Rank 0 gets `Some` of every job's values in job order (each checked to have one
/// value per site), with `on_done(job)` as each arrives; the other ranks get `None`.
pub fn solve_model_jobs<J: ModelJob, P: JobModel>(
    comm: &dyn Comm,
    plans: &[P],
    jobs: &[J],
    solve: &mut SolveModelJob<'_, J, P>,
    on_done: &(dyn Fn(usize) + Sync),
) -> Result<Option<Vec<JobValues>>, DistError> {
    if let Some(job) = jobs.iter().find(|j| j.model() >= plans.len()) {
        return Err(CommError::Protocol(format!(
            "an LB job of model {} of {}",
            job.model(),
            plans.len()
        ))
        .into());
    }
    let mut held: Option<(usize, P::Grid)> = None;
    let outcome = run_queue(
        comm,
        jobs.len(),
        &mut |j| {
            let job = &jobs[j];
            let plan = &plans[job.model()];
            if held.as_ref().map(|d| d.0) != Some(job.model()) {
                // One grid held at a time.
                held = None;
                held = Some((job.model(), plan.grid()?));
            }
            let grid = &held.as_ref().expect("a grid").1;
            let mut w = Writer::default();
            w.f32s(&solve(job, plan, grid)?);
            Ok(w.0)
        },
        on_done,
    )?;
    drop(held);
    let Some(outcome) = outcome else {
        return Ok(None);
    };
    jobs.iter()
        .zip(&outcome.results)
        .zip(&outcome.done)
        .map(|((job, result), done)| {
            let mut r = Reader::new(result, "LB job values");
            let values = r.f32s(plans[job.model()].sites())?;
            r.end()?;
            Ok(JobValues {
                values,
                seconds: done.seconds,
            })
        })
        .collect::<Result<Vec<_>, DistError>>()
        .map(Some)
}

fn lighting_error(plan: &LightingPlan, source: sylva_light::lighting::LightingError) -> DistError {
    DistError::Pipeline(sylva_pipeline::PipelineError::Lighting {
        model: plan.model.name.clone(),
        source,
    })
}

/// Every model's lighting, in scene order, on every rank (every rank calls it with the same
/// scene and plan; that is checked, and every rank must solve on the same kind of device,
/// since CPU and GPU results differ in the last bits). Rank 0 reads and writes `lb`'s cache
/// and reports each model to `progress` (`model_lit`); the count is the models that came
/// from the cache.
pub fn light_models(
    comm: &dyn Comm,
    scene: &Scene,
    lb: &LbPlan,
    progress: &dyn Progress,
) -> Result<(Vec<ModelLighting>, usize), DistError> {
    let _span = tracing::info_span!(stage::LB_PRECOMPUTE).entered();
    let root = comm.rank() == 0;
    agree(comm, "the LB solver", &lb.solver.cache_tag())?;
    let mut opts = lighting_options(scene, lb);
    agree(
        comm,
        "the LB settings",
        &format!(
            "{} ({} models) grid {} light {} preset {} sun {:?}",
            scene.name,
            scene.models.len(),
            opts.grid,
            opts.light.name(),
            opts.preset,
            scene_to_sun(scene)
        ),
    )?;
    if !root {
        opts.cache_dir = None;
    }
    let illum = scene_illumination(scene);
    let plans = scene
        .models
        .iter()
        .enumerate()
        .map(|(k, m)| {
            let opts = opts.for_model(scene, k);
            LightingPlan::new(m, &illum, &opts, lb.solver).map_err(|source| {
                DistError::Pipeline(sylva_pipeline::PipelineError::Lighting {
                    model: m.name.clone(),
                    source,
                })
            })
        })
        .collect::<Result<Vec<_>, _>>()?;

    // Rank 0: the cache; everyone: the models to solve.
    let mut lookups: Vec<CacheLookup> = Vec::new();
    let mut todo = Writer::default();
    if root {
        lookups = plans.iter().map(|p| p.lookup()).collect();
        let missing: Vec<usize> = (0..plans.len())
            .filter(|&m| !matches!(lookups[m], CacheLookup::Hit(_)))
            .collect();
        todo.u64(missing.len() as u64);
        for m in missing {
            todo.u64(m as u64);
        }
    }
    comm.broadcast(0, &mut todo.0)?;
    let mut r = Reader::new(&todo.0, "models to solve");
    let missing = (0..r.u64()?)
        .map(|_| r.u64().map(|m| m as usize))
        .collect::<Result<Vec<_>, _>>()?;
    r.end()?;
    if missing.iter().any(|&m| m >= plans.len()) {
        return Err(CommError::Protocol(format!("models to solve {missing:?}")).into());
    }
    let jobs = lb_jobs(&plans, &missing);

    if root && !jobs.is_empty() {
        progress.start("LB solves", jobs.len() as u64);
    }
    let outcome = solve_model_jobs(
        comm,
        &plans,
        &jobs,
        &mut |job, plan, grid| {
            plan.solve_colour(grid, job.colour, lb.solver, &mut |_, _| {})
                .map_err(|source| lighting_error(plan, source))
        },
        &|_| progress.advance(1),
    );
    if root && !jobs.is_empty() {
        progress.finish();
    }
    let outcome = outcome?;

    // Rank 0: each model's grid, from the cache or assembled and stored; then to everyone.
    let mut cached = 0;
    let mut lighting = Vec::with_capacity(plans.len());
    let mut solved: Vec<Option<LightingGrid>> = (0..plans.len()).map(|_| None).collect();
    let mut seconds = vec![0f64; plans.len()];
    let mut cache_warnings: Vec<Option<String>> = vec![None; plans.len()];
    if let Some(outcome) = outcome {
        let mut colours: Vec<[Option<Vec<f32>>; 3]> =
            (0..plans.len()).map(|_| Default::default()).collect();
        for (job, done) in jobs.iter().zip(outcome) {
            colours[job.model][job.colour] = Some(done.values);
            seconds[job.model] += done.seconds;
        }
        for &m in &missing {
            let plan = &plans[m];
            let sources = plan.colour_sources();
            let c: [Vec<f32>; 3] = std::array::from_fn(|i| {
                colours[m][sources[i]]
                    .clone()
                    .expect("every listed colour was solved")
            });
            let grid = plan.assemble(c);
            cache_warnings[m] = plan.store(&grid, lb.solver);
            solved[m] = Some(grid);
        }
    }
    for (m, plan) in plans.iter().enumerate() {
        let t = Instant::now();
        let mut data = Writer::default();
        let mut from_cache = None;
        if root {
            let (grid, source) = match std::mem::replace(&mut lookups[m], CacheLookup::Miss) {
                CacheLookup::Hit(grid) => (grid, LightingSource::Cached),
                CacheLookup::Miss => (solved[m].take().expect("solved"), LightingSource::Computed),
                CacheLookup::Bad(reason) => (
                    solved[m].take().expect("solved"),
                    LightingSource::Recomputed { reason },
                ),
            };
            for c in &grid.colours {
                data.f32s(c);
            }
            from_cache = Some((grid, source));
        }
        comm.broadcast(0, &mut data.0)?;
        let grid = match from_cache {
            Some((grid, source)) => {
                cached += (source == LightingSource::Cached) as usize;
                let report = LightingReport {
                    source,
                    seconds: seconds[m] + t.elapsed().as_secs_f64(),
                    path: plan.cache_path().map(|p| p.to_path_buf()),
                    dims: plan.dims(),
                    cache_warning: cache_warnings[m].take(),
                };
                progress.model_lit(plan.model, &report);
                grid
            }
            None => {
                let sites = plan.dims().sites();
                let mut r = Reader::new(&data.0, "LB grid");
                let c = [r.f32s(sites)?, r.f32s(sites)?, r.f32s(sites)?];
                r.end()?;
                plan.assemble(c)
            }
        };
        lighting.push(plan.lighting(&grid));
    }
    // Everyone reports rank 0's count.
    let mut count = (cached as u64).to_le_bytes().to_vec();
    comm.broadcast(0, &mut count)?;
    let cached = Reader::new(&count, "cached models").u64()? as usize;
    Ok((lighting, cached))
}
