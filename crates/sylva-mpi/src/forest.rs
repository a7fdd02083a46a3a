//! The physical light's forest parts across ranks: every model's four light parts
//! ([`sylva_light::lighting::PARTS`]) as jobs of the work queue, stored in rank 0's cache.
//!
//! A scene lit through the forest grid ([`sylva_light::forest`]) needs each model's parts,
//! its sun part solved on its density with the neighbours' foliage added. Every rank builds
//! the models' densities and that foliage once ([`sylva_pipeline::forest_densities`]: the same
//! inputs and a deterministic computation, so the same on every rank), rank 0 lists the
//! parts its cache lacks, the ranks solve them through the queue, and rank 0 stores each as
//! one process would (the same file, byte for byte). Each rank then prepares the scene from
//! the cache with the same densities ([`sylva_pipeline::PreparedScene::with_forest_densities`];
//! rank 0 first, the other ranks read its cache where they share its filesystem, else solve
//! again): this spreads the solves, the expensive part, over the ranks.

use sylva_geom::Scene;
use sylva_light::lighting::{PartsPlan, PARTS};
use sylva_light::relight::GlobalGridOptions;
use sylva_light::Progress;
use sylva_pipeline::{
    lighting_options, scene_illumination, scene_to_sun, ForestDensities, LbPlan, PipelineError,
};
use sylva_render::stage;

use crate::comm::{agree, Comm, CommError, Reader, Writer};
use crate::queue::run_queue;
use crate::DistError;

/// Solves the parts missing from rank 0's cache across the ranks and stores them there
/// (every rank calls it with the same scene, plan and `densities`, its own
/// [`sylva_pipeline::forest_densities`] of them; the scene and plan are checked). Returns how
/// many parts were solved. Without a cache at rank 0 nothing is solved here.
pub fn solve_forest_parts(
    comm: &dyn Comm,
    scene: &Scene,
    lb: &LbPlan,
    gopts: &GlobalGridOptions,
    densities: &ForestDensities,
    progress: &dyn Progress,
) -> Result<usize, DistError> {
    let _span = tracing::info_span!(stage::LB_PRECOMPUTE).entered();
    let root = comm.rank() == 0;
    agree(comm, "the LB solver", &lb.solver.cache_tag())?;
    let mut opts = lighting_options(scene, lb);
    agree(
        comm,
        "the forest's LB settings",
        &format!(
            "{} ({} models, {} instances) grid {} light {} sun {:?} forest grid {}",
            scene.name,
            scene.models.len(),
            scene.instances.len(),
            opts.grid,
            opts.light.name(),
            scene_to_sun(scene),
            gopts.sites
        ),
    )?;
    // Rank 0 decides whether there is anything to do: without its cache the solves could not
    // be kept.
    let mut has_cache = vec![(root && opts.cache_dir.is_some()) as u8];
    comm.broadcast(0, &mut has_cache)?;
    if has_cache != [1] {
        return Ok(0);
    }
    if !root {
        opts.cache_dir = None;
    }
    if densities.own.len() != scene.models.len() || densities.shades.len() != scene.models.len() {
        return Err(CommError::Protocol(format!(
            "forest densities of {} models for {} models",
            densities.own.len(),
            scene.models.len()
        ))
        .into());
    }
    let illum = scene_illumination(scene);
    let lighting_err = |k: usize, source| {
        DistError::Pipeline(PipelineError::Lighting {
            model: scene.models[k].name.clone(),
            source,
        })
    };
    let plans = scene
        .models
        .iter()
        .enumerate()
        .map(|(k, m)| {
            let opts = opts.for_model(scene, k);
            let own = densities.own[k].clone();
            PartsPlan::new(
                m,
                &illum,
                &opts,
                lb.solver,
                own,
                densities.shades[k].as_ref(),
            )
            .map_err(|e| lighting_err(k, e))
        })
        .collect::<Result<Vec<_>, _>>()?;

    // Rank 0: the parts its cache lacks, to everyone.
    let mut todo = Writer::default();
    if root {
        let missing: Vec<(usize, usize)> = (0..plans.len())
            .flat_map(|m| (0..PARTS.len()).map(move |k| (m, k)))
            .filter(|&(m, k)| !plans[m].is_cached(k))
            .collect();
        todo.u64(missing.len() as u64);
        for (m, k) in missing {
            todo.u64(m as u64).u64(k as u64);
        }
    }
    comm.broadcast(0, &mut todo.0)?;
    let mut r = Reader::new(&todo.0, "light parts to solve");
    let jobs = (0..r.u64()?)
        .map(|_| Ok((r.u64()? as usize, r.u64()? as usize)))
        .collect::<Result<Vec<_>, CommError>>()?;
    r.end()?;
    if jobs
        .iter()
        .any(|&(m, k)| m >= plans.len() || k >= PARTS.len())
    {
        return Err(CommError::Protocol(format!("light parts to solve {jobs:?}")).into());
    }
    if jobs.is_empty() {
        return Ok(0);
    }
    if root {
        progress.start("LB light parts", jobs.len() as u64);
    }
    let outcome = run_queue(
        comm,
        jobs.len(),
        &mut |j| {
            let (m, k) = jobs[j];
            let grid = plans[m]
                .solve(k, lb.solver, &mut |_, _, _| {})
                .map_err(|e| lighting_err(m, e))?;
            let mut w = Writer::default();
            for c in &grid.colours {
                w.f32s(c);
            }
            Ok(w.0)
        },
        &|_| progress.advance(1),
    );
    if root {
        progress.finish();
    }
    if let Some(outcome) = outcome? {
        for (&(m, k), result) in jobs.iter().zip(outcome.results) {
            let plan = &plans[m];
            let mut r = Reader::new(&result, "a light part");
            let values = r.f32s(3 * plan.dims().sites())?;
            r.end()?;
            let grid = plan.grid_from(values).map_err(|e| lighting_err(m, e))?;
            // A part that cannot be stored is solved again by the one-process lighting that
            // follows, which reports the cache's warning.
            plan.cached(k, lb.solver, || Ok(grid))
                .map_err(|e| lighting_err(m, e))?;
        }
    }
    Ok(jobs.len())
}
