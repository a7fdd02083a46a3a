//! Spectral bands (`[bands]`): bands that carry a scene's own RGB values render its RGB image
//! bit for bit, each band lands in its own layer of the EXR, and a band's leaf optics change
//! only that band.

use std::fs;

use sylva_geom::{Bands, LeafOptics, MaterialKind, Scene};
use sylva_lb::CpuSolver;
use sylva_light::{Light, Silent};
use sylva_pipeline::bands::BandImages;
use sylva_pipeline::{LbPlan, PrepareOptions, PreparedScene};
use sylva_render::{Frame, Mode, ToneMap};

const TOML: &str = r#"
name = "rose"

[[models]]
name = "rose"
species = "dogrose"

[[instances]]
model = "rose"
position = [0.0, 0.0, 0.0]

[ground]
size = [12.0, 12.0]
color = [0.2, 0.15, 0.1]

[sun]
elevation = 45.0
azimuth = 120.0

[sky]
color = [0.5, 0.6, 0.9]

[camera]
position = [0.0, 2.0, -7.0]
look_at = [0.0, 1.2, 0.0]
fov = 50.0
resolution = [48, 36]
"#;

fn rose() -> Scene {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rose.toml");
    fs::write(&path, TOML).unwrap();
    sylva_scene::load(path.to_str().unwrap()).unwrap()
}

/// The scene's own values as three bands r, g, b: its leaves' measured R and T, its bark's
/// mean colour, its ground, sun and sky.
fn own_bands(scene: &Scene) -> Bands {
    let mats = &scene.models[0].materials;
    let leaf = mats
        .iter()
        .find(|m| m.kind == MaterialKind::Leaf)
        .and_then(|m| m.optics.measured)
        .unwrap();
    let bark = mats
        .iter()
        .find(|m| m.kind == MaterialKind::Wood)
        .unwrap()
        .mean_reflectance();
    Bands {
        names: vec!["r".into(), "g".into(), "b".into()],
        leaf_reflectance: leaf.reflectance.to_vec(),
        leaf_transmittance: leaf.transmittance.to_vec(),
        bark: bark.to_vec(),
        soil: scene.ground.color.to_vec(),
        sun: scene.sun_rgb().to_vec(),
        sky: scene.sky_color.to_vec(),
        false_colour: [0, 1, 2],
    }
}

fn render(mut scene: Scene, group: Option<usize>) -> Frame {
    if let Some(g) = group {
        scene.apply_band_group(g).unwrap();
    }
    scene.set_leaf_optics(LeafOptics::Measured).unwrap();
    let p = PreparedScene::new(
        scene,
        &PrepareOptions {
            lb: Some(LbPlan {
                solver: &CpuSolver,
                grid: Some(24),
                cache_dir: None,
                light: Light::Physical,
            }),
            ..PrepareOptions::default()
        },
        &Silent,
    )
    .unwrap();
    let settings = p.settings(p.scene.camera, 1, 3);
    p.render(&settings, &Silent).unwrap()
}

#[test]
fn bands_carrying_the_rgb_values_render_the_rgb_image_into_exr_layers() {
    let scene = rose();
    // One bark colour, so that one value per band can be the bark's.
    let barks: Vec<[f32; 3]> = (scene.models[0].materials.iter())
        .filter(|m| m.kind == MaterialKind::Wood)
        .map(|m| m.mean_colour())
        .collect();
    assert!(barks.windows(2).all(|w| w[0] == w[1]), "{barks:?}");
    let rgb = render(scene.clone(), None).compose(Mode::Full);
    let mut banded = scene.clone();
    banded.bands = Some(own_bands(&scene));
    let frame = render(banded.clone(), Some(0));
    assert_eq!(
        frame.compose(Mode::Full),
        rgb,
        "the same pixels, bit for bit"
    );
    let lit = rgb.iter().filter(|p| p[1] > 0.0).count();
    assert!(lit > 1000, "{lit} lit pixels");

    let bands = banded.bands.as_ref().unwrap();
    let mut images = BandImages::new(bands, frame.width, frame.height);
    assert!(!images.complete());
    images.add_group(0, &frame);
    assert!(images.complete());
    for (c, name) in ["r", "g", "b"].into_iter().enumerate() {
        let band = images.band(name).unwrap();
        assert!(
            band.iter().zip(&rgb).all(|(v, p)| *v == p[c]),
            "band {name}"
        );
    }

    // Written: one EXR layer per band, named as the band, and a false-colour PNG.
    let dir = tempfile::tempdir().unwrap();
    let base = dir.path().join("rose.png");
    let tm = ToneMap::default();
    let written = images.write(&base, &tm).unwrap();
    let png = image::open(&written.png).unwrap().to_rgb8();
    assert_eq!(png.dimensions(), (frame.width, frame.height));
    let exr = sylva_render::output::read_exr_layers(&written.exr).unwrap();
    assert_eq!(exr.names(), ["r", "g", "b"]);
    for (c, (_, values)) in exr.layers.iter().enumerate() {
        assert_eq!(values.len(), rgb.len());
        assert!(
            values.iter().zip(&rgb).all(|(v, p)| *v == p[c]),
            "layer {c}"
        );
    }
}

#[test]
fn a_band_s_leaf_optics_change_only_that_band() {
    let scene = rose();
    let mut own = own_bands(&scene);
    let base = {
        let mut s = scene.clone();
        s.bands = Some(own.clone());
        render(s, Some(0)).compose(Mode::Full)
    };
    // The second band's leaves made brighter, as leaves are in the near-infrared.
    own.leaf_reflectance[1] = 0.45;
    own.leaf_transmittance[1] = 0.40;
    let mut s = scene.clone();
    s.bands = Some(own);
    let bright = render(s, Some(0)).compose(Mode::Full);
    let sum = |img: &[[f32; 3]], c: usize| img.iter().map(|p| p[c] as f64).sum::<f64>();
    // Brighter leaves scatter more light everywhere: no pixel of that band darker, the
    // leaves' pixels several times brighter (0.45 + 0.40 against about 0.12 + 0.15).
    assert!(
        bright
            .iter()
            .zip(&base)
            .all(|(a, b)| a[1] >= b[1] * (1.0 - 1e-5)),
        "no pixel darker"
    );
    let tripled = bright
        .iter()
        .zip(&base)
        .filter(|(a, b)| a[1] > 2.5 * b[1])
        .count();
    assert!(tripled > 80, "{tripled} pixels over 2.5× brighter");
    // The LB solves each channel on its own; only its stopping step is shared.
    for c in [0, 2] {
        let (a, b) = (sum(&bright, c), sum(&base, c));
        assert!(
            (a - b).abs() <= 1e-3 * b,
            "band {c} unchanged: {a} against {b}"
        );
    }
}
