//! `--device` for `sylva lb solve`, `sylva bench lb`, `sylva render` and `sylva bench trace`.
//! GPU runs use any adapter (lavapipe in CI); where none exists the GPU halves say SKIPPED
//! (fail under `SYLVA_REQUIRE_GPU=1`, as in CI).

use crate::common;
use common::sylva;
use sylva_lb_gpu::{AdapterChoice, ContextOptions};

/// Whether any adapter exists (software ones included), and whether it has SHADER_F16. Without
/// one the test checks only that `--device gpu` refuses, and says SKIPPED for the rest (fails
/// under `SYLVA_REQUIRE_GPU=1`).
fn adapter() -> Option<bool> {
    sylva_testkit::gpu_context(&ContextOptions::new(AdapterChoice::Any)).map(|c| c.supports_f16())
}

#[test]
fn gpu_and_cpu_write_the_same_lighting_grid() {
    let Some(_) = adapter() else {
        // Without an adapter `--device gpu` must say so instead of falling back silently.
        let (ok, _, err) = sylva(&["lb", "solve", "--device", "gpu", "--grid", "8"]);
        assert!(!ok);
        assert!(err.contains("no GPU adapter"), "{err}");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let mut grids = Vec::new();
    for device in ["cpu", "gpu"] {
        let out = dir.path().join(format!("{device}.sgrid"));
        let (ok, stdout, err) = sylva(&[
            "lb",
            "solve",
            "--shape",
            "crown",
            "--grid",
            "16x14x12",
            "--preset",
            "dogrose",
            "--device",
            device,
            "-o",
            out.to_str().unwrap(),
        ]);
        assert!(ok, "{err}");
        assert!(stdout.contains("32 steps, stop: step limit"), "{stdout}");
        if device == "gpu" {
            assert!(stdout.contains("GPU "), "{stdout}");
            assert!(stdout.contains("f32 state"), "{stdout}");
        } else {
            assert!(stdout.contains("CPU, kernel"), "{stdout}");
        }
        grids.push(sylva_lb::GridFile::read(&out).unwrap());
    }
    let (cpu, gpu) = (&grids[0], &grids[1]);
    assert_eq!(cpu.channels.len(), 3);
    for (c, g) in cpu.channels.iter().zip(&gpu.channels) {
        let scale = c.iter().fold(0.0f32, |m, &v| m.max(v));
        assert!(scale > 0.0);
        for (a, b) in c.iter().zip(g) {
            assert!(
                (a - b).abs() <= 1e-5 * a.abs().max(1e-3 * scale),
                "{a} vs {b}"
            );
        }
    }
}

#[test]
fn bench_lb_on_the_gpu_reports_the_adapter() {
    let Some(f16) = adapter() else { return };
    let mut precisions = vec![("f32", 156)];
    if f16 {
        precisions.push(("f16", 80));
    } else {
        sylva_testkit::skipped("`bench lb --precision f16`: the adapter lacks SHADER_F16");
    }
    for (precision, bytes) in precisions {
        let (ok, out, err) = sylva(&[
            "bench",
            "lb",
            "--device",
            "gpu",
            "--precision",
            precision,
            "--grid",
            "12",
            "--steps",
            "4",
            "--repeats",
            "1",
            "--json",
        ]);
        assert!(ok, "{err}");
        let v: serde_json::Value = serde_json::from_str(&out).unwrap();
        assert_eq!(v["device"], "gpu");
        assert!(!v["adapter"].as_str().unwrap().is_empty(), "{out}");
        assert_eq!(v["kernel"], format!("wgsl-{precision}"));
        assert_eq!(v["bytes_per_update"], bytes);
        let (mlups, eff, copy, ratio) = (
            v["mlups"].as_f64().unwrap(),
            v["effective_gbs"].as_f64().unwrap(),
            v["copy_gbs"].as_f64().unwrap(),
            v["ratio"].as_f64().unwrap(),
        );
        assert!(mlups > 0.0 && copy > 0.0);
        assert!((eff - mlups * bytes as f64 / 1000.0).abs() < 1e-6 * eff.max(1.0));
        assert!((ratio - eff / copy).abs() < 1e-9);
    }
}

#[test]
fn cpu_runs_name_themselves_and_refuse_f16() {
    let (ok, out, err) = sylva(&[
        "bench",
        "lb",
        "--device",
        "cpu",
        "--grid",
        "8",
        "--steps",
        "2",
        "--repeats",
        "1",
        "--json",
    ]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["device"], "cpu");
    assert!(v.get("adapter").is_none(), "{out}");
    let (ok, _, err) = sylva(&["bench", "lb", "--device", "cpu", "--precision", "f16"]);
    assert!(!ok);
    assert!(
        err.contains("--precision f16 is a GPU state format"),
        "{err}"
    );
}

#[test]
fn render_solves_lb_on_the_device_asked_for() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("rose.toml");
    std::fs::write(
        &scene,
        "[[models]]\nname = \"rose\"\nspecies = \"dogrose\"\n\n[[instances]]\nmodel = \"rose\"\nposition = [0.0, 0.0, 0.0]\n\n[lb]\ngrid = 16\n",
    )
    .unwrap();
    let render_on = |device: &str, schedule: Option<&str>| {
        let out = dir.path().join(format!("{device}.png"));
        let cache = dir.path().join(format!("cache-{device}"));
        let mut args = vec![
            "render",
            scene.to_str().unwrap(),
            "--width",
            "48",
            "--device",
            device,
            "--cache-dir",
            cache.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ];
        if let Some(s) = schedule {
            args.extend(["--lb-schedule", s]);
        }
        let (ok, stdout, err) = sylva(&args);
        (ok, stdout, err, out, cache)
    };
    // The CPU starts from a coarse solve and extrapolates by default; on the GPU's schedule
    // the two backends compare.
    let (ok, stdout, err, _, _) = render_on("cpu", None);
    assert!(ok, "{err}");
    assert!(
        stdout.contains("LB solver: CPU, kernel")
            && stdout.contains("from a half-resolution solve")
            && stdout.contains("extrapolated"),
        "{stdout}"
    );
    let render = |device: &str| render_on(device, Some("papers"));
    let (ok, stdout, err, cpu_png, _) = render("cpu");
    assert!(ok, "{err}");
    assert!(stdout.contains("the papers' 2 ×"), "{stdout}");
    assert!(stdout.contains("ray tracer: CPU"), "{stdout}");
    let Some(_) = adapter() else {
        let (ok, _, err, _, _) = render("gpu");
        assert!(!ok && err.contains("no GPU adapter"), "{err}");
        return;
    };
    for schedule in ["extrapolated", "coarse"] {
        let (ok, _, err, _, _) = render_on("gpu", Some(schedule));
        assert!(
            !ok && err.contains(&format!(
                "--lb-schedule {schedule} runs on the CPU solver only"
            )),
            "{err}"
        );
    }
    let (ok, stdout, err, gpu_png, cache) = render_on("gpu", None);
    assert!(ok, "{err}");
    assert!(
        stdout.contains("LB solver: GPU") && stdout.contains("the papers' 2 ×"),
        "{stdout}"
    );
    assert!(stdout.contains("ray tracer: GPU"), "{stdout}");
    // The GPU's entry records its solver; CPU and GPU light the model alike.
    let entry = std::fs::read_dir(&cache)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| {
            !p.to_string_lossy().contains("-density-")
                && p.extension().is_some_and(|e| e == "sgrid")
        })
        .unwrap();
    let file = sylva_lb::GridFile::read(&entry).unwrap();
    assert!(file.metadata_value("solver").unwrap().starts_with("GPU"));
    let (a, b) = (
        image::open(&cpu_png).unwrap().to_rgb8(),
        image::open(&gpu_png).unwrap().to_rgb8(),
    );
    assert_eq!(a.dimensions(), b.dimensions());
    let worst = a
        .pixels()
        .zip(b.pixels())
        .flat_map(|(p, q)| (0..3).map(move |c| p[c].abs_diff(q[c])))
        .max()
        .unwrap();
    assert!(worst <= 1, "CPU and GPU images differ by {worst} levels");
}

#[test]
fn bench_trace_reports_device_and_adapter() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("rose.toml");
    std::fs::write(
        &scene,
        "[[models]]\nname = \"rose\"\nspecies = \"dogrose\"\n\n[[instances]]\nmodel = \"rose\"\nposition = [0.0, 0.0, 0.0]\n",
    )
    .unwrap();
    let bench = |device: &str| {
        sylva(&[
            "bench",
            "trace",
            scene.to_str().unwrap(),
            "--width",
            "24",
            "--runs",
            "1",
            "--no-lb",
            "--no-cache",
            "--device",
            device,
            "--json",
        ])
    };
    let (ok, out, err) = bench("cpu");
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["device"], "cpu");
    assert!(v.get("adapter").is_none(), "{out}");
    let Some(_) = adapter() else {
        let (ok, _, err) = bench("gpu");
        assert!(!ok && err.contains("no GPU adapter"), "{err}");
        return;
    };
    let (ok, out, err) = bench("gpu");
    assert!(ok, "{err}");
    let w: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(w["device"], "gpu");
    assert!(!w["adapter"].as_str().unwrap().is_empty(), "{out}");
    // Same rays on either device.
    assert_eq!(v["primary_rays"], w["primary_rays"]);
    assert_eq!(v["shadow_rays"], w["shadow_rays"]);
}
