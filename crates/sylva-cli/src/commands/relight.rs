//! `sylva relight SCENE --suns 24`: 004 Table 1's sequence. The sun moves over 90° about the
//! zenith; each frame relights every instance from its model's base solutions (no LB solve)
//! and renders. Numbered PNGs and an animated PNG, tone mapped with one exposure for the
//! whole sequence so frames compare, and the time of every frame. With `--lat --lon --date`
//! the suns are instead the sun's path over that day (`sylva_core::solar`: one frame per
//! `--step`, named by its clock time, the night's left out). Under `mpirun` the missing
//! base solutions are solved across the ranks and every frame is rendered across them
//! (`PreparedScene::render_split`); rank 0 writes the images, the same as one process's.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Result};
use clap::Args;
use sylva_light::relight::sun_path;
use sylva_light::Silent;
use sylva_pipeline::Runner;
use sylva_render::sequence::Sequence;
use sylva_render::{mean_luminance, Mode, ToneMap};

use super::progress::bar;
use super::render::{
    prepare, relight_light, FrameArgs, GridArgs, LbArgs, PrepareRequest, RelightLightArg,
    RelitArgs, RenderLightArgs, SunArgs, ViewArgs, SCENE_HELP,
};
use super::sun_time::SunDayArgs;

/// What `sylva relight` uses: the frame's view, the LB grid and solver, how the bases
/// combine, the global grid and the sequence. The sun moves along its path (`--path-azimuth`),
/// so `--sun`, `--elevation` and `--azimuth` are refused, as is `--basis` (relighting always
/// uses them).
#[derive(Args, Debug)]
pub struct RelightArgs {
    #[arg(default_value = "demo", help = SCENE_HELP)]
    pub scene: String,
    #[command(flatten)]
    pub view: ViewArgs,
    #[command(flatten)]
    pub light: RelightLightArg,
    #[command(flatten)]
    pub lb: LbArgs,
    #[command(flatten)]
    pub relit: RelitArgs,
    #[command(flatten)]
    pub grid: GridArgs,
    /// The sun's path over a day at a place (--lat, --lon, --date, --from, --to, --step,
    /// --utc-offset), in place of 004's sequence.
    #[command(flatten)]
    pub day: SunDayArgs,
    /// Sun positions, evenly spaced over 90° about the zenith (004 Table 1: 24).
    #[arg(long, default_value_t = 24, value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub suns: u32,
    /// Azimuth of the sun's path in degrees (from +x towards +z): the sun rises from 45°
    /// elevation opposite it, passes the zenith and sets to 45° at it. Default: the scene's
    /// sun azimuth.
    #[arg(long, allow_negative_numbers = true)]
    pub path_azimuth: Option<f64>,
    /// Output directory (default sylva-out/relight-<scene>): frame-00.png, … (with --date
    /// frame-HHMM.png by clock time, frame-0530.png) and <scene>.png, the animated PNG.
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Rays per pixel (default: the scene camera's).
    #[arg(long)]
    pub rpp: Option<u32>,
    /// Milliseconds each frame shows in the animation.
    #[arg(long, default_value_t = 125)]
    pub delay_ms: u32,
    /// Reinhard key, for the whole sequence.
    #[arg(long, default_value_t = 0.18)]
    pub key: f32,
    /// Reinhard white point (default: the sequence's brightest pixel).
    #[arg(long)]
    pub white: Option<f32>,
    /// Physical light: final-gather rays per camera sample on a plant, 0 to 256 (0: the LB
    /// light at the leaf itself, several times faster; docs/light.md, "The final gather").
    #[arg(
        long,
        default_value_t = sylva_render::ShadingParams::default().gather_rays,
        allow_negative_numbers = true,
        value_parser = clap::value_parser!(u32).range(0..=i64::from(sylva_render::gather::MAX_GATHER_RAYS))
    )]
    pub gather_rays: u32,
}

impl RelightArgs {
    /// The frame options `prepare` reads: these, with the scene's sun (the path replaces it)
    /// and the paper light's settings.
    fn frame(&self) -> FrameArgs {
        FrameArgs {
            scene: self.scene.clone(),
            view: self.view.clone(),
            sun: SunArgs::default(),
            light: RenderLightArgs {
                light: self.light.light.clone(),
                gather_rays: self.gather_rays,
                ..RenderLightArgs::default()
            },
            lb: self.lb.clone(),
            relit: self.relit.clone(),
            grid: self.grid.clone(),
        }
    }
}

/// `path`, or its nearest ancestor that exists (`.` at the last): where a file under `path`
/// would take its disk space from.
fn nearest_existing(path: &Path) -> PathBuf {
    let mut p = path;
    loop {
        if p.is_dir() {
            return p.to_path_buf();
        }
        match p.parent() {
            Some(d) if !d.as_os_str().is_empty() => p = d,
            _ => return PathBuf::from("."),
        }
    }
}

/// Refuses a sequence whose frames, PNGs and animation would not fit on the disk under `dir`
/// (frames are held there, not in memory, until the sequence's one exposure is known).
fn check_disk(dir: &Path, width: u32, height: u32, frames: usize) -> Result<()> {
    let needed = Sequence::disk_bytes(width, height, frames);
    let at = nearest_existing(dir);
    if let Some(free) = sylva_io::export::available_disk_bytes(&at) {
        if needed + needed / 100 > free {
            bail!(
                "{frames} frames of {width}x{height} need up to {} on disk under {} (the linear \
                 frames held there for the sequence's one exposure, {} each, then the PNGs and \
                 the animation), but only {} is free: ask for fewer --suns or a smaller \
                 --width/--height",
                sylva_core::format_bytes(needed),
                at.display(),
                sylva_core::format_bytes(width as u64 * height as u64 * 12),
                sylva_core::format_bytes(free)
            );
        }
    }
    Ok(())
}

pub fn run(a: RelightArgs, runner: &dyn Runner) -> Result<()> {
    let root = runner.is_root();
    // The physical and the paper light have base solutions: another is refused before the
    // scene loads.
    relight_light(a.light.light.as_deref())?;
    if let Some(r) = a.rpp {
        let range = sylva_core::limits::RAYS_PER_PIXEL;
        if !range.contains(&r) {
            bail!(
                "--rpp {r}: rays per pixel must be {} to {}",
                range.start(),
                range.end()
            );
        }
    }
    if !(1..=65535).contains(&a.delay_ms) {
        bail!("--delay-ms {}: 1 to 65535", a.delay_ms);
    }
    if let Some(az) = a.path_azimuth {
        if !az.is_finite() {
            bail!("--path-azimuth {az}: not a number");
        }
    }
    let tm = ToneMap {
        key: a.key,
        white: a.white,
    };
    tm.validate().map_err(anyhow::Error::msg)?;
    // The day's path, its night left out, before any work (a sun that never rises is an
    // error).
    let day = match a.day.path()? {
        Some(path) => Some((path, path.day()?)),
        None => None,
    };
    if let (Some(dir), true) = (&a.output, root) {
        // A folder that is a file or takes no files fails now, not after the basis solves
        // (the frame names are checked in full below, once the scene is known).
        sylva_core::OutputSet::new::<&std::path::Path>(&[]).plan(&[dir.join("frame-00.png")])?;
    }
    // The disk the sequence needs is checked once the image size is known, before any LB
    // work; memory holds one frame at a time (and the one read back at the end).
    let disk_dir = a
        .output
        .clone()
        .unwrap_or_else(|| PathBuf::from("sylva-out"));
    let frames = day.as_ref().map_or(a.suns as usize, |(_, d)| d.up.len());
    let check = |w: u32, h: u32| {
        if root {
            check_disk(&disk_dir, w, h, frames)
        } else {
            Ok(())
        }
    };
    let p = prepare(
        &a.frame(),
        PrepareRequest {
            need_lb: true,
            rays_per_pixel: a.rpp,
            output_images: 2,
            force_basis: true,
            check_size: Some(&check),
            ..PrepareRequest::default()
        },
        runner,
    )?;
    let mut prepared = p.scene;
    let rpp = a.rpp.unwrap_or(prepared.scene.camera.rays_per_pixel);
    let camera = prepared.camera(p.width, p.height);
    let settings = prepared.settings(camera, rpp, a.view.seed);
    let azimuth = a
        .path_azimuth
        .unwrap_or_else(|| prepared.scene.sun.azimuth_deg());
    // Per frame: the sun, and the file name's label (the clock time on a day's path).
    let (suns, labels): (Vec<_>, Vec<String>) = match &day {
        Some((_, d)) => {
            d.up.iter()
                .map(|s| (s.sun.to_sun().as_vec3(), s.time.compact(d.has_seconds())))
                .unzip()
        }
        None => {
            let suns = sun_path(a.suns as usize, azimuth);
            let labels = (0..suns.len()).map(|k| format!("{k:02}")).collect();
            (suns, labels)
        }
    };
    // The frames and the animation replace their old versions together (or none do), and
    // bad output names fail before the long work.
    let dir = a.output.clone().unwrap_or_else(|| {
        PathBuf::from(format!(
            "sylva-out/relight-{}",
            sylva_core::file_stem(&prepared.scene.name, "scene")
        ))
    });
    let frame_paths: Vec<PathBuf> = labels
        .iter()
        .map(|l| dir.join(format!("frame-{l}.png")))
        .collect();
    let anim = dir.join(format!(
        "{}.png",
        sylva_core::file_stem(&prepared.scene.name, "scene")
    ));
    let mut outputs = sylva_core::OutputSet::new::<&std::path::Path>(&[]);
    // Rank 0 keeps the frames, on disk (an unnamed file the system removes however this
    // ends) until the sequence's exposure is known.
    let mut sequence = None;
    if root {
        outputs.plan(&frame_paths)?;
        outputs.plan(&[&anim])?;
        sequence = Some(Sequence::new(
            &nearest_existing(&dir),
            p.width,
            p.height,
            suns.len(),
            tm,
        )?);
        let path = match &day {
            Some((path, _)) => format!(
                "from {} to {} every {} at {} on {} ({}): the day's path (north -z, east +x)",
                path.from(),
                path.to(),
                path.step(),
                path.place(),
                path.date(),
                path.offset()
            ),
            None => format!("over 90° about the zenith, path azimuth {azimuth:.1}°"),
        };
        println!(
            "{} suns {path}; {}x{} at {rpp} rays/pixel{}",
            suns.len(),
            p.width,
            p.height,
            match runner.processes() {
                1 => String::new(),
                n => format!(", {n} MPI ranks"),
            }
        );
    }
    if let (Some(note), true) = (day.as_ref().and_then(|(_, d)| d.night_note()), root) {
        println!("note: {note}");
    }
    let pb = if root {
        bar(suns.len() as u64, "relight")
    } else {
        indicatif::ProgressBar::hidden()
    };
    let mut times = Vec::with_capacity(suns.len());
    let mut luminance = (0.0, 0.0);
    for (k, &sun) in suns.iter().enumerate() {
        let t0 = Instant::now();
        prepared.set_sun(sun)?;
        let t1 = Instant::now();
        // Every rank relights (cheap) and renders its share; rank 0 gets the frame.
        let Some(frame) = prepared.render_split(runner, &settings, &Silent)? else {
            continue;
        };
        let frame = frame.frame;
        let t2 = Instant::now();
        let (relight, render) = ((t1 - t0).as_secs_f64(), (t2 - t1).as_secs_f64());
        let at = match &day {
            Some((_, d)) => format!(
                " at {}: sun elevation {:5.1}° azimuth {:5.1}° from north",
                d.up[k].time, d.up[k].angles.elevation_deg, d.up[k].angles.azimuth_deg
            ),
            None => format!(
                ": sun elevation {:5.1}° azimuth {:5.1}°",
                sun.y.asin().to_degrees(),
                sun.z.atan2(sun.x).to_degrees().rem_euclid(360.0)
            ),
        };
        pb.suspend(|| {
            println!(
                "  frame {k:2}{at}: {:.3} s (relight {:.4} s, render {:.3} s: primary {:.3}, shadow {:.3}, shading {:.3})",
                relight + render,
                relight,
                render,
                frame.timings.primary_seconds,
                frame.timings.shadow_seconds,
                frame.timings.shading_seconds
            )
        });
        times.push(relight + render);
        let hdr = frame.compose(Mode::Full);
        drop(frame);
        let y = mean_luminance(&hdr);
        if k == 0 {
            luminance.0 = y;
        }
        luminance.1 = y;
        if let Some(s) = sequence.as_mut() {
            s.push(&hdr)?;
        }
        pb.inc(1);
    }
    pb.finish_and_clear();
    let Some(sequence) = sequence else {
        return Ok(());
    };
    sequence.finish(&mut outputs, &frame_paths, &anim, a.delay_ms)?;
    outputs.commit()?;
    let mean = times.iter().sum::<f64>() / times.len() as f64;
    let mut sorted = times.clone();
    sorted.sort_by(f64::total_cmp);
    let name = |p: &PathBuf| {
        p.file_name()
            .unwrap_or_default()
            .to_string_lossy()
            .to_string()
    };
    println!(
        "wrote {} frames ({} … {}) and the animation {} to {}",
        times.len(),
        name(&frame_paths[0]),
        name(&frame_paths[frame_paths.len() - 1]),
        name(&anim),
        dir.display()
    );
    println!(
        "frame time: mean {mean:.3} s, median {:.3} s, min {:.3} s, max {:.3} s; mean luminance first {:.4}, last {:.4}; no LB solve while the sun moves",
        sorted[sorted.len() / 2],
        sorted[0],
        sorted[sorted.len() - 1],
        luminance.0,
        luminance.1
    );
    Ok(())
}
