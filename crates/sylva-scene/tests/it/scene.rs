//! Scene files: parsing, errors with lines, built-in scenes, instancing.

use std::fs;
use sylva_geom::ModelOrigin;
use sylva_scene::builtin_scenes;
use sylva_scene::{SceneDesc, SceneError, SceneStats};

fn parse(text: &str) -> Result<SceneDesc, SceneError> {
    SceneDesc::parse(text, "test.toml", None)
}

fn err(text: &str) -> String {
    parse(text).unwrap_err().to_string()
}

const MINIMAL: &str = r#"
[[models]]
name = "m"
species = "dogrose"

[[instances]]
model = "m"
position = [1.0, 0.0, 2.0]
rotation = 90.0
scale = 1.5
"#;

#[test]
fn minimal_scene_builds_with_defaults() {
    let d = parse(MINIMAL).unwrap();
    assert_eq!(d.name, "test");
    assert_eq!(d.lb.grid, 128);
    assert_eq!(d.lb.preset, "leaf");
    let s = d.build().unwrap();
    assert_eq!(s.instances.len(), 1);
    let i = s.instances[0];
    assert_eq!(i.scale, 1.5);
    // The transform rotates about +y, scales, then translates.
    let p = i.transform().transform_point3(glam::Vec3::X);
    assert!(
        (p - glam::Vec3::new(1.0, 0.0, 2.0 - 1.5)).length() < 1e-5,
        "{p}"
    );
    // The default camera frames the scene and looks at it.
    let b = s.instance_bounds();
    let c = (b.min + b.max) * 0.5;
    assert!((s.camera.look_at - c).length() < 1e-3);
    assert!(s.ground.size.unwrap()[0] > b.size().x);
}

#[test]
fn unknown_keys_name_the_key_and_line() {
    let e = err("[sun]\nelevation = 40.0\nazimuth = 10.0\ncolour = [1, 1, 1]\n");
    assert!(e.starts_with("test.toml: line 4:"), "{e}");
    assert!(e.contains("colour"), "{e}");
    let e = err(&format!("{MINIMAL}\n[camera]\nfov = 40.0\nzoom = 2.0\n"));
    assert!(e.contains("line 14") && e.contains("zoom"), "{e}");
    let e = err("tilt = 3\n");
    assert!(e.contains("line 1") && e.contains("tilt"), "{e}");
    let e = err(&MINIMAL.replace("scale = 1.5", "scale = 1.5\ncolor = 2"));
    assert!(e.contains("line 11") && e.contains("color"), "{e}");
}

#[test]
fn wrong_types_and_syntax_name_the_line() {
    let e = err("[lb]\ngrid = \"big\"\n");
    assert!(e.contains("line 2") && e.contains("invalid type"), "{e}");
    let e = err("[camera]\nresolution = [640]\n");
    assert!(e.contains("line 2"), "{e}");
    let e = err("[sky\ncolor = [1,1,1]\n");
    assert!(e.contains("line 1"), "{e}");
}

#[test]
fn bad_values_are_explained() {
    let cases = [
        ("[lb]\npreset = \"fog\"\n", "unknown lb preset 'fog'"),
        ("[lb]\ngrid = 1\n", "lb grid 1"),
        ("[sun]\nelevation = 95.0\nazimuth = 0.0\n", "elevation 95"),
        (
            "[sun]\nelevation = 45.0\n",
            "both 'elevation' and 'azimuth'",
        ),
        ("[sun]\ndirection = [0.0, 0.0, 0.0]\n", "zero vector"),
        ("[camera]\nfov = 0.0\n", "fov 0"),
        (
            "[camera]\nposition = [0.0, 1.0, 0.0]\n",
            "both 'position' and 'look_at'",
        ),
        (
            "[[models]]\nname = \"a\"\nspecies = \"oak\"\n",
            "unknown species 'oak'",
        ),
        ("[[models]]\nname = \"a\"\n", "exactly one of"),
        (
            "[[models]]\nname = \"a\"\nmesh = \"no/such/tree.obj\"\n",
            "mesh 'no/such/tree.obj': no such file",
        ),
        (
            "[[models]]\nname = \"a\"\nmesh = \"tree.fbx\"\n",
            "unknown format (readable: .obj, .gltf, .glb)",
        ),
        (
            "[[models]]\nname = \"a\"\nspecies = \"pine\"\nleaf_materials = [\"*\"]\n",
            "'leaf_materials' applies to imported meshes",
        ),
        (
            "[[instances]]\nmodel = \"nope\"\ncount = 3\n",
            "model 'nope'",
        ),
    ];
    for (text, want) in cases {
        let e = err(text);
        assert!(e.contains(want), "{text:?}: {e}");
        assert!(e.starts_with("test.toml: line "), "{e}");
    }
    let e = err(&format!(
        "{MINIMAL}\n[[instances]]\nmodel = \"m\"\ncount = 3\n"
    ));
    assert!(e.contains("line 12") && e.contains("area"), "{e}");
    let e = err(&format!(
        "{MINIMAL}\n[[instances]]\nmodel = \"m\"\nposition = [0.0, 0.0, 0.0]\ncount = 3\n"
    ));
    assert!(e.contains("'count' belongs to a generator"), "{e}");
}

#[test]
fn impossible_layout_is_an_error_with_the_line() {
    let text = format!(
        "{MINIMAL}\n[[instances]]\nmodel = \"m\"\ncount = 1000\narea = {{ min = [0.0, 0.0], max = [10.0, 10.0] }}\nmin_spacing = 2.0\n"
    );
    let e = parse(&text).unwrap().build().unwrap_err().to_string();
    assert!(
        e.contains("line 12") && e.contains("could place only"),
        "{e}"
    );
}

#[test]
fn missing_files_are_named() {
    let e = SceneDesc::load("/no/such/scene.toml")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("/no/such/scene.toml") && e.contains("built-in scenes: demo"),
        "{e}"
    );
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("s.toml");
    fs::write(
        &path,
        "[[models]]\nname = \"a\"\narbaro = \"missing.xml\"\n",
    )
    .unwrap();
    let e = SceneDesc::load(path.to_str().unwrap())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("line 1") && e.contains("missing.xml") && e.contains("cannot read"),
        "{e}"
    );
}

#[test]
fn arbaro_models_resolve_relative_to_the_scene_file() {
    let dir = tempfile::tempdir().unwrap();
    fs::write(
        dir.path().join("aspen.xml"),
        r#"<arbaro><species name='quaking aspen'>
<param name='Levels' value='3'/><param name='Scale' value='8'/>
<param name="1Branches" value="20"/><param name="2Branches" value="10"/>
<param name="Leaves" value="5"/><param name="LeafShape" value="0"/>
</species></arbaro>"#,
    )
    .unwrap();
    let path = dir.path().join("forest.toml");
    fs::write(
        &path,
        "[[models]]\nname = \"aspen\"\narbaro = \"aspen.xml\"\nseed = 4\n\n[[instances]]\nmodel = \"aspen\"\ndensity = 0.01\narea = { min = [0.0, 0.0], max = [100.0, 50.0] }\nmin_spacing = 3.0\n",
    )
    .unwrap();
    let s = sylva_scene::load(path.to_str().unwrap()).unwrap();
    assert_eq!(s.name, "forest");
    assert_eq!(
        s.model_origins[0],
        ModelOrigin::Species("quaking_aspen".into())
    );
    assert_eq!(s.instances.len(), 50);
    let m = &s.models[0];
    assert!(m.triangle_count() > 1000);
    assert!(
        m.bounds.size().y > 4.0 && m.bounds.size().y < 12.0,
        "{:?}",
        m.bounds
    );
    for (k, a) in s.instances.iter().enumerate() {
        assert!((0.0..=100.0).contains(&a.position.x) && (0.0..=50.0).contains(&a.position.z));
        for b in &s.instances[k + 1..] {
            assert!(a.position.distance(b.position) >= 3.0);
        }
    }
}

#[test]
fn beech_scene_is_table_2_with_five_unique_models() {
    let s = sylva_scene::load("beech").unwrap();
    assert_eq!(s.instances.len(), 962);
    assert_eq!(s.models.len(), 5);
    assert_eq!((s.camera.width, s.camera.height), (896, 448));
    let stats = SceneStats::of(&s);
    let count = |n: &str| {
        stats
            .models
            .iter()
            .find(|m| m.species == n)
            .unwrap()
            .instances
    };
    assert_eq!(count("red_maple"), 12);
    assert_eq!(count("ohio_buckeye"), 285);
    assert_eq!(count("paper_birch"), 291);
    assert_eq!(count("southern_catalpa"), 206);
    assert_eq!(count("american_beech"), 168);
    let ratio = stats.instanced_triangles as f64 / 273_376_528.0;
    assert!(
        (0.9..=1.1).contains(&ratio),
        "{}",
        stats.instanced_triangles
    );
    // Memory is the five models, not 962 copies: well under what one copy per tree would take.
    let per_triangle_copy = stats.instanced_triangles * 40;
    assert!(
        stats.memory_bytes * 100 < per_triangle_copy,
        "{}",
        stats.memory_bytes
    );
    let json = serde_json::to_value(&stats).unwrap();
    for key in ["instances", "unique_triangles", "instanced_triangles"] {
        assert!(json.get(key).is_some(), "{key}");
    }
}

/// Issue 28 item 5: a billion instanced triangles from six models, held as six models.
#[test]
fn woodland_scene_holds_a_billion_instanced_triangles_in_six_models() {
    let s = sylva_scene::load("woodland").unwrap();
    assert_eq!(s.instances.len(), 3900);
    assert_eq!(s.models.len(), 6);
    assert_eq!((s.camera.width, s.camera.height), (896, 448));
    let stats = SceneStats::of(&s);
    assert!(
        stats.instanced_triangles >= 1_000_000_000,
        "{}",
        stats.instanced_triangles
    );
    // The models' memory, not the instances': under 0.2 GiB for a billion triangles.
    assert!(stats.memory_bytes < 200 << 20, "{}", stats.memory_bytes);
    // Every tree stands on the 480 × 240 m plot (its placement's area).
    for i in &s.instances {
        assert!(i.position.x.abs() <= 240.0 && i.position.z.abs() <= 120.0);
    }
}

#[test]
fn every_builtin_scene_parses_and_places() {
    for name in builtin_scenes::NAMES {
        let d = SceneDesc::load(name).unwrap();
        let placed = d.place_instances().unwrap();
        // Every scene shows something: plants, or a medium (the cloud alone).
        assert!(!placed.is_empty() || !d.media.is_empty(), "{name}");
        assert!(builtin_scenes::describe(name).is_some());
    }
    let canopy = SceneDesc::load("canopy").unwrap();
    assert_eq!((canopy.camera.width, canopy.camera.height), (512, 512));
    let catalpa = sylva_scene::load("catalpa").unwrap();
    assert_eq!(catalpa.instances.len(), 1);
    assert_eq!(
        catalpa.model_origins[0],
        ModelOrigin::Species("southern_catalpa".into())
    );
}

#[test]
fn scene_build_is_deterministic_across_thread_counts() {
    let build = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| sylva_scene::load("demo").unwrap())
    };
    let (a, b) = (build(1), build(2));
    assert_eq!(a.instances, b.instances);
    for (x, y) in a.models.iter().zip(&b.models) {
        assert_eq!(x.mesh.geometry_hash(), y.mesh.geometry_hash());
    }
}

#[test]
fn single_tree_scenes_build_for_every_species_and_not_for_others() {
    let text = builtin_scenes::single_tree("Red Maple").expect("a built-in species");
    let desc = SceneDesc::parse(&text, "single tree", None).unwrap();
    let scene = desc.build().unwrap();
    assert_eq!(scene.instances.len(), 1);
    assert_eq!(scene.models[0].name, "red_maple");
    assert!(builtin_scenes::single_tree("oak_of_nowhere").is_none());
}

/// Issue 31 item 8: a scene name that is a looping link says so (not "no scene file"); a
/// model file given as a scene says what the command expects instead of a TOML error.
#[test]
fn links_and_model_files_given_as_scenes_say_what_they_are() {
    let dir = tempfile::tempdir().unwrap();
    let s = |n: &str| dir.path().join(n).to_str().unwrap().to_string();
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(s("loop2"), s("loop1")).unwrap();
        std::os::unix::fs::symlink(s("loop1"), s("loop2")).unwrap();
        let e = SceneDesc::load(&s("loop1")).unwrap_err();
        assert!(!matches!(e, SceneError::NotFound(_)), "{e}");
        let msg = e.to_string();
        assert!(
            msg.contains("loop1") && msg.contains("symbolic links"),
            "{msg}"
        );
    }
    for (name, kind) in [
        ("x.gltf", "glTF"),
        ("x.GLB", "glTF"),
        ("x.obj", "Wavefront OBJ"),
    ] {
        fs::write(s(name), r#"{"asset": {"version": "2.0"}}"#).unwrap();
        let msg = SceneDesc::load(&s(name)).unwrap_err().to_string();
        assert!(
            msg.contains(&format!("is a {kind}"))
                && msg.contains("not a scene")
                && msg.contains(&format!("mesh = \"{name}\"")),
            "{msg}"
        );
    }
}

#[test]
fn a_scene_file_can_give_a_grown_model_its_measured_leaves() {
    let model = |extra: &str| {
        format!("[[models]]\nname = \"m\"\nspecies = \"dogrose\"\n{extra}\n[[instances]]\nmodel = \"m\"\nposition = [0.0, 0.0, 0.0]\n")
    };
    let cases = [
        (
            model("leaf_reflectance = [0.6, 0.1, 0.1]\nleaf_transmittance = [0.5, 0.1, 0.1]\n"),
            "model 'm': leaf: reflectance + transmittance in red is 0.6 + 0.5 > 1",
        ),
        (
            model("leaf_reflectance = [0.1, -0.1, 0.1]\nleaf_transmittance = [0.1, 0.1, 0.1]\n"),
            "model 'm': leaf: reflectance [0.1, -0.1, 0.1] must be finite and ≥ 0",
        ),
        (
            model("leaf_reflectance = [0.1, 0.1, 0.1]\n"),
            "give both 'leaf_reflectance' and 'leaf_transmittance'",
        ),
        (
            "[[models]]\nname = \"t\"\nshape = \"teapot\"\nleaf_reflectance = [0.1, 0.1, 0.1]\nleaf_transmittance = [0.1, 0.1, 0.1]\n".to_string(),
            "apply to grown models ('species' or 'arbaro') only",
        ),
        (
            "[[models]]\nname = \"t\"\nmesh = \"tree.obj\"\nleaf_reflectance = [0.1, 0.1, 0.1]\nleaf_transmittance = [0.1, 0.1, 0.1]\n".to_string(),
            "imported meshes keep their own materials",
        ),
    ];
    for (text, want) in cases {
        let e = err(&text);
        assert!(e.contains(want), "{text:?}: {e}");
        assert!(e.starts_with("test.toml: line 1: "), "{e}");
        assert!(!e.contains('\n'), "{e}");
    }
    // A valid leaf replaces the species' own: its mean reflectance and transmittance over
    // the texture are the given ones.
    let (r, t) = ([0.08f32, 0.2, 0.05], [0.06f32, 0.25, 0.02]);
    let s = parse(&model(&format!(
        "leaf_reflectance = {r:?}\nleaf_transmittance = {t:?}\n"
    )))
    .unwrap()
    .build()
    .unwrap();
    let leaf = s.models[0].materials.iter().find(|m| m.is_leaf()).unwrap();
    let (mr, mt) = (leaf.mean_reflectance(), leaf.mean_transmittance());
    for c in 0..3 {
        assert!((mr[c] - r[c]).abs() < 1e-6 * r[c], "{mr:?}");
        assert!((mt[c] - t[c]).abs() < 1e-6 * t[c], "{mt:?}");
    }
}
