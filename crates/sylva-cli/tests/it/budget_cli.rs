//! `sylva budget` as a user runs it: a built-in stand and a canopy file, JSON and text, and
//! bad input (docs/budget.md).

use crate::common;
use common::sylva;

/// `sylva budget ARGS --photons 20000` fails with one line of standard error holding `says`.
fn refused_in_one_line(args: &[&str], says: &str) {
    let mut all = vec!["budget", "--photons", "20000"];
    all.extend(args);
    let (ok, _, err) = sylva(&all);
    assert!(
        !ok && err.contains(says) && err.trim().lines().count() == 1,
        "{err}"
    );
}

#[test]
fn a_canopy_file_gets_a_budget_whose_fates_add_up() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("grove.toml");
    std::fs::write(
        &path,
        "name = \"grove\"\n[plot]\nsize = [12.0, 12.0]\n[crowns]\nshape = \"ellipsoid\"\nradius = 1.5\nhalf_height = 2.0\ncentre_height = 3.0\nlai = 3.0\ncover = 0.3\n[leaves]\nshape = \"square\"\nsize = 0.15\n\n[[bands]]\nname = \"red\"\nleaf_reflectance = 0.07\nleaf_transmittance = 0.06\nsoil_albedo = 0.12\npar = true\n\n[[bands]]\nname = \"green\"\nleaf_reflectance = 0.12\nleaf_transmittance = 0.1\nsoil_albedo = 0.12\npar = true\nweight = 0.5\n\n[[bands]]\nname = \"nir\"\nleaf_reflectance = 0.45\nleaf_transmittance = 0.4\nsoil_albedo = 0.3\n",
    )
    .unwrap();
    let out = dir.path().join("grove.json");
    let (ok, stdout, err) = sylva(&[
        "budget",
        path.to_str().unwrap(),
        "--sun-zenith",
        "40",
        "--photons",
        "40000",
        "--json",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(stdout.is_empty());
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    assert_eq!(r["stand"], "grove");
    assert_eq!(r["cyclic"], true);
    let bands = r["bands"].as_array().unwrap();
    assert_eq!(bands.len(), 3);
    let f = |b: &serde_json::Value, k: &str| b[k]["value"].as_f64().unwrap();
    for b in bands {
        // Every photon ends absorbed or in the sky; none leaves a cyclic plot sideways.
        let sum = f(b, "canopy_absorbed") + f(b, "reflected") + f(b, "soil_absorbed");
        assert!((sum - 1.0).abs() < 1e-9, "{b}");
        assert_eq!(f(b, "side_lost"), 0.0);
        // The soil absorbs 1 − ρ of every arrival (within the noise).
        let rho = if b["band"] == "nir" { 0.3 } else { 0.12 };
        let se = b["soil_absorbed"]["std_error"].as_f64().unwrap();
        assert!(
            (f(b, "soil_absorbed") - (1.0 - rho) * f(b, "ground_arrived")).abs() < 4.0 * se + 1e-3,
            "{b}"
        );
        assert!(f(b, "ground_direct") <= f(b, "ground_arrived"));
    }
    // Brighter leaves absorb less and reflect more; fAPAR weighs red 1 and green 0.5.
    assert!(f(&bands[2], "canopy_absorbed") < f(&bands[0], "canopy_absorbed"));
    assert!(f(&bands[2], "reflected") > f(&bands[0], "reflected"));
    let fapar = (f(&bands[0], "canopy_absorbed") + 0.5 * f(&bands[1], "canopy_absorbed")) / 1.5;
    assert!((r["fapar"].as_f64().unwrap() - fapar).abs() < 1e-12);
    // The same stand and seed give the same numbers; the text names the bands.
    let (ok, text, err) = sylva(&[
        "budget",
        path.to_str().unwrap(),
        "--sun-zenith",
        "40",
        "--photons",
        "40000",
    ]);
    assert!(ok, "{err}");
    assert!(text.contains("| nir |") && text.contains("fAPAR"), "{text}");
    let red = format!("{:.4}", f(&bands[0], "canopy_absorbed"));
    assert!(text.contains(&red), "{text}");
}

#[test]
fn bad_canopies_and_suns_get_one_line_errors_naming_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        ("[layer]\nlai = 0.0\nheight = 1.0\n", "layer.lai"),
        (
            "[layer]\nlai = 1.0\nheight = 1.0\n[[bands]]\nname = \"x\"\nleaf_reflectance = 0.7\nleaf_transmittance = 0.4\nsoil_albedo = 0.1\n",
            "must not exceed 1",
        ),
        ("[crowns]\nradius = 1.0\ncentre_height = 2.0\nlai = 3.0\ncover = 0.8\n", "jams"),
        ("[layer\n", "line 1"),
    ];
    for (k, (text, needle)) in cases.iter().enumerate() {
        let path = dir.path().join(format!("bad{k}.toml"));
        std::fs::write(&path, text).unwrap();
        let (ok, _, err) = sylva(&["budget", path.to_str().unwrap()]);
        assert!(!ok);
        assert!(
            err.contains(needle) && err.contains(&format!("bad{k}.toml")),
            "{err}"
        );
        assert_eq!(err.trim().lines().count(), 1, "{err}");
    }
    for (args, needle) in [
        (
            vec!["budget", "layer", "--sun-zenith", "90"],
            "--sun-zenith",
        ),
        (vec!["budget", "layer", "--photons", "100"], "--photons"),
        (vec!["budget", "no-such-stand"], "not a built-in stand"),
    ] {
        let (ok, _, err) = sylva(&args);
        assert!(!ok && err.contains(needle), "{err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
    }
}

#[test]
fn the_brf_is_reported_per_view_with_the_hot_spot_towards_the_sun() {
    let (ok, out, err) = sylva(&[
        "budget",
        "layer",
        "--sun-zenith",
        "30",
        "--photons",
        "20000",
        "--brf",
        "30:0,30:180",
        "--json",
    ]);
    assert!(ok, "{err}");
    let r: serde_json::Value = serde_json::from_str(&out).unwrap();
    for b in r["bands"].as_array().unwrap() {
        let brf = b["brf"].as_array().unwrap();
        assert_eq!(brf.len(), 2);
        assert_eq!(brf[1]["view"]["azimuth_deg"], 180.0);
        let v = |k: usize| brf[k]["brf"]["value"].as_f64().unwrap();
        // Looking along the sunlight's way back, the viewer sees the sunlit leaves: the hot
        // spot of every canopy.
        assert!(v(0) > 1.3 * v(1), "{b}");
    }
    for bad in ["95:0", "30", "x:1"] {
        let (ok, _, err) = sylva(&["budget", "layer", "--brf", bad]);
        assert!(!ok && err.contains("--brf"), "{err}");
    }
}

#[test]
fn the_brf_image_is_written_as_an_exr_of_the_bands_and_a_png_each() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("view.exr");
    let (ok, stdout, err) = sylva(&[
        "budget",
        "layer",
        "--photons",
        "20000",
        "--brf-image",
        "30:180",
        "--brf-image-size",
        "12",
        "--brf-image-out",
        out.to_str().unwrap(),
        "--json",
    ]);
    assert!(ok, "{err}");
    // Standard output stays JSON; the image view's BRF is in it although `--brf` was not
    // given, and the note on standard error gives the same value as the image's mean.
    let r: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert!(r["bands"][0]["brf"].as_array().unwrap().is_empty());
    assert!(
        err.contains("12x12 pixels") && err.contains("view_red.png"),
        "{err}"
    );
    let exr = sylva_render::output::read_exr_layers(&out).unwrap();
    assert_eq!((exr.width, exr.height), (12, 12));
    assert_eq!(exr.names(), ["red", "nir"]);
    for band in ["red", "nir"] {
        let png = image::open(dir.path().join(format!("view_{band}.png"))).unwrap();
        assert_eq!((png.width(), png.height()), (12, 12));
    }
    for (args, says) in [
        (vec!["--brf-image", "90:0"], "--brf zenith"),
        (vec!["--brf-image", "30"], "ZENITH:AZIMUTH"),
        (
            vec!["--brf-image", "0:0", "--brf-image-size", "0"],
            "--brf-image-size",
        ),
        (
            vec!["--brf-image", "0:0", "--method", "lb"],
            "--method mc or --method both",
        ),
    ] {
        let mut all = vec!["layer"];
        all.extend(args);
        refused_in_one_line(&all, says);
    }
}

#[test]
fn a_scene_holding_a_stand_gets_the_stand_s_budget() {
    // The same crowns twice: as a canopy file, and as a scene whose [stand] places them over
    // a ground of the plot's size, its [bands] giving the leaves' and the soil's optics. The
    // scene's budget (each material's optics, the ground as the soil, --cyclic) must be the
    // stand's, which reads its bands directly.
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("grove.toml"),
        "name = \"grove\"\n[plot]\nsize = [12.0, 12.0]\n[crowns]\nradius = 1.5\ncentre_height = 3.0\nlai = 3.0\ncover = 0.3\n[leaves]\nsize = 0.15\n\n[[bands]]\nname = \"red\"\nleaf_reflectance = 0.07\nleaf_transmittance = 0.06\nsoil_albedo = 0.12\npar = true\n\n[[bands]]\nname = \"nir\"\nleaf_reflectance = 0.45\nleaf_transmittance = 0.4\nsoil_albedo = 0.3\n",
    )
    .unwrap();
    let scene = dir.path().join("grove-scene.toml");
    std::fs::write(
        &scene,
        "[stand]\ncanopy = \"grove.toml\"\n[ground]\nsize = [12.0, 12.0]\n[sun]\nelevation = 55.0\nazimuth = 20.0\n\
         [bands]\nnames = [\"red\", \"nir\"]\nleaf_reflectance = [0.07, 0.45]\nleaf_transmittance = [0.06, 0.4]\n\
         bark = [0.1, 0.3]\nsoil = [0.12, 0.3]\nsky = [0.5, 0.2]\n",
    )
    .unwrap();
    let budget = |args: &[&str]| -> serde_json::Value {
        let mut all = vec!["budget", "--photons", "100000", "--json"];
        all.extend(args);
        let (ok, out, err) = sylva(&all);
        assert!(ok, "{err}");
        serde_json::from_str(&out).unwrap()
    };
    let stand = budget(&[
        dir.path().join("grove.toml").to_str().unwrap(),
        "--sun-zenith",
        "35",
        "--sun-azimuth",
        "20",
    ]);
    // The scene's own sun (elevation 55°) is the stand's zenith 35°.
    let from_scene = budget(&[scene.to_str().unwrap(), "--cyclic"]);
    assert_eq!(from_scene["sun"]["azimuth_deg"], 20.0);
    assert!((from_scene["sun"]["zenith_deg"].as_f64().unwrap() - 35.0).abs() < 1e-9);
    assert_eq!(from_scene["cyclic"], true);
    let lai = |b: &serde_json::Value| b["lai"].as_f64().unwrap();
    assert!(
        (lai(&stand) - lai(&from_scene)).abs() < 1e-3 * lai(&stand),
        "LAI {} against {}",
        lai(&from_scene),
        lai(&stand)
    );
    for k in 0..2 {
        let (a, b) = (&stand["bands"][k], &from_scene["bands"][k]);
        assert_eq!(a["band"], b["band"]);
        for fate in [
            "canopy_absorbed",
            "reflected",
            "soil_absorbed",
            "ground_direct",
        ] {
            let (x, y) = (&a[fate], &b[fate]);
            let v = |f: &serde_json::Value, k: &str| f[k].as_f64().unwrap();
            let se = v(x, "std_error").hypot(v(y, "std_error"));
            assert!(
                (v(x, "value") - v(y, "value")).abs() < 4.0 * se + 1e-4,
                "{} {fate}: scene {} against the stand's {} (± {se})",
                a["band"],
                v(y, "value"),
                v(x, "value")
            );
        }
    }
    // An isolated scene (the default) loses light through its sides; the lattice and a
    // stand's --cyclic are refused.
    let isolated = budget(&[scene.to_str().unwrap()]);
    assert!(isolated["bands"][0]["side_lost"]["value"].as_f64().unwrap() > 0.05);
    for (args, says) in [
        (
            vec![scene.to_str().unwrap(), "--method", "both"],
            "abstract stands",
        ),
        (vec!["layer", "--cyclic"], "--cyclic is for scenes"),
        (
            vec!["layer", "--leaf-optics", "texture"],
            "--leaf-optics is for scenes",
        ),
        (vec!["cloud"], "participating media"),
        (
            vec!["no-such-scene"],
            "not a built-in stand (crowns, layer) or scene (demo",
        ),
    ] {
        refused_in_one_line(&args, says);
    }
}

#[test]
fn the_lattice_budget_balances_and_stands_beside_the_photons() {
    // `--method both` on a small cyclic stand: the lattice's fractions balance, agree with the
    // photons' and the text shows their differences; `--method lb` refuses an isolated plot.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("grove.toml");
    let stand = "name = \"grove\"\n[plot]\nsize = [12.0, 12.0]\n[crowns]\nshape = \"sphere\"\nradius = 1.5\ncentre_height = 3.0\nlai = 4.0\ncover = 0.3\n[leaves]\nshape = \"disc\"\nsize = 0.1\n";
    std::fs::write(&path, stand).unwrap();
    let (ok, stdout, err) = sylva(&[
        "budget",
        path.to_str().unwrap(),
        "--sun-zenith",
        "35",
        "--method",
        "both",
        "--photons",
        "100000",
        "--json",
    ]);
    assert!(ok, "{err}");
    let r: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(r["method"], "both");
    let lattice = &r["lattice"];
    assert_eq!(lattice["cell_m"], 1.0);
    assert_eq!(lattice["grid"][0], 12);
    for (mc, lb) in r["bands"]
        .as_array()
        .unwrap()
        .iter()
        .zip(lattice["bands"].as_array().unwrap())
    {
        let v = |k: &str| lb[k].as_f64().unwrap();
        assert_eq!(lb["converged"], true);
        let sum = v("canopy_absorbed") + v("reflected") + v("soil_absorbed");
        assert!((sum - 1.0).abs() < 0.005, "{lb}");
        assert!((v("balance") - (1.0 - sum)).abs() < 1e-12);
        for k in [
            "canopy_absorbed",
            "reflected",
            "ground_arrived",
            "soil_absorbed",
        ] {
            let m = mc[k]["value"].as_f64().unwrap();
            assert!((v(k) - m).abs() < 0.03, "{k}: lattice {} against {m}", v(k));
        }
    }
    let (ok, text, err) = sylva(&[
        "budget",
        path.to_str().unwrap(),
        "--method",
        "both",
        "--photons",
        "20000",
    ]);
    assert!(ok, "{err}");
    assert!(
        text.contains("lattice-Boltzmann, cells of 1.000 m"),
        "{text}"
    );
    assert!(text.contains("Lattice − Monte Carlo"), "{text}");
    // An isolated plot, and a cell that cannot tile the plot: one line each.
    let isolated = dir.path().join("isolated.toml");
    std::fs::write(
        &isolated,
        stand.replace("[plot]\n", "[plot]\ncyclic = false\n"),
    )
    .unwrap();
    let (ok, _, err) = sylva(&["budget", isolated.to_str().unwrap(), "--method", "lb"]);
    assert!(!ok);
    assert!(err.contains("cyclic") && err.lines().count() == 1, "{err}");
    let (ok, _, err) = sylva(&[
        "budget",
        path.to_str().unwrap(),
        "--method",
        "lb",
        "--lb-cell",
        "-1",
    ]);
    assert!(!ok);
    assert!(err.contains("--lb-cell"), "{err}");
}
