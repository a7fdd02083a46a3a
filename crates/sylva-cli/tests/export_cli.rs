//! `sylva export` as a user runs it.

mod common;
use common::sylva;
use std::fs;

#[test]
fn export_demo_to_mitsuba() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let (ok, stdout, err) = sylva(&[
        "export",
        "demo",
        "--format",
        "mitsuba",
        "-o",
        out.to_str().unwrap(),
        "--spp",
        "8",
    ]);
    assert!(ok, "{err}");
    // 16 as before, plus each leaf's 2R and 2T textures (linear EXR).
    assert!(stdout.contains("wrote 22 files"), "{stdout}");
    assert!(stdout.contains("mitsuba"), "{stdout}");
    let xml = fs::read_to_string(out.join("scene.xml")).unwrap();
    assert!(xml.contains("<default name=\"spp\" value=\"8\"/>"));
    // Leaves: an even blend of a reflector of 2R and a pure transmitter (diff_trans 2) of 2T.
    assert_eq!(xml.matches("type=\"blendbsdf\"").count(), 3, "{xml}");
    assert_eq!(xml.matches("name=\"diff_trans\" value=\"2\"").count(), 3);
    for m in ["maple", "pine", "rose"] {
        assert!(out.join(format!("meshes/{m}_leaf.ply")).is_file(), "{m}");
        assert!(out.join(format!("meshes/{m}_wood.ply")).is_file(), "{m}");
        assert!(out.join(format!("textures/{m}_leaf_alpha.png")).is_file());
        assert!(out.join(format!("textures/{m}_wood.png")).is_file());
        let exrs = fs::read_dir(out.join("textures"))
            .unwrap()
            .filter_map(|e| e.ok()?.file_name().into_string().ok())
            .filter(|f| f.starts_with(m) && f.ends_with(".exr"))
            .count();
        assert_eq!(exrs, 2, "{m}: reflectance and transmittance");
    }
    assert_eq!(xml.matches("type=\"instance\"").count(), 12);
}

#[test]
fn export_small_scene_to_obj() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("one.toml");
    fs::write(
        &scene,
        "[[models]]\nname = \"rose\"\nspecies = \"dogrose\"\n\n[[instances]]\nmodel = \"rose\"\nposition = [0.0, 0.0, 0.0]\n",
    )
    .unwrap();
    let out = dir.path().join("obj");
    let (ok, stdout, err) = sylva(&[
        "export",
        scene.to_str().unwrap(),
        "-f",
        "obj",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(
        !err.contains("warning"),
        "a small scene gets no size warning: {err}"
    );
    let (ok, info, _) = sylva(&["scene", "info", scene.to_str().unwrap(), "--json"]);
    assert!(ok);
    let v: serde_json::Value = serde_json::from_str(&info).unwrap();
    let tris = v["instanced_triangles"].as_u64().unwrap();
    let text = fs::read_to_string(out.join("scene.obj")).unwrap();
    let faces = text.lines().filter(|l| l.starts_with("f ")).count() as u64;
    assert_eq!(
        faces,
        tris + 2,
        "the model's triangles and the ground's two"
    );
    let plain = stdout.replace(',', "");
    assert!(
        plain.contains(&format!("{} triangles", tris + 2)),
        "{stdout}"
    );
    let mtl = fs::read_to_string(out.join("scene.mtl")).unwrap();
    for l in mtl.lines() {
        if let Some(f) = l
            .strip_prefix("map_Kd ")
            .or_else(|| l.strip_prefix("map_d "))
        {
            assert!(out.join(f).is_file(), "{f}");
        }
    }
}

#[test]
fn export_refuses_bad_output_dir_and_unknown_format() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("not_a_dir");
    fs::write(&file, "x").unwrap();
    let (ok, _, err) = sylva(&["export", "demo", "-f", "obj", "-o", file.to_str().unwrap()]);
    assert!(!ok);
    assert!(
        err.contains("not_a_dir") && err.contains("not a directory"),
        "{err}"
    );
    let (ok, _, err) = sylva(&[
        "export",
        "demo",
        "-f",
        "gltf",
        "-o",
        dir.path().to_str().unwrap(),
    ]);
    assert!(!ok);
    assert!(
        err.contains("gltf") && err.contains("obj, mitsuba"),
        "{err}"
    );
    let (ok, _, err) = sylva(&[
        "export",
        "no_such_scene",
        "-f",
        "obj",
        "-o",
        dir.path().join("x").to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("no_such_scene"), "{err}");
    let (ok, _, err) = sylva(&[
        "export",
        "demo",
        "-f",
        "mitsuba",
        "--sun-irradiance",
        "nan",
        "-o",
        dir.path().join("y").to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("sun irradiance"), "{err}");
}
