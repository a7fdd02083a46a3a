//! The render pipeline on a GPU against the CPU: the same scene, LB lighting and camera, rays
//! traced by the GPU tracer (shaded on the CPU, or the whole frame on the GPU), and the
//! frames compared pixel by pixel. On a software adapter (lavapipe, as in CI) the GPU's hits
//! are the CPU's bit for bit, so GPU rays with CPU shading give the CPU's frame exactly, and
//! GPU shading differs only by `pow` (WGSL's exp2/log2 form against libm's powf) in the
//! specular term. Without any adapter the tests say SKIPPED (fail under `SYLVA_REQUIRE_GPU=1`).

use std::path::Path;

use sylva_lb::relight::{Codec, CompressTarget, Precision};
use sylva_lb::CpuSolver;
use sylva_light::device::DeviceKind;
use sylva_light::relight::PhysicalTarget;
use sylva_light::{Light, Silent, SunWeights};
use sylva_pipeline::{
    load_scene, tone_map_modes, BasisUse, LbPlan, PrepareOptions, PreparedScene, RelightPlan,
    DEFAULT_BAKE_BUDGET,
};
use sylva_render::{Frame, Mode, Radiance, Region, ToneMap};
use sylva_wgpu::{AdapterChoice, ContextOptions, GpuContext};

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
    sylva_testkit::gpu_context(&ContextOptions::new(AdapterChoice::Any))
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
    prepare_with(dir, gpu, shade_on_gpu, relight, Light::Paper)
}

/// [`prepare_lit`] under `light`.
fn prepare_with(
    dir: &Path,
    gpu: Option<&GpuContext>,
    shade_on_gpu: bool,
    relight: Option<RelightPlan>,
    light: Light,
) -> PreparedScene {
    let path = dir.join("roses.toml");
    std::fs::write(&path, SCENE).unwrap();
    let scene = load_scene(path.to_str().unwrap(), None).unwrap();
    let opts = PrepareOptions {
        lb: Some(LbPlan {
            solver: &CpuSolver,
            light,
            grid: None,
            cache_dir: Some(&dir.join("cache")),
        }),
        trace_gpu: gpu,
        shade_on_gpu,
        light,
        relight,
        // The per-model grids shade.wgsl mirrors; the forest grid's weighed parts shade on
        // the CPU (tested below).
        forest: None,
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

/// Largest difference between two pixels' parts, relative to the larger value floored at
/// `floor`.
fn part_difference(a: &Radiance, b: &Radiance, floor: f32) -> f32 {
    let parts = |r: &Radiance| [r.local, r.indirect, r.albedo, r.sky];
    parts(a)
        .iter()
        .zip(parts(b))
        .flat_map(|(x, y)| {
            (0..3).map(move |c| (x[c] - y[c]).abs() / x[c].abs().max(y[c].abs()).max(floor))
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
    for light in [Light::Paper, Light::Physical] {
        let cpu = prepare_with(dir.path(), None, false, None, light);
        let gpu = prepare_with(dir.path(), Some(&ctx), true, None, light);
        // The kernel reads the per-sun grids through their device side.
        assert_eq!(gpu.indirect().device().unwrap().kind(), DeviceKind::Grids);
        frames_agree(&ctx, &cpu, &gpu, (1e-5, 1e-3), &format!("{light:?}"));
    }
    // The physical light's forest grid: each instance's weighed parts, on the GPU as on the
    // CPU.
    let forest = |gpu: Option<&GpuContext>| {
        let path = dir.path().join("roses.toml");
        let scene = load_scene(path.to_str().unwrap(), None).unwrap();
        PreparedScene::new(
            scene,
            &PrepareOptions {
                lb: Some(LbPlan {
                    solver: &CpuSolver,
                    light: Light::Physical,
                    grid: None,
                    cache_dir: Some(&dir.path().join("cache")),
                }),
                trace_gpu: gpu,
                shade_on_gpu: gpu.is_some(),
                light: Light::Physical,
                ..PrepareOptions::default()
            },
            &Silent,
        )
        .unwrap()
    };
    let (cpu, gpu) = (forest(None), forest(Some(&ctx)));
    assert!(gpu.forest.is_some() && gpu.gpu_frame.is_some());
    frames_agree(&ctx, &cpu, &gpu, (1e-5, 1e-3), "physical, forest grid");
}

/// The GPU frame kernel of `gpu` against `cpu`'s frames, per pixel and part, at 1, 4 and 3
/// rays per pixel, and for a region. On lavapipe every part of every pixel agrees within
/// `tolerance`, relative to the larger value floored at `floor`.
fn frames_agree(
    ctx: &GpuContext,
    cpu: &PreparedScene,
    gpu: &PreparedScene,
    (tolerance, floor): (f32, f32),
    what: &str,
) {
    let kernel = gpu.gpu_frame.as_ref().expect("frames on the GPU");
    // Last, where the scene gathers: one gather ray per sample, which on a leaf takes one
    // side per sample (gather::split).
    let one_ray = (cpu.shading.gather_rays > 0).then_some(1);
    for (rpp, gather_rays) in [(1, None), (4, None), (3, None), (2, one_ray)] {
        let cam = cpu.camera(64, 48);
        let settings = |p: &PreparedScene| {
            let mut s = p.settings(cam, rpp, 5);
            if let Some(k) = gather_rays {
                s.shading.gather_rays = k;
            }
            s
        };
        let a = cpu.render(&settings(cpu), &Silent).unwrap();
        let b = gpu.render(&settings(gpu), &Silent).unwrap();
        assert!(b.timings.fused_seconds > 0.0 && b.timings.primary_seconds == 0.0);
        assert_eq!(a.timings.primary_rays, b.timings.primary_rays);
        // The kernel makes its camera rays with the CPU's arithmetic: on lavapipe the same
        // rays, so the same shadow rays; a hardware GPU's contracted multiply-adds may move
        // a ray across an edge, changing whether its sample needs a shadow ray.
        let (sa, sb) = (a.timings.shadow_rays, b.timings.shadow_rays);
        if ctx.is_software() {
            assert_eq!(sa, sb, "{what} rpp {rpp}");
        } else {
            assert!(
                sa.abs_diff(sb) * 200 <= sa,
                "{what} rpp {rpp}: {sa} vs {sb} shadow rays"
            );
        }
        // Every part of every pixel (at one ray per pixel: every sample) agrees; only the
        // specular pow may differ in its last bits.
        let worst = a
            .pixels
            .iter()
            .zip(&b.pixels)
            .map(|(p, q)| part_difference(p, q, floor))
            .fold(0.0, f32::max);
        let at = a
            .pixels
            .iter()
            .zip(&b.pixels)
            .position(|(p, q)| part_difference(p, q, floor) == worst)
            .unwrap_or(0);
        let detail = format!(
            "{what} rpp {rpp}: parts differ by {worst:e} at pixel {at}: CPU {:?}, GPU {:?}",
            a.pixels[at], b.pixels[at]
        );
        if ctx.is_software() {
            assert!(worst <= tolerance, "{detail}");
        } else {
            // A hardware GPU contracts multiply-adds: a hit's barycentrics move by up to
            // ~1e-4 on far, small leaves (the tracer's tests), which moves its texture
            // lookup. 99 % of pixels stay within 1e-3 in every part; the image test below
            // bounds the rest.
            let close = a
                .pixels
                .iter()
                .zip(&b.pixels)
                .filter(|(p, q)| part_difference(p, q, floor) <= tolerance.max(1e-3))
                .count();
            assert!(
                close * 100 >= 99 * a.pixels.len(),
                "{close} close; {detail}"
            );
        }
        eprintln!("{detail}");
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
fn relit_light_is_shaded_on_the_gpu_as_on_the_cpu() {
    let Some(ctx) = context() else { return };
    let dir = tempfile::tempdir().unwrap();
    let plan = RelightPlan {
        basis: BasisUse::Always,
        sun: SunWeights::ThreeBasis,
        ambient: 0.1,
        global: None,
        target: CompressTarget::recommended(),
        physical: None,
        keep_raw: true,
    };
    let mut cpu = prepare_lit(dir.path(), None, false, Some(plan));
    let mut gpu = prepare_lit(dir.path(), Some(&ctx), true, Some(plan));
    assert_eq!(gpu.tracer.device(), "gpu");
    assert!(gpu.relit.is_some() && gpu.gpu_frame.is_some());
    assert!(gpu.gpu_shading_note().is_none());
    assert_eq!(gpu.indirect().device().unwrap().kind(), DeviceKind::Relit);
    let tight = (1e-5, 1e-3);
    for sun in [
        glam::Vec3::new(0.3, 0.8, -0.2),
        glam::Vec3::new(-0.5, 0.6, 0.4),
    ] {
        // The sun moves: the kernel gets each instance's new combination, no LB solve.
        cpu.set_sun(sun).unwrap();
        gpu.set_sun(sun).unwrap();
        // Uncompressed bases: the kernel's lookup is BasisSet::sample's arithmetic.
        cpu.use_uncompressed(true).unwrap();
        gpu.use_uncompressed(true).unwrap();
        let cam = cpu.camera(64, 48);
        let a = cpu.render(&cpu.settings(cam, 1, 1), &Silent).unwrap();
        assert!(a.pixels.iter().any(|p| p.indirect.max_element() > 0.0));
        frames_agree(
            &ctx,
            &cpu,
            &gpu,
            tight,
            &format!("relit, uncompressed, sun {sun}"),
        );
        // Compressed bases: the kernel reads the Haar blocks as HaarFields::sample_into
        // does (one block's coefficients against the footprint's kernel).
        cpu.use_uncompressed(false).unwrap();
        gpu.use_uncompressed(false).unwrap();
        frames_agree(
            &ctx,
            &cpu,
            &gpu,
            tight,
            &format!("relit, compressed, sun {sun}"),
        );
    }
    // The ambient changes the kernel's free-space luminance (the ground's shade) too.
    cpu.set_illumination(SunWeights::Exact, 0.3).unwrap();
    gpu.set_illumination(SunWeights::Exact, 0.3).unwrap();
    frames_agree(&ctx, &cpu, &gpu, tight, "relit, exact weights, ambient 0.3");
}

/// The scene under the physical light relit from its base solutions (uncompressed), with the
/// final gather.
fn prepare_physical_relit(dir: &Path, gpu: Option<&GpuContext>, forest: bool) -> PreparedScene {
    prepare_physical_relit_as(dir, gpu, forest, None)
}

/// [`prepare_physical_relit`] with the bases compressed to `target` (`None`: as solved).
fn prepare_physical_relit_as(
    dir: &Path,
    gpu: Option<&GpuContext>,
    forest: bool,
    target: Option<PhysicalTarget>,
) -> PreparedScene {
    let path = dir.join("roses.toml");
    std::fs::write(&path, SCENE).unwrap();
    let scene = load_scene(path.to_str().unwrap(), None).unwrap();
    let opts = PrepareOptions {
        lb: Some(LbPlan {
            solver: &CpuSolver,
            light: Light::Physical,
            grid: None,
            cache_dir: Some(&dir.join("cache")),
        }),
        trace_gpu: gpu,
        shade_on_gpu: true,
        light: Light::Physical,
        gather_rays: 2,
        relight: Some(RelightPlan {
            basis: BasisUse::Always,
            sun: SunWeights::ThreeBasis,
            ambient: 0.0,
            physical: target,
            ..RelightPlan::default()
        }),
        forest: forest.then_some(sylva_light::relight::GlobalGridOptions { sites: 24 }),
        ..PrepareOptions::default()
    };
    PreparedScene::new(scene, &opts, &Silent).unwrap()
}

#[test]
fn the_physical_light_relit_is_shaded_on_the_gpu_as_on_the_cpu() {
    let Some(ctx) = context() else { return };
    let dir = tempfile::tempdir().unwrap();
    // With the forest grid: its relit weights are in each instance's terms.
    let mut cpu = prepare_physical_relit(dir.path(), None, true);
    let mut gpu = prepare_physical_relit(dir.path(), Some(&ctx), true);
    assert!(gpu.physical.is_some() && gpu.gpu_frame.is_some());
    assert!(gpu.gpu_shading_note().is_none());
    assert_eq!(gpu.indirect().device().unwrap().kind(), DeviceKind::Relit);
    for sun in [
        glam::Vec3::new(0.3, 0.8, -0.2),
        glam::Vec3::new(-0.5, 0.6, 0.4),
    ] {
        // The sun moves: the kernel gets each instance's new terms, no LB solve; the final
        // gather's rays read the relit light where they land.
        cpu.set_sun(sun).unwrap();
        gpu.set_sun(sun).unwrap();
        frames_agree(
            &ctx,
            &cpu,
            &gpu,
            (1e-4, 1e-3),
            &format!("physical relit, sun {sun}"),
        );
    }
}

#[test]
fn the_physical_light_relit_from_compressed_bases_is_shaded_on_the_gpu_as_on_the_cpu() {
    // The default codec: the kernel reads each instance's light decoded for the sun, the
    // grids the CPU's lookups read once decoded (a compressed lookup between sites differs
    // from them within the codec's error, far above the tolerance here).
    let Some(ctx) = context() else { return };
    let dir = tempfile::tempdir().unwrap();
    let target = Some(PhysicalTarget::recommended());
    // With the forest grid: an instance's plants and its ground read different grids.
    let mut cpu = prepare_physical_relit_as(dir.path(), None, true, target);
    let mut gpu = prepare_physical_relit_as(dir.path(), Some(&ctx), true, target);
    assert!(gpu.physical.is_some() && gpu.gpu_frame.is_some());
    assert!(
        gpu.gpu_shading_note().is_none(),
        "{:?}",
        gpu.gpu_shading_note()
    );
    let physical = gpu.physical.as_ref().unwrap();
    assert!(physical.decodes_for_device() && physical.has_forest());
    let mut frames = Vec::new();
    for sun in [
        glam::Vec3::new(0.3, 0.8, -0.2),
        glam::Vec3::new(-0.5, 0.6, 0.4),
    ] {
        // The sun moves: the GPU's grids are decoded for it and packed over the last sun's.
        cpu.set_sun(sun).unwrap();
        gpu.set_sun(sun).unwrap();
        let on_gpu = gpu.bake_summary().expect("decoded for the GPU");
        assert_eq!(on_gpu.instances, on_gpu.of);
        assert!(on_gpu.grids > gpu.scene.instances.len(), "{on_gpu:?}");
        // The CPU decodes for frames that read the light often; these small ones may not, so
        // it decodes as a large frame would (the same grids).
        let on_cpu = cpu
            .physical
            .as_ref()
            .unwrap()
            .bake_for_device(DEFAULT_BAKE_BUDGET)
            .unwrap();
        assert_eq!(
            (on_cpu.instances, on_cpu.grids, on_cpu.bytes),
            (on_gpu.instances, on_gpu.grids, on_gpu.bytes)
        );
        frames_agree(
            &ctx,
            &cpu,
            &gpu,
            (1e-4, 1e-3),
            &format!("physical relit, compressed, sun {sun}"),
        );
        let cam = gpu.camera(64, 48);
        frames.push(gpu.render(&gpu.settings(cam, 1, 1), &Silent).unwrap());
    }
    // The suns light the frame differently: the second frame read its own grids.
    let moved = frames[0]
        .pixels
        .iter()
        .zip(&frames[1].pixels)
        .filter(|(a, b)| part_difference(a, b, 1e-3) > 1e-2)
        .count();
    assert!(moved * 4 > frames[0].pixels.len(), "{moved} pixels changed");
    // A bake budget below the sun's grids: shaded on the CPU, saying why; the next sun that
    // fits goes back to the GPU.
    gpu.set_bake_budget(1);
    gpu.set_sun(glam::Vec3::new(0.2, 0.9, 0.1)).unwrap();
    assert!(gpu.gpu_frame.is_none());
    let why = gpu.gpu_shading_note().expect("a reason");
    assert!(why.contains("bake budget"), "{why}");
    let cam = gpu.camera(64, 48);
    let frame = gpu.render(&gpu.settings(cam, 1, 1), &Silent).unwrap();
    assert_eq!(frame.timings.fused_seconds, 0.0);
    gpu.set_bake_budget(DEFAULT_BAKE_BUDGET);
    gpu.set_sun(glam::Vec3::new(-0.5, 0.6, 0.4)).unwrap();
    assert!(gpu.gpu_frame.is_some() && gpu.gpu_shading_note().is_none());
    let again = gpu.render(&gpu.settings(cam, 1, 1), &Silent).unwrap();
    assert!(
        again.pixels == frames[1].pixels,
        "the same sun, the same frame"
    );
}

#[test]
fn every_stored_form_of_the_bases_is_read_on_the_gpu_as_on_the_cpu() {
    // The recommended codec stores packed Haar coefficients (the test above); the others
    // store split Haar coefficients (f16 or f32 values) or dense per-site fields (PCA).
    let Some(ctx) = context() else { return };
    let dir = tempfile::tempdir().unwrap();
    let targets = [
        CompressTarget::new(Codec::Haar { threshold: 0.004 }),
        CompressTarget {
            precision: Precision::F32,
            ..CompressTarget::new(Codec::ColourHaar { threshold: 0.002 })
        },
        CompressTarget::new(Codec::Pca { rank: 12 }),
    ];
    for target in targets {
        let plan = RelightPlan {
            basis: BasisUse::Always,
            sun: SunWeights::ThreeBasis,
            ambient: 0.2,
            global: None,
            target,
            physical: None,
            keep_raw: false,
        };
        let mut cpu = prepare_lit(dir.path(), None, false, Some(plan));
        let mut gpu = prepare_lit(dir.path(), Some(&ctx), true, Some(plan));
        let sun = glam::Vec3::new(0.4, 0.7, 0.3);
        cpu.set_sun(sun).unwrap();
        gpu.set_sun(sun).unwrap();
        frames_agree(&ctx, &cpu, &gpu, (1e-5, 1e-3), &format!("{target:?}"));
    }
}

#[test]
fn media_say_why_they_are_shaded_on_the_cpu() {
    // The media have no device side (the volume tracer is the CPU's): the pipeline's note is
    // their answer, and the GPU still traces the rays, giving the CPU's frame.
    let Some(ctx) = context() else { return };
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cloudy.toml");
    let cloud = "\n[[media]]\nname = \"puff\"\ngenerator = \"cumulus\"\ngrid = [16, 16, 16]\n\
                 size = 940.0\nposition = [10.0, 0.0, 300.0]\n";
    let text = SCENE.replace("[ground]", &format!("{cloud}\n[ground]"));
    std::fs::write(&path, text).unwrap();
    let prepare = |gpu: Option<&GpuContext>| {
        let scene = load_scene(path.to_str().unwrap(), None).unwrap();
        let opts = PrepareOptions {
            trace_gpu: gpu,
            shade_on_gpu: true,
            ..PrepareOptions::default()
        };
        PreparedScene::new(scene, &opts, &Silent).unwrap()
    };
    let (cpu, gpu) = (prepare(None), prepare(Some(&ctx)));
    assert!(!gpu.media.is_empty() && gpu.gpu_frame.is_none());
    let why = gpu.media.device().unwrap_err();
    assert_eq!(gpu.gpu_shading_note(), Some(why.0));
    assert!(why.0.contains("media"), "{why}");
    // The light alone has a device side; without a GPU there is no note.
    assert!(gpu.indirect().device().is_ok());
    assert_eq!(cpu.gpu_shading_note(), None);
    let cam = cpu.camera(64, 48);
    let a = cpu.render(&cpu.settings(cam, 1, 1), &Silent).unwrap();
    let b = gpu.render(&gpu.settings(cam, 1, 1), &Silent).unwrap();
    if ctx.is_software() {
        assert!(
            a.pixels == b.pixels,
            "GPU rays, CPU shading: the CPU's frame"
        );
    }
}
