//! `sylva render [SCENE]`: build the scene, light each model with LB (cached), build the
//! kd-trees, trace and shade, tone map, write PNG (and EXR), and print a per-stage summary.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::Args;
use glam::Vec3;
use sylva_geom::Scene;
use sylva_lb::Preset;
use sylva_render::lighting::{model_lighting, LightingOptions, LightingSource, ModelLighting};
use sylva_render::output::{write_exr, write_png};
use sylva_render::shade::transmission_from_g;
use sylva_render::tonemap::srgb8;
use sylva_render::{Frame, Mode, RenderSettings, Renderer, ShadingParams, ToneMap};
use sylva_trace::{SceneAccel, TraversalConfig};

use super::progress::bar;

/// Options shared by `sylva render` and `sylva bench trace`: what the frame looks like.
#[derive(Args, Debug, Clone)]
pub struct FrameArgs {
    /// Scene file (.toml) or built-in scene name (demo, beech, catalpa, canopy).
    #[arg(default_value = "demo")]
    pub scene: String,
    /// Image width in pixels (default: the scene camera's; with only --width or --height the
    /// other follows the scene's aspect ratio).
    #[arg(long)]
    pub width: Option<u32>,
    /// Image height in pixels (default: the scene camera's).
    #[arg(long)]
    pub height: Option<u32>,
    /// Sun direction (vector towards the sun, x,y,z with y up); default: the scene's sun.
    #[arg(long, conflicts_with_all = ["elevation", "azimuth"])]
    pub sun: Option<String>,
    /// Sun elevation above the horizon in degrees (default 50 when only --azimuth is given).
    #[arg(long)]
    pub elevation: Option<f64>,
    /// Sun azimuth in degrees from +x towards +z (default 30 when only --elevation is given).
    #[arg(long)]
    pub azimuth: Option<f64>,
    /// Short-stack entries of the kd-tree traversal (000 Fig. 1 uses 5).
    #[arg(long, default_value_t = sylva_trace::DEFAULT_STACK_SIZE)]
    pub stack: usize,
    /// Scale of the LB indirect light.
    #[arg(long, default_value_t = ShadingParams::default().indirect)]
    pub indirect: f32,
    /// Sky light on the ground as a fraction of the sun's.
    #[arg(long, default_value_t = ShadingParams::default().sky_ambient)]
    pub sky_ambient: f32,
    /// LB grid sites along each model's longest edge (default: the scene's [lb] grid).
    #[arg(long)]
    pub lb_grid: Option<usize>,
    /// Directory of the LB lighting cache.
    #[arg(long, default_value = "sylva-out/cache")]
    pub cache_dir: PathBuf,
    /// Compute LB lighting without reading or writing the cache.
    #[arg(long)]
    pub no_cache: bool,
    /// Seed of the sub-pixel jitter (rays per pixel other than 1 and 4).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Where the LB lighting is solved: cpu, gpu (the best adapter, a software one such as
    /// lavapipe included) or auto (a hardware GPU if present, else the CPU). Cache entries
    /// are kept per device.
    #[arg(long, value_enum, default_value = "auto")]
    pub device: super::device::DeviceArg,
    /// GPU state storage of the LB solve: f32, or f16 (half the memory traffic).
    #[arg(long, value_enum, default_value = "f32")]
    pub precision: super::device::PrecisionArg,
}

#[derive(Args, Debug)]
pub struct RenderArgs {
    #[command(flatten)]
    pub frame: FrameArgs,
    /// Output PNG (8-bit sRGB, tone mapped). Default: sylva-out/<scene>.png; modes other than
    /// full add -<mode> to the name.
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Also write the linear HDR image as OpenEXR beside the PNG (same name, .exr).
    #[arg(long)]
    pub hdr: bool,
    /// Rays per pixel (1, 4, or any n; averaged). Default: the scene camera's.
    #[arg(long)]
    pub rpp: Option<u32>,
    /// full: sun + LB light; local: sun only; ambient: sun + a constant ambient matching the
    /// full image's mean luminance; lb: the LB light alone; all: the four images (000 Fig. 2),
    /// tone mapped with the full image's exposure.
    #[arg(long, default_value = "full")]
    pub mode: String,
    /// Reinhard key (the log-average luminance maps to it).
    #[arg(long, default_value_t = 0.18)]
    pub key: f32,
    /// Reinhard white point in scaled luminance (default: the image's brightest pixel).
    #[arg(long)]
    pub white: Option<f32>,
}

/// Everything a frame needs, prepared once.
pub struct Prepared {
    pub scene: Scene,
    pub accel: SceneAccel,
    pub lighting: Vec<Option<ModelLighting>>,
    pub to_sun: Vec3,
    pub shading: ShadingParams,
    pub width: u32,
    pub height: u32,
    pub traversal: TraversalConfig,
    /// Seconds: scene build, LB precompute, acceleration build.
    pub scene_seconds: f64,
    pub lb_seconds: f64,
    pub accel_seconds: f64,
    /// Models whose LB light came from the cache.
    pub lb_cached: usize,
}

impl Prepared {
    pub fn renderer(&self) -> Renderer<'_> {
        let sun_colour = Vec3::from_array(sylva_core::blackbody_rgb(sylva_core::SUN_TEMPERATURE_K));
        Renderer::new(
            &self.scene,
            &self.accel,
            &self.lighting,
            self.to_sun,
            sun_colour,
            self.shading.sun_irradiance,
        )
    }

    pub fn settings(&self, rays_per_pixel: u32, seed: u64) -> RenderSettings {
        RenderSettings {
            width: self.width,
            height: self.height,
            rays_per_pixel,
            seed,
            traversal: self.traversal,
            shading: self.shading,
        }
    }

    pub fn lighting_bytes(&self) -> u64 {
        self.lighting
            .iter()
            .flatten()
            .map(ModelLighting::memory_bytes)
            .sum()
    }
}

fn resolution(a: &FrameArgs, scene: &Scene) -> Result<(u32, u32)> {
    let (w0, h0) = (scene.camera.width as f64, scene.camera.height as f64);
    let (w, h) = match (a.width, a.height) {
        (Some(w), Some(h)) => (w, h),
        (Some(w), None) => (w, ((w as f64 * h0 / w0).round() as u32).max(1)),
        (None, Some(h)) => (((h as f64 * w0 / h0).round() as u32).max(1), h),
        (None, None) => (scene.camera.width, scene.camera.height),
    };
    if w == 0 || h == 0 || w > 32768 || h > 32768 {
        bail!("resolution {w}x{h}: width and height must be 1 to 32768");
    }
    Ok((w, h))
}

/// Builds the scene and its kd-trees and lights every model (from the cache when it can).
/// `rays_per_pixel`: the most a frame will use (default: the scene camera's); the frame's
/// memory is checked for it before any LB or kd-tree work.
pub fn prepare(
    a: &FrameArgs,
    need_lb: bool,
    rays_per_pixel: Option<u32>,
    to_stdout: bool,
) -> Result<Prepared> {
    // Machine-readable runs keep stdout for their JSON.
    let say = |s: String| {
        if to_stdout {
            println!("{s}")
        } else {
            eprintln!("{s}")
        }
    };
    let t0 = Instant::now();
    let mut scene = sylva_scene::load(&a.scene)?;
    if a.sun.is_some() || a.elevation.is_some() || a.azimuth.is_some() {
        scene.sun = super::lb::parse_sun(a.sun.as_deref(), a.elevation, a.azimuth)?;
    }
    if !(1..=sylva_trace::MAX_DEPTH).contains(&a.stack) {
        bail!(
            "--stack {}: the short stack holds 1 to {} entries",
            a.stack,
            sylva_trace::MAX_DEPTH
        );
    }
    let scene_seconds = t0.elapsed().as_secs_f64();
    let (width, height) = resolution(a, &scene)?;
    let rays_per_pixel = rays_per_pixel.unwrap_or(scene.camera.rays_per_pixel);
    sylva_core::check_memory(
        &format!("a {width}x{height} frame at {rays_per_pixel} rays/pixel"),
        sylva_render::render::memory_needed(width, height, rays_per_pixel),
    )?;
    let s = scene.sun.to_sun();
    let to_sun = Vec3::new(s.x as f32, s.y as f32, s.z as f32);
    let preset = Preset::parse(&scene.lb.preset)
        .with_context(|| format!("scene {}: [lb] preset", scene.name))?;
    let g = preset.params().colours.map(|c| c.g as f32);
    let shading = ShadingParams {
        indirect: a.indirect,
        sky_ambient: a.sky_ambient,
        leaf_transmission: transmission_from_g(g),
        ..ShadingParams::default()
    };
    shading.validate().map_err(anyhow::Error::msg)?;
    say(format!(
        "scene {}: {} models, {} instances, {} instanced triangles; {width}x{height}; sun elevation {:.1}° azimuth {:.1}°",
        scene.name,
        scene.models.len(),
        scene.instances.len(),
        scene.instanced_triangles(),
        scene.sun.elevation_deg(),
        scene.sun.azimuth_deg()
    ));

    // LB lighting per model: computed once per model and sun, then cached.
    let t1 = Instant::now();
    let mut lighting = Vec::with_capacity(scene.models.len());
    let mut lb_cached = 0;
    if need_lb {
        let solver = super::device::open_solver(a.device, a.precision)?;
        say(format!("LB solver: {}", solver.describe()));
        let opts = LightingOptions {
            grid: a.lb_grid.unwrap_or(scene.lb.grid as usize),
            preset: scene.lb.preset.clone(),
            cache_dir: (!a.no_cache).then(|| a.cache_dir.clone()),
        };
        for model in &scene.models {
            let pb = bar(3, &format!("LB {}", model.name));
            let (l, report) =
                model_lighting(model, to_sun, &opts, &*solver, &mut |c, step, max| {
                    pb.set_length(3 * max as u64);
                    pb.set_position((c * max + step) as u64);
                })
                .with_context(|| format!("LB lighting of model '{}'", model.name))?;
            pb.finish_and_clear();
            match &report.source {
                LightingSource::Cached => {
                    lb_cached += 1;
                    say(format!(
                        "  LB {}: {} grid from cache ({:.2} s)",
                        model.name, report.dims, report.seconds
                    ))
                }
                LightingSource::Computed => say(format!(
                    "  LB {}: {} grid solved in {:.1} s{}",
                    model.name,
                    report.dims,
                    report.seconds,
                    report
                        .path
                        .as_ref()
                        .map(|p| format!(", cached as {}", p.display()))
                        .unwrap_or_default()
                )),
                LightingSource::Recomputed { reason } => {
                    eprintln!("warning: {reason}; recomputed");
                    say(format!(
                        "  LB {}: {} grid solved again in {:.1} s",
                        model.name, report.dims, report.seconds
                    ))
                }
            }
            lighting.push(Some(l));
        }
    } else {
        lighting.resize_with(scene.models.len(), || None);
    }
    let lb_seconds = t1.elapsed().as_secs_f64();

    let t2 = Instant::now();
    let accel = SceneAccel::build(&scene)?;
    let accel_seconds = t2.elapsed().as_secs_f64();
    Ok(Prepared {
        scene,
        accel,
        lighting,
        to_sun,
        shading,
        width,
        height,
        traversal: TraversalConfig::with_stack(a.stack),
        scene_seconds,
        lb_seconds,
        accel_seconds,
        lb_cached,
    })
}

/// Renders one frame with a progress bar.
pub fn render_frame(p: &Prepared, rays_per_pixel: u32, seed: u64) -> Result<Frame> {
    let tiles = sylva_render::render::tile_count(p.width, p.height);
    let pb = bar(3 * tiles, "render");
    let frame = p
        .renderer()
        .render(&p.settings(rays_per_pixel, seed), &|n| pb.inc(n))?;
    pb.finish_and_clear();
    Ok(frame)
}

/// `out.png` → `out-<mode>.png` for modes other than full.
fn mode_path(base: &Path, mode: Mode, several: bool) -> PathBuf {
    if mode == Mode::Full && !several {
        return base.to_path_buf();
    }
    let stem = base.file_stem().unwrap_or_default().to_string_lossy();
    let ext = base
        .extension()
        .map(|e| e.to_string_lossy().into_owned())
        .unwrap_or_else(|| "png".into());
    base.with_file_name(format!("{stem}-{}.{ext}", mode.name()))
}

pub fn run(a: RenderArgs) -> Result<()> {
    let modes: Vec<Mode> = match a.mode.as_str() {
        "all" => Mode::ALL.to_vec(),
        m => vec![Mode::parse(m)
            .with_context(|| format!("--mode '{m}': expected full, local, ambient, lb or all"))?],
    };
    let tm = ToneMap {
        key: a.key,
        white: a.white,
    };
    tm.validate().map_err(anyhow::Error::msg)?;
    if let Some(o) = &a.output {
        let ext = o.extension().map(|e| e.to_ascii_lowercase());
        if ext.as_deref() != Some(std::ffi::OsStr::new("png")) {
            bail!(
                "{}: the output is a PNG file (name it .png; --hdr adds an .exr beside it)",
                o.display()
            );
        }
    }
    if let Some(r) = a.rpp {
        if !(1..=1024).contains(&r) {
            bail!("--rpp {r}: rays per pixel must be 1 to 1024");
        }
    }
    let t_all = Instant::now();
    let p = prepare(&a.frame, modes.iter().any(|m| m.needs_lb()), a.rpp, true)?;
    let rpp = a.rpp.unwrap_or(p.scene.camera.rays_per_pixel);
    let frame = render_frame(&p, rpp, a.frame.seed)?;

    let t3 = Instant::now();
    let base = a.output.clone().unwrap_or_else(|| {
        PathBuf::from(format!(
            "sylva-out/{}.png",
            sylva_core::file_stem(&p.scene.name, "scene")
        ))
    });
    // Several modes share the full image's exposure so they compare.
    let full = frame.compose(Mode::Full);
    let exposure = tm.measure(&full);
    let mut images = Vec::new();
    for &mode in &modes {
        let hdr = if mode == Mode::Full {
            full.clone()
        } else {
            frame.compose(mode)
        };
        let stats = if modes.len() > 1 {
            exposure
        } else {
            tm.measure(&hdr)
        };
        let ldr: Vec<[u8; 3]> = tm.apply_with(&hdr, stats).into_iter().map(srgb8).collect();
        images.push((mode, hdr, ldr));
    }
    let tone_seconds = t3.elapsed().as_secs_f64();
    let t4 = Instant::now();
    for (mode, hdr, ldr) in &images {
        let path = mode_path(&base, *mode, modes.len() > 1);
        write_png(&path, frame.width, frame.height, ldr)?;
        let mut wrote = path.display().to_string();
        if a.hdr {
            let exr = path.with_extension("exr");
            write_exr(&exr, frame.width, frame.height, hdr)?;
            wrote = format!("{wrote} and {}", exr.display());
        }
        println!(
            "wrote {wrote} ({} mode, mean luminance {:.4}{})",
            mode.name(),
            sylva_render::mean_luminance(hdr),
            if *mode == Mode::Ambient {
                format!(", ambient {:.4}", frame.matched_ambient())
            } else {
                String::new()
            }
        );
    }
    let write_seconds = t4.elapsed().as_secs_f64();
    let t = &frame.timings;
    let mem = p.accel.memory();
    println!("stage                 seconds");
    for (stage, s) in [
        ("scene build", p.scene_seconds),
        ("LB precompute", p.lb_seconds),
        ("acceleration build", p.accel_seconds),
        ("primary rays", t.primary_seconds),
        ("shadow rays", t.shadow_seconds),
        ("shading", t.shading_seconds),
        ("tone mapping", tone_seconds),
        ("image output", write_seconds),
    ] {
        println!("  {stage:<20}{s:>8.3}");
    }
    println!("  {:<20}{:>8.3}", "total", t_all.elapsed().as_secs_f64());
    println!(
        "{}x{} at {rpp} rays/pixel: {} primary + {} shadow rays, {:.2} Mrays/s; frame {:.3} s; {} kd-restarts; kd-trees {}, LB grids {}",
        frame.width,
        frame.height,
        t.primary_rays,
        t.shadow_rays,
        t.mrays_per_second(),
        t.frame_seconds(),
        frame.stats.restarts,
        sylva_core::format_bytes(mem.total()),
        sylva_core::format_bytes(p.lighting_bytes()),
    );
    Ok(())
}
