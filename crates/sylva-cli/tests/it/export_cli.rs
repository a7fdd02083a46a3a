//! `sylva export` as a user runs it.

use crate::common;
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
