//! `[bands]`: parsed into the scene, each band group put into the three channels, and bad
//! band lists refused in one line naming the file, the line and the key.

use sylva_geom::MaterialKind;
use sylva_scene::{SceneDesc, SceneError};

fn parse(text: &str) -> Result<SceneDesc, SceneError> {
    SceneDesc::parse(text, "test.toml", None)
}

fn with_bands(bands: &str) -> String {
    format!(
        r#"
[[models]]
name = "m"
species = "dogrose"

[[instances]]
model = "m"
position = [0.0, 0.0, 0.0]

[bands]
{bands}
"#
    )
}

const FOUR: &str = r#"names = ["blue", "green", "red", "nir"]
leaf_reflectance = [0.04, 0.12, 0.07, 0.45]
leaf_transmittance = [0.02, 0.15, 0.05, 0.40]
bark = [0.08, 0.12, 0.16, 0.35]
soil = [0.06, 0.10, 0.14, 0.25]
sky = [0.9, 0.7, 0.55, 0.25]"#;

#[test]
fn four_bands_make_two_groups_carried_in_the_channels() {
    let scene = parse(&with_bands(FOUR)).unwrap().build().unwrap();
    let bands = scene.bands.clone().unwrap();
    assert_eq!(bands.groups(), 2);
    assert_eq!(bands.group(0), [0, 1, 2]);
    assert_eq!(bands.group(1), [3, 3, 3], "the last group repeats its band");
    assert_eq!(bands.sun, [1.0; 4], "a flat sun by default");
    assert_eq!(
        bands.false_colour,
        [3, 2, 1],
        "the last three, longest first"
    );

    let mut g1 = scene.clone();
    g1.apply_band_group(1).unwrap();
    assert_eq!(g1.ground.color, [0.25; 3]);
    assert_eq!(g1.sky_color, [0.25; 3]);
    assert_eq!(g1.sun_color, Some([1.0; 3]));
    let mats = &g1.models[0].materials;
    let leaf = mats.iter().find(|m| m.kind == MaterialKind::Leaf).unwrap();
    let m = leaf.optics.measured.unwrap();
    assert_eq!((m.reflectance, m.transmittance), ([0.45; 3], [0.40; 3]));
    let bark = mats.iter().find(|m| m.kind == MaterialKind::Wood).unwrap();
    for (r, want) in bark.mean_reflectance().iter().zip([0.35; 3]) {
        assert!((r - want).abs() < 1e-6, "bark {r} against {want}");
    }
    // Leaves take the band's values once their factors are formed.
    g1.set_leaf_optics(sylva_geom::LeafOptics::Measured)
        .unwrap();
    let leaf = g1.models[0]
        .materials
        .iter()
        .find(|m| m.kind == MaterialKind::Leaf)
        .unwrap();
    for (r, want) in leaf.mean_reflectance().iter().zip([0.45; 3]) {
        assert!((r - want).abs() < 1e-5, "leaf {r} against {want}");
    }
    assert!(scene.clone().apply_band_group(2).is_err());

    // `scene info` lists them.
    let info = sylva_scene::info::SceneInfo::of(&scene);
    let text = info.to_string();
    assert!(
        text.contains(
            "bands                4 in place of RGB (false colour: R = nir, G = red, B = green)"
        ),
        "{text}"
    );
    assert!(
        text.contains("nir            0.450   0.400   0.350   0.250   1.000   0.250"),
        "{text}"
    );
}

#[test]
fn bad_band_lists_are_refused_in_one_line() {
    let cases = [
        (
            FOUR.replace("sky = [0.9, 0.7, 0.55, 0.25]", "sky = [0.9, 0.7]"),
            "sky: 2 values for 4 bands (blue, green, red, nir)",
        ),
        (
            FOUR.replace("[0.04, 0.12, 0.07, 0.45]", "[0.04, 0.12, 0.07, 0.65]"),
            "in band 'nir' is 0.65 + 0.4 > 1",
        ),
        (
            FOUR.replace("bark = [0.08,", "bark = [-0.08,"),
            "bark: -0.08 in band 'blue' must be 0 to 1",
        ),
        (
            FOUR.replace("\"nir\"]", "\"red\"]"),
            "names: 'red' is named twice",
        ),
        (
            format!("{FOUR}\nsun = [1.0, 1.0, 1.0, nan]"),
            "sun: NaN in band 'nir' must be finite and ≥ 0",
        ),
        (
            format!("{FOUR}\nfalse_colour = [\"nir\", \"red\", \"uv\"]"),
            "false_colour names 'uv', which is not in names",
        ),
        (format!("{FOUR}\ncolour = 1"), "unknown field `colour`"),
        (
            FOUR.replace(
                "names = [\"blue\", \"green\", \"red\", \"nir\"]",
                "names = []",
            ),
            "at least one band",
        ),
        (
            {
                let names: Vec<String> = (0..1025).map(|k| format!("\"b{k}\"")).collect();
                let zeros = vec!["0.0"; 1025].join(", ");
                format!(
                    "names = [{}]\nleaf_reflectance = [{zeros}]\nleaf_transmittance = [{zeros}]\n\
                     bark = [{zeros}]\nsoil = [{zeros}]\nsky = [{zeros}]",
                    names.join(", ")
                )
            },
            "names: 1025 bands, at most 1024",
        ),
    ];
    for (bands, want) in cases {
        let e = parse(&with_bands(&bands))
            .and_then(|d| d.build())
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("test.toml: line "), "{e}");
        assert!(e.contains(want), "{e} should say {want}");
        assert_eq!(e.lines().count(), 1, "{e}");
    }
}
