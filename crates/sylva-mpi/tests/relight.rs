//! Relighting's base solutions across ranks (`sylva_mpi::precompute_relighting`, ranks as
//! threads through [`LocalComm`]): the compressed and uncompressed sets, the global grid and
//! the cache entries are those of the one-process precompute, bit for bit, with 2 and 3
//! ranks, cold and warm; every rank gets rank 0's sets when asked; a cached-only plan falls
//! back on every rank alike. (`sylva basis` under `mpirun`: crates/sylva-cli/tests/mpi_cli.rs.)

use std::path::Path;

use sylva_geom::Scene;
use sylva_lb::CpuSolver;
use sylva_light::relight::{GlobalGridOptions, StoredBasis};
use sylva_light::{Light, Silent};
use sylva_mpi::relight::basis_jobs;
use sylva_mpi::{precompute_relighting, Comm, LocalComm};
use sylva_pipeline::{load_scene, relight_options, BasisUse, LbPlan, RelightPlan, Relighting};
use sylva_testkit::basis_cache_entries;

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

[lb]
grid = 12
"#;

fn lb(cache: Option<&Path>) -> LbPlan<'_> {
    LbPlan {
        solver: &CpuSolver,
        grid: None,
        cache_dir: cache,
        light: Light::Paper,
    }
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

fn scene() -> (tempfile::TempDir, Scene) {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("roses.toml");
    std::fs::write(&file, SCENE).unwrap();
    let scene = load_scene(file.to_str().unwrap(), None).unwrap();
    (dir, scene)
}

/// `precompute_relighting` on every rank of a group of `ranks`; each rank's answer.
fn on_ranks(
    ranks: usize,
    scene: &Scene,
    cache: Option<&Path>,
    plan: &RelightPlan,
    everywhere: bool,
) -> Vec<Option<Relighting>> {
    let group = LocalComm::group(ranks);
    std::thread::scope(|s| {
        let handles: Vec<_> = group
            .iter()
            .map(|c| {
                s.spawn(move || {
                    precompute_relighting(c, scene, &lb(cache), plan, everywhere, &Silent)
                        .unwrap_or_else(|e| panic!("rank {}: {e}", c.rank()))
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
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
    let want =
        sylva_pipeline::precompute_relighting(&scene, &lb(Some(&one_cache)), &always, &Silent)
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
            let got = on_ranks(ranks, &scene, Some(&cache), &always, true);
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
    let got = on_ranks(2, &scene, None, &always, false);
    assert_same(got[0].as_ref().unwrap(), &want, "no cache");
    assert!(got[1].is_none());
}

#[test]
fn a_cached_only_plan_falls_back_on_every_rank_or_shares_the_cache() {
    let (dir, scene) = scene();
    let cache = dir.path().join("cache");
    let cached_only = plan(BasisUse::IfCached);
    // Nothing cached: every rank falls back (to the per-sun light), none solves.
    let got = on_ranks(3, &scene, Some(&cache), &cached_only, true);
    assert!(got.iter().all(Option::is_none));
    assert!(!cache.exists() || basis_cache_entries(&cache).is_empty());

    // Cached (by one process): every rank gets the sets rank 0 read.
    let want = sylva_pipeline::precompute_relighting(
        &scene,
        &lb(Some(&cache)),
        &plan(BasisUse::Always),
        &Silent,
    )
    .unwrap()
    .unwrap();
    let got = on_ranks(3, &scene, Some(&cache), &cached_only, true);
    for r in &got {
        let r = r.as_ref().unwrap();
        assert_same(r, &want, "cached");
        assert_eq!(r.cached, 2);
    }
}

#[test]
fn the_job_list_is_every_missing_model_times_its_basis_jobs() {
    let (_dir, scene) = scene();
    let (_, bopts) = relight_options(&scene, &lb(None), &plan(BasisUse::Always)).unwrap();
    let (jobs, sites) = basis_jobs(&scene, &bopts, &[1, 0]).unwrap();
    // 18 solved bases × 3 colours per model (B_0 is summed), model after model as listed.
    assert_eq!(jobs.len(), 2 * 54);
    assert!(jobs[..54].iter().all(|j| j.model == 1));
    assert!(jobs[54..].iter().all(|j| j.model == 0));
    assert_eq!(jobs[0].job.basis, 1);
    assert_eq!(sites.len(), 2);
    assert!(sites.iter().all(|&s| s > 0));
    let (jobs, _) = basis_jobs(&scene, &bopts, &[]).unwrap();
    assert!(jobs.is_empty());
    // Any other light is refused: base solutions are the paper light's.
    let physical = LbPlan {
        light: Light::Physical,
        ..lb(None)
    };
    let e = relight_options(&scene, &physical, &plan(BasisUse::Always)).unwrap_err();
    assert!(e.to_string().contains("paper"), "{e}");
}
