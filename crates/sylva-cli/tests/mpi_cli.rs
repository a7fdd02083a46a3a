//! `mpirun -np N sylva render|basis|bench trace` (built with `--features mpi`; CI runs these
//! with 2 and 3 ranks): the image, the LB cache and the relighting bases are those of one
//! process, bit for bit; a rank that fails ends the whole job with its message instead of
//! leaving the others waiting. Without `mpirun` they say SKIPPED, or fail under
//! `SYLVA_REQUIRE_MPI=1` (as in CI).
#![cfg(feature = "mpi")]

mod common;

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::sylva;
use sylva_testkit::{basis_cache_entries, files_by_name};

const SCENE: &str = r#"
name = "roses"

[[models]]
name = "rose"
species = "dogrose"

[[models]]
name = "other rose"
species = "dogrose"
seed = 5

[[instances]]
model = "rose"
position = [-1.0, 0.0, 0.0]

[[instances]]
model = "other rose"
position = [1.2, 0.0, 0.5]
rotation = 70.0

[ground]
size = [20.0, 20.0]

[camera]
position = [0.0, 3.0, -7.0]
look_at = [0.0, 0.8, 0.0]
fov = 40.0
resolution = [75, 45]
"#;

/// A job is killed (and the test fails) after this long: what "never a hang" means here.
const LIMIT: Duration = Duration::from_secs(180);

/// `mpirun -np N sylva ARGS` with `env` passed to every rank; (success, stdout, stderr).
fn mpirun(np: usize, args: &[&str], env: &[(&str, &str)]) -> (bool, String, String) {
    let mut cmd = Command::new("mpirun");
    // Oversubscribe: more ranks than cores is fine for tests; root needs its own flag.
    cmd.args(["--oversubscribe", "-np", &np.to_string()]);
    if unsafe { libc::geteuid() } == 0 {
        cmd.arg("--allow-run-as-root");
    }
    for (k, v) in env {
        cmd.args(["-x", &format!("{k}={v}")]);
    }
    cmd.arg(env!("CARGO_BIN_EXE_sylva")).args(args);
    let out_dir = tempfile::tempdir().unwrap();
    let (out_path, err_path) = (out_dir.path().join("out"), out_dir.path().join("err"));
    let mut child = cmd
        .stdin(Stdio::null())
        .stdout(std::fs::File::create(&out_path).unwrap())
        .stderr(std::fs::File::create(&err_path).unwrap())
        .spawn()
        .expect("mpirun (Debian: apt-get install openmpi-bin libopenmpi-dev)");
    let t = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if t.elapsed() > LIMIT {
            child.kill().unwrap();
            child.wait().unwrap();
            panic!(
                "mpirun -np {np} sylva {args:?} still running after {LIMIT:?}: a hang\nstderr:\n{}",
                std::fs::read_to_string(&err_path).unwrap_or_default()
            );
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    (
        status.success(),
        std::fs::read_to_string(&out_path).unwrap(),
        std::fs::read_to_string(&err_path).unwrap(),
    )
}

fn write_scene(dir: &Path) -> String {
    let p = dir.join("roses.toml");
    std::fs::write(&p, SCENE).unwrap();
    p.to_str().unwrap().to_string()
}

fn render_args<'a>(scene: &'a str, out: &'a str, cache: &'a str) -> Vec<&'a str> {
    vec![
        "render",
        scene,
        "-o",
        out,
        "--hdr",
        "--rpp",
        "4",
        "--lb-grid",
        "12",
        "--cache-dir",
        cache,
        "--device",
        "cpu",
        "--threads",
        "1",
    ]
}

#[test]
fn mpi_band_render_is_bit_identical_to_one_process() {
    if !sylva_testkit::require_mpirun() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("bands.toml");
    let bands = r#"
[bands]
names = ["red", "nir"]
leaf_reflectance = [0.07, 0.45]
leaf_transmittance = [0.05, 0.40]
bark = [0.16, 0.35]
soil = [0.14, 0.25]
sky = [0.55, 0.25]
"#;
    std::fs::write(&scene, format!("{SCENE}{bands}")).unwrap();
    let scene = scene.to_str().unwrap();
    let d = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let args = |out: &str, cache: &str| -> Vec<String> {
        let mut a: Vec<String> = render_args(scene, out, cache)
            .into_iter()
            .map(String::from)
            .collect();
        a.retain(|x| x != "--hdr"); // a band render always writes its EXR
        a
    };
    let (one, np2) = (d("one.png"), d("np2.png"));
    let a = args(&one, &d("one-cache"));
    let (ok, out, err) = sylva(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(ok, "{out}\n{err}");
    let a = args(&np2, &d("np2-cache"));
    let (ok, out, err) = mpirun(2, &a.iter().map(String::as_str).collect::<Vec<_>>(), &[]);
    assert!(ok, "{out}\n{err}");
    assert_eq!(
        out.matches("wrote ").count(),
        1,
        "rank 0 alone writes: {out}"
    );
    assert!(out.contains("LB solves shared across 2 ranks"), "{out}");
    let exr = |p: &str| std::fs::read(Path::new(p).with_extension("exr")).unwrap();
    assert!(exr(&np2) == exr(&one), "the band layers differ");
    assert!(std::fs::read(&np2).unwrap() == std::fs::read(&one).unwrap());
}

#[test]
fn mpi_render_and_lb_are_bit_identical_to_one_process() {
    if !sylva_testkit::require_mpirun() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path());
    let d = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let (one_png, one_cache) = (d("one.png"), d("one-cache"));
    let (ok, out, err) = sylva(&render_args(&scene, &one_png, &one_cache));
    assert!(ok, "{out}\n{err}");
    let want_exr = std::fs::read(d("one.exr")).unwrap();
    let want_png = std::fs::read(&one_png).unwrap();

    for np in [2, 3] {
        let (png, cache) = (d(&format!("np{np}.png")), d(&format!("np{np}-cache")));
        for pass in 0..2 {
            let (ok, out, err) = mpirun(np, &render_args(&scene, &png, &cache), &[]);
            assert!(ok, "np {np} pass {pass}:\n{out}\n{err}");
            // Rank 0 alone prints: one summary.
            assert_eq!(out.matches("wrote ").count(), 1, "{out}");
            assert!(out.contains(&format!("MPI: {np} ranks")), "{out}");
            let lb_lines = |how: &str| out.lines().filter(|l| l.contains(how)).count();
            // The forest's light parts (2 models × 4) are solved across the ranks and
            // stored in rank 0's cache (first pass), then read from it (second).
            assert!(
                out.contains(&format!("LB solves shared across {np} ranks")),
                "{out}"
            );
            let (solved, cached) = (lb_lines(" grid solved in"), lb_lines("grid from cache"));
            let want = if pass == 0 { (2, 0) } else { (0, 2) };
            assert_eq!((solved, cached), want, "pass {pass}:\n{out}");
            let exr = std::fs::read(d(&format!("np{np}.exr"))).unwrap();
            assert!(exr == want_exr, "np {np}: the linear image differs");
            assert!(
                std::fs::read(&png).unwrap() == want_png,
                "np {np}: the PNG differs"
            );
            // The LB colours were solved across ranks; the cache holds what one process
            // writes.
            assert!(files_by_name(Path::new(&cache)) == files_by_name(Path::new(&one_cache)));
        }
    }
}

fn basis_args<'a>(scene: &'a str, cache: &'a str) -> Vec<&'a str> {
    vec![
        "basis",
        scene,
        "--light",
        "paper",
        "--lb-grid",
        "12",
        "--global-grid",
        "24",
        "--keep-raw",
        "--cache-dir",
        cache,
        "--device",
        "cpu",
        "--threads",
        "1",
    ]
}

#[test]
fn mpi_basis_is_bit_identical_to_one_process() {
    if !sylva_testkit::require_mpirun() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path());
    let d = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let one_cache = d("one-cache");
    let (ok, out, err) = sylva(&basis_args(&scene, &one_cache));
    assert!(ok, "{out}\n{err}");
    let want = basis_cache_entries(Path::new(&one_cache));
    let names: Vec<&str> = want.iter().map(|e| e.0.as_str()).collect();
    // Per model a compressed and an uncompressed set, and the scene's global grid.
    assert_eq!(want.len(), 5, "{names:?}");
    assert!(names.iter().any(|n| n.ends_with(".sglobal")), "{names:?}");

    for np in [2, 3] {
        let cache = d(&format!("np{np}-cache"));
        for pass in 0..2 {
            let (ok, out, err) = mpirun(np, &basis_args(&scene, &cache), &[]);
            assert!(ok, "np {np} pass {pass}:\n{out}\n{err}");
            // Rank 0 alone prints: one summary.
            assert_eq!(out.matches("models from the cache").count(), 1, "{out}");
            assert!(
                out.contains(&format!("base solutions solved across {np} ranks")),
                "{out}"
            );
            let lines = |how: &str| out.lines().filter(|l| l.contains(how)).count();
            if pass == 0 {
                assert_eq!(lines("grid solved in"), 2, "{out}");
                assert!(out.contains("0 of 2 models from the cache"), "{out}");
                assert!(
                    out.contains("global grid: 24") && out.contains("solved"),
                    "{out}"
                );
            } else {
                assert_eq!(lines("grid from cache"), 2, "{out}");
                assert!(out.contains("2 of 2 models from the cache"), "{out}");
            }
            // The solves ran across the ranks; rank 0 assembled and stored what one process
            // stores, and the same global grid.
            assert!(
                basis_cache_entries(Path::new(&cache)) == want,
                "np {np} pass {pass}: the cache differs from one process's"
            );
        }
    }

    // A failing worker ends the job with its message, and nothing is cached.
    let cache = d("failed-cache");
    let (ok, out, err) = mpirun(
        3,
        &basis_args(&scene, &cache),
        &[("SYLVA_MPI_FAIL_RANK", "2")],
    );
    assert!(!ok, "the job must fail\n{out}\n{err}");
    // (Not the whole line: under load another rank's stderr can interleave with it.)
    assert!(
        err.contains("rank 2: failure injected by SYLVA_MPI_FAIL_RANK"),
        "{err}"
    );
    assert!(!Path::new(&cache).exists() || basis_cache_entries(Path::new(&cache)).is_empty());
}

#[test]
fn mpi_render_solves_missing_bases_across_ranks() {
    if !sylva_testkit::require_mpirun() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path());
    let d = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let args = |out: &str, cache: &str| -> Vec<String> {
        let mut a: Vec<String> = render_args(&scene, out, cache)
            .into_iter()
            .map(String::from)
            .collect();
        a.extend(
            [
                "--light",
                "paper",
                "--basis",
                "always",
                "--global-grid",
                "24",
            ]
            .map(String::from),
        );
        a
    };
    let (one_png, one_cache) = (d("one.png"), d("one-cache"));
    let one = args(&one_png, &one_cache);
    let (ok, out, err) = sylva(&one.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(ok, "{out}\n{err}");
    assert!(out.contains("relit from base solutions"), "{out}");
    let want_exr = std::fs::read(d("one.exr")).unwrap();
    let want_cache = basis_cache_entries(Path::new(&one_cache));

    let (png, cache) = (d("np2.png"), d("np2-cache"));
    let a = args(&png, &cache);
    let (ok, out, err) = mpirun(2, &a.iter().map(String::as_str).collect::<Vec<_>>(), &[]);
    assert!(ok, "{out}\n{err}");
    assert!(out.contains("relit from base solutions"), "{out}");
    assert_eq!(
        out.lines().filter(|l| l.contains("grid solved in")).count(),
        2,
        "{out}"
    );
    // Both ranks rendered units with the bases rank 0 stored and sent them.
    assert!(
        out.contains("MPI: 2 ranks") && !out.contains("rank 1: 0 units"),
        "{out}"
    );
    assert!(
        std::fs::read(d("np2.exr")).unwrap() == want_exr,
        "the linear image differs"
    );
    assert!(basis_cache_entries(Path::new(&cache)) == want_cache);
}

#[test]
fn mpi_bench_trace_reports_per_rank_seconds() {
    if !sylva_testkit::require_mpirun() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path());
    let args = [
        "bench",
        "trace",
        &scene,
        "--no-lb",
        "--no-cache",
        "--runs",
        "1",
        "--json",
        "--threads",
        "1",
    ];
    let (ok, out, err) = mpirun(2, &args, &[]);
    assert!(ok, "{out}\n{err}");
    let v: serde_json::Value = serde_json::from_str(&out).expect("one JSON object");
    assert_eq!(v["ranks"], 2);
    for m in [&v["mpi"], &v["rpp4"]["mpi"]] {
        assert_eq!(m["ranks"], 2, "{v}");
        let secs = m["rank_seconds"].as_array().unwrap();
        assert_eq!(secs.len(), 2);
        assert!(secs.iter().all(|s| s.as_f64().unwrap() > 0.0), "{m}");
        let units: u64 = m["rank_units"]
            .as_array()
            .unwrap()
            .iter()
            .map(|u| u.as_u64().unwrap())
            .sum();
        assert_eq!(units, m["units"].as_u64().unwrap());
        assert!(m["imbalance"].as_f64().unwrap() >= 0.0);
    }
    assert!(v["frame_seconds"].as_f64().unwrap() > 0.0);
}

#[test]
fn a_failing_rank_ends_the_job_with_its_message() {
    if !sylva_testkit::require_mpirun() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path());
    let png = dir.path().join("x.png");
    let cache = dir.path().join("cache");
    let args = render_args(&scene, png.to_str().unwrap(), cache.to_str().unwrap());
    // An error on a worker rank, on rank 0 (which serves the queue), a panic.
    for (np, fail, want) in [
        (
            3,
            "1",
            "error: rank 1 of 3: rank 1: failure injected by SYLVA_MPI_FAIL_RANK",
        ),
        (
            2,
            "0",
            "error: rank 0 of 2: rank 0: failure injected by SYLVA_MPI_FAIL_RANK",
        ),
        (
            3,
            "2:panic",
            "rank 2: panic injected by SYLVA_MPI_FAIL_RANK",
        ),
    ] {
        let (ok, out, err) = mpirun(np, &args, &[("SYLVA_MPI_FAIL_RANK", fail)]);
        assert!(
            !ok,
            "np {np}, failing {fail}: the job must fail\n{out}\n{err}"
        );
        assert!(err.contains(want), "np {np}, failing {fail}:\n{err}");
        assert!(!png.exists(), "no image from a failed job");
    }
}

#[test]
fn mpi_relight_frames_are_the_one_process_frames() {
    if !sylva_testkit::require_mpirun() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path());
    let d = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let args = |out: &str, cache: &str| -> Vec<String> {
        [
            "relight",
            &scene,
            "--suns",
            "3",
            "-o",
            out,
            "--lb-grid",
            "12",
            "--global-grid",
            "24",
            "--cache-dir",
            cache,
            "--device",
            "cpu",
            "--threads",
            "1",
        ]
        .map(String::from)
        .to_vec()
    };
    let one = args(&d("one"), &d("one-cache"));
    let (ok, out, err) = sylva(&one.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(ok, "{out}\n{err}");
    let files = ["frame-00.png", "frame-01.png", "frame-02.png", "roses.png"];
    let want: Vec<Vec<u8>> = files
        .iter()
        .map(|f| std::fs::read(dir.path().join("one").join(f)).unwrap())
        .collect();
    let a = args(&d("np2"), &d("np2-cache"));
    let (ok, out, err) = mpirun(2, &a.iter().map(String::as_str).collect::<Vec<_>>(), &[]);
    assert!(ok, "{out}\n{err}");
    // Rank 0 alone prints and writes; the bases were solved across the ranks.
    assert!(
        out.contains("3 suns over 90°") && out.contains("2 MPI ranks"),
        "{out}"
    );
    assert_eq!(out.matches("wrote 3 frames").count(), 1, "{out}");
    for (f, w) in files.iter().zip(&want) {
        let got = std::fs::read(dir.path().join("np2").join(f)).unwrap();
        assert!(&got == w, "{f} differs from one process's");
    }
}
