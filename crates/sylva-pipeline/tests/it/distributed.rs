//! The pipeline across processes, ranks as threads (`LocalComm` under `QueueRunner`): the
//! models' LB light, the forest's parts, relighting's bases and frames split into units give
//! the one-process light, cache entries and pixels, bit for bit, with 2 and 3 ranks, cold and
//! warm. (The same code under MPI: crates/sylva-cli/tests/mpi_cli.rs with `mpirun`.)

use std::path::Path;

use sylva_core::jobs::JobError;
use sylva_geom::Scene;
use sylva_lb::CpuSolver;
use sylva_light::relight::{GlobalGridOptions, PhysicalTarget, StoredBasis};
use sylva_light::{Light, Silent};
use sylva_mpi::{Comm, LocalComm, QueueRunner};
use sylva_pipeline::{
    load_scene, precompute_physical, precompute_relighting, relight_options, BasisUse, LbPlan,
    Local, PhysicalBasisPlan, PipelineError, PrepareOptions, PreparedScene, RelightPlan,
    Relighting, RelightingAt,
};
use sylva_render::{Frame, Region, RenderSettings};
use sylva_testkit::{basis_cache_entries, files_by_name};

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

fn lb(cache: Option<&Path>, light: Light) -> LbPlan<'_> {
    LbPlan {
        solver: &CpuSolver,
        light,
        grid: None,
        cache_dir: cache,
    }
}

/// Each model lit for the sun alone (no forest grid), or through the forest grid.
fn options(cache: &Path, forest: bool) -> PrepareOptions<'_> {
    PrepareOptions {
        lb: Some(lb(Some(cache), Light::Physical)),
        light: Light::Physical,
        largest_frame: Some((61, 37, 9)),
        forest: forest.then(GlobalGridOptions::default),
        ..PrepareOptions::default()
    }
}

fn scene() -> (tempfile::TempDir, Scene) {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("roses.toml");
    std::fs::write(&file, SCENE).unwrap();
    let scene = load_scene(file.to_str().unwrap(), None).unwrap();
    (dir, scene)
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

/// `f(runner)` on every rank of a group of `ranks` (threads); each rank's answer.
fn on_ranks<T: Send>(ranks: usize, f: impl Fn(&QueueRunner) -> T + Sync) -> Vec<T> {
    let group = LocalComm::group(ranks);
    std::thread::scope(|s| {
        let handles: Vec<_> = group
            .iter()
            .map(|c| {
                let f = &f;
                s.spawn(move || f(&QueueRunner::new(c)))
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    })
}

/// Prepared and rendered on every rank: the frames at rank 0, each rank's forest light and
/// count of models from the cache.
type RankResult = (
    Option<Vec<Frame>>,
    Option<sylva_light::forest::ForestLight>,
    usize,
);

fn prepare_and_render(runner: &QueueRunner, scene: &Scene, opts: PrepareOptions) -> RankResult {
    let opts = PrepareOptions { runner, ..opts };
    let p = PreparedScene::new(scene.clone(), &opts, &Silent).unwrap();
    let frames: Vec<Option<Frame>> = settings(&p)
        .iter()
        .map(|s| {
            p.render_split(runner, s, &Silent).unwrap().map(|d| {
                assert_eq!(d.ranks.len(), runner.comm().size());
                assert_eq!(
                    d.ranks.iter().map(|r| r.units).sum::<usize>(),
                    d.layout.units()
                );
                assert!(d.imbalance() >= 0.0);
                d.frame
            })
        })
        .collect();
    let frames =
        (runner.comm().rank() == 0).then(|| frames.into_iter().map(Option::unwrap).collect());
    (frames, p.forest, p.lb_models_cached)
}

/// The models' light (per sun, and through the forest grid) prepared on 2 and 3 ranks, cold
/// then warm: rank 0 stores the cache entries one process stores, every rank has the light
/// one process has, and the frames split across the ranks are the one-process frames.
#[test]
fn distributed_light_and_frames_are_the_one_process_ones() {
    let (dir, scene) = scene();
    for forest in [false, true] {
        let one_cache = dir.path().join(format!("one-{forest}"));
        let one = PreparedScene::new(scene.clone(), &options(&one_cache, forest), &Silent).unwrap();
        assert_eq!(one.forest.is_some(), forest);
        let want: Vec<Frame> = settings(&one)
            .iter()
            .map(|s| one.render(s, &Silent).unwrap())
            .collect();
        // In one process a split frame is the frame.
        let split = one
            .render_split(&Local, &settings(&one)[1], &Silent)
            .unwrap()
            .unwrap();
        assert!(bits(&split.frame) == bits(&want[1]));

        for ranks in [2, 3] {
            let cache = dir.path().join(format!("ranks{ranks}-{forest}"));
            for pass in 0..2 {
                let what = format!("{ranks} ranks, forest {forest}, pass {pass}");
                let got = on_ranks(ranks, |r| {
                    prepare_and_render(r, &scene, options(&cache, forest))
                });
                for (rank, (frames, f, cached)) in got.iter().enumerate() {
                    assert_eq!(frames.is_some(), rank == 0, "{what}");
                    // Solved on the first pass, read back on the second.
                    assert_eq!(
                        *cached,
                        if pass == 0 { 0 } else { 2 },
                        "{what}, rank {rank}"
                    );
                    assert!(
                        *f == one.forest,
                        "{what}, rank {rank}: the forest light differs"
                    );
                }
                let frames = got[0].0.as_ref().unwrap();
                for (f, w) in frames.iter().zip(&want) {
                    assert_eq!(f.region, w.region);
                    assert!(bits(f) == bits(w), "{what}, region {:?}", w.region);
                    assert_eq!(f.timings.primary_rays, w.timings.primary_rays);
                    assert_eq!(f.stats.rays, w.stats.rays);
                }
                // Rank 0 wrote the cache entries one process writes, byte for byte.
                assert_eq!(files_by_name(&cache), files_by_name(&one_cache), "{what}");
            }
        }
    }
}

#[test]
fn ranks_with_different_frames_refuse_and_the_abort_ends_the_others() {
    let (_dir, scene) = scene();
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
                    let r = p.render_split(&QueueRunner::new(c), &settings, &Silent);
                    match &r {
                        Err(PipelineError::Jobs(JobError::Disagree(m))) => {
                            assert!(m.starts_with("process 1 has the frame"), "{m}");
                            c.abort(1)
                        }
                        Err(PipelineError::Jobs(JobError::Transport(m))) => {
                            assert!(m.contains("aborted"), "{m}")
                        }
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

/// Bases solved where missing or cached only; the uncompressed sets kept (so they are
/// compared and shared too); a small global grid.
fn plan(basis: BasisUse) -> RelightPlan {
    RelightPlan {
        basis,
        keep_raw: true,
        global: Some(GlobalGridOptions { sites: 24 }),
        ..RelightPlan::default()
    }
}

/// `precompute_relighting` on every rank of a group of `ranks`; each rank's answer.
fn bases_on_ranks(
    ranks: usize,
    scene: &Scene,
    cache: Option<&Path>,
    plan: &RelightPlan,
    at: RelightingAt,
) -> Vec<Option<Relighting>> {
    on_ranks(ranks, |r| {
        precompute_relighting(scene, &lb(cache, Light::Paper), plan, r, at, &Silent)
            .unwrap_or_else(|e| panic!("rank {}: {e}", r.comm().rank()))
    })
}

/// Panics unless `got` holds `want`'s sets and global grid, bit for bit.
fn assert_same(got: &Relighting, want: &Relighting, what: &str) {
    assert_eq!(got.compressed.len(), want.compressed.len(), "{what}");
    let pairs = got
        .compressed
        .iter()
        .zip(&want.compressed)
        .chain(got.raw.iter().zip(&want.raw));
    for (k, (g, w)) in pairs.enumerate() {
        let same = match (g, w) {
            (Some(StoredBasis::Compressed(g)), Some(StoredBasis::Compressed(w))) => g == w,
            (Some(StoredBasis::Full(g)), Some(StoredBasis::Full(w))) => g == w,
            _ => false,
        };
        assert!(same, "{what}: stored set {k} differs");
    }
    assert!(want.global.is_some(), "{what}");
    assert!(got.global == want.global, "{what}: the global grid differs");
}

#[test]
fn distributed_bases_are_the_one_process_ones() {
    let (dir, scene) = scene();
    let one_cache = dir.path().join("one");
    let always = plan(BasisUse::Always);
    let want = precompute_relighting(
        &scene,
        &lb(Some(&one_cache), Light::Paper),
        &always,
        &Local,
        RelightingAt::Everywhere,
        &Silent,
    )
    .unwrap()
    .expect("solved");
    assert_eq!(want.cached, 0);
    let want_entries = basis_cache_entries(&one_cache);
    // Per model a compressed and an uncompressed entry, and the global grid.
    assert_eq!(
        want_entries.len(),
        5,
        "{:?}",
        want_entries.iter().map(|e| &e.0)
    );

    for ranks in [2, 3] {
        let cache = dir.path().join(format!("ranks{ranks}"));
        for pass in 0..2 {
            let what = format!("{ranks} ranks, pass {pass}");
            let got = bases_on_ranks(
                ranks,
                &scene,
                Some(&cache),
                &always,
                RelightingAt::Everywhere,
            );
            // Every rank has rank 0's sets: solved across the ranks, then read back.
            for (rank, r) in got.iter().enumerate() {
                let r = r.as_ref().unwrap_or_else(|| panic!("{what}: rank {rank}"));
                assert_same(r, &want, &format!("{what}, rank {rank}"));
                assert_eq!(r.cached, if pass == 0 { 0 } else { 2 }, "{what}");
            }
            // Rank 0 wrote what one process writes.
            assert!(
                basis_cache_entries(&cache) == want_entries,
                "{what}: cache entries differ"
            );
        }
    }

    // No cache, and the sets kept at rank 0 alone.
    let got = bases_on_ranks(2, &scene, None, &always, RelightingAt::Root);
    assert_same(got[0].as_ref().unwrap(), &want, "no cache");
    assert!(got[1].is_none());
}

#[test]
fn a_cached_only_plan_falls_back_on_every_rank_or_shares_the_cache() {
    let (dir, scene) = scene();
    let cache = dir.path().join("cache");
    let cached_only = plan(BasisUse::IfCached);
    // Nothing cached: every rank falls back (to the per-sun light), none solves.
    let got = bases_on_ranks(
        3,
        &scene,
        Some(&cache),
        &cached_only,
        RelightingAt::Everywhere,
    );
    assert!(got.iter().all(Option::is_none));
    assert!(!cache.exists() || basis_cache_entries(&cache).is_empty());

    // Cached (by one process): every rank gets the sets rank 0 read.
    let want = precompute_relighting(
        &scene,
        &lb(Some(&cache), Light::Paper),
        &plan(BasisUse::Always),
        &Local,
        RelightingAt::Everywhere,
        &Silent,
    )
    .unwrap()
    .unwrap();
    let got = bases_on_ranks(
        3,
        &scene,
        Some(&cache),
        &cached_only,
        RelightingAt::Everywhere,
    );
    for r in &got {
        let r = r.as_ref().unwrap();
        assert_same(r, &want, "cached");
        assert_eq!(r.cached, 2);
    }
}

#[test]
fn bases_are_the_paper_lights() {
    let (_dir, scene) = scene();
    let physical = lb(None, Light::Physical);
    let e = relight_options(&scene, &physical, &plan(BasisUse::Always)).unwrap_err();
    assert!(e.to_string().contains("paper"), "{e}");
}

/// A cache's entries by name: the compressed physical bases by their payload (their
/// metadata records solve seconds, which differ from run to run), the others whole.
fn physical_cache_entries(dir: &Path) -> Vec<(String, Vec<u8>)> {
    files_by_name(dir)
        .into_iter()
        .map(|(name, bytes)| {
            if !name.ends_with(".spbasis") {
                return (name, bytes);
            }
            let c = sylva_core::container::read_container(
                &dir.join(&name),
                b"SYLVAPBS",
                1,
                "compressed physical basis",
            )
            .unwrap();
            (name, c.payload)
        })
        .collect()
}

#[test]
fn distributed_physical_bases_are_the_one_process_ones() {
    let (dir, scene) = scene();
    let bplan = PhysicalBasisPlan {
        basis: BasisUse::Always,
        target: Some(PhysicalTarget::recommended()),
        keep_raw: true,
    };
    let physical = |runner: &dyn sylva_pipeline::Runner, cache: &Path| {
        precompute_physical(
            &scene,
            &lb(Some(cache), Light::Physical),
            &bplan,
            None,
            runner,
            &Silent,
        )
        .unwrap()
        .expect("solved")
    };
    let one = dir.path().join("one");
    let want = physical(&Local, &one);
    assert_eq!(want.cached, 0);
    assert!(want.solve_seconds.is_some());
    let want_entries = physical_cache_entries(&one);
    // Per model 28 parts (25 sun parts, the overhead sun's plan's sky, ground and top sky)
    // and the compressed basis.
    assert_eq!(want_entries.len(), 2 * (25 + 3 + 1));
    for ranks in [2, 3] {
        let cache = dir.path().join(format!("ranks{ranks}"));
        for pass in 0..2 {
            let what = format!("{ranks} ranks, pass {pass}");
            let got = on_ranks(ranks, |r| physical(r, &cache));
            for (rank, r) in got.iter().enumerate() {
                assert!(r.bases == want.bases, "{what}, rank {rank}: bases differ");
                assert!(r.raw == want.raw, "{what}, rank {rank}: parts differ");
                assert_eq!(r.cached, if pass == 0 { 0 } else { 2 }, "{what}");
                assert_eq!(r.raw_bytes, want.raw_bytes, "{what}");
            }
            assert!(
                physical_cache_entries(&cache) == want_entries,
                "{what}: cache entries differ"
            );
        }
    }
}
