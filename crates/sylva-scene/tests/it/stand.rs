//! `[stand]`: an abstract canopy's crowns (or layer) as a scene's models and instances.

use sylva_geom::ModelOrigin;
use sylva_grow::stand::{placements, unit_model, CanopySpec};
use sylva_scene::SceneDesc;

#[test]
fn a_built_in_stand_becomes_its_crown_models_and_placed_instances() {
    let d = SceneDesc::parse("[stand]\ncanopy = \"crowns\"\n", "s.toml", None).unwrap();
    let spec = CanopySpec::builtin("crowns").unwrap();
    assert_eq!(d.models.len(), 16);
    assert_eq!(d.models[3].name, "crowns-crown-3");
    let placed = placements(&spec).unwrap();
    assert_eq!(d.instances.len(), placed.len());
    let instances = d.place_instances().unwrap();
    for (a, b) in instances.iter().zip(&placed) {
        assert_eq!(
            (a.model, a.position, a.rotation_deg),
            (b.model, b.position, b.rotation_deg)
        );
    }
}

#[test]
fn a_stand_file_next_to_the_scene_builds_with_the_scenes_own_models() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("grove.toml"),
        "name = \"grove\"\n[plot]\nsize = [12.0, 12.0]\n[crowns]\nradius = 1.5\ncentre_height = 3.0\nlai = 2.0\ncover = 0.3\n[leaves]\nsize = 0.2\n",
    )
    .unwrap();
    let scene = dir.path().join("scene.toml");
    std::fs::write(
        &scene,
        "[[models]]\nname = \"rose\"\nspecies = \"dogrose\"\n[[instances]]\nmodel = \"rose\"\nposition = [8.0, 0.0, 0.0]\n[stand]\ncanopy = \"grove.toml\"\n",
    )
    .unwrap();
    let d = SceneDesc::load_file(&scene).unwrap();
    let spec = CanopySpec::load(&dir.path().join("grove.toml")).unwrap();
    // The rose, then one model per crown (fewer crowns than variants).
    let crowns = spec.crown_count() as usize;
    assert_eq!(d.models.len(), 1 + crowns);
    assert_eq!(d.instances.len(), 1 + crowns);
    let s = d.build().unwrap();
    assert_eq!(s.model_origins[1], ModelOrigin::Shape("stand grove".into()));
    // The crown models are the stand's own, leaf for leaf.
    let m = unit_model(&spec, 2);
    assert_eq!(s.models[3].mesh.positions, m.mesh.positions);
    assert!(s.models[3].materials.iter().all(|m| m.is_leaf()));
}

#[test]
fn bad_stands_name_the_scene_line_and_the_canopy() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("bad.toml"),
        "[layer]\nlai = 1.0\nheight = 1.0\n[[bands]]\nname = \"x\"\nleaf_reflectance = 0.7\nleaf_transmittance = 0.5\nsoil_albedo = 0.1\n",
    )
    .unwrap();
    let scene = dir.path().join("scene.toml");
    for (stand, needle) in [
        ("bad.toml", "must not exceed 1"),
        ("missing.toml", "no such canopy file"),
    ] {
        std::fs::write(
            &scene,
            format!("name = \"s\"\n\n[stand]\ncanopy = \"{stand}\"\n"),
        )
        .unwrap();
        let e = SceneDesc::load_file(&scene).unwrap_err().to_string();
        assert!(e.contains(needle) && e.contains("line 3"), "{e}");
        assert!(e.contains(stand), "{e}");
    }
    let e = SceneDesc::parse("[stand]\ncanopy = \"crowns\"\nseed = 2\n", "s.toml", None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("unknown field"), "{e}");
}
