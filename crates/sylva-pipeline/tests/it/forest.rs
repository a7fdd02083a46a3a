//! The physical light's coarse forest grid (docs/light.md, "Forests"): a model's light parts
//! sum to its light in the open, a lone tree keeps its light, a tree in its neighbours'
//! shade gets less, and every weight is linear in the sun's irradiance and the sky's
//! radiance.

use glam::{Affine3A, Vec3};
use sylva_core::colour::luminance;
use sylva_lb::light::Environment;
use sylva_lb::{CpuSolver, DensityGrid, MediumParams};
use sylva_light::forest::{free_weights, neighbour_shade, ForestInstance, ForestLight};
use sylva_light::lighting::{
    model_density, model_lighting, model_lighting_parts, model_lighting_parts_on,
    physical_environment, LightingOptions, PartWeights,
};
use sylva_light::relight::GlobalGridOptions;
use sylva_light::{Light, Silent};
use sylva_pipeline::scene_illumination;
use sylva_pipeline::{load_scene, LbPlan, PrepareOptions, PreparedScene};

const GRID: usize = 24;

fn opts() -> LightingOptions {
    LightingOptions {
        grid: GRID,
        light: Light::Physical,
        preset: "leaf".into(),
        cache_dir: None,
    }
}

/// The `shade` scene's models as parts: (density, medium) per model.
pub(crate) fn shade_parts() -> (sylva_geom::Scene, Vec<(DensityGrid, MediumParams)>) {
    let scene = load_scene("shade", None).unwrap();
    let illum = scene_illumination(&scene);
    let fine = scene
        .models
        .iter()
        .map(|m| {
            let (_, _, d, medium) =
                model_lighting_parts(m, &illum, &opts(), &CpuSolver, &mut |_, _, _| {}).unwrap();
            (d, medium)
        })
        .collect();
    (scene, fine)
}

pub(crate) fn instances<'a>(
    scene: &sylva_geom::Scene,
    fine: &'a [(DensityGrid, MediumParams)],
    which: &[usize],
) -> Vec<ForestInstance<'a>> {
    which
        .iter()
        .map(|&k| {
            let i = &scene.instances[k];
            let (d, m) = &fine[i.model as usize];
            ForestInstance {
                model: Some((d, m)),
                to_world: i.transform(),
            }
        })
        .collect()
}

fn y(v: Vec3) -> f32 {
    luminance(v.to_array())
}

#[test]
fn the_parts_sum_to_the_model_alone() {
    let scene = load_scene("shade", None).unwrap();
    let illum = scene_illumination(&scene);
    let model = &scene.models[1];
    let (whole, _) = model_lighting(model, &illum, &opts(), &CpuSolver, &mut |_, _, _| {}).unwrap();
    let (parts, _, _, _) =
        model_lighting_parts(model, &illum, &opts(), &CpuSolver, &mut |_, _, _| {}).unwrap();
    let free = parts.parts().unwrap().free;
    let d = whole.dims();
    let mut worst = 0.0f32;
    let mut peak = 0.0f32;
    for x in 0..d.nx {
        for yy in 0..d.ny {
            for z in 0..d.nz {
                let p = whole.site_position(x, yy, z);
                let a = whole.sample(p);
                let b = parts.sample_weighted(p, &free);
                worst = worst.max((a - b).abs().max_element());
                peak = peak.max(a.max_element());
            }
        }
    }
    assert!(peak > 0.0);
    assert!(
        worst <= 1e-4 * peak,
        "parts differ by {worst} (peak {peak})"
    );
}

#[test]
fn a_lone_tree_keeps_its_light() {
    let (scene, fine) = shade_parts();
    let env = physical_environment(&scene_illumination(&scene)).unwrap();
    let free = free_weights(&env);
    let mut reports = Vec::new();
    let g = ForestLight::solve(
        &instances(&scene, &fine, &[2]),
        &env,
        0.0,
        &GlobalGridOptions { sites: 32 },
        &mut |done, total| reports.push((done, total)),
    )
    .unwrap();
    // Progress comes with every LB step (a long solve moves its bar), in order, to the end.
    assert!(reports.len() > 3 * 32, "{} reports", reports.len());
    assert!(reports
        .windows(2)
        .all(|w| w[0].0 <= w[1].0 && w[0].1 == w[1].1));
    assert_eq!(reports.last().map(|r| r.0), reports.last().map(|r| r.1));
    let w = g.weights[0];
    let r = |a: Vec3, b: Vec3| y(a) / y(b);
    assert!((y(w.sun) - 1.0).abs() < 0.02, "sun {}", y(w.sun));
    assert!(
        (r(w.sky, free.sky) - 1.0).abs() < 0.05,
        "sky {w:?} / {free:?}"
    );
    assert!(
        (r(w.sky_top, free.sky_top) - 1.0).abs() < 0.02,
        "sky through the top {w:?} / {free:?}"
    );
    // The ground around a lone tree is its own shade's too (the fine grid assumes it open):
    // less, but not far.
    let ground = r(w.ground, free.ground);
    assert!(ground > 0.6 && ground < 1.05, "ground {ground}");
    // No instance with a grid: the free weights exactly.
    let g = ForestLight::solve(
        &[ForestInstance {
            model: None,
            to_world: Affine3A::IDENTITY,
        }],
        &env,
        0.0,
        &GlobalGridOptions { sites: 32 },
        &mut |_, _| {},
    )
    .unwrap();
    assert_eq!(g.weights, vec![free]);
    assert!(ForestLight::solve(
        &instances(&scene, &fine, &[2]),
        &env,
        0.0,
        &GlobalGridOptions { sites: 4 },
        &mut |_, _| {},
    )
    .is_err());
}

#[test]
fn a_tree_in_its_neighbours_shade_gets_less_light() {
    // 004 Fig. 2: instance 1 stands in the beech's shade, instance 2, the same model, in
    // the open.
    let (scene, fine) = shade_parts();
    let env = physical_environment(&scene_illumination(&scene)).unwrap();
    let g = ForestLight::solve(
        &instances(&scene, &fine, &[0, 1, 2]),
        &env,
        0.0,
        &GlobalGridOptions::default(),
        &mut |_, _| {},
    )
    .unwrap();
    let (shaded, open) = (g.weights[1], g.weights[2]);
    assert!(y(open.sun) > 0.95, "open {open:?}");
    assert!(
        y(shaded.sun) < 0.5 * y(open.sun),
        "shaded {shaded:?} open {open:?}"
    );
    assert!(
        y(shaded.sky) < y(open.sky),
        "shaded {shaded:?} open {open:?}"
    );

    // In the renderer: the shaded instance's crown gets less indirect light than with its
    // model's light in the open (the same instance, --no-global).
    let prepare = |forest| {
        PreparedScene::new(
            scene.clone(),
            &PrepareOptions {
                lb: Some(LbPlan {
                    solver: &CpuSolver,
                    grid: Some(GRID),
                    cache_dir: None,
                    light: Light::Physical,
                }),
                forest,
                ..PrepareOptions::default()
            },
            &Silent,
        )
        .unwrap()
    };
    let with = prepare(Some(GlobalGridOptions::default()));
    let without = prepare(None);
    assert!(with.forest.is_some() && without.forest.is_none());
    let inst = &with.tracer.cpu().accel.instances()[1];
    let centre = 0.5 * (inst.world_bounds.min + inst.world_bounds.max);
    let (a, b) = (
        with.indirect().plant(1, inst, centre).unwrap(),
        without.indirect().plant(1, inst, centre).unwrap(),
    );
    assert!(y(a) < 0.9 * y(b), "with the forest grid {a}, without {b}");
}

#[test]
fn the_weights_are_linear_in_the_sun_and_the_sky() {
    let (scene, fine) = shade_parts();
    let env = physical_environment(&scene_illumination(&scene)).unwrap();
    let inst = instances(&scene, &fine, &[0, 1, 2]);
    let solve = |e: &Environment| {
        ForestLight::solve(
            &inst,
            e,
            0.0,
            &GlobalGridOptions { sites: 32 },
            &mut |_, _| {},
        )
        .unwrap()
        .weights
    };
    let both = solve(&env);
    let sun = solve(&Environment {
        sky_radiance: [0.0; 3],
        ..env
    });
    let sky = solve(&Environment {
        sun_irradiance: [0.0; 3],
        ..env
    });
    let twice = solve(&Environment {
        sun_irradiance: env.sun_irradiance.map(|v| 2.0 * v),
        sky_radiance: env.sky_radiance.map(|v| 2.0 * v),
        ..env
    });
    let close = |a: Vec3, b: Vec3, what: &str| {
        let tol = 1e-3 * a.max_element().max(b.max_element()).max(1e-3);
        assert!((a - b).abs().max_element() <= tol, "{what}: {a} vs {b}");
    };
    for i in 0..inst.len() {
        let (w, s, k, t): (PartWeights, PartWeights, PartWeights, PartWeights) =
            (both[i], sun[i], sky[i], twice[i]);
        // The sun's transmittance depends on neither.
        close(w.sun, s.sun, "sun part, sun only");
        close(w.sun, t.sun, "sun part, doubled");
        // The arriving light: the sun's share plus the sky's, and twice under both doubled.
        close(w.sky, s.sky + k.sky, "sky part, sum");
        close(w.ground, s.ground + k.ground, "ground part, sum");
        close(2.0 * w.sky, t.sky, "sky part, doubled");
        close(2.0 * w.ground, t.ground, "ground part, doubled");
    }
}

#[test]
fn neighbours_inside_the_box_shade_only_the_sun_part() {
    // The shade scene's beech box holds part of a catalpa's crown: its sun part is solved
    // with that foliage added, its diffuse parts on its own density. (Not less light
    // everywhere: the added leaves also scatter the beam, towards some of the sites.)
    let scene = load_scene("shade", None).unwrap();
    let illum = scene_illumination(&scene);
    let own: Vec<(DensityGrid, MediumParams)> = scene
        .models
        .iter()
        .map(|m| model_density(m, &illum, &opts(), &CpuSolver).unwrap())
        .collect();
    let grids: Vec<&DensityGrid> = own.iter().map(|(d, _)| d).collect();
    let placed: Vec<(usize, Affine3A)> = scene
        .instances
        .iter()
        .map(|i| (i.model as usize, i.transform()))
        .collect();
    let shades = neighbour_shade(&grids, &placed, 0.0, &GlobalGridOptions::default()).unwrap();
    let (k, shade) = shades
        .iter()
        .enumerate()
        .find_map(|(k, s)| s.as_ref().map(|s| (k, s)))
        .expect("a box with a neighbour's foliage in it");
    assert!(shade.added_depth > 0.0 && shade.added_depth < shade.own_depth);
    let model = &scene.models[k];
    let lit = |shade| {
        model_lighting_parts_on(
            model,
            &illum,
            &opts(),
            &CpuSolver,
            own[k].0.clone(),
            shade,
            &mut |_, _, _| {},
        )
        .unwrap()
    };
    let (plain, _, d0, _) = lit(None);
    let (shaded, _, d1, _) = lit(Some(shade));
    // The density handed on (to the forest grid) is the model's own either way.
    assert_eq!(d0.density, d1.density);
    let only = |sun: f32, sky_top: f32, sky: f32, ground: f32| PartWeights {
        sun: Vec3::splat(sun),
        sky_top: Vec3::splat(sky_top),
        sky: Vec3::splat(sky),
        ground: Vec3::splat(ground),
    };
    let d = plain.dims();
    let (mut changed, mut peak) = (0.0f32, 0.0f32);
    for x in 0..d.nx {
        for yy in 0..d.ny {
            for z in 0..d.nz {
                let p = plain.site_position(x, yy, z);
                for w in [
                    only(0.0, 1.0, 0.0, 0.0),
                    only(0.0, 0.0, 1.0, 0.0),
                    only(0.0, 0.0, 0.0, 1.0),
                ] {
                    assert_eq!(
                        plain.sample_weighted(p, &w),
                        shaded.sample_weighted(p, &w),
                        "a diffuse part changed at {p}"
                    );
                }
                let sun = only(1.0, 0.0, 0.0, 0.0);
                let (a, b) = (
                    plain.sample_weighted(p, &sun),
                    shaded.sample_weighted(p, &sun),
                );
                changed = changed.max((y(a) - y(b)).abs());
                peak = peak.max(y(a));
            }
        }
    }
    assert!(
        changed > 0.01 * peak,
        "the sun part did not change: {changed} of {peak}"
    );
}

/// A forest grid's answer is cached: read back exactly as solved, keyed by what it was solved
/// from (another sun, a moved instance: another entry), and a damaged entry is solved again
/// and named.
#[test]
fn the_forest_grid_is_cached_and_a_damaged_entry_is_solved_again() {
    use sylva_light::forest::ForestCache;
    use sylva_light::lighting::LightingSource;

    let (scene, fine) = shade_parts();
    let env = physical_environment(&scene_illumination(&scene)).unwrap();
    let inst = instances(&scene, &fine, &[0, 1, 2]);
    let gopts = GlobalGridOptions { sites: 32 };
    let dir = tempfile::tempdir().unwrap();
    let cache = ForestCache::new(dir.path(), "shade");
    let at = Some(&cache);
    let cached = |inst: &[ForestInstance], env: &Environment| {
        ForestLight::solve_cached(inst, env, 0.0, &gopts, at, &mut |_, _| {}).unwrap()
    };
    let solved = ForestLight::solve(&inst, &env, 0.0, &gopts, &mut |_, _| {}).unwrap();

    let (first, r) = cached(&inst, &env);
    assert_eq!(r.source, LightingSource::Computed);
    assert_eq!(r.what, "forest grid");
    let path = r.path.clone().expect("an entry");
    assert!(path.exists(), "{}", path.display());
    assert_eq!(first, solved);
    let (again, r) = cached(&inst, &env);
    assert_eq!(r.source, LightingSource::Cached);
    assert_eq!(again, solved, "read back bit for bit");

    // Another sun, and one instance moved, are other entries.
    let low = Environment {
        sun_travel: [-0.8, -0.6, 0.0],
        ..env
    };
    let (other, r) = cached(&inst, &low);
    assert_eq!(r.source, LightingSource::Computed);
    assert_ne!(r.path.as_ref(), Some(&path));
    assert_ne!(other, solved);
    let mut moved = inst.clone();
    moved[2].to_world = Affine3A::from_translation(Vec3::new(0.5, 0.0, 0.0)) * moved[2].to_world;
    let (_, r) = cached(&moved, &env);
    assert_eq!(r.source, LightingSource::Computed);
    assert_ne!(r.path.as_ref(), Some(&path));

    // A truncated entry and a foreign file are solved again, the file named, and replaced.
    let bytes = std::fs::read(&path).unwrap();
    for bad in [&bytes[..bytes.len() - 5], &b"garbage"[..]] {
        std::fs::write(&path, bad).unwrap();
        let (value, r) = cached(&inst, &env);
        match &r.source {
            LightingSource::Recomputed { reason } => {
                assert!(reason.contains(&path.display().to_string()), "{reason}")
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(value, solved);
        assert_eq!(std::fs::read(&path).unwrap(), bytes, "replaced");
    }

    // What the root sends: the same answer, and refused for another forest.
    let sent = solved.to_bytes();
    assert_eq!(ForestLight::from_bytes(&sent, 3).unwrap(), solved);
    assert!(ForestLight::from_bytes(&sent, 2).is_err());
    assert!(ForestLight::from_bytes(&sent[..sent.len() - 4], 3).is_err());
}
