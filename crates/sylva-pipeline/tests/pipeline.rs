//! The render pipeline as a library, end to end on a small scene: what it reports through
//! `Progress`, its stages as `tracing` spans, the LB cache across two preparations, the
//! frame through `PreparedScene::render`, tone mapping and the files it writes.

use std::fs;
use std::path::Path;
use std::sync::Mutex;

use sylva_geom::Model;
use sylva_lb::CpuSolver;
use sylva_light::lighting::{LightingReport, LightingSource};
use sylva_light::{Progress, Silent};
use sylva_pipeline::{
    load_scene, resolution, tone_map_modes, write_images, LbPlan, PipelineError, PrepareOptions,
    PreparedScene,
};
use sylva_render::{stage, Mode, Region, StageClock, ToneMap};
use tracing_subscriber::layer::SubscriberExt;

const SCENE: &str = r#"
name = "roses"

[[models]]
name = "rose"
species = "dogrose"

[[instances]]
model = "rose"
position = [0.0, 0.0, 0.0]

[[instances]]
model = "rose"
position = [1.5, 0.0, 1.0]
rotation = 40.0

[ground]
size = [12.0, 12.0]

[camera]
position = [0.0, 2.5, -5.0]
look_at = [0.5, 0.6, 0.0]
fov = 45.0
resolution = [40, 30]

[lb]
grid = 16
"#;

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
    fn advance(&self, n: u64) {
        self.0.lock().unwrap().push(format!("advance {n}"));
    }
    fn finish(&self) {
        self.0.lock().unwrap().push("finish".into());
    }
    fn model_lit(&self, model: &Model, report: &LightingReport) {
        let how = match report.source {
            LightingSource::Cached => "cached",
            LightingSource::Computed => "computed",
            LightingSource::Recomputed { .. } => "recomputed",
        };
        self.0
            .lock()
            .unwrap()
            .push(format!("lit {} {how}", model.name));
    }
}

fn prepare(path: &Path, cache: &Path, progress: &dyn Progress) -> PreparedScene {
    let scene = load_scene(path.to_str().unwrap(), None).unwrap();
    let opts = PrepareOptions {
        lb: Some(LbPlan {
            solver: &CpuSolver,
            light: sylva_light::Light::Physical,
            grid: None,
            cache_dir: Some(cache),
        }),
        largest_frame: Some((40, 30, 4)),
        // The per-model pipeline (the forest grid's is tests/forest.rs').
        forest: None,
        ..PrepareOptions::default()
    };
    PreparedScene::new(scene, &opts, progress).unwrap()
}

#[test]
fn the_pipeline_reports_times_caches_renders_and_writes() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("roses.toml");
    fs::write(&path, SCENE).unwrap();
    let cache = dir.path().join("cache");
    let clock = StageClock::new();
    let subscriber = tracing_subscriber::registry().with(clock.clone());
    let _guard = tracing::subscriber::set_default(subscriber);

    // First preparation: the one model is solved and cached, reported in order.
    let log = Log::default();
    let p = prepare(&path, &cache, &log);
    assert_eq!(p.lb_models_cached, 0);
    let events = log.0.lock().unwrap().clone();
    assert_eq!(events, ["start LB rose 3", "finish", "lit rose computed"]);
    assert!(p.lighting_bytes() > 0);
    for s in [stage::SCENE_BUILD, stage::LB_PRECOMPUTE, stage::ACCEL_BUILD] {
        assert_eq!(clock.count(s), 1, "{s}");
    }
    assert_eq!(clock.count(stage::LB_MODEL), 1, "one span per unique model");
    assert!(clock.seconds(stage::LB_PRECOMPUTE) >= clock.seconds(stage::LB_MODEL));

    // Second: from the cache, the same light.
    let log = Log::default();
    let q = prepare(&path, &cache, &log);
    assert_eq!(q.lb_models_cached, 1);
    assert_eq!(log.0.lock().unwrap().last().unwrap(), "lit rose cached");
    assert_eq!(q.light.model(0), p.light.model(0));

    // A frame: progress counts every tile three times; the region is the same pixels.
    let log = Log::default();
    let camera = p.camera(40, 30);
    let settings = p.settings(camera, 4, 1);
    let frame = p.render(&settings, &log).unwrap();
    assert_eq!(clock.count(stage::FRAME), 1);
    let events = log.0.lock().unwrap().clone();
    assert_eq!(
        events.first().unwrap(),
        &format!("start render {}", 3 * 5 * 4)
    );
    let advanced: u64 = events
        .iter()
        .filter_map(|e| e.strip_prefix("advance "))
        .map(|n| n.parse::<u64>().unwrap())
        .sum();
    assert_eq!(advanced, 3 * 5 * 4);
    let region = Region {
        x0: 9,
        y0: 7,
        width: 20,
        height: 11,
    };
    let part = q
        .render(
            &sylva_render::RenderSettings { region, ..settings },
            &Silent,
        )
        .unwrap();
    for y in 0..11 {
        for x in 0..20 {
            let a = part.pixels[(y * 20 + x) as usize];
            let b = frame.pixels[((7 + y) * 40 + 9 + x) as usize];
            assert!(a == b, "({x}, {y})");
        }
    }

    // All four modes, tone mapped together and written beside each other.
    let images = tone_map_modes(&frame, &Mode::ALL, &ToneMap::default());
    assert_eq!(images.len(), 4);
    let base = dir.path().join("out/roses.png");
    let written = write_images(&base, frame.width, frame.height, &images, true).unwrap();
    for (w, m) in written.iter().zip(Mode::ALL) {
        let want = dir.path().join(format!("out/roses-{}.png", m.name()));
        assert_eq!(w.png, want);
        assert!(w.png.is_file() && w.exr.as_ref().unwrap().is_file());
        let png = image::open(&w.png).unwrap().to_rgb8();
        assert_eq!(png.dimensions(), (40, 30));
    }
    assert_eq!(clock.count(stage::TONE_MAPPING), 1);
    assert_eq!(clock.count(stage::IMAGE_OUTPUT), 1);
    // A set of modes shares the full image's exposure, so its full image is the one made
    // alone.
    let alone = tone_map_modes(&frame, &[Mode::Full], &ToneMap::default());
    assert_eq!(alone[0].ldr, images[0].ldr);
}

#[test]
fn bad_inputs_are_errors_naming_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("roses.toml");
    fs::write(&path, SCENE).unwrap();
    let scene = load_scene(path.to_str().unwrap(), None).unwrap();
    assert!(matches!(
        resolution(Some(0), None, &scene.camera),
        Err(PipelineError::Resolution { .. })
    ));
    assert_eq!(resolution(Some(80), None, &scene.camera).unwrap(), (80, 60));
    let opts = PrepareOptions {
        indirect: f32::NAN,
        ..PrepareOptions::default()
    };
    let e = PreparedScene::new(scene.clone(), &opts, &Silent)
        .err()
        .unwrap();
    assert!(e.to_string().contains("indirect"), "{e}");
    let opts = PrepareOptions {
        largest_frame: Some((16384, 16384, 1024)),
        ..PrepareOptions::default()
    };
    let e = PreparedScene::new(scene, &opts, &Silent).err().unwrap();
    assert!(e.to_string().contains("16384x16384 frame"), "{e}");
    // Issue 19, item 6: the images made from a frame count too. A frame that fits alone
    // must not pass when its four mode images would not.
    let frame = sylva_render::render::memory_needed(8192, 8192, 1);
    let images = sylva_render::render::output_memory_needed(8192, 8192, 4);
    assert!(images > frame / 2, "frame {frame} B, images {images} B");
    // Issue 19, item 12: a sun below the horizon is refused, not rendered lit from below.
    let below = sylva_core::Sun::from_angles(-30.0, 0.0).unwrap();
    let e = load_scene("demo", Some(below)).err().unwrap();
    assert!(e.to_string().contains("30.0° below the horizon"), "{e}");
    let e = load_scene("no-such-scene.toml", None).err().unwrap();
    assert!(e.to_string().contains("no-such-scene"), "{e}");
}
