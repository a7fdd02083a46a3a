//! Relighting's base solutions (paper 004) planned as jobs ([`crate::jobs`]): the root looks
//! every model's basis up in its cache; each missing model's solves (19 bases × colours) run
//! as jobs, all of them one job in one process, one per solve across processes (a solve run
//! alone is bit for bit that solve of the whole set); the root assembles, compresses and stores
//! each model's set, then makes the coarse global grid. The sets, cache entries and global
//! grid are one process's whatever the process count (only the solve times recorded in the
//! entries differ).

use std::time::Instant;

use sylva_core::jobs::Runner;
use sylva_core::wire::{Reader, Writer};
use sylva_geom::{Model, Scene};
use sylva_lb::relight::{BasisSet, CompressedBasis, CHANNELS};
use sylva_light::lighting::{LightingError, LightingSource};
use sylva_light::relight::{
    lookup_basis, store_basis, BasisLookup, BasisPlan, BasisReport, GlobalLight, ModelBasis,
    StoredBasis,
};
use sylva_light::Progress;
use sylva_render::stages::stage;

use crate::jobs::run_jobs;
use crate::{finish_relighting, relight_options, BasisUse, LbPlan, PipelineError, RelightPlan};
use crate::{Relighting, RelightingAt};

fn model_error(model: &Model, source: LightingError) -> PipelineError {
    PipelineError::Lighting {
        model: model.name.clone(),
        source,
    }
}

/// Every model's base solutions and the scene's global grid as `plan` asks (from the root's
/// cache, or solved on `lb.solver` through `runner` and cached there), without building
/// anything else: what `sylva basis` runs. Every process calls it with the same scene and
/// plan (checked; with `--basis always` every process must solve on the same kind of device,
/// since CPU and GPU results differ in the last bits). The root reports each model's basis
/// and the global grid to `progress`. `None` everywhere when the plan takes cached bases only
/// and one is missing; with several processes, the others get the root's relighting when
/// `share` says so, else `None`.
pub fn precompute_relighting(
    scene: &Scene,
    lb: &LbPlan,
    plan: &RelightPlan,
    runner: &dyn Runner,
    share: RelightingAt,
    progress: &dyn Progress,
) -> Result<Option<Relighting>, PipelineError> {
    let (root, several) = (runner.is_root(), runner.processes() > 1);
    let (lopts, bopts) = relight_options(scene, lb, plan)?;
    let _span = tracing::info_span!(stage::LB_PRECOMPUTE).entered();
    let solver = match plan.basis {
        BasisUse::IfCached => None,
        BasisUse::Always => Some(lb.solver),
    };
    if several {
        if let Some(s) = solver {
            runner.agree("the LB solver", &s.cache_tag())?;
        }
        runner.agree(
            "the basis settings",
            &format!(
                "{} ({} models, presets {:?}) grid {} {plan:?} {share:?}",
                scene.name,
                scene.models.len(),
                bopts.iter().map(|o| o.preset.as_str()).collect::<Vec<_>>(),
                lopts.grid,
            ),
        )?;
    }

    // The root: the cache; every process: the models to solve, or that a cached-only plan
    // falls back.
    let mut found: Vec<Option<(ModelBasis, BasisReport)>> = Vec::new();
    let mut sources: Vec<Option<LightingSource>> = Vec::new();
    if root {
        for (model, o) in scene.models.iter().zip(&bopts) {
            match lookup_basis(model, o, solver).map_err(|e| model_error(model, e))? {
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
    }
    let (fall_back, missing) = sylva_core::jobs::from_root(
        runner,
        "the models to solve",
        || {
            let missing: Vec<usize> = (0..found.len()).filter(|&m| found[m].is_none()).collect();
            Ok::<_, PipelineError>((solver.is_none() && !missing.is_empty(), missing))
        },
        |(fall_back, missing): &(bool, Vec<usize>)| {
            let mut w = Writer::default();
            w.u64(*fall_back as u64)
                .u64s(&missing.iter().map(|&m| m as u64).collect::<Vec<_>>());
            w.0
        },
        |data| {
            let mut r = Reader::new(data, "models to solve");
            let fall_back = r.u64()? != 0;
            let missing = r.indices(scene.models.len())?;
            r.end()?;
            Ok((fall_back, missing))
        },
    )?;
    if fall_back {
        return Ok(None);
    }

    // One round of jobs per missing model: its raw set is held only while it is assembled.
    for &m in &missing {
        let started = Instant::now();
        let (model, opts) = (&scene.models[m], &bopts[m]);
        let fail = |e: LightingError| model_error(model, e);
        let solver = solver.expect("models are missing only with a solver");
        let (dims, solves) =
            BasisPlan::jobs_of(model, opts.grid, &opts.preset, solver.schedule()).map_err(fail)?;
        // Per job, the solves it runs: all of them in one process.
        let jobs: Vec<std::ops::Range<usize>> = match several {
            true => (0..solves.len()).map(|s| s..s + 1).collect(),
            false => std::iter::once(0..solves.len()).collect(),
        };
        let units = match several {
            true => jobs.len() as u64,
            false => 1,
        };
        if root {
            progress.start(&format!("basis {}", model.name), units);
        }
        let mut held: Option<BasisPlan> = None;
        let outcome = run_jobs(
            runner,
            jobs.len(),
            &mut |j| {
                let _span = (!several)
                    .then(|| tracing::info_span!(stage::LB_MODEL, model = %model.name).entered());
                if held.is_none() {
                    held = Some(
                        BasisPlan::new(model, opts.grid, &opts.preset, solver.schedule())
                            .map_err(fail)?,
                    );
                }
                let plan = held.as_ref().expect("a basis plan");
                let run = &solves[jobs[j].clone()];
                let max_steps = plan.options.solve.max_steps;
                let values = plan
                    .run(run, solver, &mut |k, step| {
                        if !several {
                            progress.set(
                                (k * max_steps + step) as u64,
                                (run.len() * max_steps) as u64,
                            )
                        }
                    })
                    .map_err(fail)?;
                let mut w = Writer::default();
                for (_, v) in &values {
                    w.f32s(v);
                }
                Ok(w.0)
            },
            &|_| {
                if several {
                    progress.advance(1)
                }
            },
        );
        if root {
            progress.finish();
        }
        let Some(results) = outcome? else {
            continue;
        };
        // The root: the set assembled, compressed and stored as one process does it.
        let plan = match held.take() {
            Some(p) => p,
            None => {
                BasisPlan::new(model, opts.grid, &opts.preset, solver.schedule()).map_err(fail)?
            }
        };
        let mut assembly = plan.assembly().map_err(fail)?;
        let mut solve_seconds = 0.0;
        for (range, done) in jobs.iter().zip(results) {
            solve_seconds += done.seconds;
            let mut r = Reader::new(&done.bytes, "basis job values");
            for &job in &solves[range.clone()] {
                assembly
                    .insert(job, r.f32s(dims.sites())?)
                    .map_err(|e| fail(e.into()))?;
            }
            r.end()?;
        }
        let source = sources[m].take().expect("a missing model's lookup");
        let stored = store_basis(
            model,
            opts,
            plan,
            assembly,
            solver,
            source,
            solve_seconds,
            started,
        )
        .map_err(fail)?;
        found[m] = Some(stored);
    }

    let relighting = match root {
        true => {
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
        false => None,
    };
    match (several, share) {
        (true, RelightingAt::Everywhere) => share_relighting(runner, scene, relighting).map(Some),
        _ => Ok(relighting),
    }
}

/// The root's relighting on every process: each model's compressed set (and uncompressed one
/// when kept), then the global grid and the count of cached models.
fn share_relighting(
    runner: &dyn Runner,
    scene: &Scene,
    relighting: Option<Relighting>,
) -> Result<Relighting, PipelineError> {
    let bad = |what: String| PipelineError::Jobs(sylva_core::jobs::JobError::Transport(what));
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
        runner.share(&mut data.0)?;
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
    runner.share(&mut data.0)?;
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
