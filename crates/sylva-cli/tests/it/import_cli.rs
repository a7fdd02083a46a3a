//! `sylva scene info` on a scene whose model is an imported mesh file.

use crate::common;
use common::sylva;
use std::path::Path;

/// A glTF with an external buffer: two triangles of the unit square, one with an opaque
/// material (wood), one with an alpha-masked material (leaf).
fn write_plant(dir: &Path) {
    let positions: [f32; 12] = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 0.0];
    let indices: [u16; 6] = [0, 1, 2, 0, 2, 3];
    let mut bin: Vec<u8> = positions.iter().flat_map(|f| f.to_le_bytes()).collect();
    bin.extend(indices.iter().flat_map(|i| i.to_le_bytes()));
    std::fs::write(dir.join("plant.bin"), &bin).unwrap();
    let gltf = serde_json::json!({
        "asset": {"version": "2.0"},
        "buffers": [{"uri": "plant.bin", "byteLength": bin.len()}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 48},
            {"buffer": 0, "byteOffset": 48, "byteLength": 12}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
             "min": [0.0, 0.0, 0.0], "max": [1.0, 1.0, 0.0]},
            {"bufferView": 1, "byteOffset": 0, "componentType": 5123, "count": 3, "type": "SCALAR"},
            {"bufferView": 1, "byteOffset": 6, "componentType": 5123, "count": 3, "type": "SCALAR"}
        ],
        "materials": [
            {"name": "stem"},
            {"name": "blade", "alphaMode": "MASK"}
        ],
        "meshes": [{"primitives": [
            {"attributes": {"POSITION": 0}, "indices": 1, "material": 0},
            {"attributes": {"POSITION": 0}, "indices": 2, "material": 1}
        ]}],
        "nodes": [{"mesh": 0, "scale": [2.0, 2.0, 2.0]}],
        "scenes": [{"nodes": [0]}]
    });
    std::fs::write(dir.join("plant.gltf"), gltf.to_string()).unwrap();
}

#[test]
fn scene_info_reports_an_imported_mesh() {
    let dir = tempfile::tempdir().unwrap();
    write_plant(dir.path());
    let scene = dir.path().join("garden.toml");
    std::fs::write(
        &scene,
        "[[models]]\nname = \"plant\"\nmesh = \"plant.gltf\"\n\n[[instances]]\nmodel = \"plant\"\ncount = 3\narea = { min = [-5.0, -5.0], max = [5.0, 5.0] }\n",
    )
    .unwrap();
    let (ok, out, err) = sylva(&["scene", "info", scene.to_str().unwrap(), "--json"]);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["instances"], 3);
    assert_eq!(v["unique_triangles"], 2);
    assert_eq!(v["instanced_triangles"], 6);
    let m = &v["models"][0];
    assert_eq!(m["name"], "plant");
    assert_eq!(m["species"], "plant.gltf");
    assert_eq!(m["leaf_triangles"], 1);
    assert_eq!(m["wood_triangles"], 1);
    // The node's scale 2 makes the plant 2 m tall.
    assert!(
        (v["bounds_max"][1].as_f64().unwrap() - 2.0).abs() < 1e-5,
        "{v}"
    );

    let (ok, out, err) = sylva(&["scene", "info", scene.to_str().unwrap()]);
    assert!(ok, "{err}");
    assert!(out.contains("plant.gltf"), "{out}");

    // A broken mesh: the error names the scene line, the mesh file and the element.
    std::fs::write(dir.path().join("plant.bin"), [0u8; 10]).unwrap();
    let (ok, _, err) = sylva(&["scene", "info", scene.to_str().unwrap()]);
    assert!(!ok);
    assert!(
        err.contains("garden.toml: line 1: model 'plant'")
            && err.contains("plant.gltf: buffers[0]")
            && err.contains("buffer too short"),
        "{err}"
    );
}
