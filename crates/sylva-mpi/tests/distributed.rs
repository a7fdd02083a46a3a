//! The distributed pipeline with ranks as threads ([`LocalComm`]): LB lighting solved colour
//! by colour across ranks and a frame split into units give the one-process grids, cache
//! entries and pixels, bit for bit, with 2 and 3 ranks. (The same code under MPI is tested
//! by `crates/sylva-cli/tests/mpi_cli.rs` with `mpirun`.)

use std::path::Path;

use sylva_geom::Scene;
use sylva_lb::CpuSolver;
use sylva_light::lighting::LightingPlan;
use sylva_light::Silent;
use sylva_mpi::lighting::{solve_model_jobs, ModelJob};
use sylva_mpi::{
    light_models, render_frame, solve_forest_parts, Comm, CommError, DistError, LocalComm,
};
use sylva_pipeline::{
    forest_densities, lighting_options, load_scene, LbPlan, PrepareOptions, PreparedScene,
};
use sylva_render::{Frame, Region, RenderSettings};
use sylva_testkit::files_by_name;

const SCENE: &str = r#"
name = "two roses"

[[models]]
name = "rose"
species = "dogrose"

[[models]]
name = "other rose"
species = "dogrose"
seed = 5

[[instances]]
model = "rose"
position = [0.0, 0.0, 0.0]

[[instances]]
model = "other rose"
position = [1.5, 0.0, 1.0]
rotation = 40.0

[ground]
size = [12.0, 12.0]

[camera]
position = [0.0, 2.5, -5.0]
look_at = [0.5, 0.6, 0.0]
fov = 45.0
resolution = [61, 37]

[lb]
grid = 12
"#;

fn options(cache: &Path) -> PrepareOptions<'_> {
    PrepareOptions {
        lb: Some(LbPlan {
            solver: &CpuSolver,
            light: sylva_light::Light::Physical,
            grid: None,
            cache_dir: Some(cache),
        }),
        largest_frame: Some((61, 37, 4)),
        // Ranks light models per colour without the forest grid (docs/light.md, Limits).
        forest: None,
        ..PrepareOptions::default()
    }
}

fn bits(f: &Frame) -> Vec<[u32; 12]> {
    f.pixels
        .iter()
        .map(|p| {
            let mut out = [0u32; 12];
            for (k, v) in [p.local, p.indirect, p.albedo, p.sky].iter().enumerate() {
                for a in 0..3 {
                    out[3 * k + a] = v[a].to_bits();
                }
            }
            out
        })
        .collect()
}

/// The settings of the frames compared: the whole image at 1 and 4 rays per pixel, and a
/// region off the tile grid.
fn settings(p: &PreparedScene) -> Vec<RenderSettings> {
    let camera = p.camera(61, 37);
    let region = Region {
        x0: 5,
        y0: 3,
        width: 50,
        height: 29,
    };
    vec![
        p.settings(camera, 1, 7),
        p.settings(camera, 4, 7),
        RenderSettings {
            region,
            ..p.settings(camera, 9, 7)
        },
    ]
}

/// On every rank: light the models across the ranks, render `settings` across them; rank 0
/// returns the frames and the count of models from the cache.
fn distributed(comm: &LocalComm, scene: Scene, cache: &Path) -> Option<(Vec<Frame>, usize)> {
    let opts = options(cache);
    let (lighting, cached) =
        light_models(comm, &scene, opts.lb.as_ref().unwrap(), &Silent).unwrap();
    let p = PreparedScene::with_lighting(scene, &opts, lighting, cached).unwrap();
    let frames: Vec<Option<Frame>> = settings(&p)
        .iter()
        .map(|s| {
            render_frame(comm, &p, s, &Silent).unwrap().map(|d| {
                assert_eq!(d.ranks.len(), comm.size());
                assert_eq!(
                    d.ranks.iter().map(|r| r.units).sum::<usize>(),
                    d.layout.units()
                );
                assert!(d.imbalance() >= 0.0);
                d.frame
            })
        })
        .collect();
    (comm.rank() == 0).then(|| (frames.into_iter().map(Option::unwrap).collect(), cached))
}

#[test]
fn distributed_lighting_and_frames_are_the_one_process_ones() {
    let dir = tempfile::tempdir().unwrap();
    let scene_file = dir.path().join("roses.toml");
    std::fs::write(&scene_file, SCENE).unwrap();

    let one_cache = dir.path().join("one");
    // Each rank would build the scene itself; building it once is faster and the same.
    let scene = load_scene(scene_file.to_str().unwrap(), None).unwrap();
    let one = PreparedScene::new(scene.clone(), &options(&one_cache), &Silent).unwrap();
    let want: Vec<Frame> = settings(&one)
        .iter()
        .map(|s| one.render(s, &Silent).unwrap())
        .collect();

    for ranks in [2, 3] {
        let cache = dir.path().join(format!("ranks{ranks}"));
        for pass in 0..2 {
            let group = LocalComm::group(ranks);
            let got = std::thread::scope(|s| {
                let handles: Vec<_> = group
                    .iter()
                    .map(|c| {
                        let scene = scene.clone();
                        let cache = &cache;
                        s.spawn(move || distributed(c, scene, cache))
                    })
                    .collect();
                let mut results: Vec<_> = handles.into_iter().map(|h| h.join().unwrap()).collect();
                assert!(results[1..].iter().all(Option::is_none));
                results.swap_remove(0).unwrap()
            });
            let (frames, cached) = got;
            // Solved on the first pass, read back on the second.
            assert_eq!(cached, if pass == 0 { 0 } else { 2 }, "{ranks} ranks");
            for (f, w) in frames.iter().zip(&want) {
                assert_eq!(f.region, w.region);
                assert!(bits(f) == bits(w), "{ranks} ranks, region {:?}", w.region);
                assert_eq!(f.timings.primary_rays, w.timings.primary_rays);
                assert_eq!(f.stats.rays, w.stats.rays);
            }
            // Rank 0 wrote the cache entries one process writes, byte for byte.
            assert_eq!(
                files_by_name(&cache),
                files_by_name(&one_cache),
                "{ranks} ranks"
            );
        }
    }
}

#[test]
fn ranks_with_different_frames_refuse_and_the_abort_ends_the_others() {
    let dir = tempfile::tempdir().unwrap();
    let scene_file = dir.path().join("roses.toml");
    std::fs::write(&scene_file, SCENE).unwrap();
    let scene = load_scene(scene_file.to_str().unwrap(), None).unwrap();
    let p = PreparedScene::new(scene, &PrepareOptions::default(), &Silent).unwrap();
    let group = LocalComm::group(2);
    std::thread::scope(|s| {
        let handles: Vec<_> = group
            .iter()
            .map(|c| {
                let p = &p;
                s.spawn(move || {
                    let seed = if c.rank() == 1 { 8 } else { 7 };
                    let settings = p.settings(p.camera(61, 37), 1, seed);
                    let r = render_frame(c, p, &settings, &Silent);
                    match &r {
                        Err(DistError::Disagree(m)) => {
                            assert!(m.starts_with("rank 1 has the frame"), "{m}");
                            c.abort(1)
                        }
                        Err(DistError::Comm(CommError::Aborted)) => {}
                        other => panic!("rank {}: {:?}", c.rank(), other.as_ref().map(|_| ())),
                    }
                })
            })
            .collect();
        let results: Vec<_> = handles.into_iter().map(|h| h.join()).collect();
        assert!(results[0].is_ok(), "rank 0 is released by the abort");
        assert!(results[1].is_err(), "rank 1 aborted");
    });
}

/// A job kind other than `LbJob` (as relighting's `BasisModelJob` is): a model's density
/// scaled by a factor. Listed, queued and gathered by `solve_model_jobs` alone.
struct ScaledDensity {
    model: usize,
    scale: f32,
}

impl ModelJob for ScaledDensity {
    fn model(&self) -> usize {
        self.model
    }
}

#[test]
fn any_list_of_model_jobs_runs_through_the_queue_in_job_order() {
    let dir = tempfile::tempdir().unwrap();
    let scene_file = dir.path().join("roses.toml");
    std::fs::write(&scene_file, SCENE).unwrap();
    let scene = load_scene(scene_file.to_str().unwrap(), None).unwrap();
    let lb = LbPlan {
        solver: &CpuSolver,
        light: sylva_light::Light::Physical,
        grid: None,
        cache_dir: None,
    };
    let opts = lighting_options(&scene, &lb);
    let plans: Vec<LightingPlan> = scene
        .models
        .iter()
        .map(|m| {
            LightingPlan::new(
                m,
                &sylva_pipeline::scene_illumination(&scene),
                &opts,
                &CpuSolver,
            )
            .unwrap()
        })
        .collect();
    // Models interleaved, so ranks switch density grids.
    let jobs: Vec<ScaledDensity> = (0..7)
        .map(|k| ScaledDensity {
            model: k % 2,
            scale: k as f32 + 0.5,
        })
        .collect();
    let want: Vec<Vec<f32>> = jobs
        .iter()
        .map(|j| {
            let d = plans[j.model].density().unwrap();
            d.density.iter().map(|v| v * j.scale).collect()
        })
        .collect();
    assert!(want.iter().any(|w| w.iter().any(|&v| v > 0.0)));

    for ranks in [2, 3] {
        let group = LocalComm::group(ranks);
        let got = std::thread::scope(|s| {
            let handles: Vec<_> = group
                .iter()
                .map(|c| {
                    let (plans, jobs) = (&plans, &jobs);
                    s.spawn(move || {
                        solve_model_jobs(
                            c,
                            plans,
                            jobs,
                            &mut |job, plan, grid| {
                                assert_eq!(grid.dims, plan.dims());
                                Ok(grid.density.iter().map(|v| v * job.scale).collect())
                            },
                            &|_| {},
                        )
                        .unwrap()
                    })
                })
                .collect();
            let mut results: Vec<_> = handles.into_iter().map(|h| h.join().unwrap()).collect();
            assert!(results[1..].iter().all(Option::is_none));
            results.swap_remove(0).unwrap()
        });
        let values: Vec<Vec<f32>> = got.into_iter().map(|v| v.values).collect();
        assert!(values == want, "{ranks} ranks");
    }

    // A job of a model the plans do not have is refused before anything runs.
    let group = LocalComm::group(1);
    let bad = [ScaledDensity {
        model: 2,
        scale: 1.0,
    }];
    let err = solve_model_jobs(
        &group[0],
        &plans,
        &bad,
        &mut |_, _, _| Ok(Vec::new()),
        &|_| {},
    )
    .unwrap_err();
    assert!(err.to_string().contains("model 2 of 2"), "{err}");
}

#[test]
fn forest_parts_solved_across_ranks_are_the_one_process_entries() {
    let dir = tempfile::tempdir().unwrap();
    let scene_file = dir.path().join("roses.toml");
    std::fs::write(&scene_file, SCENE).unwrap();
    let scene = load_scene(scene_file.to_str().unwrap(), None).unwrap();
    let gopts = sylva_light::relight::GlobalGridOptions::default();
    fn forest_options(cache: &Path) -> PrepareOptions<'_> {
        PrepareOptions {
            forest: Some(sylva_light::relight::GlobalGridOptions::default()),
            ..options(cache)
        }
    }
    // One process: the forest path solves and caches every model's four parts.
    let one_cache = dir.path().join("one");
    let one = PreparedScene::new(scene.clone(), &forest_options(&one_cache), &Silent).unwrap();
    assert!(one.forest.is_some());
    let parts = 4 * scene.models.len();
    assert_eq!(files_by_name(&one_cache).len(), parts);
    for ranks in [2, 3] {
        let cache = dir.path().join(format!("forest{ranks}"));
        for pass in 0..2 {
            let group = LocalComm::group(ranks);
            let solved: Vec<usize> = std::thread::scope(|s| {
                let handles: Vec<_> = group
                    .iter()
                    .map(|c| {
                        let (scene, cache, gopts) = (&scene, &cache, &gopts);
                        s.spawn(move || {
                            let opts = options(cache);
                            let lb = opts.lb.as_ref().unwrap();
                            let densities = forest_densities(scene, lb, gopts).unwrap();
                            solve_forest_parts(c, scene, lb, gopts, &densities, &Silent).unwrap()
                        })
                    })
                    .collect();
                handles.into_iter().map(|h| h.join().unwrap()).collect()
            });
            // Every part on the first pass, none once cached; every rank agrees.
            let want = if pass == 0 { parts } else { 0 };
            assert_eq!(solved, vec![want; ranks], "{ranks} ranks, pass {pass}");
            // Rank 0 stored the entries one process stores, byte for byte.
            assert_eq!(
                files_by_name(&cache),
                files_by_name(&one_cache),
                "{ranks} ranks"
            );
        }
        // Prepared from that cache, the light is the one process's.
        let p = PreparedScene::new(scene.clone(), &forest_options(&cache), &Silent).unwrap();
        assert_eq!(p.forest, one.forest);
        let s = &settings(&one)[0];
        assert!(bits(&p.render(s, &Silent).unwrap()) == bits(&one.render(s, &Silent).unwrap()));
    }
}
