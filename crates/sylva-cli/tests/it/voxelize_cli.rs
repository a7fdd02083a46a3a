//! `sylva voxelize`, `sylva lb solve --model/--scene` and `sylva bench voxelize` as a user runs
//! them.

use crate::common;
use common::sylva;

use sylva_lb::GridFile;

#[test]
fn voxelize_then_info_then_solve() {
    let dir = tempfile::tempdir().unwrap();
    let grid = dir.path().join("maple.sgrid");
    let g = grid.to_str().unwrap();
    let (ok, out, err) = sylva(&["voxelize", "red_maple", "--grid", "32", "-o", g]);
    assert!(ok, "{err}");
    assert!(out.contains("occupied sites"), "{out}");
    assert!(out.contains("wood sites"), "{out}");
    let png = std::fs::read(grid.with_extension("png")).unwrap();
    assert_eq!(&png[1..4], b"PNG");

    // The file is a density grid with 32 sites along the longest edge, placed in model space
    // and carrying where it came from.
    let file = GridFile::read(&grid).unwrap();
    assert_eq!(file.dims.longest_edge(), 32);
    assert_eq!(file.metadata_value("model"), Some("red_maple"));
    assert_eq!(file.metadata_value("grid_n"), Some("32"));
    let tris: usize = file.metadata_value("triangles").unwrap().parse().unwrap();
    assert!(tris > 100_000, "{tris}");
    let density = file.clone().into_density(&grid).unwrap();
    // The grid is centred on the model's box, which fills the interior along its longest
    // edge: site centres span the box plus half a cell (the shell) at either end there.
    let parse = |k: &str| -> Vec<f32> {
        let v = file.metadata_value(k).unwrap();
        v.split(',').map(|x| x.parse().unwrap()).collect()
    };
    let (lo, hi) = (parse("model_min"), parse("model_max"));
    let b = density.bounds;
    let cell: f32 = file.metadata_value("cell_size").unwrap().parse().unwrap();
    let d = [file.dims.nx, file.dims.ny, file.dims.nz];
    for a in 0..3 {
        let centre = 0.5 * (b.min[a] + b.max[a]);
        assert!(
            (centre - 0.5 * (lo[a] + hi[a])).abs() < 1e-3,
            "axis {a}: {b:?}"
        );
        assert!((b.max[a] - b.min[a] - (d[a] - 1) as f32 * cell).abs() < 1e-3);
        if d[a] == 32 {
            assert!(
                (b.min[a] - (lo[a] - 0.5 * cell)).abs() < 1e-3,
                "axis {a}: {b:?}"
            );
        }
    }
    let (ok, out, err) = sylva(&["lb", "info", g]);
    assert!(ok, "{err}");
    assert!(out.contains("density grid"), "{out}");
    assert!(out.contains("red_maple"), "{out}");

    let lit = dir.path().join("lit.sgrid");
    let (ok, out, err) = sylva(&[
        "lb",
        "solve",
        "--input",
        g,
        "--steps",
        "8",
        "-o",
        lit.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(out.contains("8 steps"), "{out}");
    // The lighting grid sits where the density grid does.
    let lighting = GridFile::read(&lit).unwrap();
    assert_eq!(lighting.bounds, file.bounds);
    assert_eq!(lighting.dims, file.dims);
}

#[test]
fn f16_grid_holds_the_same_densities_to_half_precision() {
    let dir = tempfile::tempdir().unwrap();
    let a = dir.path().join("a.sgrid");
    let b = dir.path().join("b.sgrid");
    for (p, extra) in [(&a, None), (&b, Some("--f16"))] {
        let mut args = vec![
            "voxelize",
            "dogrose",
            "--grid",
            "24",
            "-o",
            p.to_str().unwrap(),
        ];
        args.extend(extra);
        let (ok, _, err) = sylva(&args);
        assert!(ok, "{err}");
    }
    let (fa, fb) = (GridFile::read(&a).unwrap(), GridFile::read(&b).unwrap());
    assert!(std::fs::metadata(&b).unwrap().len() < std::fs::metadata(&a).unwrap().len());
    for (x, y) in fa.channels[0].iter().zip(&fb.channels[0]) {
        assert!((x - y).abs() <= 1e-3, "{x} vs {y}");
    }
}

#[test]
fn solve_takes_a_model_or_a_scene_model_directly() {
    let dir = tempfile::tempdir().unwrap();
    let out1 = dir.path().join("m.sgrid");
    let (ok, out, err) = sylva(&[
        "lb",
        "solve",
        "--model",
        "red_maple",
        "--grid",
        "32",
        "--steps",
        "8",
        "-o",
        out1.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(out.contains("voxelized red_maple"), "{out}");
    let lit = GridFile::read(&out1).unwrap();
    assert_eq!(lit.dims.longest_edge(), 32);
    // Placed in model space, not the unit cube.
    assert!(lit.bounds.max[1] > 5.0, "{:?}", lit.bounds);

    // The demo scene's dogrose, with its model's preset (the demo gives its roses the
    // dogrose preset) unless told otherwise.
    let out2 = dir.path().join("s.sgrid");
    let (ok, out, err) = sylva(&[
        "lb",
        "solve",
        "--scene",
        "demo",
        "--scene-model",
        "rose",
        "--grid",
        "20",
        "--steps",
        "4",
        "-o",
        out2.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(out.contains("voxelized demo: rose"), "{out}");
    let lit = GridFile::read(&out2).unwrap();
    assert_eq!(lit.dims.longest_edge(), 20);
    assert_eq!(lit.metadata_value("preset"), Some("dogrose"));

    // A scene with several models needs --scene-model; the error lists them.
    let (ok, _, err) = sylva(&["lb", "solve", "--scene", "demo", "--steps", "2"]);
    assert!(!ok);
    assert!(err.contains("maple, pine, rose"), "{err}");
    // A model grid is one number.
    let (ok, _, err) = sylva(&["lb", "solve", "--model", "dogrose", "--grid", "8x8x8"]);
    assert!(!ok);
    assert!(err.contains("longest edge"), "{err}");
}

#[test]
fn bad_models_and_sizes_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let o = dir.path().join("x.sgrid");
    let o = o.to_str().unwrap();
    let (ok, _, err) = sylva(&["voxelize", "oak", "-o", o]);
    assert!(!ok);
    assert!(
        err.contains("red_maple") && err.contains("american_beech"),
        "{err}"
    );
    let (ok, _, err) = sylva(&["voxelize", "tree.stl", "-o", o]);
    assert!(!ok);
    assert!(err.contains("unsupported model file type"), "{err}");
    for n in ["0", "100000"] {
        let (ok, _, err) = sylva(&["voxelize", "dogrose", "--grid", n, "-o", o]);
        assert!(!ok);
        assert!(err.contains(&format!("N = {n}")), "{err}");
    }
    assert!(!std::path::Path::new(o).exists());
}

#[test]
fn bench_voxelize_reports_json() {
    let (ok, out, err) = sylva(&[
        "bench", "voxelize", "dogrose", "--grid", "24", "--runs", "2", "--json",
    ]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    assert_eq!(v["model"], "dogrose");
    assert_eq!(v["runs"].as_array().unwrap().len(), 2);
    let tris = v["triangles"].as_f64().unwrap();
    let secs = v["seconds"].as_f64().unwrap();
    assert!((v["triangles_per_s"].as_f64().unwrap() - tris / secs).abs() < 1e-6 * tris / secs);
    assert!(v["threads"].as_u64().unwrap() >= 1);
    assert!(v["occupied_sites"].as_u64().unwrap() > 0);
}
