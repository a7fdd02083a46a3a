//! `sylva lb` and `sylva bench lb` as a user runs them.

use std::path::Path;

use crate::common;
use common::sylva;

/// A 14×12×10 raw f32 medium: a half-dense ball.
fn write_raw(path: &Path) {
    let (nx, ny, nz) = (14usize, 12usize, 10usize);
    let mut bytes = Vec::new();
    for x in 0..nx {
        for y in 0..ny {
            for z in 0..nz {
                let d = [(x, nx), (y, ny), (z, nz)]
                    .iter()
                    .map(|&(v, n)| (v as f32 - (n - 1) as f32 / 2.0).powi(2))
                    .sum::<f32>();
                let rho: f32 = if d < 16.0 { 0.5 } else { 0.0 };
                bytes.extend_from_slice(&rho.to_le_bytes());
            }
        }
    }
    std::fs::write(path, bytes).unwrap();
}

#[test]
fn solve_writes_grid_and_preview_identically_on_any_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    let raw = dir.path().join("ball.raw");
    write_raw(&raw);
    let mut outputs = Vec::new();
    for threads in ["1", "2"] {
        let out = dir.path().join(format!("lit{threads}.sgrid"));
        let (ok, stdout, err) = sylva(&[
            "--threads",
            threads,
            "lb",
            "solve",
            "--raw",
            raw.to_str().unwrap(),
            "--raw-dims",
            "14x12x10",
            "--raw-type",
            "f32",
            "--preset",
            "dogrose",
            "--elevation",
            "60",
            "-o",
            out.to_str().unwrap(),
        ]);
        assert!(ok, "{err}");
        assert!(stdout.contains("28 steps, stop: step limit"), "{stdout}");
        let png = std::fs::read(out.with_extension("png")).unwrap();
        assert_eq!(&png[1..4], b"PNG");
        outputs.push(std::fs::read(&out).unwrap());
    }
    assert_eq!(outputs[0], outputs[1], "thread count changed the result");

    let file = dir.path().join("lit1.sgrid");
    let (ok, info, err) = sylva(&["lb", "info", file.to_str().unwrap()]);
    assert!(ok, "{err}");
    assert!(info.contains("lighting grid"), "{info}");
    assert!(info.contains("14×12×10"), "{info}");
    assert!(info.contains("preset     dogrose"), "{info}");

    let bytes = std::fs::read(&file).unwrap();
    let cut = dir.path().join("cut.sgrid");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let (ok, _, err) = sylva(&["lb", "info", cut.to_str().unwrap()]);
    assert!(!ok);
    assert!(err.contains("cut.sgrid is truncated"), "{err}");
}

#[test]
fn bad_inputs_are_refused_with_reasons() {
    let dir = tempfile::tempdir().unwrap();
    let raw = dir.path().join("short.raw");
    std::fs::write(&raw, [0u8; 100]).unwrap();
    let (ok, _, err) = sylva(&[
        "lb",
        "solve",
        "--raw",
        raw.to_str().unwrap(),
        "--raw-dims",
        "8x8x8",
    ]);
    assert!(!ok);
    assert!(
        err.contains("short.raw") && err.contains("512 bytes"),
        "{err}"
    );

    let (ok, _, err) = sylva(&["lb", "solve", "--grid", "2000"]);
    assert!(!ok);
    assert!(err.contains("needs") && err.contains("TiB"), "{err}");

    let (ok, _, err) = sylva(&["lb", "solve", "--shape", "torus"]);
    assert!(!ok);
    assert!(err.contains("unknown shape 'torus'"), "{err}");

    let (ok, _, err) = sylva(&[
        "lb",
        "solve",
        "--shape",
        "sphere",
        "--grid",
        "8",
        "--g",
        "0.5,nan,0",
    ]);
    assert!(!ok);
    assert!(err.contains("green g"), "{err}");
}

#[test]
fn bench_lb_json_has_the_fields() {
    let (ok, out, err) = sylva(&[
        "bench",
        "lb",
        "--grid",
        "16",
        "--steps",
        "4",
        "--repeats",
        "1",
        "--json",
    ]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    for key in [
        "grid",
        "steps",
        "seconds",
        "mlups",
        "effective_gbs",
        "copy_gbs",
        "ratio",
    ] {
        assert!(v.get(key).is_some(), "missing {key} in {out}");
    }
    assert_eq!(v["grid"], "16x16x16");
    assert_eq!(v["steps"], 4);
    let (mlups, eff, copy, ratio) = (
        v["mlups"].as_f64().unwrap(),
        v["effective_gbs"].as_f64().unwrap(),
        v["copy_gbs"].as_f64().unwrap(),
        v["ratio"].as_f64().unwrap(),
    );
    assert!(mlups > 0.0 && copy > 0.0);
    assert!((eff - mlups * 156.0 / 1000.0).abs() < 1e-6 * eff.max(1.0));
    assert!((ratio - eff / copy).abs() < 1e-9);
}

#[test]
fn bench_lb_runs_the_kernel_it_is_given() {
    let args = [
        "bench",
        "lb",
        "--grid",
        "12",
        "--steps",
        "3",
        "--repeats",
        "1",
        "--json",
    ];
    let with = |extra: &[&str]| sylva(&[&args[..], extra].concat());
    let (ok, out, err) = with(&["--device", "cpu", "--kernel", "portable"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["kernel"], "portable");
    // Without one the widest the CPU has runs (the default report says which).
    let (ok, out, err) = with(&["--device", "cpu"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["kernel"], sylva_lb::kernel::KernelIsa::detect().name());
    // A kernel is a CPU choice; a name clap does not know is refused.
    let (ok, _, err) = with(&["--device", "auto", "--kernel", "portable"]);
    assert!(!ok && err.contains("--device cpu"), "{err}");
    let (ok, _, err) = with(&["--device", "cpu", "--kernel", "sse9"]);
    assert!(!ok && err.contains("sse9"), "{err}");
}
