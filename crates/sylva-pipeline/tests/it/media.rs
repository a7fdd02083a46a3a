//! Media in the render pipeline: compositing against the primary hit (a medium behind a
//! surface changes nothing there), shadows on surfaces, determinism over thread counts, the
//! media's LB cache, and per-model presets in the models' LB cache.

use std::fs;
use std::path::Path;
use std::sync::Mutex;

use glam::Vec3;
use sylva_geom::{Aabb, Medium, Model, Scene};
use sylva_lb::CpuSolver;
use sylva_light::lighting::{Light, LightingReport, LightingSource};
use sylva_light::media::MediumVolume;
use sylva_light::{Media, ModelGridLight, Progress};
use sylva_pipeline::{load_scene, LbPlan, PrepareOptions, PreparedScene};
use sylva_render::shade::shade_materials;
use sylva_render::{RenderSettings, Renderer, ShadingParams};
use sylva_trace::{KdTracer, PinholeCamera, SceneAccel, TraversalConfig};

/// A board at y = 2 over a ground plane, seen from above at an angle, sun from +x.
fn board_scene(dir: &Path) -> Scene {
    sylva_testkit::write_board(dir);
    let toml = r#"
[[models]]
name = "board"
mesh = "board.obj"
wood_materials = ["board"]

[[instances]]
model = "board"
position = [0.0, 0.0, 0.0]

[ground]
size = [20.0, 20.0]
color = [0.2, 0.3, 0.4]

[sun]
direction = [0.3, 1.0, 0.0]

[camera]
position = [0.0, 10.0, -6.0]
look_at = [0.0, 0.0, 0.0]
fov = 60.0
resolution = [64, 48]
"#;
    let path = dir.join("board.toml");
    fs::write(&path, toml).unwrap();
    sylva_scene::load(path.to_str().unwrap()).unwrap()
}

/// An absorbing slab of density 1 (σ_s = 0: the cloud preset's σ_t all absorption) spanning
/// `lo..hi`, 0.1 cells.
fn slab(lo: Vec3, hi: Vec3) -> MediumVolume {
    let h = 0.1;
    let n = ((hi - lo) / h).round();
    let dims = [n.x as usize + 1, n.y as usize + 1, n.z as usize + 1];
    let mut rho = vec![0.0f32; dims[0] * dims[1] * dims[2]];
    for x in 1..dims[0] - 1 {
        for y in 1..dims[1] - 1 {
            for z in 1..dims[2] - 1 {
                rho[(x * dims[1] + y) * dims[2] + z] = 1.0;
            }
        }
    }
    let m = Medium::new(
        "slab",
        dims,
        Aabb {
            min: lo,
            max: lo + n * h,
        },
        rho,
        "cloud",
    )
    .unwrap();
    let mut params = sylva_lb::Preset::Cloud.params();
    for c in &mut params.colours {
        c.sigma_a = 0.3;
        c.sigma_s = 0.0;
    }
    MediumVolume::new(
        &m,
        &params,
        None,
        Vec3::new(0.3, 1.0, 0.0).normalize(),
        Vec3::ONE,
        Vec3::ONE,
    )
}

fn render(scene: &Scene, media: &Media) -> sylva_render::Frame {
    let tracer = KdTracer::new(
        SceneAccel::build(scene).unwrap(),
        TraversalConfig::default(),
    );
    let light = ModelGridLight::new(vec![None], &scene.models, tracer.accel.instances());
    let materials = shade_materials(&scene.models);
    let sun = Vec3::from_array(sylva_core::blackbody_rgb(sylva_core::SUN_TEMPERATURE_K));
    Renderer::new(
        scene,
        &tracer,
        &light,
        &materials,
        Vec3::new(0.3, 1.0, 0.0),
        sun,
        1.0,
    )
    .with_media(media)
    .render(
        &RenderSettings::full(scene.camera, 1, 3, ShadingParams::default()),
        &|_| {},
    )
    .unwrap()
}

/// Whether the segment from `a` along `d` up to `t` crosses the open box `lo..hi`.
fn crosses(a: Vec3, d: Vec3, t: f32, lo: Vec3, hi: Vec3) -> bool {
    let inv = d.recip();
    let (p, q) = ((lo - a) * inv, (hi - a) * inv);
    let t0 = p.min(q).max_element().max(0.0);
    let t1 = p.max(q).min_element().min(t);
    t0 < t1
}

#[test]
fn media_composite_against_the_primary_hit_and_shade_the_sun() {
    let dir = tempfile::tempdir().unwrap();
    let scene = board_scene(dir.path());
    // Under the board, above the ground: behind the board from the camera. A second slab
    // high up casts its shadow on open ground.
    let (lo, hi) = (Vec3::new(-1.5, 0.2, -1.5), Vec3::new(1.5, 1.5, 1.5));
    let (lo2, hi2) = (Vec3::new(3.0, 6.0, 2.0), Vec3::new(5.0, 7.0, 4.0));
    let media = Media {
        volumes: vec![slab(lo, hi), slab(lo2, hi2)],
    };
    let clear = render(&scene, &Media::default());
    let cloudy = render(&scene, &media);
    let cam = PinholeCamera::new(&scene.camera).unwrap();
    let to_sun = Vec3::new(0.3, 1.0, 0.0).normalize();
    let (mut board, mut seen_through, mut shadowed) = (0, 0, 0);
    for y in 0..48u32 {
        for x in 0..64u32 {
            let ray = cam.ray(x as f32 + 0.5, y as f32 + 0.5);
            let i = (y * 64 + x) as usize;
            let (a, b) = (clear.pixels[i], cloudy.pixels[i]);
            // The first surface: the board (y = 2, |x|, |z| ≤ 1) or the ground (y = 0).
            let t_board = (2.0 - ray.origin.y) / ray.dir.y;
            let p = ray.at(t_board);
            if p.x.abs() < 0.99 && p.z.abs() < 0.99 {
                // In front of the medium: not a bit changes.
                assert_eq!(a, b, "board pixel ({x}, {y})");
                board += 1;
                continue;
            }
            if p.x.abs() < 1.01 && p.z.abs() < 1.01 {
                continue; // the board's edge
            }
            let t = -ray.origin.y / ray.dir.y;
            let g = ray.at(t);
            // Density ramps to zero over the outer cell: "through" means through the
            // dense interior (shrunk by two cells); rays that only graze the ramp are skipped.
            let boxes = [(lo, hi), (lo2, hi2)];
            let any = |f: &dyn Fn(Vec3, Vec3) -> bool| boxes.iter().any(|&(a, b)| f(a, b));
            let inner = |a: Vec3, b: Vec3| (a + 0.2, b - 0.2);
            let through = any(&|a, b| {
                let (a, b) = inner(a, b);
                crosses(ray.origin, ray.dir, t, a, b)
            });
            let in_shadow = any(&|a, b| {
                let (a, b) = inner(a, b);
                crosses(g, to_sun, 1e9, a, b)
            });
            let grazing = any(&|a, b| crosses(ray.origin, ray.dir, t, a, b)) != through
                || any(&|a, b| crosses(g, to_sun, 1e9, a, b)) != in_shadow;
            if grazing {
                continue;
            }
            let under_board = crosses(
                g,
                to_sun,
                1e9,
                Vec3::new(-1.0, 1.99, -1.0),
                Vec3::new(1.0, 2.01, 1.0),
            );
            if through {
                // Behind the medium: everything it carries is attenuated, nothing added.
                let lb = b.local + b.sky + b.indirect;
                let la = a.local + a.sky + a.indirect;
                assert!(
                    lb.max_element() < 0.98 * la.max_element(),
                    "({x}, {y}): {lb} vs {la}"
                );
                seen_through += 1;
            } else if in_shadow && !under_board {
                // Only the sun is shaded: the sky light on the ground stays.
                assert!(
                    b.local.max_element() < 0.98 * a.local.max_element(),
                    "({x}, {y})"
                );
                assert_eq!(a.indirect, b.indirect);
                shadowed += 1;
            } else if !in_shadow {
                assert_eq!(a, b, "ground pixel ({x}, {y}) away from the medium");
            }
        }
    }
    assert!(
        board > 40 && seen_through > 20 && shadowed > 10,
        "{board} {seen_through} {shadowed}"
    );
}

#[test]
fn media_render_the_same_on_any_number_of_threads() {
    let dir = tempfile::tempdir().unwrap();
    let scene = board_scene(dir.path());
    let media = Media {
        volumes: vec![slab(Vec3::new(-1.5, 0.2, -1.5), Vec3::new(1.5, 1.5, 1.5))],
    };
    let many = render(&scene, &media);
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| render(&scene, &media));
    assert_eq!(one.pixels, many.pixels);
}

/// Everything the pipeline reported, as text.
#[derive(Default)]
struct Log(Mutex<Vec<String>>);

impl Progress for Log {
    fn start(&self, what: &str, total: u64) {
        self.0.lock().unwrap().push(format!("start {what} {total}"));
    }
    fn set(&self, done: u64, total: u64) {
        assert!(done <= total, "{done} of {total}");
    }
    fn model_lit(&self, model: &Model, report: &LightingReport) {
        self.0
            .lock()
            .unwrap()
            .push(format!("lit {} {}", model.name, how(report)));
    }
    fn medium_lit(&self, medium: &Medium, reports: &[LightingReport]) {
        let hows: Vec<&str> = reports.iter().map(how).collect();
        self.0
            .lock()
            .unwrap()
            .push(format!("lit {} {}", medium.name, hows.join(" ")));
    }
}

fn how(report: &LightingReport) -> &'static str {
    match report.source {
        LightingSource::Cached => "cached",
        LightingSource::Computed => "computed",
        LightingSource::Recomputed { .. } => "recomputed",
    }
}

const CLOUD_AND_ROSES: &str = r#"
[[models]]
name = "rose"
species = "dogrose"

[[models]]
name = "rose_own"
species = "dogrose"
preset = "dogrose"

[[instances]]
model = "rose"
position = [0.0, 0.0, 0.0]

[[instances]]
model = "rose_own"
position = [1.5, 0.0, 1.0]

[[media]]
name = "puff"
generator = "cumulus"
grid = [32, 24, 24]
size = 620.0
position = [0.0, 0.0, 900.0]

[sun]
elevation = 50.0
azimuth = 200.0

[camera]
position = [0.0, 2.5, -5.0]
look_at = [0.0, 60.0, 300.0]
fov = 60.0
resolution = [40, 30]

[lb]
grid = 16
"#;

fn prepare(path: &Path, cache: &Path, sun: Option<sylva_core::Sun>, log: &Log) -> PreparedScene {
    let scene = load_scene(path.to_str().unwrap(), sun).unwrap();
    // The paper light: its plant medium is the model's preset (the physical light's comes
    // from the leaves' optics, whatever the preset).
    let opts = PrepareOptions {
        lb: Some(LbPlan {
            solver: &CpuSolver,
            grid: None,
            cache_dir: Some(cache),
            light: Light::Paper,
        }),
        light: Light::Paper,
        ..PrepareOptions::default()
    };
    PreparedScene::new(scene, &opts, log).unwrap()
}

#[test]
fn media_and_model_presets_are_cached_by_what_they_depend_on() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cloudy.toml");
    fs::write(&path, CLOUD_AND_ROSES).unwrap();
    let cache = dir.path().join("cache");
    // The light's entries (each model's voxelized density, and a forest's grid, is cached
    // beside them).
    let entries = || {
        let mut names: Vec<String> = fs::read_dir(&cache)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".sgrid") && !n.contains("-density-"))
            .collect();
        names.sort();
        names
    };
    let log = Log::default();
    let p = prepare(&path, &cache, None, &log);
    assert_eq!(
        *log.0.lock().unwrap(),
        [
            // The models' solves (jobs), then each model's report as the root stores it.
            "start LB rose 3",
            "start LB rose_own 3",
            "lit rose computed",
            "lit rose_own computed",
            "start LB puff 6",
            "lit puff computed computed",
        ]
    );
    // The same species under two presets: two entries, different light.
    assert_ne!(p.light.model(0), p.light.model(1));
    let names = entries();
    assert_eq!(names.len(), 4, "{names:?}");
    assert!(names.iter().any(|n| n.starts_with("puff-sun-")));
    assert!(names.iter().any(|n| n.starts_with("puff-sky-")));
    assert_eq!(p.media.volumes.len(), 1);
    // The cloud is in view: the frame is not just sky.
    let frame = p
        .render(&p.settings(p.camera(40, 30), 1, 1), &sylva_light::Silent)
        .unwrap();
    let sky = Vec3::from_array(p.scene.sky_color);
    assert!(frame
        .pixels
        .iter()
        .any(|r| r.sky != Vec3::ZERO && r.sky != sky));

    // Again: everything from the cache, the same volume.
    let log = Log::default();
    let q = prepare(&path, &cache, None, &log);
    assert!(log
        .0
        .lock()
        .unwrap()
        .contains(&"lit puff cached cached".to_string()));
    let again = q
        .render(&q.settings(q.camera(40, 30), 1, 1), &sylva_light::Silent)
        .unwrap();
    assert_eq!(frame.pixels, again.pixels);

    // Another sun: the sun's solve is new, the sky's is not.
    let log = Log::default();
    let sun = sylva_core::Sun::from_angles(30.0, 100.0).unwrap();
    prepare(&path, &cache, Some(sun), &log);
    assert!(log
        .0
        .lock()
        .unwrap()
        .contains(&"lit puff computed cached".to_string()));
}
