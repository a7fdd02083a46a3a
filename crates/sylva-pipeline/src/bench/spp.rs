//! `sylva bench spp`: the steps of 003's rendering system (Fig. 9) timed on a scene, beside
//! the paper's Table 4: deep opacity maps and instance grids (steps 2-3), the sky (step 4), a
//! new sun (step 5) and a frame with the plane-parallel light (step 6).

use std::fmt;
use std::time::Instant;

use serde::Serialize;
use sylva_core::measure::median;
use sylva_geom::Scene;
use sylva_spp::trees::meshes::SceneMeshes;
use sylva_spp::trees::system::{SppLight, SppSystem, SystemConfig};

use super::BenchError;
use crate::{PrepareOptions, PreparedScene, Silent};

/// 003 Table 4 (Core2 Quad Q8200 2.33 GHz, GeForce GTX 295, 22 directions).
#[derive(Debug, Serialize, Clone, Copy)]
pub struct PaperScene {
    pub scene: &'static str,
    pub polygons: f64,
    pub cells: f64,
    pub preprocess_ms: f64,
    pub sky_ms: f64,
    pub sun_ms: f64,
    pub display_ms: f64,
}

pub const PAPER_TABLE4: [PaperScene; 4] = [
    PaperScene {
        scene: "CHERRY16",
        polygons: 1.0e6,
        cells: 13e3,
        preprocess_ms: 117.0,
        sky_ms: 25.0,
        sun_ms: 3.9,
        display_ms: 27.0,
    },
    PaperScene {
        scene: "CHERRY64",
        polygons: 4.0e6,
        cells: 52e3,
        preprocess_ms: 533.0,
        sky_ms: 100.0,
        sun_ms: 3.9,
        display_ms: 101.0,
    },
    PaperScene {
        scene: "MAPLE16",
        polygons: 3.5e6,
        cells: 10e3,
        preprocess_ms: 95.3,
        sky_ms: 20.0,
        sun_ms: 6.7,
        display_ms: 29.0,
    },
    PaperScene {
        scene: "MAPLE64",
        polygons: 14e6,
        cells: 40e3,
        preprocess_ms: 426.0,
        sky_ms: 80.0,
        sun_ms: 6.7,
        display_ms: 131.0,
    },
];

/// What [`spp`] measured.
#[derive(Debug, Clone, Serialize)]
pub struct SppBench {
    pub scene: String,
    pub instances: usize,
    pub prototypes: usize,
    pub polygons: u64,
    pub cells: usize,
    pub directions: usize,
    pub width: u32,
    pub height: u32,
    pub threads: usize,
    pub runs: u32,
    /// Steps 2-3: maps in the sample directions and the grids' depths (eq. 31), ms.
    pub preprocess_ms: f64,
    /// Step 4: the sky's light at the grid points, ms.
    pub sky_ms: f64,
    /// Step 5: maps along the new sun and G at the grid points, ms.
    pub sun_ms: f64,
    /// Step 6: one frame with the plane-parallel light (ray traced, 1 ray/pixel), ms.
    pub display_ms: f64,
    /// The frame's shading pass alone (where the SPP light is evaluated), ms.
    pub shading_ms: f64,
    /// The baseline: the same frame without indirect light on the plants, ms.
    pub baseline_display_ms: f64,
    pub baseline_shading_ms: f64,
    /// Leaf meshes grouped once for the maps (not in the paper's steps), ms.
    pub meshes_ms: f64,
    pub accel_build_ms: f64,
    pub memory_bytes: u64,
    pub paper: [PaperScene; 4],
}

/// `runs` (at least one) timed runs of each step of 003's system on `scene` under `config`,
/// and of a `width × height` frame with its light and without.
pub fn spp(
    scene: Scene,
    config: SystemConfig,
    (width, height): (u32, u32),
    runs: u32,
) -> Result<SppBench, BenchError> {
    config.validate()?;
    let runs = runs.max(1);
    let t = Instant::now();
    let prepared = PreparedScene::new(
        scene,
        &PrepareOptions {
            largest_frame: Some((width, height, 1)),
            // The SPP light is normalised like the paper's LB light and shaded as it.
            light: sylva_light::Light::Paper,
            ..PrepareOptions::default()
        },
        &Silent,
    )?;
    let accel_build_ms = 1e3 * t.elapsed().as_secs_f64();
    let scene = &prepared.scene;
    let accel = &prepared.tracer.cpu().accel;
    let t = Instant::now();
    let meshes = SceneMeshes::new(&scene.models, accel);
    let meshes_ms = 1e3 * t.elapsed().as_secs_f64();
    let (mut pre, mut sky, mut sun) = (Vec::new(), Vec::new(), Vec::new());
    let mut system = None;
    for run in 0..runs {
        let mut s = SppSystem::build(&scene.models, &scene.instances, accel, &meshes, config)
            .map_err(BenchError::SppBuild)?;
        pre.push(s.timings.sample_maps + s.timings.grid_depths);
        // A different sun each run, as when the light moves.
        let d = sylva_core::Sun::from_angles(40.0 + 5.0 * run as f64, 30.0 + 20.0 * run as f64)?
            .travel();
        s.set_light(&scene.models, accel, &meshes, d.as_vec3())?;
        sun.push(s.timings.light_maps + s.timings.light_grid);
        s.update_sky();
        sky.push(s.timings.sky);
        system = Some(s);
    }
    let mut system = system.expect("at least one run");
    let d = scene.sun.travel();
    system.set_light(&scene.models, accel, &meshes, d.as_vec3())?;
    let light = SppLight::with_preset(&system, &scene.lb.preset)?;
    let camera = prepared.camera(width, height);
    let settings = prepared.settings(camera, 1, 1);
    // The baseline, alternated with the SPP frame: the same frame with no indirect light
    // on the plants (the scene is prepared without LB grids), sun and sky only.
    prepared.render_with(&light, &settings, &Silent)?;
    prepared.render(&settings, &Silent)?;
    let (mut frame, mut shading) = (Vec::new(), Vec::new());
    let (mut base_frame, mut base_shading) = (Vec::new(), Vec::new());
    for _ in 0..runs {
        let f = prepared.render_with(&light, &settings, &Silent)?;
        frame.push(f.timings.frame_seconds());
        shading.push(f.timings.shading_seconds);
        let f = prepared.render(&settings, &Silent)?;
        base_frame.push(f.timings.frame_seconds());
        base_shading.push(f.timings.shading_seconds);
    }
    Ok(SppBench {
        scene: scene.name.clone(),
        instances: scene.instances.len(),
        prototypes: system.prototypes().len(),
        polygons: scene.instanced_triangles(),
        cells: system.cells(),
        directions: config.directions,
        width,
        height,
        threads: rayon::current_num_threads(),
        runs,
        preprocess_ms: 1e3 * median(pre),
        sky_ms: 1e3 * median(sky),
        sun_ms: 1e3 * median(sun),
        display_ms: 1e3 * median(frame),
        shading_ms: 1e3 * median(shading),
        baseline_display_ms: 1e3 * median(base_frame),
        baseline_shading_ms: 1e3 * median(base_shading),
        meshes_ms,
        accel_build_ms,
        memory_bytes: system.memory_bytes(),
        paper: PAPER_TABLE4,
    })
}

impl fmt::Display for SppBench {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let b = self;
        writeln!(
            f,
            "003 Table 4 steps on {}: {} instances ({} prototype), {} polygons, {} grid cells, {} directions, {} threads, median of {} runs",
            b.scene, b.instances, b.prototypes, b.polygons, b.cells, b.directions, b.threads, b.runs
        )?;
        writeln!(
            f,
            "                          polygons    cells  steps 2-3   step 4   step 5   step 6"
        )?;
        writeln!(
            f,
            "  sylva               {:>12} {:>8} {:>8.1} ms {:>5.1} ms {:>5.1} ms {:>5.0} ms ({}x{} ray traced; shading {:.0} ms)",
            b.polygons, b.cells, b.preprocess_ms, b.sky_ms, b.sun_ms, b.display_ms, b.width, b.height, b.shading_ms
        )?;
        writeln!(
            f,
            "  baseline: the same frame without indirect light {:.0} ms (shading {:.0} ms); SPP frame / baseline {:.2}, shading {:.2}",
            b.baseline_display_ms,
            b.baseline_shading_ms,
            b.display_ms / b.baseline_display_ms,
            b.shading_ms / b.baseline_shading_ms
        )?;
        for p in &b.paper {
            writeln!(
                f,
                "  paper {:<10}    {:>12} {:>8} {:>8.1} ms {:>5.1} ms {:>5.1} ms {:>5.0} ms",
                p.scene, p.polygons, p.cells, p.preprocess_ms, p.sky_ms, p.sun_ms, p.display_ms
            )?;
        }
        writeln!(
            f,
            "  (not in the paper's steps: leaf meshes {:.0} ms, kd-trees {:.0} ms; maps and grids hold {})",
            b.meshes_ms,
            b.accel_build_ms,
            sylva_core::format_bytes(b.memory_bytes)
        )
    }
}
