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
use sylva_lb::LightingGrid;
use sylva_render::lighting::{
    CacheLookup, LightingPlan, LightingReport, LightingSource, ModelLighting,
};
use sylva_render::{lighting_options, scene_to_sun, stage, LbPlan, Progress};

use crate::comm::{agree, Comm, CommError, Reader, Writer};
use crate::queue::run_queue;
use crate::DistError;

/// One solve of the LB precomputation: a model's colour under the sun. Relighting's base
/// solutions (004: 19 boundary conditions per colour) would add a boundary index here and
/// list 19 × 3 jobs per model; the queue, the gathering and the broadcast stay as they are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LbJob {
    /// Index into the scene's models.
    pub model: usize,
    /// 0, 1, 2: R, G, B.
    pub colour: usize,
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
            "{} ({} models) grid {} preset {} sun {:?}",
            scene.name,
            scene.models.len(),
            opts.grid,
            opts.preset,
            scene_to_sun(scene)
        ),
    )?;
    if !root {
        opts.cache_dir = None;
    }
    let to_sun = scene_to_sun(scene);
    let plans = scene
        .models
        .iter()
        .map(|m| {
            LightingPlan::new(m, to_sun, &opts, lb.solver).map_err(|source| {
                DistError::Pipeline(sylva_render::PipelineError::Lighting {
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

    // The solves: one density grid kept at a time (a rank often gets a model's colours in a
    // row).
    if root && !jobs.is_empty() {
        progress.start("LB solves", jobs.len() as u64);
    }
    let mut density: Option<(usize, sylva_lb::DensityGrid)> = None;
    let outcome = run_queue(
        comm,
        jobs.len(),
        &mut |j| {
            let job = jobs[j];
            let plan = &plans[job.model];
            let lighting_error = |source| {
                DistError::Pipeline(sylva_render::PipelineError::Lighting {
                    model: plan.model.name.clone(),
                    source,
                })
            };
            if density.as_ref().map(|d| d.0) != Some(job.model) {
                density = None;
                density = Some((job.model, plan.density().map_err(lighting_error)?));
            }
            let grid = &density.as_ref().expect("density").1;
            let totals = plan
                .solve_colour(grid, job.colour, lb.solver, &mut |_, _| {})
                .map_err(lighting_error)?;
            let mut w = Writer::default();
            w.f32s(&totals);
            Ok(w.0)
        },
        &|_| progress.advance(1),
    );
    drop(density);
    if root && !jobs.is_empty() {
        progress.finish();
    }
    let outcome = outcome?;

    // Rank 0: each model's grid, from the cache or assembled and stored; then to everyone.
    let mut cached = 0;
    let mut lighting = Vec::with_capacity(plans.len());
    let mut solved: Vec<Option<LightingGrid>> = (0..plans.len()).map(|_| None).collect();
    let mut seconds = vec![0f64; plans.len()];
    if let Some(outcome) = &outcome {
        let mut colours: Vec<[Option<Vec<f32>>; 3]> =
            (0..plans.len()).map(|_| Default::default()).collect();
        for ((job, result), done) in jobs.iter().zip(&outcome.results).zip(&outcome.done) {
            let sites = plans[job.model].dims().sites();
            let mut r = Reader::new(result, "LB colour");
            colours[job.model][job.colour] = Some(r.f32s(sites)?);
            r.end()?;
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
            plan.store(&grid, lb.solver).map_err(|source| {
                DistError::Pipeline(sylva_render::PipelineError::Lighting {
                    model: plan.model.name.clone(),
                    source,
                })
            })?;
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
