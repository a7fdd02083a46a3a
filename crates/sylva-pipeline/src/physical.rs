//! The physical light's base solutions (issue 27, docs/relight.md) planned as jobs: per model
//! its sun part for each of the 13 lattice directions a sun above the horizon travels along,
//! and its three diffuse parts ([`sylva_light::relight::physical`]), each a light part of the
//! per-sun light ([`PartsPlan`]) solved for a unit sun along that direction, so each is
//! cached, solved as a job and shared exactly as a forest's parts are
//! ([`crate::forest::solve_light_parts`]); then, with a forest, the coarse grid's parts
//! ([`ForestBases`]), solved by every process (deterministic). Nothing here depends on the
//! sun's direction: the light it gives moves with the sun without a solve.

use sylva_core::jobs::Runner;
use sylva_geom::Scene;
use sylva_light::forest::{ForestBases, ForestInstance};
use sylva_light::lighting::{
    model_density, LightingError, LightingReport, LightingSource, PartsPlan,
};
use sylva_light::relight::physical::{
    overhead_part, sun_part_illumination, PhysicalBasis, SUN_PARTS,
};
use sylva_light::relight::GlobalGridOptions;
use sylva_light::Progress;
use sylva_render::stages::stage;

use crate::forest::{forest_densities, solve_light_parts, uses_forest, PlanParts};
use crate::jobs::root_count;
use crate::{lighting_options, scene_illumination, BasisUse, LbPlan, PipelineError};

/// Every model's physical basis and the forest grid's parts: what a scene is relit with.
pub struct PhysicalRelighting {
    pub bases: Vec<Option<PhysicalBasis>>,
    pub forest: Option<ForestBases>,
    /// Models whose parts all came from the cache.
    pub cached: usize,
    /// Seconds the parts' solves took, when every part was solved now (`None` when some came
    /// from the cache: their solve time is not recorded).
    pub solve_seconds: Option<f64>,
}

/// Every model's [`PhysicalBasis`] (from the root's cache, or solved through `runner` and
/// cached there) and, for a forest (`forest`, more than one instance), the coarse grid's
/// parts. `None` when `basis` takes cached bases only and a part is missing. Every process
/// calls it with the same scene and options and gets the same relighting.
pub fn precompute_physical(
    scene: &Scene,
    lb: &LbPlan,
    basis: BasisUse,
    forest: Option<&GlobalGridOptions>,
    runner: &dyn Runner,
    progress: &dyn Progress,
) -> Result<Option<PhysicalRelighting>, PipelineError> {
    let _span = tracing::info_span!(stage::LB_PRECOMPUTE).entered();
    let several = runner.processes() > 1;
    let illum = scene_illumination(scene);
    let mut opts = lighting_options(scene, lb);
    if several {
        runner.agree("the LB solver", &lb.solver.cache_tag())?;
        runner.agree(
            "the physical basis settings",
            &format!(
                "{} ({} models, {} instances) grid {} forest grid {:?} {basis:?}",
                scene.name,
                scene.models.len(),
                scene.instances.len(),
                opts.grid,
                forest.map(|f| f.sites),
            ),
        )?;
    }
    if !runner.is_root() {
        opts.cache_dir = None;
    }
    let lighting_err = |k: usize, source: LightingError| PipelineError::Lighting {
        model: scene.models[k].name.clone(),
        source,
    };
    let in_forest = uses_forest(scene, lb.light, forest);
    let (own, shades) = match (in_forest, forest) {
        (true, Some(gopts)) => {
            let d = forest_densities(scene, lb, gopts)?;
            (d.own, d.shades)
        }
        _ => {
            let own = scene
                .models
                .iter()
                .enumerate()
                .map(|(k, m)| {
                    model_density(m, &illum, &opts.for_model(scene, k), lb.solver)
                        .map(|(d, _)| d)
                        .map_err(|e| lighting_err(k, e))
                })
                .collect::<Result<Vec<_>, _>>()?;
            let shades = own.iter().map(|_| None).collect();
            (own, shades)
        }
    };
    for (model, shade) in scene.models.iter().zip(&shades) {
        if let Some(s) = shade {
            progress.neighbour_shade(model, s);
        }
    }
    // Per model, one plan per sun direction; the overhead sun's also solves the diffuse
    // parts (they do not depend on the sun).
    let overhead = overhead_part();
    let mut plans = Vec::with_capacity(scene.models.len() * SUN_PARTS);
    // Per model, the medium its parts are solved with (the forest grid mixes them).
    let mut media = Vec::with_capacity(scene.models.len());
    for (k, model) in scene.models.iter().enumerate() {
        let mopts = opts.for_model(scene, k);
        for part in 0..SUN_PARTS {
            let plan = PartsPlan::new(
                model,
                &sun_part_illumination(&illum, part),
                &mopts,
                lb.solver,
                own[k].clone(),
                shades[k].as_ref(),
            )
            .map_err(|e| lighting_err(k, e))?;
            if part == 0 {
                media.push(plan.medium().clone());
            }
            plans.push(PlanParts {
                model: k,
                plan,
                parts: if part == overhead {
                    vec![0, 1, 2, 3]
                } else {
                    vec![0]
                },
            });
        }
    }
    if basis == BasisUse::IfCached {
        let all_cached = sylva_core::jobs::from_root(
            runner,
            "whether every part is cached",
            || {
                Ok::<_, PipelineError>(
                    plans
                        .iter()
                        .all(|w| w.parts.iter().all(|&k| w.plan.is_cached(k))),
                )
            },
            |yes: &bool| vec![*yes as u8],
            |data| Ok(data.first() == Some(&1)),
        )?;
        if !all_cached {
            return Ok(None);
        }
    }
    let solved = solve_light_parts(scene, lb, &plans, runner, progress)?;

    // Per model: its 13 sun parts and the overhead plan's diffuse parts.
    let mut sun: Vec<Vec<sylva_lb::LightingGrid>> =
        scene.models.iter().map(|_| Vec::new()).collect();
    let mut diffuse: Vec<Vec<sylva_lb::LightingGrid>> =
        scene.models.iter().map(|_| Vec::new()).collect();
    let mut reports: Vec<Option<LightingReport>> = scene.models.iter().map(|_| None).collect();
    let mut all_solved = true;
    for (w, (mut grids, report)) in plans.iter().zip(solved) {
        let m = w.model;
        if let Some(r) = report {
            all_solved &= r.source != LightingSource::Cached;
            reports[m] = Some(match reports[m].take() {
                None => r,
                Some(mut acc) => {
                    acc.seconds += r.seconds;
                    acc.cache_warning = acc.cache_warning.or(r.cache_warning);
                    acc.source = acc.source.merge(r.source);
                    acc
                }
            });
        }
        let rest = grids.split_off(1);
        sun[m].push(grids.pop().expect("the sun part"));
        if !rest.is_empty() {
            diffuse[m] = rest;
        }
    }
    let mut cached = 0;
    let mut bases = Vec::with_capacity(scene.models.len());
    for (m, (sun, diffuse)) in sun.into_iter().zip(diffuse).enumerate() {
        if let Some(r) = &reports[m] {
            cached += (r.source == LightingSource::Cached) as usize;
            progress.model_lit(&scene.models[m], r);
        }
        let [sky, ground, skytop] = &diffuse[..] else {
            return Err(lighting_err(
                m,
                LightingError::Illumination("the diffuse parts are missing".into()),
            ));
        };
        bases.push(Some(
            PhysicalBasis::new(&sun, sky, ground, skytop).map_err(|e| lighting_err(m, e))?,
        ));
    }
    let cached = root_count(runner, "cached models", cached)?;
    let solve_seconds = all_solved.then(|| reports.iter().flatten().map(|r| r.seconds).sum());

    // The forest grid's parts: every process solves them (deterministic, and small).
    let forest = match (in_forest, forest) {
        (true, Some(gopts)) => {
            let fine: Vec<_> = own.iter().zip(&media).collect();
            let instances: Vec<ForestInstance> = scene
                .instances
                .iter()
                .map(|i| {
                    let (d, m) = fine[i.model as usize];
                    ForestInstance {
                        model: Some((d, m)),
                        to_world: i.transform(),
                    }
                })
                .collect();
            progress.start("forest grid parts", ForestBases::SOLVES as u64);
            let ground = illum.ground.map(|g| g.as_dvec3().to_array());
            let bases = ForestBases::solve(&instances, ground, 0.0, gopts, &mut |done, total| {
                progress.set(done as u64, total as u64)
            });
            progress.finish();
            Some(bases.map_err(|source| PipelineError::Global {
                scene: scene.name.clone(),
                source,
            })?)
        }
        _ => None,
    };
    Ok(Some(PhysicalRelighting {
        bases,
        forest,
        cached,
        solve_seconds,
    }))
}
