//! The render pipeline on a GPU against the CPU: the same scene, LB lighting and camera, rays
//! traced by the GPU tracer (shaded on the CPU, or the whole frame on the GPU), and the
//! frames compared pixel by pixel. On a software adapter (lavapipe, as in CI) the GPU's hits
//! are the CPU's bit for bit, so GPU rays with CPU shading give the CPU's frame exactly, and
//! GPU shading differs only by `pow` (WGSL's exp2/log2 form against libm's powf) in the
//! specular term. Without any adapter the tests print why and pass.

use std::path::Path;

use sylva_lb::relight::CompressTarget;
use sylva_lb::CpuSolver;
use sylva_render::{
    load_scene, tone_map_modes, BasisUse, Frame, LbPlan, Mode, PrepareOptions, PreparedScene,
    Radiance, Region, RelightPlan, Silent, SunWeights, ToneMap,
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

/// The scene prepared with the CPU's LB lighting, rays on `gpu` (or the CPU), shaded on the
/// GPU when `shade_on_gpu`.
fn prepare(dir: &Path, gpu: Option<&GpuContext>, shade_on_gpu: bool) -> PreparedScene {
    prepare_lit(dir, gpu, shade_on_gpu, None)
}

/// [`prepare`], relit from base solutions when `relight` says so.
fn prepare_lit(
    dir: &Path,
    gpu: Option<&GpuContext>,
    shade_on_gpu: bool,
    relight: Option<RelightPlan>,
) -> PreparedScene {
    let path = dir.join("roses.toml");
    std::fs::write(&path, SCENE).unwrap();
    let scene = load_scene(path.to_str().unwrap(), None).unwrap();
    let opts = PrepareOptions {
        lb: Some(LbPlan {
            solver: &CpuSolver,
            light: sylva_render::Light::Paper,
            grid: None,
            cache_dir: Some(&dir.join("cache")),
        }),
        trace_gpu: gpu,
        shade_on_gpu,
        // shade.wgsl implements the paper light; the physical light shades on the CPU.
        light: sylva_render::Light::Paper,
        relight,
        ..PrepareOptions::default()
    };
    PreparedScene::new(scene, &opts, &Silent).unwrap()
}

/// Fraction of pixels whose tone-mapped 8-bit values (full mode, each frame exposed for
/// itself) are all within one level.
fn within_one_level(a: &Frame, b: &Frame) -> f64 {
    let tm = ToneMap::default();
    let (ia, ib) = (
        tone_map_modes(a, &[Mode::Full], &tm),
        tone_map_modes(b, &[Mode::Full], &tm),
    );
    let close = ia[0]
        .ldr
        .iter()
        .zip(&ib[0].ldr)
        .filter(|(p, q)| (0..3).all(|c| p[c].abs_diff(q[c]) <= 1))
        .count();
    close as f64 / ia[0].ldr.len() as f64
}

/// Largest difference between two pixels' parts, relative to the larger value (floored at
/// 1e-3, below which nothing shows).
fn part_difference(a: &Radiance, b: &Radiance) -> f32 {
    let parts = |r: &Radiance| [r.local, r.indirect, r.albedo, r.sky];
    parts(a)
        .iter()
        .zip(parts(b))
        .flat_map(|(x, y)| {
            (0..3).map(move |c| (x[c] - y[c]).abs() / x[c].abs().max(y[c].abs()).max(1e-3))
        })
        .fold(0.0, f32::max)
}

#[test]
fn gpu_rays_give_the_cpu_image() {
    let Some(ctx) = context() else { return };
    let dir = tempfile::tempdir().unwrap();
    let cpu = prepare(dir.path(), None, false);
    let gpu = prepare(dir.path(), Some(&ctx), false);
    assert_eq!(gpu.tracer.device(), "gpu");
    assert!(gpu.gpu_frame.is_none());
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

#[test]
fn gpu_shading_matches_the_cpu_per_pixel() {
    let Some(ctx) = context() else { return };
    let dir = tempfile::tempdir().unwrap();
    let cpu = prepare(dir.path(), None, false);
    let gpu = prepare(dir.path(), Some(&ctx), true);
    let kernel = gpu.gpu_frame.as_ref().expect("frames on the GPU");
    for rpp in [1, 4, 3] {
        let cam = cpu.camera(64, 48);
        let a = cpu.render(&cpu.settings(cam, rpp, 5), &Silent).unwrap();
        let b = gpu.render(&gpu.settings(cam, rpp, 5), &Silent).unwrap();
        assert!(b.timings.fused_seconds > 0.0 && b.timings.primary_seconds == 0.0);
        assert_eq!(a.timings.primary_rays, b.timings.primary_rays);
        assert_eq!(a.timings.shadow_rays, b.timings.shadow_rays, "rpp {rpp}");
        // Every part of every pixel (at one ray per pixel: every sample) agrees; only the
        // specular pow may differ in its last bits.
        let worst = a
            .pixels
            .iter()
            .zip(&b.pixels)
            .map(|(p, q)| part_difference(p, q))
            .fold(0.0, f32::max);
        let bound = if ctx.is_software() { 1e-5 } else { 1e-3 };
        assert!(worst <= bound, "rpp {rpp}: parts differ by {worst:e}");
        let same = a
            .pixels
            .iter()
            .zip(&b.pixels)
            .filter(|(p, q)| p == q)
            .count();
        eprintln!(
            "rpp {rpp}: {same} of {} pixels bit-identical, largest part difference {worst:e}",
            a.pixels.len()
        );
        // The frame shows every kind of surface: sky, ground in and out of shade, lit and
        // shaded leaves with LB light.
        let lit_ground = b
            .pixels
            .iter()
            .filter(|p| p.local.x > 0.0 && p.indirect.x > 0.0)
            .count();
        assert!(lit_ground > 100, "{lit_ground}");
        assert!(within_one_level(&a, &b) >= 0.999);
    }
    assert_eq!(kernel.cpu_pixels(), 0);
    // A region of the GPU frame is the same pixels of the whole GPU frame.
    let cam = gpu.camera(64, 48);
    let full = gpu.render(&gpu.settings(cam, 1, 1), &Silent).unwrap();
    let mut s = gpu.settings(cam, 1, 1);
    s.region = Region {
        x0: 5,
        y0: 9,
        width: 50,
        height: 30,
    };
    let part = gpu.render(&s, &Silent).unwrap();
    for y in 0..30 {
        for x in 0..50 {
            assert_eq!(part.pixels[y * 50 + x], full.pixels[(y + 9) * 64 + x + 5]);
        }
    }
}

#[test]
fn relit_light_on_a_gpu_traces_there_and_shades_on_the_cpu() {
    let Some(ctx) = context() else { return };
    let dir = tempfile::tempdir().unwrap();
    let plan = RelightPlan {
        basis: BasisUse::Always,
        sun: SunWeights::ThreeBasis,
        ambient: 0.1,
        global: None,
        target: CompressTarget::recommended(),
        keep_raw: false,
    };
    let mut cpu = prepare_lit(dir.path(), None, false, Some(plan));
    // GPU shading asked for: the frame kernel cannot combine base solutions, so the GPU
    // traces the rays, the CPU shades, and the scene says so.
    let mut gpu = prepare_lit(dir.path(), Some(&ctx), true, Some(plan));
    assert_eq!(gpu.tracer.device(), "gpu");
    assert!(gpu.relit.is_some() && gpu.gpu_frame.is_none());
    assert!(gpu.gpu_shading_note().is_some_and(|n| n.contains("CPU")));
    assert!(cpu.gpu_shading_note().is_none());
    for sun in [
        glam::Vec3::new(0.3, 0.8, -0.2),
        glam::Vec3::new(-0.5, 0.6, 0.4),
    ] {
        cpu.set_sun(sun).unwrap();
        gpu.set_sun(sun).unwrap();
        let cam = cpu.camera(64, 48);
        let a = cpu.render(&cpu.settings(cam, 1, 1), &Silent).unwrap();
        let b = gpu.render(&gpu.settings(cam, 1, 1), &Silent).unwrap();
        assert!(a.pixels.iter().any(|p| p.indirect.max_element() > 0.0));
        if ctx.is_software() {
            assert!(a.pixels == b.pixels, "sun {sun}: frames differ");
        }
        assert!(within_one_level(&a, &b) >= 0.999);
    }
}
