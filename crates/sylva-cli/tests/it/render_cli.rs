//! `sylva render` and `sylva bench trace` end to end on a small scene.

use crate::common;

use common::sylva;
use std::fs;
use std::path::Path;

const SCENE: &str = r#"
name = "roses"

[[models]]
name = "rose"
species = "dogrose"

[[instances]]
model = "rose"
count = 3
area = { min = [-3.0, -3.0], max = [3.0, 3.0] }
min_spacing = 2.0
seed = 5

[ground]
size = [20.0, 20.0]

[camera]
position = [0.0, 3.0, -9.0]
look_at = [0.0, 0.8, 0.0]
fov = 40.0
resolution = [64, 40]
"#;

fn write_scene(dir: &Path) -> String {
    let p = dir.join("roses.toml");
    fs::write(&p, SCENE).unwrap();
    p.to_str().unwrap().to_string()
}

#[test]
fn render_writes_images_caches_lb_and_recovers_from_a_corrupt_cache() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path());
    let out = dir.path().join("img/roses.png");
    let cache = dir.path().join("cache");
    let args = |mode: &'static str| {
        vec![
            "render".to_string(),
            scene.clone(),
            "-o".into(),
            out.to_str().unwrap().into(),
            "--hdr".into(),
            "--mode".into(),
            mode.into(),
            "--lb-grid".into(),
            "16".into(),
            "--cache-dir".into(),
            cache.to_str().unwrap().into(),
        ]
    };
    let run = |mode| {
        let a = args(mode);
        sylva(&a.iter().map(String::as_str).collect::<Vec<_>>())
    };
    let (ok, stdout, stderr) = run("full");
    assert!(ok, "{stdout}{stderr}");
    assert!(stdout.contains("solved"), "{stdout}");
    for stage in [
        "scene build",
        "LB precompute",
        "primary rays",
        "shadow rays",
        "shading",
        "tone mapping",
    ] {
        assert!(stdout.contains(stage), "summary lacks {stage}: {stdout}");
    }
    let png = image::open(&out).unwrap().to_rgb8();
    assert_eq!(png.dimensions(), (64, 40));
    let exr = image::open(out.with_extension("exr")).unwrap().to_rgb32f();
    assert_eq!(exr.dimensions(), (64, 40));
    // Not a flat image: sky, ground and plants differ.
    let first = png.get_pixel(0, 0);
    assert!(png.pixels().any(|p| p != first));

    // Second run: from the cache, the same image.
    let (ok, stdout, _) = run("full");
    assert!(ok && stdout.contains("from cache"), "{stdout}");
    assert_eq!(image::open(&out).unwrap().to_rgb8(), png);

    // A corrupted light entry is reported, recomputed, and the image is unchanged (the
    // model's voxelized density is cached beside it).
    let entry = fs::read_dir(&cache)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| {
            !p.to_string_lossy().contains("-density-")
                && p.extension().is_some_and(|e| e == "sgrid")
        })
        .unwrap();
    let mut bytes = fs::read(&entry).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x5a;
    fs::write(&entry, bytes).unwrap();
    let (ok, stdout, stderr) = run("full");
    assert!(ok, "{stderr}");
    assert!(
        stderr.contains("warning") && stderr.contains(entry.file_name().unwrap().to_str().unwrap()),
        "{stderr}"
    );
    assert!(stdout.contains("solved again"), "{stdout}");
    assert_eq!(image::open(&out).unwrap().to_rgb8(), png);

    // All four modes of 000 Fig. 2, named after the output.
    let (ok, stdout, stderr) = run("all");
    assert!(ok, "{stderr}");
    for m in ["full", "local", "ambient", "lb"] {
        let p = dir.path().join(format!("img/roses-{m}.png"));
        assert!(p.exists(), "{stdout}");
    }
}

#[test]
fn render_refuses_bad_options_with_reasons() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path());
    let cases: &[(&[&str], &str)] = &[
        (&["--mode", "fancy"], "--mode 'fancy'"),
        (&["--rpp", "0"], "rays per pixel"),
        (&["-o", "x.jpg"], "PNG"),
        (&["--width", "0"], "resolution"),
        (&["--sun", "0,0,0"], "--sun"),
        (&["--indirect", "NaN"], "indirect"),
        (&["--key=-1"], "key"),
        (&["--stack", "0"], "--stack 0"),
        (
            &["--width", "16384", "--height", "16384"],
            "16384x16384 frame",
        ),
    ];
    for (extra, want) in cases {
        let mut a = vec!["render", scene.as_str(), "--no-cache"];
        if !extra.contains(&"--mode") {
            a.extend(["--mode", "local"]);
        }
        a.extend_from_slice(extra);
        let (ok, stdout, stderr) = sylva(&a);
        assert!(!ok, "{a:?} should fail: {stdout}");
        assert!(stderr.contains(want), "{a:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{stderr}");
    }
    let (ok, _, stderr) = sylva(&["render", "no-such-scene.toml"]);
    assert!(!ok && stderr.contains("no-such-scene"), "{stderr}");
}

#[test]
fn bench_trace_json_has_the_fields() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path());
    let (ok, stdout, stderr) = sylva(&[
        "bench",
        "trace",
        &scene,
        "--no-lb",
        "--no-cache",
        "--runs",
        "1",
        "--json",
    ]);
    assert!(ok, "{stderr}");
    let v: serde_json::Value = serde_json::from_str(&stdout).expect("one JSON object");
    assert_eq!(v["width"], 64);
    assert_eq!(v["height"], 40);
    assert_eq!(v["rays_per_pixel"], 1);
    assert!(v["frame_seconds"].as_f64().unwrap() > 0.0);
    assert!(v["mrays_per_second"].as_f64().unwrap() > 0.0);
    assert_eq!(v["rpp4"]["rays_per_pixel"], 4);
    assert_eq!(v["rpp4"]["primary_rays"], 4 * 64 * 40);
    assert_eq!(v["memory"]["unique_models"], 1);
}

const BANDS: &str = r#"
[bands]
names = ["blue", "green", "red", "nir"]
leaf_reflectance = [0.04, 0.12, 0.07, 0.45]
leaf_transmittance = [0.02, 0.15, 0.05, 0.40]
bark = [0.08, 0.12, 0.16, 0.35]
soil = [0.06, 0.10, 0.14, 0.25]
sky = [0.9, 0.7, 0.55, 0.25]
false_colour = ["nir", "red", "green"]
"#;

#[test]
fn a_scene_with_bands_renders_a_layer_per_band_and_a_false_colour_png() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("bands.toml");
    fs::write(&scene, format!("{SCENE}{BANDS}")).unwrap();
    let scene = scene.to_str().unwrap();
    let out = dir.path().join("out/bands.png");
    let cache = dir.path().join("cache");
    let (out_s, cache_s) = (out.to_str().unwrap(), cache.to_str().unwrap());
    let run = |extra: &[&str]| {
        let mut a = vec![
            "render",
            scene,
            "-o",
            out_s,
            "--lb-grid",
            "12",
            "--cache-dir",
            cache_s,
        ];
        a.extend_from_slice(extra);
        sylva(&a)
    };
    let (ok, stdout, stderr) = run(&[]);
    assert!(ok, "{stdout}\n{stderr}");
    // Two renders: blue, green, red; then nir.
    assert!(stdout.contains("bands blue, green, red:"), "{stdout}");
    assert!(stdout.contains("bands nir:"), "{stdout}");
    assert!(
        stdout.contains("false colour: R = nir, G = red, B = green"),
        "{stdout}"
    );
    let png = image::open(&out).unwrap().to_rgb8();
    assert_eq!(png.dimensions(), (64, 40));

    let exr = sylva_render::output::read_exr_layers(&out.with_extension("exr")).unwrap();
    assert_eq!(exr.layers.len(), 4);
    // The top row sees the sky, whose radiance each band gives.
    let top_row = |name: &str| {
        let v = exr
            .layer(name)
            .unwrap_or_else(|| panic!("a layer named {name}"));
        assert_eq!(v.len(), 64 * 40);
        v[..64].iter().sum::<f32>() / 64.0
    };
    for (band, sky) in [("blue", 0.9), ("green", 0.7), ("red", 0.55), ("nir", 0.25)] {
        let got = top_row(band);
        assert!((got - sky).abs() < 1e-4, "{band}: sky {got}, given {sky}");
    }

    // Refused before any work, in one line naming the scene.
    for (extra, want) in [
        (&["--mode", "all"][..], "--mode all"),
        (&["--leaf-optics", "texture"][..], "--leaf-optics measured"),
    ] {
        let (ok, _, stderr) = run(extra);
        assert!(!ok);
        assert!(
            stderr.contains(want) && stderr.contains("bands.toml"),
            "{stderr}"
        );
    }
}

#[test]
fn bench_rays_reports_three_sets_and_exports_them_with_its_report() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path());
    let out = dir.path().join("rays");
    let (ok, stdout, stderr) = sylva(&[
        "bench",
        "rays",
        &scene,
        "--no-cache",
        "--runs",
        "1",
        "--json",
        "--export",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{stderr}");
    let v: serde_json::Value = serde_json::from_str(&stdout).expect("one JSON object");
    let sets = v["sets"].as_array().unwrap();
    let names: Vec<&str> = sets.iter().map(|s| s["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["primary", "shadow", "incoherent"]);
    assert_eq!(sets[0]["rays"], 64 * 40);
    // A shadow and an incoherent ray per primary hit.
    assert_eq!(sets[1]["rays"], sets[0]["hits"]);
    assert_eq!(sets[2]["rays"], sets[0]["hits"]);
    let saved: serde_json::Value =
        serde_json::from_slice(&fs::read(out.join("sylva.json")).unwrap()).unwrap();
    assert_eq!(saved["sets"], v["sets"]);
    let manifest: serde_json::Value =
        serde_json::from_slice(&fs::read(out.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(manifest["sets"][0]["rays"], 64 * 40);
    // Rows of 8 f32 per ray.
    let rays = fs::metadata(out.join("shadow_rays.f32")).unwrap().len();
    assert_eq!(rays, 32 * sets[1]["rays"].as_u64().unwrap());

    // An export path that is a file is refused, naming it.
    let file = dir.path().join("taken");
    fs::write(&file, "x").unwrap();
    let (ok, _, stderr) = sylva(&[
        "bench",
        "rays",
        &scene,
        "--no-cache",
        "--runs",
        "1",
        "--export",
        file.to_str().unwrap(),
    ]);
    assert!(!ok);
    assert!(stderr.contains("taken"), "{stderr}");
}

/// Runs `sylva ARGS` as if `mpirun` had started it as one of two processes (the variable Open
/// MPI sets; the check comes before MPI would start): (success, stderr).
fn as_one_of_two(args: &[&str]) -> (bool, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_sylva"))
        .args(args)
        .env("OMPI_COMM_WORLD_SIZE", "2")
        .output()
        .expect("run sylva");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn under_mpirun_commands_that_do_not_split_their_work_refuse() {
    for args in [
        &["scene", "list"][..],
        &["bench", "scene", "demo"],
        &["bench", "relight", "demo"],
    ] {
        let (ok, err) = as_one_of_two(args);
        assert!(!ok, "{args:?}");
        assert!(
            err.contains("started by mpirun as one of 2 processes")
                && err.contains("does not split its work across processes"),
            "{args:?}: {err}"
        );
    }
}

#[cfg(not(feature = "mpi"))]
#[test]
fn a_build_without_mpi_refuses_to_render_under_mpirun() {
    for args in [
        &["render", "demo"][..],
        &["bench", "trace", "demo"],
        &["basis", "demo"],
    ] {
        let (ok, err) = as_one_of_two(args);
        assert!(!ok, "{args:?}");
        assert!(
            err.contains("this sylva was built without MPI") && err.contains("--features mpi"),
            "{args:?}: {err}"
        );
    }
}

/// Issue 27: `render --lat --lon --date --time` places the sun (north -z, east +x), the
/// clock at `--utc-offset` (default: the longitude's zone).
#[test]
fn render_places_the_sun_by_date_time_and_place() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path());
    let out = dir.path().join("noon.png");
    let render = |extra: &[&str]| {
        let mut args = vec![
            "render",
            &scene,
            "--mode",
            "local",
            "--no-cache",
            "--width",
            "32",
            "--height",
            "24",
            "-o",
            out.to_str().unwrap(),
            "--lat",
            "48.1",
            "--lon",
            "11.6",
            "--date",
            "2026-06-21",
        ];
        args.extend(extra);
        let (ok, stdout, stderr) = sylva(&args);
        assert!(ok, "{stdout}{stderr}");
        stdout
    };
    // Munich's solar noon, 12:14 at UTC+01:00 (its longitude's zone): the sun due south,
    // 65.3° up, over +z (world azimuth 90°).
    let noon = render(&["--time", "12:14"]);
    assert!(
        noon.contains("sun at 48.1°N 11.6°E on 2026-06-21 at 12:14 (UTC+01:00): elevation 65.3°"),
        "{noon}"
    );
    let world = |s: &str| -> f64 {
        let at = s.find("; sun elevation").unwrap();
        let tail = &s[at..];
        let az = tail.find("azimuth ").unwrap() + "azimuth ".len();
        tail[az..].split('°').next().unwrap().parse().unwrap()
    };
    assert!((world(&noon) - 90.0).abs() < 1.0, "{noon}");
    // One mode other than full: its name is added.
    assert!(image::open(dir.path().join("noon-local.png")).is_ok());
    // The same moment on summer time's clock.
    let same = render(&["--time", "13:14", "--utc-offset", "+02:00"]);
    assert!(same.contains("(UTC+02:00): elevation 65.3°"), "{same}");
    // 08:00: the morning sun in the east (world azimuth near 0°, +x).
    let morning = render(&["--time", "08:00"]);
    let az = world(&morning);
    assert!(!(60.0..300.0).contains(&az), "{morning}");
}
