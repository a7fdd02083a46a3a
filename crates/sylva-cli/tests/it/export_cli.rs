//! `sylva export` as a user runs it.

use crate::common;
use common::sylva;
use std::fs;

#[test]
fn a_band_group_exports_its_bands_values_in_the_three_channels() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("bands.toml");
    fs::write(
        &scene,
        r#"
[[models]]
name = "rose"
species = "dogrose"

[[instances]]
model = "rose"
position = [0.0, 0.0, 0.0]

[ground]
size = [10.0, 10.0]

[bands]
names = ["red", "nir", "swir"]
leaf_reflectance = [0.07, 0.45, 0.3]
leaf_transmittance = [0.05, 0.40, 0.2]
bark = [0.16, 0.35, 0.3]
soil = [0.125, 0.25, 0.375]
sun = [1.0, 0.75, 0.5]
sky = [0.5, 0.25, 0.125]
"#,
    )
    .unwrap();
    let scene = scene.to_str().unwrap();
    let out = dir.path().join("out");
    let export = |extra: &[&str]| {
        let mut a = vec![
            "export",
            scene,
            "--format",
            "mitsuba",
            "-o",
            out.to_str().unwrap(),
        ];
        a.extend_from_slice(extra);
        sylva(&a)
    };
    let (ok, _, err) = export(&["--band-group", "0"]);
    assert!(ok, "{err}");
    assert!(
        err.contains("band group 0 (1 in all): red, nir, swir"),
        "{err}"
    );
    let xml = fs::read_to_string(out.join("scene.xml")).unwrap();
    // The sky, the ground and the sun (π times its per-band irradiance) carry the bands.
    assert!(
        xml.contains("radiance\" value=\"0.5, 0.25, 0.125\""),
        "sky:\n{xml}"
    );
    assert!(
        xml.contains("reflectance\" value=\"0.125, 0.25, 0.375\""),
        "ground:\n{xml}"
    );
    assert!(
        xml.contains("irradiance\" value=\"3.1415927, 2.3561945, 1.5707964\""),
        "sun:\n{xml}"
    );

    // Refused: a group past the bands, and a scene without bands.
    let (ok, _, err) = export(&["--band-group", "1"]);
    assert!(
        !ok && err.contains("the scene's 3 bands make 1 groups"),
        "{err}"
    );
    let (ok, _, err) = sylva(&[
        "export",
        "catalpa",
        "--format",
        "obj",
        "-o",
        out.to_str().unwrap(),
        "--band-group",
        "0",
    ]);
    assert!(!ok && err.contains("has no [bands]"), "{err}");
}

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

/// Issue 26: Ctrl-C during an export goes through sylva-core's one handler: the OBJ being
/// written is removed, and the command says it was interrupted (it used to install a second
/// SIGINT handler of its own, which replaced that one).
#[cfg(unix)]
#[test]
fn ctrl_c_during_an_export_removes_the_partial_file_and_says_so() {
    use std::process::{Command, Stdio};
    use std::time::{Duration, Instant};
    let dir = tempfile::tempdir().unwrap();
    // Enough plants that scene.obj takes seconds to write.
    let mut toml = String::from("[[models]]\nname = \"rose\"\nspecies = \"dogrose\"\n");
    for i in 0..1000 {
        let (x, z) = ((i % 32) as f32 * 3.0, (i / 32) as f32 * 3.0);
        toml += &format!("\n[[instances]]\nmodel = \"rose\"\nposition = [{x}, 0.0, {z}]\n");
    }
    let scene = dir.path().join("many.toml");
    fs::write(&scene, toml).unwrap();
    let out = dir.path().join("obj");
    let mut child = Command::new(env!("CARGO_BIN_EXE_sylva"))
        .args(["export", scene.to_str().unwrap(), "-f", "obj", "-o"])
        .arg(&out)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let temporaries = || -> Vec<String> {
        fs::read_dir(&out)
            .map(|d| {
                d.filter_map(|e| e.ok()?.file_name().into_string().ok())
                    .filter(|n| n.ends_with(".tmp"))
                    .collect()
            })
            .unwrap_or_default()
    };
    let start = Instant::now();
    while !temporaries().iter().any(|n| n.starts_with(".scene.obj.")) {
        assert!(
            child.try_wait().unwrap().is_none(),
            "the export ended first"
        );
        assert!(start.elapsed() < Duration::from_secs(120), "no scene.obj");
        std::thread::sleep(Duration::from_millis(5));
    }
    // SAFETY: signalling the child this test started.
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGINT) }, 0);
    let output = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(1), "{err}");
    assert!(err.contains("export interrupted (Ctrl-C)"), "{err}");
    assert!(!out.join("scene.obj").exists());
    assert_eq!(temporaries(), Vec::<String>::new());
}
