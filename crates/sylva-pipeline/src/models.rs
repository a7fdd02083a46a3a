//! Every model's LB light for the scene's sun, planned as jobs ([`crate::jobs`]): the root
//! looks each model up in the cache, the models it lacks are solved as jobs (one per model in
//! one process, the solver's three colours together; one per colour across processes, a
//! colour solved alone being bit for bit that colour of the three), the root assembles and
//! stores each, and every process gets every model's grid from the root (no process relies on
//! seeing the root's files).

use std::time::Instant;

use sylva_core::jobs::{from_root, Runner};
use sylva_core::wire::{Reader, Writer};
use sylva_geom::Scene;
use sylva_lb::{DensityGrid, LightingGrid};
use sylva_light::lighting::{
    CacheLookup, LightingPlan, LightingReport, LightingSource, ModelLighting,
};
use sylva_light::Progress;
use sylva_render::stages::stage;

use crate::jobs::{root_count, run_jobs_with_bar};
use crate::{lighting_options, scene_illumination, scene_to_sun, LbPlan, PipelineError};

/// Every model's LB lighting, in scene order, on every process of `runner` (each calls it
/// with the same scene and plan; that is checked, and every process must solve on the same
/// kind of device, since CPU and GPU results differ in the last bits). The root reads and
/// writes `lb`'s cache and reports each model to `progress`; the count is the models that
/// came from the cache.
pub fn light_models(
    scene: &Scene,
    lb: &LbPlan,
    runner: &dyn Runner,
    progress: &dyn Progress,
) -> Result<(Vec<ModelLighting>, usize), PipelineError> {
    let _span = tracing::info_span!(stage::LB_PRECOMPUTE).entered();
    let (root, several) = (runner.is_root(), runner.processes() > 1);
    let mut opts = lighting_options(scene, lb);
    if several {
        runner.agree("the LB solver", &lb.solver.cache_tag())?;
        runner.agree(
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
    }
    if !root {
        opts.cache_dir = None;
    }
    let illum = scene_illumination(scene);
    let plans = scene
        .models
        .iter()
        .enumerate()
        .map(|(k, m)| {
            LightingPlan::new(m, &illum, &opts.for_model(scene, k), lb.solver).map_err(|source| {
                PipelineError::Lighting {
                    model: m.name.clone(),
                    source,
                }
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    let fail = |plan: &LightingPlan, source| PipelineError::Lighting {
        model: plan.model.name.clone(),
        source,
    };

    // The root: the cache; every process: the models to solve.
    let mut lookups: Vec<CacheLookup> = match root {
        true => plans.iter().map(|p| p.lookup()).collect(),
        false => Vec::new(),
    };
    let missing: Vec<usize> = from_root(
        runner,
        "the models to solve",
        || {
            Ok::<_, PipelineError>(
                (0..plans.len())
                    .filter(|&m| !matches!(lookups[m], CacheLookup::Hit(_)))
                    .collect(),
            )
        },
        |m: &Vec<usize>| {
            let mut w = Writer::default();
            w.u64s(&m.iter().map(|&i| i as u64).collect::<Vec<_>>());
            w.0
        },
        |data| {
            let mut r = Reader::new(data, "models to solve");
            let m = r.indices(plans.len())?;
            r.end()?;
            Ok(m)
        },
    )?;
    // (model, colour): all three colours in one process.
    let mut jobs: Vec<(usize, Option<usize>)> = Vec::new();
    for &m in &missing {
        if !several {
            jobs.push((m, None));
            continue;
        }
        for (colour, &source) in plans[m].colour_sources().iter().enumerate() {
            if source == colour {
                jobs.push((m, Some(colour)));
            }
        }
    }

    // The density of the model whose jobs this process runs, kept for its next job.
    let mut held: Option<(usize, DensityGrid)> = None;
    let outcome = run_jobs_with_bar(
        runner,
        "LB solves",
        jobs.len(),
        &mut |j| {
            let (m, colour) = jobs[j];
            let plan = &plans[m];
            let _span = (!several)
                .then(|| tracing::info_span!(stage::LB_MODEL, model = %plan.model.name).entered());
            if held.as_ref().map(|h| h.0) != Some(m) {
                held = None; // one grid held at a time
                held = Some((m, plan.density().map_err(|e| fail(plan, e))?));
            }
            let density = &held.as_ref().expect("a density").1;
            let mut w = Writer::default();
            match colour {
                Some(c) => {
                    let values = plan.solve_colour(density, c, lb.solver, &mut |_, _| {});
                    w.f32s(&values.map_err(|e| fail(plan, e))?);
                }
                None => {
                    progress.start(&format!("LB {}", plan.model.name), 3);
                    let grid = plan.solve(density, lb.solver, &mut |c, step, max| {
                        progress.set((c * max + step) as u64, 3 * max as u64)
                    });
                    progress.finish();
                    for c in &grid.map_err(|e| fail(plan, e))?.colours {
                        w.f32s(c);
                    }
                }
            }
            Ok(w.0)
        },
        progress,
    );
    let outcome = outcome?;

    // The root: each solved model's grid assembled and stored.
    let mut solved: Vec<Option<LightingGrid>> = (0..plans.len()).map(|_| None).collect();
    let mut seconds = vec![0f64; plans.len()];
    let mut cache_warnings: Vec<Option<String>> = vec![None; plans.len()];
    if let Some(results) = outcome {
        let mut colours: Vec<[Option<Vec<f32>>; 3]> =
            (0..plans.len()).map(|_| Default::default()).collect();
        for (&(m, colour), done) in jobs.iter().zip(results) {
            let sites = plans[m].dims().sites();
            let mut r = Reader::new(&done.bytes, "LB job values");
            match colour {
                Some(c) => colours[m][c] = Some(r.f32s(sites)?),
                None => {
                    for c in &mut colours[m] {
                        *c = Some(r.f32s(sites)?);
                    }
                }
            }
            r.end()?;
            seconds[m] += done.seconds;
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

    // Every model's grid, from the cache or solved, from the root to every process.
    let mut cached = 0;
    let mut lighting = Vec::with_capacity(plans.len());
    for (m, plan) in plans.iter().enumerate() {
        let t = Instant::now();
        let mut source = None;
        let grid = from_root(
            runner,
            "a model's LB grid",
            || {
                let (grid, s) = match std::mem::replace(&mut lookups[m], CacheLookup::Miss) {
                    CacheLookup::Hit(grid) => (grid, LightingSource::Cached),
                    CacheLookup::Miss => {
                        (solved[m].take().expect("solved"), LightingSource::Computed)
                    }
                    CacheLookup::Bad(reason) => (
                        solved[m].take().expect("solved"),
                        LightingSource::Recomputed { reason },
                    ),
                };
                source = Some(s);
                Ok::<_, PipelineError>(grid)
            },
            |grid| {
                let mut w = Writer::default();
                for c in &grid.colours {
                    w.f32s(c);
                }
                w.0
            },
            |data| {
                let sites = plan.dims().sites();
                let mut r = Reader::new(data, "LB grid");
                let c = [r.f32s(sites)?, r.f32s(sites)?, r.f32s(sites)?];
                r.end()?;
                Ok(plan.assemble(c))
            },
        )?;
        if let Some(source) = source {
            cached += (source == LightingSource::Cached) as usize;
            let report = LightingReport {
                source,
                seconds: seconds[m] + t.elapsed().as_secs_f64(),
                path: plan.cache_path().map(|p| p.to_path_buf()),
                dims: plan.dims(),
                cache_warning: cache_warnings[m].take(),
            };
            progress.model_lit(plan.model, &report);
        }
        lighting.push(plan.lighting(&grid));
    }
    let cached = root_count(runner, "cached models", cached)?;
    Ok((lighting, cached))
}
