//! Rendering a tiny scene whose pixel values can be worked out by hand: a wooden board above a
//! ground plane, lit by a tilted sun. Also the comparison modes' relations, and determinism
//! over thread counts.

use std::fs;
use std::path::Path;

use glam::Vec3;
use sylva_geom::Scene;
use sylva_light::lighting::{model_lighting, Light, LightingOptions, ModelLighting};
use sylva_light::ModelGridLight;
use sylva_pipeline::{load_scene, LbPlan, PrepareOptions, PreparedScene, Silent};
use sylva_render::shade::shade_materials;
use sylva_render::{
    mean_luminance, Frame, Mode, Region, RenderError, RenderSettings, Renderer, ShadingParams,
};
use sylva_trace::{KdTracer, PinholeCamera, SceneAccel, TraceStats, TraversalConfig};

const KD: Vec3 = Vec3::new(0.5, 0.4, 0.3);
const GROUND: Vec3 = Vec3::new(0.2, 0.3, 0.4);
const SKY: Vec3 = Vec3::new(0.5, 0.6, 0.9);

fn board_scene(dir: &Path, extra_instances: &str) -> Scene {
    board_scene_of(dir, extra_instances, "wood_materials")
}

/// The board scene with the board's material listed under `materials` (`wood_materials`,
/// or `leaf_materials` for a board that transmits).
fn board_scene_of(dir: &Path, extra_instances: &str, materials: &str) -> Scene {
    sylva_testkit::write_board(dir);
    let toml = format!(
        r#"
name = "board"

[[models]]
name = "board"
mesh = "board.obj"
{materials} = ["board"]

[[instances]]
model = "board"
position = [0.0, 0.0, 0.0]
{extra_instances}

[ground]
size = [20.0, 20.0]
color = [0.2, 0.3, 0.4]

[sun]
direction = [0.3, 1.0, 0.0]

[sky]
color = [0.5, 0.6, 0.9]

[camera]
position = [0.0, 10.0, -6.0]
look_at = [0.0, 0.0, 0.0]
fov = 60.0
resolution = [64, 48]
"#
    );
    let path = dir.join("board.toml");
    fs::write(&path, toml).unwrap();
    sylva_scene::load(path.to_str().unwrap()).unwrap()
}

fn to_sun() -> Vec3 {
    Vec3::new(0.3, 1.0, 0.0).normalize()
}

fn sun_colour() -> Vec3 {
    Vec3::from_array(sylva_core::blackbody_rgb(sylva_core::SUN_TEMPERATURE_K))
}

fn settings(scene: &Scene, rpp: u32) -> RenderSettings {
    RenderSettings::full(scene.camera, rpp, 7, ShadingParams::default())
}

/// Renders `settings` of `scene` on the CPU tracer with per-model LB grids `lighting`.
fn try_render(
    scene: &Scene,
    lighting: &[Option<ModelLighting>],
    settings: &RenderSettings,
) -> Result<Frame, RenderError> {
    let tracer = KdTracer::new(
        SceneAccel::build(scene).unwrap(),
        TraversalConfig::default(),
    );
    let light = ModelGridLight::new(lighting.to_vec(), &scene.models, tracer.accel.instances());
    let materials = shade_materials(&scene.models);
    Renderer::new(
        scene,
        &tracer,
        &light,
        &materials,
        to_sun(),
        sun_colour(),
        1.0,
    )
    .render(settings, &|_| {})
}

fn render_with(
    scene: &Scene,
    lighting: &[Option<ModelLighting>],
    settings: &RenderSettings,
) -> Frame {
    try_render(scene, lighting, settings).unwrap()
}

fn render(scene: &Scene, lighting: &[Option<ModelLighting>], rpp: u32) -> Frame {
    render_with(scene, lighting, &settings(scene, rpp))
}

/// A frame of the physical light at `rpp` rays per pixel and `gather_rays` per sample (seed 7).
fn render_gathering(
    scene: &Scene,
    lighting: &[Option<ModelLighting>],
    rpp: u32,
    gather_rays: u32,
) -> Frame {
    let p = ShadingParams {
        gather_rays,
        ..ShadingParams::default()
    };
    render_with(
        scene,
        lighting,
        &RenderSettings::full(scene.camera, rpp, 7, p),
    )
}

/// The pixel whose centre ray sees world point `p`.
fn pixel_of(cam: &PinholeCamera, p: Vec3) -> (u32, u32) {
    let c = cam.project(p).unwrap();
    (c.x as u32, c.y as u32)
}

fn close(a: Vec3, b: Vec3) -> bool {
    (a - b).abs().max_element() <= 1e-5 * b.abs().max_element().max(1e-3)
}

#[test]
fn lit_and_shadowed_pixels_match_hand_computed_values() {
    for light in Light::ALL {
        hand_computed_values(light);
    }
}

fn hand_computed_values(light: Light) {
    let dir = tempfile::tempdir().unwrap();
    let scene = board_scene(dir.path(), "");
    let p = ShadingParams {
        light,
        ..ShadingParams::default()
    };
    let frame = render_with(
        &scene,
        &[None],
        &RenderSettings::full(scene.camera, 1, 7, p),
    );
    let cam = PinholeCamera::new(&scene.camera).unwrap();
    let px = |p: Vec3| {
        let (x, y) = pixel_of(&cam, p);
        (
            frame.pixels[(y * frame.width + x) as usize],
            cam.pixel_ray(x, y),
        )
    };
    let sun = sun_colour();
    let cos = to_sun().y;
    let physical = light == Light::Physical;
    // The ground's indirect light: the open sky's (physical: its radiance L_sky is an
    // irradiance π L_sky, i.e. L_sky in units of E0), or a constant ambient of the sun.
    let ground_sky = if physical {
        GROUND * SKY
    } else {
        GROUND * sun * p.sky_ambient
    };

    // Ground in the sun: ground × sun × cos θ.
    let (lit, _) = px(Vec3::new(6.0, 0.0, 4.0));
    assert!(close(lit.local, GROUND * sun * cos), "{lit:?}");
    assert!(close(lit.indirect, ground_sky));
    assert!(close(
        lit.albedo,
        if physical { GROUND } else { GROUND * sun }
    ));
    assert_eq!(lit.sky, Vec3::ZERO);

    // The board's shadow: its centre shifted by -2 · (0.3 / 1.0) along x.
    let (shadow, _) = px(Vec3::new(-0.6, 0.0, 0.0));
    // Seen from the camera the board may hide the shadow's centre; check it does not.
    let (sx, sy) = pixel_of(&cam, Vec3::new(-0.6, 0.0, 0.0));
    let hit_t = {
        let r = cam.pixel_ray(sx, sy);
        -r.origin.y / r.dir.y
    };
    let r = cam.pixel_ray(sx, sy);
    let q = r.at(hit_t);
    let over_board = {
        let t2 = (2.0 - r.origin.y) / r.dir.y;
        let b = r.at(t2);
        b.x.abs() <= 1.0 && b.z.abs() <= 1.0
    };
    assert!(!over_board && (q.x + 0.6).abs() < 0.5 && q.z.abs() < 0.5);
    assert_eq!(shadow.local, Vec3::ZERO, "{shadow:?}");
    assert!(close(shadow.indirect, ground_sky));

    // The board, seen from above: Lambert (+ Phong in the paper's light) by hand at the
    // pixel's hit point.
    let (board, ray) = px(Vec3::new(0.3, 2.0, 0.6));
    let t = (2.0 - ray.origin.y) / ray.dir.y;
    let hit = ray.at(t);
    assert!(hit.x.abs() < 1.0 && hit.z.abs() < 1.0);
    let n = Vec3::Y;
    let l = to_sun();
    let r = 2.0 * n.dot(l) * n - l;
    let v = -ray.dir;
    let (ks, s) = if physical {
        (0.0, 1.0)
    } else {
        p.wood_specular
    };
    let want = (KD * cos + Vec3::splat(ks * r.dot(v).max(0.0).powf(s))) * sun;
    assert!(close(board.local, want), "{:?} vs {want:?}", board.local);
    assert_eq!(
        board.indirect,
        Vec3::ZERO,
        "no lighting grid: no indirect light"
    );

    // A pixel above the horizon sees the sky.
    let top = frame.pixels[0];
    assert_eq!(top.sky, SKY);
    assert_eq!(top.local + top.indirect + top.albedo, Vec3::ZERO);
}

fn with_lb(scene: &Scene) -> Vec<Option<ModelLighting>> {
    let opts = LightingOptions {
        grid: 16,
        light: Light::Physical,
        preset: "leaf".into(),
        cache_dir: None,
    };
    let illum = sylva_pipeline::illumination(scene, to_sun(), 1.0);
    scene
        .models
        .iter()
        .map(|m| {
            Some(
                model_lighting(m, &illum, &opts, &sylva_lb::CpuSolver, &mut |_, _, _| {})
                    .unwrap()
                    .0,
            )
        })
        .collect()
}

#[test]
fn modes_recombine_as_in_fig_2() {
    // 000 Fig. 2: the full image (a) is the local one (b) plus the texture-modulated LB light
    // (d); (c) replaces (d) by one constant ambient of the full image's mean luminance. Each
    // mode's pixels against values worked out by hand: the board's top is open to the sky, so
    // the light gathered there is its reflectance times the sky's (see the next test); the
    // ground takes the open sky's light whether or not the board shades it from the sun.
    let dir = tempfile::tempdir().unwrap();
    let scene = board_scene(dir.path(), "");
    let frame = render(&scene, &with_lb(&scene), 1);
    let [full, local, ambient, lb] = Mode::ALL.map(|m| frame.compose(m));
    let cam = PinholeCamera::new(&scene.camera).unwrap();
    let at = |image: &[[f32; 3]], p: Vec3| {
        let (x, y) = pixel_of(&cam, p);
        Vec3::from_array(image[(y * frame.width + x) as usize])
    };
    let sun_light = sun_colour() * to_sun().y;
    let c = frame.matched_ambient();
    assert!(c > 0.0);
    // (a point, its sunlight, its LB light, its albedo: the response to a unit ambient)
    let board = |x: f32, z: f32| (Vec3::new(x, 2.0, z), KD * sun_light, KD * SKY, KD);
    let ground = |x: f32, z: f32, sunlit: bool| {
        let direct = if sunlit {
            GROUND * sun_light
        } else {
            Vec3::ZERO
        };
        (Vec3::new(x, 0.0, z), direct, GROUND * SKY, GROUND)
    };
    for (p, direct, indirect, albedo) in [
        board(0.3, 0.6),
        board(-0.5, -0.2),
        board(0.7, -0.7),
        ground(6.0, 4.0, true),
        // In the board's shadow: its centre shifted by -2 · (0.3 / 1.0) along x.
        ground(-0.6, 0.0, false),
    ] {
        for (mode, image, want) in [
            ("full", &full, direct + indirect),
            ("local", &local, direct),
            ("ambient", &ambient, direct + albedo * c),
            ("lb", &lb, indirect),
        ] {
            let got = at(image, p);
            assert!(close(got, want), "{mode} at {p}: {got} vs {want}");
        }
    }
    // The sky, seen directly, is in every image but the LB light's.
    for (image, want) in [
        (&full, SKY),
        (&local, SKY),
        (&ambient, SKY),
        (&lb, Vec3::ZERO),
    ] {
        assert_eq!(Vec3::from_array(image[0]), want);
    }
    // The local image is the one rendered without any LB grid: the LB adds light, never
    // changes the sun's.
    assert_eq!(local, render(&scene, &[None], 1).compose(Mode::Local));
    // The ambient's constant gives the full image's mean luminance, which the LB raises.
    let (mf, ma, ml) = (
        mean_luminance(&full),
        mean_luminance(&ambient),
        mean_luminance(&local),
    );
    assert!((ma - mf).abs() <= 1e-4 * mf, "ambient {ma} vs full {mf}");
    assert!(
        ml < 0.99 * mf,
        "LB light adds to the local image: {ml} vs {mf}"
    );
}

#[test]
fn the_gathered_light_on_an_open_board_is_its_reflectance_times_the_sky() {
    // The board's top faces the whole sky and nothing stands above it: every gather ray of
    // its front hemisphere escapes to the sky, so the gathered light is R ⊙ L_sky exactly,
    // whatever the number of rays. Without the gather (0 rays) the board takes the LB light
    // at its point through the sheet formula, R u / 4.
    let dir = tempfile::tempdir().unwrap();
    let scene = board_scene(dir.path(), "");
    let lighting = with_lb(&scene);
    let l = lighting[0].as_ref().unwrap();
    let cam = PinholeCamera::new(&scene.camera).unwrap();
    for rays in [0, 1, 8] {
        let frame = render_gathering(&scene, &lighting, 1, rays);
        for (x, z) in [(0.3, 0.6), (-0.5, -0.2), (0.7, -0.7)] {
            let (px, py) = pixel_of(&cam, Vec3::new(x, 2.0, z));
            let ray = cam.pixel_ray(px, py);
            let hit = ray.at((2.0 - ray.origin.y) / ray.dir.y);
            assert!(hit.x.abs() < 1.0 && hit.z.abs() < 1.0);
            let got = frame.pixels[(py * frame.width + px) as usize].indirect;
            let want = if rays == 0 {
                KD * l.sample(hit) * 0.25
            } else {
                KD * SKY
            };
            assert!(
                (got - want).abs().max_element() < 1e-5,
                "{rays} rays at {hit}: {got} vs {want}"
            );
        }
    }
}

#[test]
fn one_gather_ray_on_a_leaf_gathers_both_sides() {
    // A leaf board transmits: its gathered light is R of the sky above plus T of what lies
    // below (the ground, its shadow). With one ray per sample the pixel's samples take the
    // sides in turn, each counting twice, so the board's mean gathered light agrees with
    // eight rays per sample (which split four and four) within the rays' noise; a side left
    // without rays would lose T's whole share.
    let dir = tempfile::tempdir().unwrap();
    let mut scene = board_scene_of(dir.path(), "", "leaf_materials");
    (scene.camera.width, scene.camera.height) = (256, 192);
    let leaf = &shade_materials(&scene.models)[0][0];
    assert!(leaf.leaf && leaf.optics.transmit.iter().all(|&t| t > 0.0));
    let lighting = with_lb(&scene);
    let cam = PinholeCamera::new(&scene.camera).unwrap();
    let board: Vec<usize> = (0..scene.camera.height)
        .flat_map(|y| (0..scene.camera.width).map(move |x| (x, y)))
        .filter(|&(x, y)| {
            let ray = cam.pixel_ray(x, y);
            let hit = ray.at((2.0 - ray.origin.y) / ray.dir.y);
            hit.x.abs() < 0.9 && hit.z.abs() < 0.9
        })
        .map(|(x, y)| (y * scene.camera.width + x) as usize)
        .collect();
    assert!(board.len() > 500, "{} board pixels", board.len());
    let mean = |rays: u32| {
        let frame = render_gathering(&scene, &lighting, 8, rays);
        board
            .iter()
            .map(|&i| frame.pixels[i].indirect)
            .sum::<Vec3>()
            / board.len() as f32
    };
    let (one, eight) = (mean(1), mean(8));
    // The front sees only sky: R ⊙ L_sky. T's share below is what one ray could lose.
    let front = leaf.base * Vec3::from_array(leaf.optics.reflect) * SKY;
    assert!(
        (eight - front).min_element() > 0.05 * eight.max_element(),
        "T's share: {eight} vs front {front}"
    );
    let rel = ((one - eight).abs() / eight).max_element();
    assert!(rel < 0.03, "one ray {one} vs eight {eight}: {rel}");
}

#[test]
fn frames_do_not_depend_on_the_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    let scene = board_scene(
        dir.path(),
        r#"
[[instances]]
model = "board"
count = 4
area = { min = [-6.0, -6.0], max = [6.0, 6.0] }
min_spacing = 2.5
seed = 3
"#,
    );
    let lighting = with_lb(&scene);
    let run = |threads: usize, rpp: u32| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| render(&scene, &lighting, rpp))
    };
    for rpp in [1, 5] {
        let (a, b) = (run(1, rpp), run(2, rpp));
        assert!(a.pixels == b.pixels, "rpp {rpp}: 1 and 2 threads differ");
    }
}

#[test]
fn supersampling_averages_sub_pixel_samples() {
    let dir = tempfile::tempdir().unwrap();
    let scene = board_scene(dir.path(), "");
    // The paper light: the board's wood and the ground differ in their local light.
    let paper = ShadingParams {
        light: Light::Paper,
        ..ShadingParams::default()
    };
    let at = |rpp| RenderSettings::full(scene.camera, rpp, 7, paper);
    let one = render_with(&scene, &[None], &at(1));
    let four = render_with(&scene, &[None], &at(4));
    // Inside the lit ground every sample sees the same radiance: 4 rays average to the 1-ray
    // value; on the board's edge they mix board and ground.
    let cam = PinholeCamera::new(&scene.camera).unwrap();
    let (x, y) = pixel_of(&cam, Vec3::new(6.0, 0.0, 4.0));
    let i = (y * one.width + x) as usize;
    assert!(close(four.pixels[i].local, one.pixels[i].local));
    let edge = (0..one.width)
        .map(|x| {
            let p = cam.project(Vec3::new(1.0, 2.0, 0.0)).unwrap();
            ((p.y as u32) * one.width + x) as usize
        })
        .filter(|&i| {
            let l = four.pixels[i].local;
            let lo = one.pixels[i].local;
            l != lo
        })
        .count();
    assert!(edge > 0, "4 rays per pixel change the edge pixels");
    assert_eq!(four.timings.primary_rays, 4 * one.timings.primary_rays);
}

#[test]
fn ground_under_a_plant_gets_less_sky_light_than_open_ground() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rose.toml");
    fs::write(
        &path,
        r#"
name = "rose"

[[models]]
name = "rose"
species = "dogrose"

[[instances]]
model = "rose"
position = [0.0, 0.0, 0.0]

[ground]
size = [20.0, 20.0]
color = [0.2, 0.3, 0.4]

[camera]
position = [0.0, 4.0, -5.0]
look_at = [0.0, 0.0, 0.0]
fov = 60.0
resolution = [48, 36]
"#,
    )
    .unwrap();
    let scene = sylva_scene::load(path.to_str().unwrap()).unwrap();
    let lighting = with_lb(&scene);
    let frame = render(&scene, &lighting, 1);
    // Physical light: the open ground reflects its albedo of the sky's radiance.
    let open_sky = GROUND * Vec3::from_array(scene.sky_color);
    let ground: Vec<Vec3> = frame
        .pixels
        .iter()
        .filter(|r| close(r.albedo, GROUND))
        .map(|r| r.indirect)
        .collect();
    assert!(ground.len() > 100);
    // Away from the rose the full sky ambient; near its base, less; never more.
    assert!(ground.iter().any(|g| close(*g, open_sky)));
    assert!(
        ground.iter().any(|g| g.x < 0.9 * open_sky.x),
        "no shade under the rose"
    );
    assert!(ground.iter().all(|g| g.x <= open_sky.x * (1.0 + 1e-5)));
    // Without LB grids the ground takes the open sky everywhere.
    let plain = render(&scene, &[None], 1);
    assert!(plain
        .pixels
        .iter()
        .filter(|r| close(r.albedo, GROUND))
        .all(|r| close(r.indirect, open_sky)));
}

#[test]
fn a_region_is_the_same_pixels_as_the_full_image() {
    let dir = tempfile::tempdir().unwrap();
    let scene = board_scene(
        dir.path(),
        r#"
[[instances]]
model = "board"
position = [2.5, 0.0, 1.5]
rotation = 30.0
"#,
    );
    let lighting = with_lb(&scene);
    for rpp in [1, 4, 5] {
        let full = render(&scene, &lighting, rpp);
        // Off the 8-pixel tile grid, odd sizes, and one touching the image's corner.
        for (x0, y0, width, height) in [(5, 3, 13, 9), (0, 0, 64, 1), (33, 21, 31, 27)] {
            let region = Region {
                x0,
                y0,
                width,
                height,
            };
            let part = render_with(
                &scene,
                &lighting,
                &RenderSettings {
                    region,
                    ..settings(&scene, rpp)
                },
            );
            assert_eq!(
                (part.width, part.height, part.region),
                (width, height, region)
            );
            for y in 0..height {
                for x in 0..width {
                    let a = part.pixels[(y * width + x) as usize];
                    let b = full.pixels[((y0 + y) * full.width + x0 + x) as usize];
                    assert!(a == b, "rpp {rpp}, region {region:?}: pixel ({x}, {y})");
                }
            }
            assert_eq!(
                part.timings.primary_rays,
                (width * height * rpp) as u64,
                "{region:?}"
            );
        }
    }
    // A region outside the image is refused, naming it.
    for (x0, width) in [(60, 5), (0, 0)] {
        let region = Region {
            x0,
            y0: 0,
            width,
            height: 4,
        };
        let settings = RenderSettings {
            region,
            ..settings(&scene, 1)
        };
        let e = try_render(&scene, &lighting, &settings)
            .unwrap_err()
            .to_string();
        assert!(e.contains("64x48 image"), "{e}");
    }
}

#[test]
fn any_camera_renders_its_own_view() {
    let dir = tempfile::tempdir().unwrap();
    let scene = board_scene(dir.path(), "");
    // Not the scene's camera: low, from the side, at another size.
    let camera = sylva_geom::Camera {
        position: Vec3::new(8.0, 3.0, 1.0),
        look_at: Vec3::new(0.0, 2.0, 0.0),
        fov_deg: 40.0,
        width: 40,
        height: 30,
        rays_per_pixel: 1,
    };
    let frame = render_with(
        &scene,
        &[None],
        &RenderSettings::full(camera, 1, 7, ShadingParams::default()),
    );
    assert_eq!((frame.width, frame.height), (40, 30));
    let cam = PinholeCamera::new(&camera).unwrap();
    // The board's near edge, seen from the side at y = 2, shows wood albedo; the scene
    // camera's view would put other things there.
    let (x, y) = pixel_of(&cam, Vec3::new(0.9, 2.0, 0.0));
    let px = frame.pixels[(y * frame.width + x) as usize];
    // Physical albedo: the wood's reflectance, its colour.
    assert!(close(px.albedo, KD), "{px:?}");
    // Above the board: sky.
    assert_eq!(frame.pixels[0].sky, SKY);
}

#[test]
fn a_pixel_traced_alone_is_the_frame_s_pixel_with_the_gather() {
    // Renderer::pixel (the GPU frame's fallback) against the batched frame: same rays,
    // same gather, same light, bit for bit; and it counts the same secondary rays.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rose.toml");
    std::fs::write(
        &path,
        "name = \"rose\"\n[[models]]\nname = \"rose\"\nspecies = \"dogrose\"\n\
         [[instances]]\nmodel = \"rose\"\nposition = [0.0, 0.0, 0.0]\n\
         [ground]\nsize = [12.0, 12.0]\n\
         [camera]\nposition = [0.0, 2.0, -4.5]\nlook_at = [0.2, 0.6, 0.5]\nfov = 45.0\n\
         resolution = [32, 24]\n",
    )
    .unwrap();
    let scene = load_scene(path.to_str().unwrap(), None).unwrap();
    let opts = PrepareOptions {
        lb: Some(LbPlan {
            solver: &sylva_lb::CpuSolver,
            light: Light::Physical,
            grid: Some(24),
            cache_dir: None,
        }),
        light: Light::Physical,
        forest: None,
        ..PrepareOptions::default()
    };
    let p = PreparedScene::new(scene, &opts, &Silent).unwrap();
    let settings = p.settings(p.camera(32, 24), 3, 5);
    assert!(settings.shading.gather_rays > 0);
    let frame = p.render(&settings, &Silent).unwrap();
    let r = p.renderer();
    let camera = PinholeCamera::new(&settings.camera).unwrap();
    let mut stats = TraceStats::default();
    let mut secondary = 0;
    let mut gathered = 0;
    for y in 0..24 {
        for x in 0..32 {
            let (px, rays) = r.pixel(&camera, x, y, &settings, &mut stats);
            assert_eq!(px, frame.pixels[(y * 32 + x) as usize], "pixel ({x}, {y})");
            secondary += rays;
            gathered += (px.albedo != Vec3::ZERO && px.indirect != Vec3::ZERO) as usize;
        }
    }
    assert_eq!(secondary, frame.timings.shadow_rays);
    assert!(
        gathered > 50,
        "{gathered} plant or ground pixels with indirect light"
    );
}
