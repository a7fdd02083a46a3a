//! `sylva spp trees` on `sparse_maple`, the tree of 003 Table 3's size (docs/spp.md).

use crate::common;
use common::sylva;

fn trees(extra: &[&str]) -> serde_json::Value {
    let mut args = vec![
        "spp",
        "trees",
        "sparse_maple",
        "--no-lb",
        "--photons",
        "400000",
        "--json",
    ];
    args.extend_from_slice(extra);
    let (ok, out, err) = sylva(&args);
    assert!(ok, "{err}");
    serde_json::from_str(&out).unwrap()
}

#[test]
fn sparse_maple_is_003s_tree_size_with_a_sparse_crown() {
    // 003 §4.2: "18K triangles", lit from above, albedo 0.95 (the defaults).
    let (ok, out, err) = sylva(&["species", "show", "sparse_maple", "--json"]);
    assert!(ok, "{err}");
    let s: serde_json::Value = serde_json::from_str(&out).unwrap();
    let tris = s["triangles"].as_u64().unwrap();
    assert!((16_200..=19_800).contains(&tris), "{tris} triangles");

    let r = trees(&[]);
    assert_eq!(r["albedo"], 0.95);
    // From straight above.
    let light: Vec<f64> = (0..3).map(|k| r["light"][k].as_f64().unwrap()).collect();
    assert!(
        light[1] == -1.0 && light[0].abs() < 1e-6 && light[2].abs() < 1e-6,
        "{light:?}"
    );
    assert_eq!(r["instances"], 1);
    assert_eq!(r["leaf_meshes"], 4988);
    // docs/spp.md: about half a surface above the mean leaf, 1.3 along the whole vertical,
    // and the leaves meet the overhead light at |n·s0| 0.44.
    let f = |k: &str| r[k].as_f64().unwrap();
    assert!((0.45..0.65).contains(&f("mean_depth")), "{r}");
    assert!((1.15..1.5).contains(&f("mean_thickness")), "{r}");
    assert!((0.4..0.49).contains(&f("mean_cos_light")), "{r}");
}

#[test]
fn with_horizontal_leaves_sparse_maple_keeps_003s_order() {
    // The planophile limit of the same crown: SPPG < SS < SPP, as in 003 Table 3 (17, 39 and
    // 68 % with 2 M photons; the margins are ten times the Monte Carlo noise of this run).
    let r = trees(&["--horizontal-leaves"]);
    assert!(r["mean_cos_light"].as_f64().unwrap() > 0.99, "{r}");
    let e = &r["errors"];
    let (sppg, spp, ss, noise) = (
        e["sppg"].as_f64().unwrap(),
        e["spp"].as_f64().unwrap(),
        e["ss"].as_f64().unwrap(),
        e["mc_noise"].as_f64().unwrap(),
    );
    assert!(noise < 0.05, "{e}");
    assert!(sppg + 0.1 < ss && ss + 0.1 < spp, "{e}");
}
