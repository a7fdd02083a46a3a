//! The physical light's base solutions (issue 27, docs/relight.md) planned as jobs: per model
//! its sun part for each of the 25 directions a sun above the horizon is solved along,
//! and its three diffuse parts ([`sylva_light::relight::physical`]), each a light part of the
//! per-sun light ([`PartsPlan`]) solved for a unit sun along that direction, so each is
//! cached, solved as a job and shared exactly as a forest's parts are
//! ([`crate::forest::solve_light_parts`]); then, with a forest, the coarse grid's parts
//! ([`ForestBases`]), from the root's cache or solved there and sent to every process. Nothing here depends on the
//! sun's direction: the light it gives moves with the sun without a solve.

use std::time::Instant;

use sylva_core::cache::{CacheKey, Lookup};
use sylva_core::jobs::{from_root, Runner};
use sylva_core::wire::{Reader, Writer};
use sylva_geom::Scene;
use sylva_lb::{Bounds, DensityGrid, Dims};
use sylva_light::forest::ForestBases;
use sylva_light::lighting::{
    model_density, part_path, LightingError, LightingReport, LightingSource, PartsLayout, PartsPlan,
};
use sylva_light::relight::physical::{
    overhead_part, sun_part_illumination, PhysicalBasis, PARTS, SUN_PARTS,
};
use sylva_light::relight::physical_basis::{
    compressed_physical_key, lookup_physical, physical_path, store_physical, CachedPhysical,
    CompressedPhysicalBasis, PhysicalTarget, StoredPhysicalBasis, PHYSICAL_EXTENSION,
};
use sylva_light::relight::GlobalGridOptions;
use sylva_light::Progress;
use sylva_render::stages::stage;

use crate::forest::{
    coarse_at_root, forest_cache, forest_densities, forest_instances, solve_light_parts,
    uses_forest, CoarseError, PlanParts,
};
use crate::jobs::root_count;
use crate::{lighting_options, scene_illumination, BasisUse, LbPlan, PipelineError};

/// What the physical light's bases are made and kept as.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhysicalBasisPlan {
    /// Solve missing parts, or take cached bases only.
    pub basis: BasisUse,
    /// The parts compressed to this, and the compressed basis cached per model (`None`:
    /// kept as solved, 28 × 3 f32 per site).
    pub target: Option<PhysicalTarget>,
    /// With a target, also keep the uncompressed parts ([`PhysicalRelighting::raw`]).
    pub keep_raw: bool,
}

/// Every model's physical basis and the forest grid's parts: what a scene is relit with.
pub struct PhysicalRelighting {
    /// Per model, its basis as the light reads it: compressed with a target.
    pub bases: Vec<Option<StoredPhysicalBasis>>,
    /// Per model, its uncompressed parts beside compressed ones (with
    /// [`PhysicalBasisPlan::keep_raw`]); empty otherwise.
    pub raw: Vec<Option<PhysicalBasis>>,
    pub forest: Option<ForestBases>,
    /// Models whose basis (compressed, or its parts) came from the cache.
    pub cached: usize,
    /// Seconds the parts' solves took: solved now, or as recorded in the compressed entries
    /// (`None` when some came from the cache without a record).
    pub solve_seconds: Option<f64>,
    /// Seconds the forest grid's parts took (from the cache or solved); `None` without a
    /// forest grid.
    pub forest_seconds: Option<f64>,
    /// Bytes of every model's parts uncompressed (28 × 3 f32 per site).
    pub raw_bytes: u64,
}

/// The 28 parts' cache keys of a model in [`PhysicalBasis`]'s order: its sun parts' (one
/// plan per direction), then the overhead plan's top sky, sky and ground (the side sky is
/// the sky less the top's).
fn part_keys(sun_parts: &[PartsLayout], overhead: usize) -> [CacheKey; PARTS] {
    std::array::from_fn(|k| {
        let (plan, part) = basis_part(k, overhead);
        sun_parts[plan].keys[part]
    })
}

/// Where part `k` of [`PhysicalBasis`]'s order comes from: (the sun plan, its light part):
/// each sun plan's sun part, then the overhead plan's top sky, sky and ground.
fn basis_part(k: usize, overhead: usize) -> (usize, usize) {
    match k {
        k if k < SUN_PARTS => (k, 0),
        k => (overhead, [3, 1, 2][k - SUN_PARTS]),
    }
}

/// Whether a model's basis has its files in `dir` (not yet read): the compressed entry
/// `compressed` or every part (from which it is made), or every part when they are kept
/// too or there is no target.
fn basis_files_present(
    dir: &std::path::Path,
    model: &sylva_geom::Model,
    layouts: &[PartsLayout],
    compressed: Option<CacheKey>,
    bplan: &PhysicalBasisPlan,
) -> bool {
    let parts_present = || {
        part_keys(layouts, overhead_part())
            .iter()
            .enumerate()
            .all(|(k, &key)| {
                let (_, part) = basis_part(k, overhead_part());
                part_path(dir, model, part, key).exists()
            })
    };
    // With a target, a missing compressed entry is made from cached parts.
    match compressed {
        Some(key) if !bplan.keep_raw => {
            physical_path(&sylva_core::cache::Cache::new(dir), model, key).exists()
                || parts_present()
        }
        _ => parts_present(),
    }
}

/// Whether model `k` of a forest may have its basis in `dir` (whose file `names` are given),
/// asked before its density: a compressed entry of any key (its key holds the neighbours'
/// foliage), or its diffuse parts (whose keys do not). `false` means surely not.
fn forest_basis_may_be_cached(
    dir: &std::path::Path,
    names: &[String],
    scene: &Scene,
    k: usize,
    lb: &LbPlan,
    opts: &sylva_light::lighting::LightingOptions,
) -> Result<bool, LightingError> {
    let model = &scene.models[k];
    let prefix = format!("{}-physical-", sylva_core::file_stem(&model.name, "model"));
    let suffix = format!(".{PHYSICAL_EXTENSION}");
    if names
        .iter()
        .any(|n| n.starts_with(&prefix) && n.ends_with(&suffix))
    {
        return Ok(true);
    }
    let layout = PartsPlan::layout(
        model,
        &sun_part_illumination(&scene_illumination(scene), overhead_part()),
        &opts.for_model(scene, k),
        lb.solver,
        None,
    )?;
    Ok((SUN_PARTS..PARTS).all(|k| {
        let (_, part) = basis_part(k, overhead_part());
        part_path(dir, model, part, layout.keys[part]).exists()
    }))
}

/// Every model's physical basis (compressed to `bplan`'s target and cached as such, or as
/// parts; from the root's cache, or solved through `runner` and cached there) and, for a
/// forest (`forest`, more than one instance), the coarse grid's parts. `None` when
/// `bplan.basis` takes cached bases only and one is missing. Every process calls it with the
/// same scene and options and gets the same relighting.
pub fn precompute_physical(
    scene: &Scene,
    lb: &LbPlan,
    bplan: &PhysicalBasisPlan,
    forest: Option<&GlobalGridOptions>,
    runner: &dyn Runner,
    progress: &dyn Progress,
) -> Result<Option<PhysicalRelighting>, PipelineError> {
    let _span = tracing::info_span!(stage::LB_PRECOMPUTE).entered();
    let several = runner.processes() > 1;
    let root = runner.is_root();
    let illum = scene_illumination(scene);
    let mut opts = lighting_options(scene, lb);
    if several {
        runner.agree("the LB solver", &lb.solver.cache_tag())?;
        runner.agree(
            "the physical basis settings",
            &format!(
                "{} ({} models, {} instances) grid {} forest grid {:?} {bplan:?}",
                scene.name,
                scene.models.len(),
                scene.instances.len(),
                opts.grid,
                forest.map(|f| f.sites),
            ),
        )?;
    }
    if !root {
        opts.cache_dir = None;
    }
    let lighting_err = |k: usize, source: LightingError| PipelineError::Lighting {
        model: scene.models[k].name.clone(),
        source,
    };
    let in_forest = uses_forest(scene, lb.light, forest);
    // In a forest the parts' keys need every model voxelized and the neighbours' foliage
    // measured (seconds). Cached bases only: first rule out what surely is not cached.
    if bplan.basis == BasisUse::IfCached && in_forest {
        let maybe = from_root(
            runner,
            "whether every basis may be cached",
            || {
                let Some(dir) = opts.cache_dir.as_deref() else {
                    return Ok(false);
                };
                let names: Vec<String> = std::fs::read_dir(dir)
                    .map(|entries| {
                        entries
                            .flatten()
                            .map(|e| e.file_name().to_string_lossy().into_owned())
                            .collect()
                    })
                    .unwrap_or_default();
                (0..scene.models.len()).try_fold(true, |all, k| {
                    Ok::<_, PipelineError>(
                        all && forest_basis_may_be_cached(dir, &names, scene, k, lb, &opts)
                            .map_err(|e| lighting_err(k, e))?,
                    )
                })
            },
            |yes: &bool| vec![*yes as u8],
            |data| Ok(data.first() == Some(&1)),
        )?;
        if !maybe {
            return Ok(None);
        }
    }
    // In a forest every model's density and the neighbours' foliage added to it are made
    // first: the sun parts' keys hold the added foliage's, and the forest grid needs them all.
    let forest_d = match (in_forest, forest) {
        (true, Some(gopts)) => Some(forest_densities(scene, lb, gopts, progress)?),
        _ => None,
    };
    let shade_key = |m: usize| {
        forest_d
            .as_ref()
            .and_then(|d| d.shades[m].as_ref())
            .map(|s| s.key)
    };
    // Per model, one plan per sun direction; the overhead sun's also solves the diffuse
    // parts (they do not depend on the sun). Their keys, grids and media first, without
    // densities.
    let overhead = overhead_part();
    let mut layouts: Vec<Vec<PartsLayout>> = Vec::with_capacity(scene.models.len());
    for (k, model) in scene.models.iter().enumerate() {
        let mopts = opts.for_model(scene, k);
        let suns: Vec<_> = (0..SUN_PARTS)
            .map(|part| sun_part_illumination(&illum, part))
            .collect();
        layouts.push(
            PartsPlan::layouts(model, &suns, &mopts, lb.solver, shade_key(k))
                .map_err(|e| lighting_err(k, e))?,
        );
    }
    // Per model, the medium its parts are solved with (the forest grid mixes them).
    let media: Vec<_> = layouts.iter().map(|l| l[0].medium.clone()).collect();
    let keys: Vec<Option<CacheKey>> = layouts
        .iter()
        .map(|l| {
            bplan
                .target
                .map(|t| compressed_physical_key(&part_keys(l, overhead), &t))
        })
        .collect();
    // Per model, its parts' grid and box.
    let grids: Vec<(Dims, Bounds)> = layouts.iter().map(|l| (l[0].dims, l[0].bounds)).collect();
    // Cached bases only: the cache's files answer from the keys before any plan is made or
    // part read (without a forest, before any model is voxelized: seconds each), for a
    // basis that is not there, a default render's usual case.
    if bplan.basis == BasisUse::IfCached {
        let present = from_root(
            runner,
            "whether every basis may be cached",
            || {
                Ok::<_, PipelineError>(opts.cache_dir.as_deref().is_some_and(|dir| {
                    (0..scene.models.len()).all(|m| {
                        basis_files_present(dir, &scene.models[m], &layouts[m], keys[m], bplan)
                    })
                }))
            },
            |yes: &bool| vec![*yes as u8],
            |data| Ok(data.first() == Some(&1)),
        )?;
        if !present {
            return Ok(None);
        }
    }
    // Told once the bases are used (a render that falls back to the per-sun light tells it).
    if let Some(d) = &forest_d {
        for (model, shade) in scene.models.iter().zip(&d.shades) {
            if let Some(s) = shade {
                progress.neighbour_shade(model, s);
            }
        }
    }

    // The root: each model's compressed entry, when there is a target and a cache.
    let t_lookup = Instant::now();
    let mut hits: Vec<Option<CachedPhysical>> = scene.models.iter().map(|_| None).collect();
    let mut bad: Vec<Option<String>> = scene.models.iter().map(|_| None).collect();
    if let (Some(dir), true) = (&opts.cache_dir, root) {
        for (m, key) in keys.iter().enumerate() {
            let Some(key) = *key else { continue };
            let (dims, bounds) = grids[m];
            match lookup_physical(dir, &scene.models[m], key, dims, bounds) {
                Lookup::Hit(h) => hits[m] = Some(h),
                Lookup::Miss => {}
                Lookup::Bad(reason) => bad[m] = Some(reason),
            }
        }
    }
    let lookup_seconds = t_lookup.elapsed().as_secs_f64();
    // To every process: the models whose parts are needed (no compressed entry, or the
    // uncompressed parts kept as well).
    let need: Vec<usize> = from_root(
        runner,
        "the models whose parts are needed",
        || {
            Ok::<_, PipelineError>(
                (0..scene.models.len())
                    .filter(|&m| bplan.target.is_none() || bplan.keep_raw || hits[m].is_none())
                    .collect(),
            )
        },
        |need: &Vec<usize>| {
            let mut w = Writer::default();
            w.u64s(&need.iter().map(|&m| m as u64).collect::<Vec<_>>());
            w.0
        },
        |data| {
            let mut r = Reader::new(data, "models whose parts are needed");
            let need = r.indices(scene.models.len())?;
            r.end()?;
            Ok(need)
        },
    )?;
    // The densities of the models whose parts are needed (a forest's are all made), and
    // those models' plans.
    let (mut own, shades): (Vec<Option<DensityGrid>>, Vec<_>) = match forest_d {
        Some(d) => (d.own.into_iter().map(Some).collect(), d.shades),
        None => scene.models.iter().map(|_| (None, None)).unzip(),
    };
    let mut wanted: Vec<PlanParts> = Vec::with_capacity(need.len() * SUN_PARTS);
    for &k in &need {
        let model = &scene.models[k];
        let mopts = opts.for_model(scene, k);
        if own[k].is_none() {
            let (d, _) =
                model_density(model, &illum, &mopts, lb.solver).map_err(|e| lighting_err(k, e))?;
            own[k] = Some(d);
        }
        let density = own[k].as_ref().expect("made above");
        for part in 0..SUN_PARTS {
            let plan = PartsPlan::new(
                model,
                &sun_part_illumination(&illum, part),
                &mopts,
                lb.solver,
                density.clone(),
                shades[k].as_ref(),
            )
            .map_err(|e| lighting_err(k, e))?;
            wanted.push(PlanParts {
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
    if bplan.basis == BasisUse::IfCached {
        let all_cached = from_root(
            runner,
            "whether every part is cached",
            || {
                Ok::<_, PipelineError>(
                    wanted
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
    let solved = solve_light_parts(scene, lb, &wanted, runner, progress)?;

    // Per model needed: its 25 sun parts and the overhead plan's diffuse parts.
    let mut sun: Vec<Vec<sylva_lb::LightingGrid>> =
        scene.models.iter().map(|_| Vec::new()).collect();
    let mut diffuse: Vec<Vec<sylva_lb::LightingGrid>> =
        scene.models.iter().map(|_| Vec::new()).collect();
    let mut reports: Vec<Option<LightingReport>> = scene.models.iter().map(|_| None).collect();
    let mut all_solved: Vec<bool> = scene.models.iter().map(|_| true).collect();
    for (w, (mut grids, report)) in wanted.iter().zip(solved) {
        let m = w.model;
        if let Some(r) = report {
            all_solved[m] &= r.source != LightingSource::Cached;
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
    let mut full: Vec<Option<PhysicalBasis>> = scene.models.iter().map(|_| None).collect();
    for &m in &need {
        let [sky, ground, skytop] = &diffuse[m][..] else {
            return Err(lighting_err(
                m,
                LightingError::Illumination("the diffuse parts are missing".into()),
            ));
        };
        full[m] =
            Some(PhysicalBasis::new(&sun[m], sky, ground, skytop).map_err(|e| lighting_err(m, e))?);
    }
    // Per model, its parts' solve seconds: solved now, or as its compressed entry recorded.
    let mut seconds: Vec<Option<f64>> = (0..scene.models.len())
        .map(|m| match (&reports[m], all_solved[m]) {
            (Some(r), true) => Some(r.seconds),
            _ => None,
        })
        .collect();

    let mut cached = 0;
    let mut bases: Vec<Option<StoredPhysicalBasis>> = Vec::with_capacity(scene.models.len());
    let mut raw: Vec<Option<PhysicalBasis>> = Vec::new();
    for m in 0..scene.models.len() {
        let model = &scene.models[m];
        let (Some(target), Some(key)) = (bplan.target, keys[m]) else {
            // Kept as solved.
            if let Some(r) = &reports[m] {
                cached += (r.source == LightingSource::Cached) as usize;
                progress.model_lit(model, r);
            }
            bases.push(full[m].take().map(StoredPhysicalBasis::Full));
            continue;
        };
        // The root: the cached compressed basis, or the parts compressed and stored; to
        // every process.
        let t = Instant::now();
        let mut report = reports[m].clone();
        let hit = hits[m].take();
        let compressed = from_root(
            runner,
            "a model's compressed physical basis",
            || {
                if let Some((c, recorded)) = hit {
                    seconds[m] = recorded;
                    report = Some(LightingReport {
                        source: LightingSource::Cached,
                        seconds: lookup_seconds / scene.models.len() as f64,
                        path: opts
                            .cache_dir
                            .as_ref()
                            .map(|d| physical_path(&sylva_core::cache::Cache::new(d), model, key)),
                        dims: c.dims(),
                        cache_warning: None,
                    });
                    return Ok(c);
                }
                let parts = full[m]
                    .as_ref()
                    .expect("parts of a model not cached compressed");
                let density = own[m].as_ref().expect("a needed model's density");
                let c = CompressedPhysicalBasis::compress(parts, density, &target)
                    .map_err(|e| lighting_err(m, e))?;
                if let (Some(dir), Some(r)) = (&opts.cache_dir, report.as_mut()) {
                    let warning = store_physical(dir, model, key, &c, seconds[m]);
                    r.cache_warning = r.cache_warning.take().or(warning);
                    r.path = Some(physical_path(
                        &sylva_core::cache::Cache::new(dir),
                        model,
                        key,
                    ));
                    // A damaged or stale entry was replaced: say why.
                    if let Some(reason) = bad[m].take() {
                        r.source = LightingSource::Recomputed { reason };
                    }
                    r.seconds += t.elapsed().as_secs_f64();
                }
                Ok::<_, PipelineError>(c)
            },
            CompressedPhysicalBasis::to_bytes,
            |data| {
                CompressedPhysicalBasis::from_bytes(data).map_err(|e| {
                    PipelineError::Jobs(sylva_core::jobs::JobError::Transport(format!(
                        "a model's compressed physical basis: {e}"
                    )))
                })
            },
        )?;
        if let Some(r) = &report {
            cached += (r.source == LightingSource::Cached) as usize;
            progress.model_lit(model, r);
        }
        if bplan.keep_raw {
            raw.resize_with(scene.models.len(), || None);
            raw[m] = full[m].take();
        }
        bases.push(Some(StoredPhysicalBasis::Compressed(Box::new(compressed))));
    }
    let cached = root_count(runner, "cached models", cached)?;
    let solve_seconds = from_root(
        runner,
        "the parts' solve seconds",
        || Ok::<_, PipelineError>(seconds.iter().copied().sum::<Option<f64>>()),
        |s: &Option<f64>| s.map_or(Vec::new(), |s| s.to_le_bytes().to_vec()),
        |data| Ok(data.try_into().ok().map(f64::from_le_bytes)),
    )?;
    let raw_bytes = grids
        .iter()
        .map(|&(dims, _)| PhysicalBasis::memory_needed(dims))
        .sum();

    // The forest grid's parts: the root's from its cache or solved (and cached), sent to
    // every process.
    let mut forest_seconds = None;
    let forest = match (in_forest, forest) {
        (true, Some(gopts)) => {
            let fine: Vec<(&DensityGrid, _)> = own
                .iter()
                .map(|d| d.as_ref().expect("a forest's densities"))
                .zip(&media)
                .collect();
            let instances = forest_instances(scene, &fine);
            let t = Instant::now();
            let ground = illum.ground.map(|g| g.as_dvec3().to_array());
            let cache = forest_cache(scene, opts.cache_dir.as_deref());
            let bases = coarse_at_root(
                runner,
                progress,
                (
                    "the forest grid's parts",
                    "forest grid parts",
                    ForestBases::SOLVES as u64,
                ),
                |step| {
                    ForestBases::solve_cached(&instances, ground, 0.0, gopts, cache.as_ref(), step)
                },
                ForestBases::parts_bytes,
                |data| ForestBases::with_parts(&instances, ground, 0.0, gopts, data),
            )
            .map_err(|source| match source {
                CoarseError::Light(source) => PipelineError::Global {
                    scene: scene.name.clone(),
                    source,
                },
                CoarseError::Pipeline(e) => e,
            })?;
            forest_seconds = Some(t.elapsed().as_secs_f64());
            Some(bases)
        }
        _ => None,
    };
    Ok(Some(PhysicalRelighting {
        bases,
        raw,
        forest,
        cached,
        solve_seconds,
        forest_seconds,
        raw_bytes,
    }))
}
