//! `sylva scene` and `sylva species` as a user runs them.

use crate::common;
use common::sylva;

#[test]
fn scene_info_json_has_the_counts() {
    let (ok, out, err) = sylva(&["scene", "info", "catalpa", "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["instances"], 1);
    let unique = v["unique_triangles"].as_u64().unwrap();
    assert_eq!(v["instanced_triangles"].as_u64().unwrap(), unique);
    assert!((140_000..=171_000).contains(&unique), "{unique}");
    assert_eq!(v["camera"]["resolution"], serde_json::json!([512, 512]));
    assert_eq!(v["lb"]["preset"], "leaf");
}

#[test]
fn scene_errors_name_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.toml");
    std::fs::write(&path, "[lb]\ngrid = 64\nsmoothness = 2\n").unwrap();
    let (ok, _, err) = sylva(&["scene", "info", path.to_str().unwrap()]);
    assert!(!ok);
    assert!(
        err.contains("bad.toml: line 3") && err.contains("smoothness"),
        "{err}"
    );
    let (ok, _, err) = sylva(&["scene", "info", "no_such_scene"]);
    assert!(!ok);
    assert!(err.contains("no_such_scene"), "{err}");
}

#[test]
fn species_list_and_show() {
    let (ok, out, err) = sylva(&["species", "list"]);
    assert!(ok, "{err}");
    for name in ["red_maple", "american_beech", "pine", "dogrose"] {
        assert!(out.contains(name), "{out}");
    }
    assert!(out.contains("496,719"), "{out}");
    let (ok, out, err) = sylva(&["species", "show", "pine", "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["params"]["Shape"], 0.0);
    assert!(v["triangles"].as_u64().unwrap() > 100_000);
    // The measured leaf and its source (000 Table 1 for the forest species).
    let r: Vec<f64> = serde_json::from_value(v["leaf_reflectance"].clone()).unwrap();
    let t: Vec<f64> = serde_json::from_value(v["leaf_transmittance"].clone()).unwrap();
    for (got, want) in r.iter().zip([0.070, 0.125, 0.040]) {
        assert!((got - want).abs() < 1e-6, "{r:?}");
    }
    for (got, want) in t.iter().zip([0.055, 0.150, 0.020]) {
        assert!((got - want).abs() < 1e-6, "{t:?}");
    }
    assert!(
        v["leaf_source"].as_str().unwrap().contains("000 Table 1"),
        "{v}"
    );
    let (ok, out, err) = sylva(&["species", "show", "dogrose"]);
    assert!(ok, "{err}");
    assert!(out.contains("reflectance 0.079, 0.122, 0.049"), "{out}");
    assert!(out.contains("002 Table 1"), "{out}");
    let (ok, _, err) = sylva(&["species", "show", "baobab"]);
    assert!(!ok && err.contains("baobab"), "{err}");
}

#[test]
fn species_xml_round_trips_through_show() {
    let dir = tempfile::tempdir().unwrap();
    let (ok, xml, err) = sylva(&["species", "show", "dogrose", "--xml"]);
    assert!(ok, "{err}");
    let path = dir.path().join("rose.xml");
    std::fs::write(&path, xml).unwrap();
    let (ok, out, err) = sylva(&["species", "show", path.to_str().unwrap()]);
    assert!(ok, "{err}");
    assert!(out.contains("species dogrose"), "{out}");
}
