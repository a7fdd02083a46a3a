//! `sylva bench spp SCENE`: the steps of 003's rendering system (Fig. 9) timed on a scene,
//! beside the paper's Table 4: deep opacity maps and instance grids (steps 2-3), the sky
//! (step 4), a new sun (step 5) and a frame with the plane-parallel light (step 6).

use anyhow::{Context, Result};
use serde::Serialize;
use std::time::Instant;
use sylva_light::Silent;
use sylva_pipeline::{PrepareOptions, PreparedScene};
use sylva_spp::trees::meshes::SceneMeshes;
use sylva_spp::trees::system::{SppLight, SppSystem, SystemConfig};

use super::bench_scene::median;

#[derive(clap::Args)]
pub struct BenchSppArgs {
    /// Scene file, built-in scene or built-in species (one tree of it).
    #[arg(default_value = "red_maple")]
    scene: String,
    /// Repeat the scene's trees on a K × K lattice (003 Table 4: 16 and 64 instances are
    /// `--repeat 4` and `--repeat 8`).
    #[arg(long, default_value_t = 4)]
    repeat: usize,
    /// Sample directions of the deep opacity maps (003 Table 4: 22).
    #[arg(long, default_value_t = 22)]
    directions: usize,
    /// Points along each edge of an instance's grid.
    #[arg(long, default_value_t = 16)]
    grid: usize,
    /// Frame size (the scene camera's view, moved back to see the whole lattice).
    #[arg(long, default_value_t = 512)]
    width: u32,
    #[arg(long, default_value_t = 512)]
    height: u32,
    /// Timed runs of each step (after one untimed warm-up of the frame); medians reported.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=50))]
    runs: u32,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
}

/// 003 Table 4 (Core2 Quad Q8200 2.33 GHz, GeForce GTX 295, 22 directions).
#[derive(Serialize, Clone, Copy)]
struct PaperScene {
    scene: &'static str,
    polygons: f64,
    cells: f64,
    preprocess_ms: f64,
    sky_ms: f64,
    sun_ms: f64,
    display_ms: f64,
}

const PAPER_TABLE4: [PaperScene; 4] = [
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

#[derive(Serialize)]
struct SppBench {
    scene: String,
    instances: usize,
    prototypes: usize,
    polygons: u64,
    cells: usize,
    directions: usize,
    width: u32,
    height: u32,
    threads: usize,
    runs: u32,
    /// Steps 2-3: maps in the sample directions and the grids' depths (eq. 31), ms.
    preprocess_ms: f64,
    /// Step 4: the sky's light at the grid points, ms.
    sky_ms: f64,
    /// Step 5: maps along the new sun and G at the grid points, ms.
    sun_ms: f64,
    /// Step 6: one frame with the plane-parallel light (ray traced, 1 ray/pixel), ms.
    display_ms: f64,
    /// The frame's shading pass alone (where the SPP light is evaluated), ms.
    shading_ms: f64,
    /// The baseline: the same frame without indirect light on the plants, ms.
    baseline_display_ms: f64,
    baseline_shading_ms: f64,
    /// Leaf meshes grouped once for the maps (not in the paper's steps), ms.
    meshes_ms: f64,
    accel_build_ms: f64,
    memory_bytes: u64,
    paper: [PaperScene; 4],
}

pub fn run(a: BenchSppArgs) -> Result<()> {
    let base = super::spp_trees::load_scene_or_species(&a.scene)?;
    let scene = sylva_spp::trees::experiment::repeated(&base, a.repeat, None)?;
    let config = SystemConfig {
        directions: a.directions,
        grid: a.grid,
        ..SystemConfig::default()
    };
    config.validate()?;
    let t = Instant::now();
    let prepared = PreparedScene::new(
        scene,
        &PrepareOptions {
            largest_frame: Some((a.width, a.height, 1)),
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
    let travel = |elevation: f64, azimuth: f64| -> Result<[f32; 3]> {
        let s = sylva_core::Sun::from_angles(elevation, azimuth)?.travel();
        Ok([s.x as f32, s.y as f32, s.z as f32])
    };
    let (mut pre, mut sky, mut sun) = (Vec::new(), Vec::new(), Vec::new());
    let mut system = None;
    for run in 0..a.runs {
        let mut s = SppSystem::build(&scene.models, &scene.instances, accel, &meshes, config)
            .context("building the deep opacity maps and instance grids")?;
        pre.push(s.timings.sample_maps + s.timings.grid_depths);
        // A different sun each run, as when the light moves.
        let d = travel(40.0 + 5.0 * run as f64, 30.0 + 20.0 * run as f64)?;
        s.set_light(&scene.models, accel, &meshes, d.into())?;
        sun.push(s.timings.light_maps + s.timings.light_grid);
        s.update_sky();
        sky.push(s.timings.sky);
        system = Some(s);
    }
    let mut system = system.expect("at least one run");
    let d = scene.sun.travel();
    system.set_light(
        &scene.models,
        accel,
        &meshes,
        [d.x as f32, d.y as f32, d.z as f32].into(),
    )?;
    let light = SppLight::with_preset(&system, &scene.lb.preset)?;
    let camera = prepared.camera(a.width, a.height);
    let settings = prepared.settings(camera, 1, 1);
    // The baseline, alternated with the SPP frame: the same frame with no indirect light
    // on the plants (the scene is prepared without LB grids), sun and sky only.
    prepared.render_with(&light, &settings, &Silent)?;
    prepared.render(&settings, &Silent)?;
    let (mut frame, mut shading) = (Vec::new(), Vec::new());
    let (mut base_frame, mut base_shading) = (Vec::new(), Vec::new());
    for _ in 0..a.runs {
        let f = prepared.render_with(&light, &settings, &Silent)?;
        frame.push(f.timings.frame_seconds());
        shading.push(f.timings.shading_seconds);
        let f = prepared.render(&settings, &Silent)?;
        base_frame.push(f.timings.frame_seconds());
        base_shading.push(f.timings.shading_seconds);
    }
    let b = SppBench {
        scene: scene.name.clone(),
        instances: scene.instances.len(),
        prototypes: system.prototypes().len(),
        polygons: scene.instanced_triangles(),
        cells: system.cells(),
        directions: a.directions,
        width: a.width,
        height: a.height,
        threads: rayon::current_num_threads(),
        runs: a.runs,
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
    };
    if a.json {
        println!("{}", serde_json::to_string(&b)?);
        return Ok(());
    }
    println!(
        "003 Table 4 steps on {}: {} instances ({} prototype), {} polygons, {} grid cells, {} directions, {} threads, median of {} runs",
        b.scene, b.instances, b.prototypes, b.polygons, b.cells, b.directions, b.threads, b.runs
    );
    println!("                          polygons    cells  steps 2-3   step 4   step 5   step 6");
    println!(
        "  sylva               {:>12} {:>8} {:>8.1} ms {:>5.1} ms {:>5.1} ms {:>5.0} ms ({}x{} ray traced; shading {:.0} ms)",
        b.polygons, b.cells, b.preprocess_ms, b.sky_ms, b.sun_ms, b.display_ms, b.width, b.height, b.shading_ms
    );
    println!(
        "  baseline: the same frame without indirect light {:.0} ms (shading {:.0} ms); SPP frame / baseline {:.2}, shading {:.2}",
        b.baseline_display_ms,
        b.baseline_shading_ms,
        b.display_ms / b.baseline_display_ms,
        b.shading_ms / b.baseline_shading_ms
    );
    for p in &b.paper {
        println!(
            "  paper {:<10}    {:>12} {:>8} {:>8.1} ms {:>5.1} ms {:>5.1} ms {:>5.0} ms",
            p.scene, p.polygons, p.cells, p.preprocess_ms, p.sky_ms, p.sun_ms, p.display_ms
        );
    }
    println!(
        "  (not in the paper's steps: leaf meshes {:.0} ms, kd-trees {:.0} ms; maps and grids hold {})",
        b.meshes_ms,
        b.accel_build_ms,
        sylva_core::format_bytes(b.memory_bytes)
    );
    Ok(())
}
