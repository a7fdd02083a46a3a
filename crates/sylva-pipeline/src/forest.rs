//! The physical light of a forest: every model's four light parts
//! ([`sylva_light::lighting::PARTS`]) solved as jobs ([`crate::jobs`]) on its own density, its
//! sun part with the neighbours' foliage added, and the coarse forest grid's weights of them
//! per instance ([`ForestLight`]).
//!
//! Every process builds the models' densities and that foliage ([`forest_densities`]: the
//! same inputs and a deterministic computation, so the same everywhere); the root lists the
//! parts its cache lacks, they are solved as jobs, the root stores each as one process would
//! (the same file, byte for byte) and sends every model's parts to every process, which
//! weighs them through the forest grid itself.

use std::time::Instant;
use sylva_core::jobs::{from_root, Runner};
use sylva_core::wire::{Reader, Writer};
use sylva_geom::Scene;
use sylva_lb::{DensityGrid, LightingGrid, MediumParams};

use sylva_light::forest::{neighbour_shade_cached, ForestCache, ForestInstance, ForestLight};
use sylva_light::lighting::{
    model_density_cached, physical_environment, Light, LightingError, LightingReport,
    LightingSource, ModelLighting, PartsPlan, ShadedDensity, PARTS,
};
use sylva_light::relight::GlobalGridOptions;
use sylva_light::relight::GlobalReport;
use sylva_light::Progress;
use sylva_render::stages::stage;

use crate::jobs::{root_count, run_jobs_with_bar};
use crate::{lighting_options, scene_illumination, scene_to_sun, LbPlan, PipelineError};

/// Whether `PreparedScene::new` lights `scene` through the forest grid: the physical light,
/// a forest grid asked for, and more than one instance (a lone tree's light is its model's).
pub fn uses_forest(scene: &Scene, light: Light, forest: Option<&GlobalGridOptions>) -> bool {
    light == Light::Physical && forest.is_some() && scene.instances.len() > 1
}

/// What a forest's light parts are solved on ([`light_forest`]): every model's own density
/// (voxelized as its LB solve sees it, scene order) and the neighbours' foliage added to its
/// sun part's ([`neighbour_shade`]; `None`: none reaches into its boxes).
#[derive(Debug, Clone)]
pub struct ForestDensities {
    pub own: Vec<DensityGrid>,
    pub shades: Vec<Option<ShadedDensity>>,
}

/// [`ForestDensities`] of `scene`: its models voxelized (or their densities from the cache,
/// its troubles told to `progress`), the neighbours' foliage measured on the coarse grid of
/// `gopts`.
pub fn forest_densities(
    scene: &Scene,
    lb: &LbPlan,
    gopts: &GlobalGridOptions,
    progress: &dyn Progress,
) -> Result<ForestDensities, PipelineError> {
    let illum = scene_illumination(scene);
    let lopts = lighting_options(scene, lb);
    let own = scene
        .models
        .iter()
        .enumerate()
        .map(|(k, model)| {
            let lopts = lopts.for_model(scene, k);
            let (density, key, warning) = model_density_cached(model, &illum, &lopts, lb.solver)
                .map_err(|source| PipelineError::Lighting {
                    model: model.name.clone(),
                    source,
                })?;
            if let Some(w) = warning {
                progress.density_warning(model, &w);
            }
            Ok::<_, PipelineError>((density, key))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let (own, keys): (Vec<DensityGrid>, Vec<_>) = own.into_iter().unzip();
    let grids: Vec<&DensityGrid> = own.iter().collect();
    let placed: Vec<(usize, glam::Affine3A)> = scene
        .instances
        .iter()
        .map(|i| (i.model as usize, i.transform()))
        .collect();
    // Every process reads or measures it alike (the same entry, byte for byte), as the
    // densities.
    let cache = forest_cache(scene, lopts.cache_dir.as_deref());
    let (shades, warning) =
        neighbour_shade_cached(&grids, &keys, &placed, 0.0, gopts, cache.as_ref()).map_err(
            |source| PipelineError::Global {
                scene: scene.name.clone(),
                source,
            },
        )?;
    if let Some(w) = warning {
        progress.shade_warning(&w);
    }
    Ok(ForestDensities { own, shades })
}

/// Every model's physical light as its four parts (each from the root's cache when it can),
/// solved on `densities` ([`forest_densities`]) through `runner`, and the coarse forest
/// grid's weights of them per instance ([`ForestLight`]); how many models came from the
/// cache. Every process of `runner` calls it with the same scene, plan and densities (the
/// scene and plan are checked) and gets the same light.
pub fn light_forest(
    scene: &Scene,
    lb: &LbPlan,
    gopts: &GlobalGridOptions,
    densities: ForestDensities,
    runner: &dyn Runner,
    progress: &dyn Progress,
) -> Result<(Vec<ModelLighting>, usize, ForestLight), PipelineError> {
    let _span = tracing::info_span!(stage::LB_PRECOMPUTE).entered();
    let (root, several) = (runner.is_root(), runner.processes() > 1);
    let illum = scene_illumination(scene);
    let global_err = |source| PipelineError::Global {
        scene: scene.name.clone(),
        source,
    };
    let mut opts = lighting_options(scene, lb);
    if several {
        runner.agree("the LB solver", &lb.solver.cache_tag())?;
        runner.agree(
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
    }
    if !root {
        opts.cache_dir = None;
    }
    let ForestDensities { own, shades } = densities;
    if own.len() != scene.models.len() || shades.len() != scene.models.len() {
        return Err(global_err(LightingError::Global(format!(
            "forest densities of {} models for {} models",
            own.len(),
            scene.models.len()
        ))));
    }
    for (model, shade) in scene.models.iter().zip(&shades) {
        if let Some(s) = shade {
            progress.neighbour_shade(model, s);
        }
    }
    let lighting_err = |k: usize, source| PipelineError::Lighting {
        model: scene.models[k].name.clone(),
        source,
    };
    let plans = scene
        .models
        .iter()
        .zip(own)
        .enumerate()
        .map(|(k, (m, own))| {
            let opts = opts.for_model(scene, k);
            PartsPlan::new(m, &illum, &opts, lb.solver, own, shades[k].as_ref())
                .map_err(|e| lighting_err(k, e))
        })
        .collect::<Result<Vec<_>, _>>()?;

    let wanted: Vec<PlanParts> = plans
        .into_iter()
        .enumerate()
        .map(|(model, plan)| PlanParts {
            model,
            plan,
            parts: (0..PARTS.len()).collect(),
        })
        .collect();
    let solved = solve_light_parts(scene, lb, &wanted, runner, progress)?;
    let mut cached = 0;
    let mut lighting = Vec::with_capacity(wanted.len());
    let mut fine = Vec::with_capacity(wanted.len());
    for (w, (grids, report)) in wanted.into_iter().zip(solved) {
        if let Some(report) = report {
            cached += (report.source == LightingSource::Cached) as usize;
            progress.model_lit(&scene.models[w.model], &report);
        }
        let (l, density, medium) = w.plan.assemble(&grids);
        lighting.push(l);
        fine.push((density, medium));
    }
    let cached = root_count(runner, "cached models", cached)?;

    // The forest grid's weights: the root's from its cache or solved (and cached), sent to
    // every process.
    let env = physical_environment(&illum).map_err(global_err)?;
    let fine: Vec<_> = fine.iter().map(|(d, m)| (d, m)).collect();
    let instances = forest_instances(scene, &fine);
    let cache = forest_cache(scene, opts.cache_dir.as_deref());
    let forest = coarse_at_root(
        runner,
        progress,
        ("the forest grid", "forest grid", 3),
        |step| ForestLight::solve_cached(&instances, &env, 0.0, gopts, cache.as_ref(), step),
        ForestLight::to_bytes,
        |data| {
            ForestLight::from_bytes(data, scene.instances.len())
                .map_err(|e| LightingError::Global(format!("from the root: {e}")))
        },
    )
    .map_err(|source| match source {
        CoarseError::Light(e) => global_err(e),
        CoarseError::Pipeline(e) => e,
    })?;
    Ok((lighting, cached, forest))
}

/// Where a forest's answers are cached: beside its light in `dir` (`None`: no cache).
pub(crate) fn forest_cache(scene: &Scene, dir: Option<&std::path::Path>) -> Option<ForestCache> {
    dir.map(|dir| ForestCache::new(dir, &scene.name))
}

/// `scene`'s instances as the forest grid sees them: each with its model's density and
/// medium (`fine`, scene order).
pub(crate) fn forest_instances<'a>(
    scene: &Scene,
    fine: &[(&'a DensityGrid, &'a MediumParams)],
) -> Vec<ForestInstance<'a>> {
    scene
        .instances
        .iter()
        .map(|i| ForestInstance {
            model: Some(fine[i.model as usize]),
            to_world: i.transform(),
        })
        .collect()
}

/// Why [`coarse_at_root`] failed: the coarse grid's own error, or passing it around.
pub(crate) enum CoarseError {
    Light(LightingError),
    Pipeline(PipelineError),
}

impl From<sylva_core::jobs::JobError> for CoarseError {
    fn from(e: sylva_core::jobs::JobError) -> CoarseError {
        CoarseError::Pipeline(e.into())
    }
}

impl std::fmt::Display for CoarseError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CoarseError::Light(e) => e.fmt(f),
            CoarseError::Pipeline(e) => e.fmt(f),
        }
    }
}

/// A coarse grid's answer made at the root by `solve` (from its cache or solved; under a
/// progress bar `bar` of `steps`, its report told) and sent to every process of `runner`
/// (`what` names it there).
pub(crate) fn coarse_at_root<T>(
    runner: &dyn Runner,
    progress: &dyn Progress,
    (what, bar, steps): (&str, &str, u64),
    solve: impl FnOnce(&mut dyn FnMut(usize, usize)) -> Result<(T, GlobalReport), LightingError>,
    encode: impl FnOnce(&T) -> Vec<u8>,
    decode: impl FnOnce(&[u8]) -> Result<T, LightingError>,
) -> Result<T, CoarseError> {
    from_root(
        runner,
        what,
        || {
            progress.start(bar, steps);
            let got = solve(&mut |done, total| progress.set(done as u64, total as u64));
            progress.finish();
            let (value, report) = got.map_err(CoarseError::Light)?;
            progress.global_grid(&report);
            Ok(value)
        },
        encode,
        |data| decode(data).map_err(CoarseError::Light),
    )
}

/// A plan's wanted parts, in its order, and (at the root) what its report says of them.
pub(crate) type SolvedParts = (Vec<LightingGrid>, Option<LightingReport>);

/// A model's light-parts plan and the parts wanted of it.
pub(crate) struct PlanParts<'a> {
    pub model: usize,
    pub plan: PartsPlan<'a>,
    pub parts: Vec<usize>,
}

/// The parts each plan wants (each from the root's cache when it can, else solved as jobs
/// through `runner` and stored at the root), on every process: per plan its grids in its
/// order, and at the root what its report says of them (`None` elsewhere).
pub(crate) fn solve_light_parts(
    scene: &Scene,
    lb: &LbPlan,
    plans: &[PlanParts],
    runner: &dyn Runner,
    progress: &dyn Progress,
) -> Result<Vec<SolvedParts>, PipelineError> {
    let several = runner.processes() > 1;
    let lighting_err = |k: usize, source| PipelineError::Lighting {
        model: scene.models[k].name.clone(),
        source,
    };
    // Every (plan, part), in order.
    let all: Vec<(usize, usize)> = plans
        .iter()
        .enumerate()
        .flat_map(|(p, w)| w.parts.iter().map(move |&k| (p, k)))
        .collect();
    // The root: the parts its cache lacks, to every process.
    let jobs: Vec<usize> = from_root(
        runner,
        "the light parts to solve",
        || {
            Ok::<_, PipelineError>(
                (0..all.len())
                    .filter(|&j| !plans[all[j].0].plan.is_cached(all[j].1))
                    .collect(),
            )
        },
        |jobs: &Vec<usize>| {
            let mut w = Writer::default();
            w.u64s(&jobs.iter().map(|&j| j as u64).collect::<Vec<_>>());
            w.0
        },
        |data| {
            let mut r = Reader::new(data, "light parts to solve");
            let jobs = r.indices(all.len())?;
            r.end()?;
            Ok(jobs)
        },
    )?;
    let outcome = run_jobs_with_bar(
        runner,
        "LB light parts",
        jobs.len(),
        &mut |j| {
            let (p, k) = all[jobs[j]];
            let w = &plans[p];
            let name = &scene.models[w.model].name;
            let _span =
                (!several).then(|| tracing::info_span!(stage::LB_MODEL, model = %name).entered());
            if !several {
                progress.start(&format!("LB {name} ({} part)", w.plan.part_name(k)), 3);
            }
            let grid = w.plan.solve(k, lb.solver, &mut |c, step, max| {
                if !several {
                    progress.set((c * max + step) as u64, 3 * max as u64)
                }
            });
            if !several {
                progress.finish();
            }
            let mut out = Writer::default();
            for c in &grid.map_err(|e| lighting_err(w.model, e))?.colours {
                out.f32s(c);
            }
            Ok(out.0)
        },
        progress,
    );
    let outcome = outcome?;

    // The root: each part from its cache or the jobs, stored; every plan's parts to every
    // process.
    let mut solved: Vec<Option<(Vec<f32>, f64)>> = (0..all.len()).map(|_| None).collect();
    if let Some(results) = outcome {
        for (&j, done) in jobs.iter().zip(results) {
            let sites = plans[all[j].0].plan.dims().sites();
            let mut r = Reader::new(&done.bytes, "a light part");
            solved[j] = Some((r.f32s(3 * sites)?, done.seconds));
            r.end()?;
        }
    }
    let mut out = Vec::with_capacity(plans.len());
    let mut first = 0;
    for w in plans {
        let t = Instant::now();
        let mut report = None;
        let plan = &w.plan;
        let base = first;
        first += w.parts.len();
        let grids = from_root(
            runner,
            "a model's light parts",
            || {
                let mut seconds = 0.0;
                let parts = plan
                    .cached_some(&w.parts, lb.solver, &mut |k| {
                        let at = base + w.parts.iter().position(|&q| q == k).expect("wanted");
                        let (values, s) = solved[at].take().ok_or_else(|| {
                            LightingError::Global(format!(
                                "the {} part was neither in the cache nor solved",
                                plan.part_name(k)
                            ))
                        })?;
                        seconds += s;
                        plan.grid_from(values)
                    })
                    .map_err(|e| lighting_err(w.model, e))?;
                report = Some(LightingReport {
                    source: parts.source,
                    seconds: seconds + t.elapsed().as_secs_f64(),
                    path: parts.path,
                    dims: plan.dims(),
                    cache_warning: parts.cache_warning,
                });
                Ok::<_, PipelineError>(parts.grids)
            },
            |grids: &Vec<LightingGrid>| {
                let mut out = Writer::default();
                for c in grids.iter().flat_map(|g| &g.colours) {
                    out.f32s(c);
                }
                out.0
            },
            |data| {
                let mut r = Reader::new(data, "a model's light parts");
                let grids = (0..w.parts.len())
                    .map(|_| {
                        let values = r.f32s(3 * plan.dims().sites())?;
                        plan.grid_from(values).map_err(|e| lighting_err(w.model, e))
                    })
                    .collect::<Result<Vec<_>, PipelineError>>()?;
                r.end()?;
                Ok(grids)
            },
        )?;
        out.push((grids, report));
    }
    Ok(out)
}
