//! Scene files with media (clouds), per-model LB presets and built-in shapes.

use glam::Vec3;
use sylva_geom::{MaterialKind, ModelOrigin};
use sylva_scene::{builtin_scenes, SceneDesc, SceneError, SceneStats};

fn parse(text: &str) -> Result<SceneDesc, SceneError> {
    SceneDesc::parse(text, "test.toml", None)
}

fn err(text: &str) -> String {
    parse(text).unwrap_err().to_string()
}

const CLOUDY: &str = r#"
[[models]]
name = "rose"
species = "dogrose"
preset = "dogrose"

[[models]]
name = "maple"
species = "red_maple"

[[instances]]
model = "rose"
position = [0.0, 0.0, 0.0]

[[media]]
name = "puff"
generator = "cumulus"
grid = [48, 32, 32]
size = 940.0
seed = 5
position = [10.0, 0.0, 300.0]

[lb]
preset = "leaf"
"#;

#[test]
fn media_are_generated_and_placed() {
    let d = parse(CLOUDY).unwrap();
    assert_eq!(d.media.len(), 1);
    assert_eq!(d.media[0].preset, "cloud", "the default preset of a medium");
    let s = d.build().unwrap();
    let m = &s.media[0];
    assert_eq!((m.name.as_str(), m.dims), ("puff", [48, 32, 32]));
    // 940 m over 47 cells: 20 m cells; the box's bottom face is centred on the position.
    assert!((m.cell() - 20.0).abs() < 1e-4);
    assert!((m.bounds.min - Vec3::new(10.0 - 470.0, 0.0, 300.0 - 310.0)).length() < 1e-3);
    assert!((m.bounds.max - Vec3::new(480.0, 620.0, 610.0)).length() < 1e-3);
    assert!(m.occupancy().1 > 0);
    // Same seed, same cloud; the scene's memory counts the grid.
    let again = parse(CLOUDY).unwrap().build().unwrap();
    assert_eq!(again.media[0].density, m.density);
    assert!(s.memory_bytes() >= m.memory_bytes());
    let stats = SceneStats::of(&s);
    assert_eq!(stats.media[0].grid, [48, 32, 32]);
    assert_eq!(stats.media[0].preset, "cloud");
}

#[test]
fn models_carry_their_own_preset() {
    let s = parse(CLOUDY).unwrap().build().unwrap();
    assert_eq!(s.model_presets, ["dogrose", "leaf"]);
    assert_eq!(s.model_preset(0), "dogrose");
    assert_eq!(s.model_preset(1), "leaf");
    let stats = SceneStats::of(&s);
    assert_eq!(stats.models[0].preset, "dogrose");
    // The demo's dogroses use the dogrose preset (002 Table 1).
    let demo = sylva_scene::load("demo").unwrap();
    let rose = demo.models.iter().position(|m| m.name == "rose").unwrap();
    assert_eq!(demo.model_preset(rose), "dogrose");
    let maple = demo.models.iter().position(|m| m.name == "maple").unwrap();
    assert_eq!(demo.model_preset(maple), "leaf");
}

#[test]
fn the_teapot_is_a_shape() {
    let text = "[[models]]\nname = \"pot\"\nshape = \"teapot\"\ncolor = [0.9, 0.2, 0.1]\npreset = \"pmma\"\n\n[[instances]]\nmodel = \"pot\"\nposition = [0.0, 0.0, 0.0]\n";
    let s = parse(text).unwrap().build().unwrap();
    assert_eq!(s.model_origins[0], ModelOrigin::Shape("teapot".into()));
    let m = &s.models[0];
    assert_eq!(m.name, "pot");
    assert_eq!(m.materials[0].kind, MaterialKind::Solid);
    assert_eq!(m.materials[0].base_color, [0.9, 0.2, 0.1]);
    assert!((m.bounds.max.y - 3.15).abs() < 1e-5);
    assert_eq!(s.model_presets, ["pmma"]);
}

#[test]
fn bad_media_presets_and_shapes_are_explained() {
    let medium = |extra: &str| format!("[[media]]\nname = \"c\"\ngenerator = \"cumulus\"\n{extra}");
    let cases = [
        (medium("grid = [8, 64, 64]\n"), "grid 8×64×64"),
        (medium("size = -3.0\n"), "size -3"),
        (medium("size = nan\n"), "size NaN"),
        (medium("position = [0.0, inf, 0.0]\n"), "position"),
        (medium("preset = \"smoke\"\n"), "unknown lb preset 'smoke'"),
        (
            "[[media]]\nname = \"c\"\ngenerator = \"stratus\"\n".to_string(),
            "unknown generator 'stratus' (generators: cumulus)",
        ),
        (medium("colour = 1\n"), "colour"),
        (
            format!("{}\n{}", medium(""), medium("")),
            "medium 'c': is defined twice",
        ),
        (
            "[[models]]\nname = \"a\"\nspecies = \"pine\"\npreset = \"oak\"\n".to_string(),
            "model 'a': unknown lb preset 'oak' (presets: leaf, dogrose, cloud, pmma)",
        ),
        (
            "[[models]]\nname = \"a\"\nshape = \"cow\"\n".to_string(),
            "unknown shape 'cow' (shapes: teapot)",
        ),
        (
            "[[models]]\nname = \"a\"\nspecies = \"pine\"\ncolor = [1.0, 1.0, 1.0]\n".to_string(),
            "'color' applies to built-in shapes",
        ),
        (
            "[[models]]\nname = \"a\"\nshape = \"teapot\"\ncolor = [2.0, 1.0, 1.0]\n".to_string(),
            "color [2.0, 1.0, 1.0] must lie in [0, 1]",
        ),
        (
            "[[models]]\nname = \"a\"\nshape = \"teapot\"\nspecies = \"pine\"\n".to_string(),
            "exactly one of 'species', 'arbaro', 'mesh' or 'shape'",
        ),
    ];
    for (text, want) in cases {
        let e = err(&text);
        assert!(e.contains(want), "{text:?}: {e}");
        assert!(e.starts_with("test.toml: line "), "{e}");
    }
    // A cloud the generator cannot make (air too dry for the box) is an error at build time,
    // naming the medium and its line.
    let dry =
        "\n[[media]]\nname = \"dry\"\ngenerator = \"cumulus\"\ngrid = [32, 16, 16]\nsize = 62.0\n";
    let e = parse(dry).unwrap().build().unwrap_err().to_string();
    assert!(e.starts_with("test.toml: line 2: medium 'dry':"), "{e}");
    assert!(e.contains("condensation level at 300 m"), "{e}");
}

#[test]
fn built_in_media_scenes_load() {
    for name in ["cloud", "teapot", "demo_cloud"] {
        assert!(builtin_scenes::NAMES.contains(&name));
        assert!(builtin_scenes::describe(name).is_some());
    }
    let cloud = sylva_scene::load("cloud").unwrap();
    assert_eq!(cloud.media.len(), 1);
    assert_eq!(cloud.media[0].dims, [256, 128, 128]);
    assert_eq!(cloud.media[0].preset, "cloud");
    assert!(cloud.models.is_empty() && !cloud.ground.enabled);
    let teapot = SceneDesc::load("teapot").unwrap();
    assert_eq!(teapot.models[0].preset.as_deref(), Some("pmma"));
    let forest = SceneDesc::load("demo_cloud").unwrap();
    assert_eq!(forest.media.len(), 1);
    assert_eq!(
        forest.models.len(),
        SceneDesc::load("demo").unwrap().models.len()
    );
}
