//! The render pipeline on a GPU against the CPU: the same scene, LB lighting and camera,
//! rays traced by the GPU tracer, and the images compared. On a software adapter (lavapipe,
//! as in CI) the GPU's hits are the CPU's bit for bit. Without any adapter the tests print
//! why and pass.

use std::path::Path;

use sylva_lb::CpuSolver;
use sylva_render::{
    load_scene, tone_map_modes, LbPlan, Mode, PrepareOptions, PreparedScene, Region, Silent,
    ToneMap,
};
use sylva_wgpu::{AdapterChoice, ContextOptions, GpuContext, GpuError};

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
position = [1.2, 0.0, 0.8]
rotation = 40.0
scale = 1.2

[[instances]]
model = "rose"
position = [-1.0, 0.0, 1.4]
rotation = 200.0
scale = 0.8

[ground]
size = [12.0, 12.0]

[camera]
position = [0.0, 2.0, -4.5]
look_at = [0.2, 0.6, 0.5]
fov = 45.0
resolution = [64, 48]

[lb]
grid = 16
"#;

fn context() -> Option<GpuContext> {
    match GpuContext::new(&ContextOptions::new(AdapterChoice::Any)) {
        Ok(ctx) => {
            eprintln!("GPU render tests on {}", ctx.describe());
            Some(ctx)
        }
        Err(e @ GpuError::NoAdapter { .. }) => {
            eprintln!("skipping GPU test: {e}");
            None
        }
        Err(e) => panic!("opening the GPU failed: {e}"),
    }
}

/// The scene prepared with the CPU's LB lighting, rays on `gpu` (or the CPU).
fn prepare(dir: &Path, gpu: Option<&GpuContext>) -> PreparedScene {
    let path = dir.join("roses.toml");
    std::fs::write(&path, SCENE).unwrap();
    let scene = load_scene(path.to_str().unwrap(), None).unwrap();
    let opts = PrepareOptions {
        lb: Some(LbPlan {
            solver: &CpuSolver,
            grid: None,
            cache_dir: Some(&dir.join("cache")),
        }),
        trace_gpu: gpu,
        ..PrepareOptions::default()
    };
    PreparedScene::new(scene, &opts, &Silent).unwrap()
}

#[test]
fn gpu_rays_give_the_cpu_image() {
    let Some(ctx) = context() else { return };
    let dir = tempfile::tempdir().unwrap();
    let cpu = prepare(dir.path(), None);
    let gpu = prepare(dir.path(), Some(&ctx));
    assert_eq!(gpu.tracer.device(), "gpu");
    for rpp in [1, 4] {
        let cam = cpu.camera(64, 48);
        let a = cpu.render(&cpu.settings(cam, rpp, 1), &Silent).unwrap();
        let b = gpu.render(&gpu.settings(cam, rpp, 1), &Silent).unwrap();
        assert_eq!(a.timings.primary_rays, b.timings.primary_rays);
        assert_eq!(a.timings.shadow_rays, b.timings.shadow_rays);
        let sky = a.pixels.iter().filter(|p| p.sky.x > 0.0).count();
        assert!(sky > 0 && sky < a.pixels.len() / 2, "{sky} sky pixels");
        if ctx.is_software() {
            assert!(a.pixels == b.pixels, "rpp {rpp}: frames differ");
        }
        let (ia, ib) = (
            tone_map_modes(&a, &[Mode::Full], &ToneMap::default()),
            tone_map_modes(&b, &[Mode::Full], &ToneMap::default()),
        );
        let close = ia[0]
            .ldr
            .iter()
            .zip(&ib[0].ldr)
            .filter(|(p, q)| (0..3).all(|c| p[c].abs_diff(q[c]) <= 1))
            .count();
        assert!(
            close * 1000 >= 999 * ia[0].ldr.len(),
            "{close} of {}",
            ia[0].ldr.len()
        );
    }
    // A region renders the same pixels as the whole frame.
    let cam = gpu.camera(64, 48);
    let full = gpu.render(&gpu.settings(cam, 1, 1), &Silent).unwrap();
    let mut s = gpu.settings(cam, 1, 1);
    s.region = Region {
        x0: 13,
        y0: 7,
        width: 29,
        height: 21,
    };
    let part = gpu.render(&s, &Silent).unwrap();
    for y in 0..21 {
        for x in 0..29 {
            assert_eq!(part.pixels[y * 29 + x], full.pixels[(y + 7) * 64 + x + 13]);
        }
    }
}
